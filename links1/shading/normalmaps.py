"""Mitsuba's shading-frame wrappers ``normalmap`` and ``bumpmap`` in float64, as Mitsuba 3.9.1
evaluates, samples and gives their densities (``src/bsdfs/normalmap.cpp``, ``bumpmap.cpp``).

Both turn the hit's shading frame and hand the nested BSDF the turned one:

* the hit's frame is Mitsuba's ``initialize_sh_frame``: ``n`` the shading normal, ``s`` the
  part of ``dp_du`` across it, ``t = n × s`` (``coordinate_system(n)`` where ``dp_du = 0``);
* ``normalmap``: the perturbed normal is ``2 c - 1`` of the texture's colour ``c`` in that
  frame, its tangent ``(1, 0, 0)`` made normal to it;
* ``bumpmap``: the height texture's gradient ``scale · ∇h`` (Mitsuba's ``eval_1_grad``) moves
  ``dp_du``, ``dp_dv`` along ``n``; the normal is their cross product (turned to the geometric
  normal's side), its tangent Mitsuba's Gram–Schmidt of ``dp_du``, which takes the world
  ``dp_du`` as a vector of the local frame (kept, so both agree with Mitsuba);
* with ``flip_invalid_normals`` (default) a normal that leaves the viewer below its horizon
  has its tangential part mirrored; with ``use_shadowing_function`` (default) the value is
  times Estevez et al.'s shadowing term ``2 / (1 + sqrt(1 + α² tan² θ_o))``,
  ``α² = min(tan² θ_n / 8, 1)`` (Ray Tracing Gems 2019, ch. 12);
* a light direction on the other side of the turned normal than of the unturned one gives 0.

They need the hit's ``dp_du``, ``dp_dv`` and geometric normal: the integrator hands them to
``at`` in ``given`` (keys ``dp_du``, ``dp_dv``, ``ng``; :meth:`links1.geometry.base.Shape.tangents`).
The nested BSDF's delta lobes (mirror and refraction rays) leave about the turned normal, as
Mitsuba's ``sample`` draws them (:meth:`_Perturbed.delta_frame`). Inside ``twosided`` the frame
is mirrored from behind, as Mitsuba mirrors the local directions.
"""
from __future__ import annotations

import copy
import inspect
from dataclasses import dataclass

import numpy as np

from .materials import Material
from .textures import Texture
from ..maths.vec import coordinate_system, cross, dot, normalize

__all__ = ["NormalMap", "BumpMap", "FRAME_KEYS", "shadow_terminator"]

#: what the integrator puts into ``given`` for a material that :func:`needs_frame`
FRAME_KEYS = ("dp_du", "dp_dv", "ng")


def needs_frame(material) -> bool:
    """Whether ``material`` or a BSDF nested in it turns the shading frame (needs ``FRAME_KEYS``)."""
    if isinstance(material, _Perturbed):
        return True
    return any(needs_frame(v) for v in vars(material).values() if isinstance(v, Material))


def _tan2(z):
    """Mitsuba's ``Frame3f::tan_theta_2`` of a unit vector with ``cos θ = z``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.maximum(1.0 - z * z, 0.0) / (z * z)


def shadow_terminator(n_z, wo_z):
    """Estevez et al.'s shadowing term (Mitsuba's ``eval_shadow_terminator``) of the turned
    normal and the light direction, both by their cosine to the unturned normal."""
    alpha2 = np.minimum(0.125 * _tan2(n_z), 1.0)
    with np.errstate(invalid="ignore"):
        g = 2.0 / (1.0 + np.sqrt(1.0 + alpha2 * _tan2(wo_z)))
    return np.nan_to_num(g)


def _with_tangent(fn, *args, tangent):
    """Call a nested material's eval/pdf/sample with ``tangent`` where it takes one."""
    if "tangent" in inspect.signature(fn).parameters:
        return fn(*args, tangent=tangent)
    return fn(*args)


def _world(v, frame):
    s, t, z = frame
    return v[:, 0:1] * s + v[:, 1:2] * t + v[:, 2:3] * z


