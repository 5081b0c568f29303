"""Light sources (docs/method.md §4.1, paper 3-3-1). Every intensity is an RGB triple.

Each light answers one question for a batch of shading points ``p`` (N, 3)::

    wi, dist, L = light.illuminate(p)

``wi`` is the unit direction from ``p`` toward the light, ``dist`` the length of the shadow
ray (``inf`` for a parallel light; the base plane for the cylinder spotlight) and ``L`` the
strength ``L_s`` arriving at ``p`` (zero where the light does not reach).

Lights with extent (Mitsuba ``area`` emitters, ``constant`` and ``envmap`` environments) are
*sampled*: ``sample(p, n, u, v) -> (wi, dist, Lw)`` takes a point ``(u, v)`` in [0, 1)² (from
:func:`links1.maths.sampling.light_samples_uv`) and ``n`` the shading normal facing the viewer, and
returns the direction and distance to the sampled light point and ``Lw = L_e / pdf`` (pdf in
solid angle at ``p``), so that ``material.eval(wo, wi) · Lw`` estimates the light's direct
term; averaged over samples this converges to Mitsuba's ``direct`` for diffuse surfaces.
Each has ``light_id`` (the stream tag, see :func:`links1.maths.sampling.light_tag`): for an
area light its rank by place (:func:`number_area_lights`), whatever order the shapes were loaded in.

For multiple importance sampling with BSDF samples, ``sample_pdf(p, n, u, v)`` returns the
same and the pdf as a fourth value, and ``pdf(p, n, wi, dist, ng)`` gives the solid-angle
density with which ``sample`` draws ``wi`` from ``p`` (``dist`` and ``ng``: where ``wi`` meets
an area light and its geometric normal there; environments need neither).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..maths.vec import coordinate_system, cross, dot, length, matvec
from .textures import is_texture
from ..geometry.shapes import Disk, Quadric, TriangleMesh

FALLOFFS = ("none", "inverse_square")

#: ``light_id`` of the first environment (constant / envmap); the k-th adds k.
ENV_LIGHT_ID = 0x40000000


def _rgb(v) -> np.ndarray:
    return np.broadcast_to(np.asarray(v, dtype=np.float64), (3,)).copy()


def _unit(v, what: str) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v)
    if not (np.isfinite(n) and n > 0):
        raise ValueError(f"{what} must be a finite non-zero vector, got {v.tolist()}")
    return v / n


class Light:
    """Interface: ``illuminate(p) -> (wi, dist, L)``."""

    name: str = ""

    def illuminate(self, p: np.ndarray):  # pragma: no cover - interface
        raise NotImplementedError


@dataclass
class ParallelLight(Light):
    """The paper's parallel light; Mitsuba's ``directional`` emitter.

    ``direction`` is the direction the light travels; ``irradiance`` its strength (RGB).
    """

    direction: np.ndarray
    irradiance: np.ndarray
    name: str = ""

    def __post_init__(self):
        self.direction = _unit(self.direction, "directional: direction")
        self.irradiance = _rgb(self.irradiance)

    def illuminate(self, p):
        n = p.shape[0]
        wi = np.broadcast_to(-self.direction, (n, 3))
        return wi, np.full(n, np.inf), np.broadcast_to(self.irradiance, (n, 3))


@dataclass
class PointLight(Light):
    """The paper's point light with a cosine lobe, eq. (3.10).

    ``L_s = L1 + L2 cos θ`` for ``|θ| ≤ 90°`` and ``L1`` beyond, θ measured from
    ``direction`` (the direction of maximum strength). With ``L2 = 0`` and
    ``falloff='inverse_square'`` this is Mitsuba's isotropic ``point`` emitter (``L1`` = intensity).
    """

    position: np.ndarray
    direction: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    L1: np.ndarray = field(default_factory=lambda: np.ones(3))
    L2: np.ndarray = field(default_factory=lambda: np.zeros(3))
    falloff: str = "none"
    name: str = ""

    def __post_init__(self):
        self.position = np.asarray(self.position, dtype=np.float64).reshape(3)
        self.direction = _unit(self.direction, "links1_point: direction")
        self.L1 = _rgb(self.L1)
        self.L2 = _rgb(self.L2)
        if self.falloff not in FALLOFFS:
            raise ValueError(f"falloff must be one of {FALLOFFS}, got {self.falloff!r}")

    def illuminate(self, p):
        to_light = self.position - p
        dist = length(to_light)
        with np.errstate(invalid="ignore", divide="ignore"):
            wi = to_light / np.where(dist > 0, dist, 1.0)[:, None]
        cos_theta = -dot(wi, self.direction)  # angle from the lobe axis to the shaded point
        lobe = np.where(cos_theta[:, None] >= 0.0, cos_theta[:, None], 0.0)
        L = self.L1 + self.L2 * lobe  # eq. (3.10)
        if self.falloff == "inverse_square":
            with np.errstate(divide="ignore"):
                L = L / np.where(dist > 0, dist * dist, np.inf)[:, None]
        return wi, dist, L


@dataclass
class CylinderSpotLight(Light):
    """The paper's spotlight: parallel light inside a semi-infinite cylinder (3-3-1 iii).

    ``origin`` is the centre of the base disc, ``direction`` the direction the light travels,
    ``radius`` the cylinder's radius. Points behind the base plane or farther than ``radius``
    from the axis are unlit; shadow rays end at the base plane.
    """

    origin: np.ndarray
    direction: np.ndarray
    radius: float
    intensity: np.ndarray
    name: str = ""

    def __post_init__(self):
        self.origin = np.asarray(self.origin, dtype=np.float64).reshape(3)
        self.direction = _unit(self.direction, "links1_spot: direction")
        self.radius = float(self.radius)
        if not (np.isfinite(self.radius) and self.radius > 0):
            raise ValueError(f"links1_spot: radius must be > 0, got {self.radius}")
        self.intensity = _rgb(self.intensity)

    def illuminate(self, p):
        rel = p - self.origin
        s = dot(rel, self.direction)  # distance in front of the base plane
        radial = rel - s[:, None] * self.direction
        rho2 = dot(radial, radial)
        inside = (s > 0.0) & (rho2 <= self.radius * self.radius)
        n = p.shape[0]
        wi = np.broadcast_to(-self.direction, (n, 3))
        L = np.where(inside[:, None], self.intensity, 0.0)
        return wi, np.where(inside, s, 0.0), L


@dataclass
class ConeSpotLight(Light):
    """Mitsuba's ``spot`` emitter: a cone with a linear fall-off between ``beam_width`` and
    ``cutoff_angle`` (degrees), inverse-square distance fall-off. With a ``texture``
    (:class:`links1.shading.textures.Texture`) it is a projector, as Mitsuba's: the intensity is
    scaled by the texture at ``uv = 1/2 + (x, y) / (2 z tan(cutoff))``, ``(x, y, z)`` the
    direction from the light to the point in the light's frame."""

    to_world: np.ndarray
    intensity: np.ndarray
    cutoff_angle: float = 20.0
    beam_width: float | None = None
    name: str = ""
    texture: object = None

    def __post_init__(self):
        self.intensity = _rgb(self.intensity)
        if self.beam_width is None:
            self.beam_width = self.cutoff_angle * 3.0 / 4.0
        self.position = self.to_world[:3, 3].copy()
        self.axis = _unit(self.to_world[:3, 2], "spot: to_world z axis")
        self.cutoff = np.deg2rad(self.cutoff_angle)
        self.beam = np.deg2rad(self.beam_width)
        self._from_world = np.linalg.inv(self.to_world)   # the projector's frame (texture lookups)

    def illuminate(self, p):
        to_light = self.position - p
        dist = length(to_light)
        with np.errstate(invalid="ignore", divide="ignore"):
            wi = to_light / np.where(dist > 0, dist, 1.0)[:, None]
        cos_theta = -dot(wi, self.axis)
        theta = np.arccos(np.clip(cos_theta, -1.0, 1.0))
        ramp = np.where(cos_theta >= np.cos(self.beam), 1.0,
                        (self.cutoff - theta) / max(self.cutoff - self.beam, 1e-300))
        ramp = np.where(cos_theta > np.cos(self.cutoff), ramp, 0.0)
        with np.errstate(divide="ignore"):
            L = self.intensity * (ramp / np.where(dist > 0, dist * dist, np.inf))[:, None]
        if self.texture is not None:
            lit = ramp > 0   # Mitsuba looks the texture up only inside the cone
            local = matvec(self._from_world, -wi[lit])
            k = 0.5 / (local[:, 2] * np.tan(self.cutoff))
            uv = np.stack([0.5 + local[:, 0] * k, 0.5 + local[:, 1] * k], axis=1)
            tex = np.zeros_like(L)
            tex[lit] = self.texture.eval(uv)
            L = L * tex
        return wi, dist, L


@dataclass
class ProjectorLight(Light):
    """Mitsuba's ``projector`` emitter: a point light at the origin of ``to_world`` projecting
    the ``irradiance`` image (a :class:`links1.shading.textures.Texture` or an RGB constant)
    through a perspective frustum of horizontal field of view ``x_fov`` (degrees) and the
    image's aspect ratio, along the frame's +z, as Mitsuba's ``Projector::sample_direction``:
    a point at ``(x, y, z)`` in the light's frame (``z > 0``) takes the image at

        ``uv = (1/2 - x / (2 z tan(x_fov/2)), 1/2 - aspect · y / (2 z tan(x_fov/2)))``

    (the perspective camera's film position, row 0 at the top; nothing outside [0, 1]²) and
    receives ``π · scale · irradiance(uv) / (z² cos θ)``, ``θ`` between the light's axis and
    the direction to the point: the irradiance on the plane ``z = 1`` facing the light is the
    image's."""

    to_world: np.ndarray
    irradiance: object
    x_fov: float
    aspect: float = 1.0
    scale: float = 1.0
    name: str = ""

    def __post_init__(self):
        self.to_world = np.asarray(self.to_world, dtype=np.float64)
        if not callable(getattr(self.irradiance, "eval", None)):
            self.irradiance = _rgb(self.irradiance)
        self.position = self.to_world[:3, 3].copy()
        self.axis = self.to_world[:3, 2].copy()   # as Mitsuba: to_world · (0, 0, 1), unnormalised
        self._from_world = np.linalg.inv(self.to_world)
        self._tan = float(np.tan(np.deg2rad(self.x_fov) / 2.0))

    def illuminate(self, p):
        to_light = self.position - p
        dist = length(to_light)
        with np.errstate(invalid="ignore", divide="ignore"):
            wi = to_light / np.where(dist > 0, dist, 1.0)[:, None]
        local = matvec(self._from_world, p) + self._from_world[:3, 3]
        z = local[:, 2]
        with np.errstate(invalid="ignore", divide="ignore"):
            k = 0.5 / (z * self._tan)
            u = 0.5 - local[:, 0] * k
            v = 0.5 - self.aspect * local[:, 1] * k
            lit = (z > 0) & (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)
            falloff = np.where(lit, np.pi * self.scale / (z * z * -dot(self.axis, wi)), 0.0)
        L = np.zeros((p.shape[0], 3))
        if isinstance(self.irradiance, np.ndarray):
            L[lit] = self.irradiance
        else:
            L[lit] = self.irradiance.eval(np.stack([u[lit], v[lit]], axis=1))
        return wi, dist, L * falloff[:, None]