@dataclass
class _Perturbed(Material):
    """Common part: the hit's frame, the turned frame, and eval/pdf/sample around ``nested``."""

    nested: Material = None
    flip_invalid_normals: bool = True
    use_shadowing_function: bool = True
    two_sided: bool = False
    name: str = ""

    def __post_init__(self):
        nst = self.nested
        self.has_reflection = nst.has_reflection
        self.has_transmission = nst.has_transmission
        self.scale_radiance = nst.scale_radiance
        self.straight_transmission = nst.straight_transmission
        self.shadow_t = nst.shadow_t
        self.ambient = nst.ambient
        self._hit = None

    @property
    def smooth(self) -> bool:
        return getattr(self.nested, "smooth", False)

    @property
    def glossy(self) -> bool:
        return getattr(self.nested, "glossy", False)

    #: the texture parameter that turns the frame
    _map = ""

    @property
    def textured(self) -> tuple:
        return (self._map,) + (("nested",) if self.nested.textured else ())

    def at(self, uv, given=None):
        if not given or any(k not in given for k in FRAME_KEYS):
            raise ValueError(f"{type(self).__name__} needs the hits' {', '.join(FRAME_KEYS)}")
        bound = copy.copy(self)
        bound.nested = self.nested.at(uv, given) if self.nested.textured else self.nested
        bound._hit = (tuple(np.asarray(given[k], dtype=np.float64) for k in FRAME_KEYS)
                      + (self._lookup(uv),))
        return bound

    def _lookup(self, uv):  # pragma: no cover - interface
        raise NotImplementedError

    def _turned(self, hit, n_raw, base, wo, wi_z):  # pragma: no cover - interface
        """The turned frame's normal and tangent (N, 3) each, in the hit's frame ``base``
        (``wo`` the viewer, ``wi_z`` its cosine there, mirrored from behind a two-sided one)."""
        raise NotImplementedError

    # --------------------------------------------------------------------------- frames
    def _frames(self, wo, n_raw):
        """The hit's frame ``(s, t, z)`` (world; ``z = -n_raw`` where a two-sided surface is
        seen from behind), the viewer's cosine in it, the turned normal in it and the turned
        frame's normal and tangent in the world."""
        if self._hit is None:
            raise ValueError(f"{type(self).__name__} is evaluated unbound: call at() with the hits' frame")
        dp_du = self._hit[0]
        s = dp_du - n_raw * dot(n_raw, dp_du)[:, None]   # Mitsuba's initialize_sh_frame
        ln = np.sqrt(dot(s, s))
        degenerate = np.all(dp_du == 0.0, axis=1) | (ln == 0.0)
        s = np.where(degenerate[:, None], coordinate_system(n_raw)[0],
                     s / np.where(ln > 0, ln, 1.0)[:, None])
        t = cross(n_raw, s)
        wi_z = dot(wo, n_raw)
        z = n_raw
        behind = np.zeros(wi_z.shape, dtype=bool)
        if self.two_sided:   # Mitsuba's twosided: the local directions mirrored from behind
            behind = wi_z < 0
            z = np.where(behind[:, None], -n_raw, n_raw)
            wi_z = np.abs(wi_z)
        base = (s, t, z)
        pn, ps = self._turned(self._hit, n_raw, (s, t, n_raw), wo, wi_z)
        pn_w, ps_w = _world(pn, base), _world(ps, base)
        # Behind, the turned frame is left-handed: the nested BSDF (right-handed frames) sees
        # the directions reflected across its (s, n) plane, which maps one frame onto the other.
        mirror = np.where(behind[:, None], cross(pn_w, ps_w), 0.0)
        return base, wi_z, pn, pn_w, ps_w, mirror

    def _flip_invalid(self, n, wi_l):
        """Mitsuba's ``flip_invalid_normals``: mirror the tangential part of a normal ``n``
        (local) that the viewer ``wi_l`` (local) sees from the other side than the surface."""
        if not self.flip_invalid_normals:
            return n
        flip = wi_l[:, 2] * dot(wi_l, n) <= 0.0
        return np.where(flip[:, None], n * np.array([-1.0, -1.0, 1.0]), n)

    @staticmethod
    def _reflect(v, mirror):
        """``v`` reflected across the plane normal to ``mirror`` (zero rows: unchanged)."""
        return v - 2.0 * dot(v, mirror)[:, None] * mirror

    @staticmethod
    def _local(v, s, t, z):
        return np.stack([dot(v, s), dot(v, t), dot(v, z)], axis=1)

    def _nested_normals(self, wo, pn_w):
        """The turned normal as the nested BSDF takes it: facing the viewer, and as it is."""
        return np.where((dot(pn_w, wo) < 0)[:, None], -pn_w, pn_w), pn_w

    # --------------------------------------------------------------------------- the BSDF
    def eval(self, wo, wi, n, n_raw, tangent=None):
        (s, t, z), wi_z, pn, pn_w, ps_w, mirror = self._frames(wo, n_raw)
        cos_o = dot(wi, z)
        active = (cos_o * dot(wi, pn_w) > 0) & ((wi_z != 0) | (not self.two_sided))
        nf, nr = self._nested_normals(wo, pn_w)
        f = _with_tangent(self.nested.eval, self._reflect(wo, mirror), self._reflect(wi, mirror),
                          nf, nr, tangent=ps_w)
        if self.use_shadowing_function:
            f = f * shadow_terminator(pn[:, 2], cos_o)[:, None]
        return np.where(active[:, None], f, 0.0)

    def pdf(self, wo, wi, n, n_raw, tangent=None):
        (s, t, z), wi_z, pn, pn_w, ps_w, mirror = self._frames(wo, n_raw)
        active = (dot(wi, z) * dot(wi, pn_w) > 0) & ((wi_z != 0) | (not self.two_sided))
        nf, nr = self._nested_normals(wo, pn_w)
        p = _with_tangent(self.nested.pdf, self._reflect(wo, mirror), self._reflect(wi, mirror),
                          nf, nr, tangent=ps_w)
        return np.where(active, p, 0.0)

    def sample(self, wo, n, n_raw, u, uv, tangent=None):
        (s, t, z), wi_z, pn, pn_w, ps_w, mirror = self._frames(wo, n_raw)
        nf, nr = self._nested_normals(wo, pn_w)
        wi, weight, pdf = _with_tangent(self.nested.sample, self._reflect(wo, mirror), nf, nr, u, uv,
                                        tangent=ps_w)
        wi = self._reflect(wi, mirror)
        weight, active = self._kept(wi, weight, z, wi_z, pn, pn_w)
        return wi, weight, np.where(active, pdf, 0.0)

    def _kept(self, wi, weight, z, wi_z, pn, pn_w):
        """A sampled direction's weight as Mitsuba's ``sample`` returns it, and where it is kept:
        0 where the nested BSDF gave none or ``wi`` leaves on one side of the turned normal
        ``pn_w`` and the other of the unturned ``z`` (not folded back); times the shadowing term."""
        cos_o = dot(wi, z)
        active = np.any(weight != 0, axis=1) & (dot(wi, pn_w) * cos_o > 0)
        if self.two_sided:
            active &= wi_z != 0
        if self.use_shadowing_function:
            weight = weight * shadow_terminator(pn[:, 2], cos_o)[:, None]
        return np.where(active[:, None], weight, 0.0), active

    def specular(self, wo, n, entering):
        return self.nested.specular(wo, n, entering)

    def delta_frame(self, wo, n_raw):
        """Where the nested BSDF's delta lobes leave, as Mitsuba's ``sample`` draws them in the
        turned frame: ``(n, entering, keep)``. ``n`` is the turned normal facing the viewer ``wo``
        (the mirror and refraction rays, eq. 3.12-3.15, are taken about it, their weights from
        ``specular(wo, n, entering)``), ``entering`` whether the viewer is on the turned normal's
        side (the nested BSDF's ``cos θ_i > 0``). ``keep(direction, weight)`` is a lobe's weight as
        Mitsuba returns it (:meth:`_kept`): a reflection turned below the surface is dropped."""
        (s, t, z), wi_z, pn, pn_w, ps_w, mirror = self._frames(wo, n_raw)
        # the twosided mirror fixes the turned normal: rays reflected or refracted about it are
        # the mirror images of the mirrored ones, so no mirroring is needed here
        cos_i = dot(wo, pn_w)
        n = np.where((cos_i < 0)[:, None], -pn_w, pn_w)

        def keep(direction, weight):
            return self._kept(direction, weight, z, wi_z, pn, pn_w)[0]

        return n, cos_i > 0, keep