# ------------------------------------------------------------------------ sampled lights
class SampledLight(Light):
    """A light sampled at points ``(u, v)`` (module docstring)."""

    light_id: int = 0
    sampled = True

    def sample(self, p, n, u, v):
        """``(wi, dist, L_e / pdf)`` of the light points ``(u, v)`` (module docstring)."""
        return self.sample_pdf(p, n, u, v)[:3]

    def sample_pdf(self, p, n, u, v):  # pragma: no cover - interface
        """:meth:`sample` and the solid-angle pdf (N,) of each direction (0: no sample)."""
        raise NotImplementedError

    def pdf(self, p, n, wi, dist=None, ng=None):  # pragma: no cover - interface
        raise NotImplementedError


def number_area_lights(lights) -> list[int]:
    """Give the area lights among ``lights`` their ``light_id`` (the tag of their sample streams,
    :func:`links1.maths.sampling.light_tag`) by where they are, so that every loader of a scene
    gives the same light the same samples: the core's reader (shapes in file order), Mitsuba's
    ``mi.load_file`` (which orders its shapes by kind) and ``links1_mitsuba.load_file`` alike.

    The lights are sorted by their :meth:`AreaLight.place` (centroid, size, normal), each
    rounded to a grid of ``1e-4`` of the lights' extent (centroid and size) or ``1e-4`` (normal),
    so the float32 and float64 copies of one light sort alike; lights on the same grid point keep
    the order given. ``light_id`` is the rank; returns the indices of the area lights (into
    ``lights``) in that order."""
    idx = [i for i, light in enumerate(lights) if isinstance(light, AreaLight)]
    places = [lights[i].place() for i in idx]
    extent = max((float(np.abs(c).max()) + size for c, size, _ in places), default=0.0)
    grid = 1e-4 * extent if extent > 0 else 1.0

    def key(k):
        c, size, n = places[k]
        return (*np.rint(c / grid).astype(np.int64).tolist(), int(np.rint(size / grid)),
                *np.rint(n * 1e4).astype(np.int64).tolist(), k)

    order = sorted(range(len(idx)), key=key)
    for rank, k in enumerate(order):
        lights[idx[k]].light_id = rank
    return [idx[k] for k in order]


def _inverse(w):
    """``1 / w`` where ``w > 0``, else 0 (the pdf of a sample of weight ``w = 1 / pdf``)."""
    return np.where(w > 0, 1.0 / np.where(w > 0, w, 1.0), 0.0)


def _uniform_triangle(u, v):
    """Barycentrics (b0, b1, b2) of the uniform point ``(u, v)`` on a triangle (sqrt warp)."""
    su = np.sqrt(u)
    b0 = 1.0 - su
    b1 = v * su
    return b0, b1, 1.0 - b0 - b1


class AreaLight(SampledLight):
    """Mitsuba's ``area`` emitter on a shape: radiance ``L_e`` leaving the front side (the side
    its outward normal points to), one-sided as Mitsuba's. ``L_e`` may be a texture
    (:mod:`links1.shading.textures`), evaluated at the sampled point's uv: the estimate stays
    unbiased (Mitsuba samples the texture instead; both converge to the same image).

    Sampling by shape: a triangle mesh (obj, ply, rectangle, cube) picks a triangle by the
    area CDF with ``u`` (remapped to [0, 1) inside the chosen triangle) then a uniform point
    (``b0 = 1 - sqrt(u')``, ``b1 = v sqrt(u')``); a sphere samples the cone it subtends at ``p``
    (``cos θ = (1 - u) + u cos θ_max``, ``φ = 2π v`` about the axis toward the centre in
    :func:`links1.maths.vec.coordinate_system`; nothing from inside); a disk a uniform point
    (``r = sqrt(u)``, ``φ = 2π v``). The triangle and the disk convert the area pdf to solid
    angle with ``d² / cos θ_light``.
    """

    def __init__(self, shape, radiance, name: str = ""):
        self.shape = shape
        #: a ``bitmap`` / ``checkerboard`` radiance, evaluated at the sampled point's uv (the
        #: shape's own parameterisation, as where a ray hits it); ``radiance`` is then None
        self.texture = radiance if is_texture(radiance) else None
        self.radiance = None if self.texture is not None else _rgb(radiance)
        self.name = name or getattr(shape, "name", "")
        self.light_id = 0   # numbered by place among the scene's area lights: number_area_lights
        if isinstance(shape, TriangleMesh):
            self.kind = "mesh"
            v, f = shape.vertices, shape.faces
            if getattr(shape, "normals", None) is not None:
                # Mitsuba emits on the side of a mesh's shading normals where it has them
                # (mesh.cpp sample_position): a face wound against them (a mirroring to_world
                # turns the winding, not the normals) is turned back, as the loader turns it
                f = np.where((dot(cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]),
                                  shape.normals[f].sum(axis=1)) < 0)[:, None], f[:, [0, 2, 1]], f)
            self.v0, self.v1, self.v2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
            cr = cross(self.v1 - self.v0, self.v2 - self.v0)
            dbl = length(cr)
            self.normals = cr / np.where(dbl > 0, dbl, 1.0)[:, None]
            area = 0.5 * dbl
            self.area = float(np.sum(area))
            if not self.area > 0:
                raise ValueError(f"area emitter on {self.name!r}: the mesh has no area")
            self.cdf = np.cumsum(area) / self.area
            self.cdf[-1] = 1.0
        elif isinstance(shape, Quadric) and shape.kind == "sphere" and not shape.clips:
            lin = shape.to_world[:3, :3]
            r = np.linalg.norm(lin, axis=0)
            if not np.allclose(lin.T @ lin, np.diag(r * r), rtol=1e-9, atol=1e-12 * r.max() ** 2) or \
                    not np.allclose(r, r[0], rtol=1e-9):
                raise ValueError(f"area emitter on {self.name!r}: only round spheres can be sampled")
            self.kind = "sphere"
            self.center = shape.m.copy()
            self.r = float(r[0])
        elif isinstance(shape, Disk):
            self.kind = "disk"
            self.m = shape.to_world.copy()
            self.normal = shape._normal.copy()
            self.area = float(np.pi * np.linalg.norm(np.cross(self.m[:3, 0], self.m[:3, 1])))
        else:
            raise ValueError(f"area emitter on {self.name!r}: the core cannot sample a "
                             f"{type(shape).__name__} (mesh, rectangle, cube, sphere, disk)")

    def bounds(self):
        return self.shape.bounds()

    def place(self):
        """Where the light is, independent of how it was loaded: ``(centre, size, normal)``, its
        area-weighted centroid, the square root of its area and its area-weighted mean normal
        (zero for a closed shape). :func:`number_area_lights` orders lights by it."""
        if self.kind == "mesh":
            cr = cross(self.v1 - self.v0, self.v2 - self.v0)
            a = 0.5 * length(cr)
            centre = ((self.v0 + self.v1 + self.v2) * a[:, None]).sum(axis=0) / (3.0 * a.sum())
            n, area = cr.sum(axis=0), self.area
        elif self.kind == "sphere":
            centre, n, area = np.asarray(self.center, dtype=np.float64), np.zeros(3), 4.0 * np.pi * self.r ** 2
        else:
            centre, n, area = self.m[:3, 3], self.normal, self.area
        ln = float(np.linalg.norm(n))
        return np.asarray(centre, dtype=np.float64), float(np.sqrt(area)), (n / ln if ln > 1e-12 * area else np.zeros(3))

    def illuminate(self, p):  # pragma: no cover - sampled lights use sample()
        raise TypeError("an area light is sampled: use sample()")

    def sample_pdf(self, p, n, u, v):
        if self.kind == "sphere":
            return self._sample_sphere(p, u, v)
        if self.kind == "mesh":
            k = np.minimum(np.searchsorted(self.cdf, u, side="right"), len(self.cdf) - 1)
            lo = np.where(k > 0, self.cdf[np.maximum(k - 1, 0)], 0.0)
            u2 = np.clip((u - lo) / np.maximum(self.cdf[k] - lo, 1e-300), 0.0, 1.0)
            b0, b1, b2 = _uniform_triangle(u2, v)
            q = self.v0[k] * b0[:, None] + self.v1[k] * b1[:, None] + self.v2[k] * b2[:, None]
            nl = self.normals[k]
            if self.texture is not None:
                uv = self.shape.uv_at(np.stack([b0, b1, b2], axis=1), k)
        else:  # disk
            r = np.sqrt(u)
            phi = 2.0 * np.pi * v
            local = np.stack([r * np.cos(phi), r * np.sin(phi), np.zeros_like(r)], axis=-1)
            q = matvec(self.m, local) + self.m[:3, 3]
            nl = np.broadcast_to(self.normal, q.shape)
            if self.texture is not None:
                uv = self.shape.uv(q, np.zeros_like(q), np.zeros(len(q)), np.zeros(len(q), dtype=np.int64))
        to = q - p
        d2 = dot(to, to)
        dist = np.sqrt(d2)
        with np.errstate(invalid="ignore", divide="ignore"):
            wi = to / np.where(dist > 0, dist, 1.0)[:, None]
            cos_l = -dot(nl, wi)
            w = np.where((cos_l > 0) & (d2 > 0), self.area * cos_l / np.where(d2 > 0, d2, 1.0), 0.0)
        return wi, dist, self._emitted(uv if self.texture is not None else None) * w[:, None], _inverse(w)

    def pdf(self, p, n, wi, dist=None, ng=None):
        """The solid-angle pdf with which :meth:`sample` draws ``wi`` from ``p``, where ``wi``
        meets the light at distance ``dist`` with geometric normal ``ng``: a sphere's cone,
        ``1 / (2π (1 - cos θ_max))`` (0 from inside); a mesh or disk, uniform in area,
        ``d² / (A |cos θ_light|)``."""
        if self.kind == "sphere":
            to_c = self.center - p
            dc2 = dot(to_c, to_c)
            outside = dc2 > self.r * self.r
            sin2_max = np.minimum(self.r * self.r / np.where(outside, dc2, 1.0), 1.0)
            one_minus = sin2_max / (1.0 + np.sqrt(1.0 - sin2_max))
            return np.where(outside, _inverse(2.0 * np.pi * one_minus), 0.0)
        cos_l = np.abs(dot(ng, wi))
        return np.where(cos_l > 0, dist * dist / (self.area * np.where(cos_l > 0, cos_l, 1.0)), 0.0)

    def _emitted(self, uv):
        """``L_e`` (3,) or, textured, at the sampled points' ``uv`` (N, 3)."""
        return self.radiance if self.texture is None else self.texture.eval(uv)

    def _sample_sphere(self, p, u, v):
        to_c = self.center - p
        dc2 = dot(to_c, to_c)
        dc = np.sqrt(dc2)
        outside = dc > self.r
        axis = to_c / np.where(dc > 0, dc, 1.0)[:, None]
        sin2_max = np.minimum(self.r * self.r / np.where(outside, dc2, 1.0), 1.0)
        cos_max = np.sqrt(1.0 - sin2_max)
        one_minus = sin2_max / (1.0 + cos_max)          # 1 - cos θ_max without cancellation
        cos_t = 1.0 - u * one_minus
        sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
        phi = 2.0 * np.pi * v
        s, t = coordinate_system(axis)
        wi = (s * (sin_t * np.cos(phi))[:, None] + t * (sin_t * np.sin(phi))[:, None]
              + axis * cos_t[:, None])
        # nearest intersection with the sphere along wi
        dist = dc * cos_t - np.sqrt(np.maximum(0.0, self.r * self.r - dc2 * sin_t * sin_t))
        w = np.where(outside, 2.0 * np.pi * one_minus, 0.0)
        uv = None
        if self.texture is not None:
            q = p + wi * dist[:, None]
            uv = self.shape.uv(q, np.zeros_like(q), np.zeros(len(q)), np.zeros(len(q), dtype=np.int64))
        return wi, np.where(outside, dist, 0.0), self._emitted(uv) * w[:, None], _inverse(w)