@dataclass
class NormalMap(_Perturbed):
    """Mitsuba ``normalmap``: the nested BSDF in the frame of the normal ``2 c - 1`` that the
    texture ``normalmap`` (``c`` its RGB, usually a ``raw`` bitmap) gives in the hit's frame."""

    normalmap: object = None

    _map = "normalmap"

    def _lookup(self, uv):
        if isinstance(self.normalmap, Texture):
            return self.normalmap.eval(uv)
        return np.broadcast_to(np.asarray(self.normalmap, dtype=np.float64), (len(uv), 3))

    def _turned(self, hit, n_raw, base, wo, wi_z):
        s, t, z = base
        wi_l = np.stack([dot(wo, s), dot(wo, t), wi_z], axis=1)
        nl = self._flip_invalid(2.0 * hit[3] - 1.0, wi_l)
        pn = normalize(nl)
        ps = normalize(np.array([1.0, 0.0, 0.0]) - pn * pn[:, 0:1])
        return pn, ps


@dataclass
class BumpMap(_Perturbed):
    """Mitsuba ``bumpmap``: the nested BSDF in the frame of the surface displaced along its
    normal by ``scale`` times the height texture (a ``bitmap``: Mitsuba has the gradient of
    no other texture)."""

    texture: Texture = None
    scale: float = 1.0

    _map = "texture"

    def __post_init__(self):
        super().__post_init__()
        self.scale = float(self.scale)
        if not hasattr(self.texture, "eval_1_grad"):
            raise ValueError(f"bumpmap needs a texture with a gradient (a bitmap), got "
                             f"{type(self.texture).__name__}")

    def _lookup(self, uv):
        return self.scale * self.texture.eval_1_grad(uv)

    def _turned(self, hit, n_raw, base, wo, wi_z):
        dp_du, dp_dv, ng, grad = hit
        s, t, z = base
        du = dp_du + n_raw * (grad[:, 0] - dot(n_raw, dp_du))[:, None]
        dv = dp_dv + n_raw * (grad[:, 1] - dot(n_raw, dp_dv))[:, None]
        nb = normalize(cross(du, dv))
        nb = np.where((dot(ng, nb) < 0)[:, None], -nb, nb)
        pn = self._local(nb, s, t, z)
        wi_l = np.stack([dot(wo, s), dot(wo, t), wi_z], axis=1)
        pn = self._flip_invalid(pn, wi_l)
        # Mitsuba's Gram-Schmidt takes the world dp_du as a local vector
        ps = normalize(dp_du - pn * dot(pn, dp_du)[:, None])
        return pn, ps