class ConstantEnvironment(SampledLight):
    """Mitsuba's ``constant`` emitter: radiance ``L`` from every direction. Sampled
    cosine-weighted about ``n`` (``r = sqrt(u)``, ``φ = 2π v``, ``z = sqrt(1 - u)``, pdf ``z/π``):
    an unshadowed diffuse surface of albedo ρ gets exactly ``ρ L``."""

    def __init__(self, radiance, light_id: int = ENV_LIGHT_ID, name: str = ""):
        self.radiance = _rgb(radiance)
        self.light_id = light_id
        self.name = name

    def eval(self, d):
        return np.broadcast_to(self.radiance, d.shape).copy()

    def illuminate(self, p):  # pragma: no cover - sampled lights use sample()
        raise TypeError("an environment is sampled: use sample()")

    def sample_pdf(self, p, n, u, v):
        r = np.sqrt(u)
        phi = 2.0 * np.pi * v
        z = np.sqrt(np.maximum(0.0, 1.0 - u))
        s, t = coordinate_system(n)
        wi = s * (r * np.cos(phi))[:, None] + t * (r * np.sin(phi))[:, None] + n * z[:, None]
        with np.errstate(divide="ignore"):
            w = np.where(z > 0, np.pi / np.where(z > 0, z, 1.0), 0.0)
        return wi, np.full(p.shape[0], np.inf), self.radiance * w[:, None], z / np.pi

    def pdf(self, p, n, wi, dist=None, ng=None):
        """``cos θ / π`` about ``n`` (0 below it)."""
        return np.maximum(dot(n, wi), 0.0) / np.pi


class EnvironmentMap(SampledLight):
    """Mitsuba's ``envmap``: a latitude-longitude image ``data`` (H, W, 3), linear RGB, in
    Mitsuba's conventions: local direction ``(sin φ sin θ, cos θ, -cos φ sin θ)`` for
    ``u = φ/2π``, ``v = θ/π``; nodes at ``u = (x + 0.5)/W`` (x wraps), ``v = y/(H - 1)``, bilinear
    between them; ``to_world`` rotates it, ``scale`` multiplies it.

    Sampled by cells (the W x (H-1) squares between nodes): a cell is picked with probability
    proportional to the largest luminance of its four nodes times ``sin θ`` at its centre
    (row by the marginal CDF with ``v``, column by the row's CDF with ``u``, both remapped into
    the cell), uniform inside it; pdf in solid angle ``p_cell W (H-1) / (2π² sin θ)``.
    """

    def __init__(self, data, to_world=None, scale: float = 1.0, light_id: int = ENV_LIGHT_ID,
                 name: str = ""):
        data = np.asarray(data, dtype=np.float64)
        if data.ndim == 2:
            data = data[:, :, None]
        if data.shape[2] == 1:
            data = np.repeat(data, 3, axis=2)
        data = data[:, :, :3]
        H, W = data.shape[:2]
        if W < 2 or H < 3:
            raise ValueError(f"envmap: the image must be at least 2x3 pixels, got {W}x{H}")
        if not np.all(np.isfinite(data)) or np.any(data < 0):
            raise ValueError("envmap: the image has negative or non-finite values")
        self.nodes = np.concatenate([data, data[:, :1]], axis=1) * float(scale)  # (H, W+1, 3)
        self.W, self.H = W, H
        self.to_world = np.eye(4) if to_world is None else np.asarray(to_world, dtype=np.float64)
        self.inv = np.linalg.inv(self.to_world[:3, :3])
        self.light_id = light_id
        self.name = name
        lum = self.nodes @ np.array([0.212671, 0.715160, 0.072169])
        corner = np.maximum(np.maximum(lum[:-1, :-1], lum[:-1, 1:]), np.maximum(lum[1:, :-1], lum[1:, 1:]))
        sin_c = np.sin((np.arange(H - 1) + 0.5) * np.pi / (H - 1))
        wcell = corner * sin_c[:, None]                    # (H-1, W)
        row = wcell.sum(axis=1)
        total = float(row.sum())
        self.dark = not total > 0
        self.row_cdf = np.cumsum(row) / max(total, 1e-300)
        self.row_cdf[-1] = 1.0
        self.col_cdf = np.cumsum(wcell, axis=1) / np.maximum(row, 1e-300)[:, None]
        self.col_cdf[:, -1] = 1.0
        self.p_cell = wcell / max(total, 1e-300)

    def _bilinear(self, x, y):
        ix = np.minimum(np.floor(x).astype(np.int64), self.W - 1)
        iy = np.minimum(np.floor(y).astype(np.int64), self.H - 2)
        fx, fy = (x - ix)[:, None], (y - iy)[:, None]
        N = self.nodes
        return ((N[iy, ix] * (1 - fx) + N[iy, ix + 1] * fx) * (1 - fy)
                + (N[iy + 1, ix] * (1 - fx) + N[iy + 1, ix + 1] * fx) * fy)

    def eval(self, d):
        """Radiance arriving from directions ``d`` (N, 3) (escaping rays)."""
        loc = matvec(self.inv, d)
        u = np.arctan2(loc[:, 0], -loc[:, 2]) / (2.0 * np.pi) - 0.5 / self.W
        u = u - np.floor(u)
        v = np.arccos(np.clip(loc[:, 1], -1.0, 1.0)) / np.pi
        return self._bilinear(u * self.W, v * (self.H - 1))

    def illuminate(self, p):  # pragma: no cover - sampled lights use sample()
        raise TypeError("an environment is sampled: use sample()")

    def _cell_pdf(self, ix, iy, st):
        """The solid-angle pdf of cell ``(ix, iy)`` at ``sin θ = st``."""
        return self.p_cell[iy, ix] * (self.W * (self.H - 1)) / (2.0 * np.pi * np.pi * np.maximum(st, 1e-300))

    def pdf(self, p, n, wi, dist=None, ng=None):
        """The pdf of the cell :meth:`eval`'s mapping puts ``wi`` in."""
        if self.dark:
            return np.zeros(wi.shape[0])
        loc = matvec(self.inv, wi)
        u = np.arctan2(loc[:, 0], -loc[:, 2]) / (2.0 * np.pi) - 0.5 / self.W
        u = u - np.floor(u)
        ct = np.clip(loc[:, 1] / np.maximum(length(loc), 1e-300), -1.0, 1.0)
        ix = np.minimum(np.floor(u * self.W).astype(np.int64), self.W - 1)
        iy = np.minimum(np.floor(np.arccos(ct) * ((self.H - 1) / np.pi)).astype(np.int64), self.H - 2)
        st = np.sqrt(np.maximum(0.0, 1.0 - ct * ct))
        return np.where(st > 0, self._cell_pdf(ix, iy, st), 0.0)

    def sample_pdf(self, p, n, u, v):
        npts = p.shape[0]
        if self.dark:
            return np.broadcast_to(n, (npts, 3)).copy(), np.full(npts, np.inf), np.zeros((npts, 3)), np.zeros(npts)
        iy = np.minimum(np.searchsorted(self.row_cdf, v, side="right"), self.H - 2)
        lo = np.where(iy > 0, self.row_cdf[np.maximum(iy - 1, 0)], 0.0)
        fy = np.clip((v - lo) / np.maximum(self.row_cdf[iy] - lo, 1e-300), 0.0, 1.0)
        ix = np.zeros(npts, dtype=np.int64)
        for r in np.unique(iy):
            m = iy == r
            ix[m] = np.searchsorted(self.col_cdf[r], u[m], side="right")
        ix = np.minimum(ix, self.W - 1)
        hi = self.col_cdf[iy, ix]
        lo = np.where(ix > 0, self.col_cdf[iy, np.maximum(ix - 1, 0)], 0.0)
        fx = np.clip((u - lo) / np.maximum(hi - lo, 1e-300), 0.0, 1.0)
        x, y = ix + fx, iy + fy
        theta = y * (np.pi / (self.H - 1))
        phi = (x + 0.5) * (2.0 * np.pi / self.W)
        st = np.sin(theta)
        loc = np.stack([np.sin(phi) * st, np.cos(theta), -np.cos(phi) * st], axis=-1)
        wi = matvec(self.to_world, loc)
        wi = wi / length(wi)[:, None]
        pdf = self._cell_pdf(ix, iy, st)
        L = self._bilinear(x, y)
        ok = (pdf > 0) & (st > 0)
        w = np.where(ok, 1.0 / np.where(pdf > 0, pdf, 1.0), 0.0)
        return wi, np.full(npts, np.inf), L * w[:, None], np.where(ok, pdf, 0.0)
