"""The LINKS-1 Whitted integrator in float64 numpy (docs/method.md §2–4, paper 3-1 and 3-3).

One call traces a batch of rays. Each ray finds its nearest hit through the hierarchy of
bounding boxes (3-2-4); the hit is shaded with eq. (3.11) under every light, each light
dimmed by the transmittances of the objects its shadow ray crosses (3-3-3), and mirror
and refraction rays recurse (eq. 3.12–3.16) until ``max_depth``. The batch is split into
the subsets that need each next step, so a scene without mirrors spawns no mirror rays,
a scene without glass no refraction rays.

Area and environment lights are sampled (``light_samples`` points per hit). At a hit whose
material has diffuse or glossy lobes (``material.smooth``; not links1_phong, which keeps the
paper's light samples alone), one BSDF sample joins them: the direction the
material draws at the hit's BSDF sample (:func:`links1.maths.sampling.bsdf_samples_uv`) is
traced to the nearest surface; where it meets a sampled area light's front or escapes to an
environment, that light's radiance counts. Both strategies are weighted by the power
heuristic (Veach's multiple importance sampling), as Mitsuba's ``direct``; delta lights stay
exact, and other hits use the light samples alone.

The method decisions shared with the Mitsuba plugin are listed in docs/architecture.md.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..scene import params
from ..geometry.accel import Accel
from ..shading.glossy import _call, _call_sample
from ..shading.lights import AreaLight, ConstantEnvironment, EnvironmentMap
from ..maths.sampling import (KEY_REFLECT, KEY_REFRACT, bsdf_samples_uv, child_keys, light_samples_uv,
                              power_heuristic)
from ..shading.textures import MeshAttribute, is_texture
from ..shading.normalmaps import FRAME_KEYS, needs_frame
from ..maths.vec import coordinate_system, dot, max_abs
from . import occluders

#: Relative size of the ray-origin offset (float64: about 1e6 ulps of |p|, far above the
#: intersection error of every primitive here, far below any feature size a scene has).
OFFSET_SCALE = 2.0 ** -32

#: Default weight below which a branch of the ray tree is not traced (POV-Ray's adc_bailout).
DEFAULT_MIN_WEIGHT = params.default("links1_whitted", "min_weight")


@dataclass
class Hits:
    """The cheap record of the nearest hits of a batch: distance, shape, primitive."""

    t: np.ndarray
    shape: np.ndarray
    prim: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        return self.shape >= 0


@dataclass
class SurfaceRecord:
    """The full record, built once for the winning hits: point and normals."""

    p: np.ndarray
    ng: np.ndarray  # geometric normal, outward
    ns: np.ndarray  # shading normal, outward (eq. 3.3 for meshes)


@dataclass
class TraceStats:
    """Counters for a render: rays by kind, and per-ray-slot primitive tests."""

    rays: dict = field(default_factory=lambda: {"camera": 0, "shadow": 0, "reflect": 0, "refract": 0})


@dataclass
class ScenePlan:
    """What the integrator needs to know about a scene, looked at once (cached on the scene):
    materials grouped so each is evaluated once per batch, per-shape shadow transmittance
    (3-3-3), which kinds of secondary rays can occur, and per light which shapes can occlude
    it and which shapes' points need a shadow ray at all (:mod:`links1.tracing.occluders`)."""

    materials: list
    material_of: np.ndarray
    shadow_t: np.ndarray
    any_reflection: bool
    any_transmission: bool
    any_emission: bool
    shadow_need: list
    shadow_inner: list
    shadow_t_light: list


def scene_plan(scene, key: bytes | None = None) -> ScenePlan:
    """The per-scene tables the integrator needs, built once per content of the scene
    (:meth:`links1.scene.scene.Scene.cached`)."""
    return scene.cached("plan", lambda: _build_plan(scene), key)


def _build_plan(scene) -> ScenePlan:
    shapes = scene.shapes
    index = {}
    materials = []
    for s in shapes:
        if id(s.material) not in index:
            index[id(s.material)] = len(materials)
            materials.append(s.material)
    shadow_t = np.array([s.material.shadow_t for s in shapes]).reshape(-1, 3)
    occluder, need = occluders.shadow_plan(shapes, scene.lights)
    plan = ScenePlan(
        materials=materials,
        material_of=np.array([index[id(s.material)] for s in shapes], dtype=np.int64),
        shadow_t=shadow_t,
        any_reflection=any(m.has_reflection for m in materials),
        any_transmission=any(m.has_transmission for m in materials),
        any_emission=any(s.emission is not None for s in shapes),
        shadow_need=need,
        # closed convex occluders skipped above: their own points with the light on the inner
        # side of the surface still need a shadow ray (links1.tracing.occluders)
        shadow_inner=[occ & occluders.closed_convex(shapes) & ~nd for occ, nd in zip(occluder, need)],
        shadow_t_light=[np.where(occ[:, None], shadow_t, 1.0) for occ in occluder],
    )
    return plan


class WhittedIntegrator:
    """Traces batches of rays through a :class:`links1.scene.scene.Scene`.

    Parameters
    ----------
    scene : Scene
    max_depth : int
        Surface interactions along one branch of the ray tree (primary hit = 1).
    min_weight : float
        A secondary ray is spawned only if its weight in the pixel (largest RGB component of
        the product of r and t factors down the tree) exceeds this (default 1/255; 0 traces all).
    light_samples : int
        Shadow rays per sampled light (area emitters, environments) per hit (default 1).
    camera : links1.sensor.camera.Camera or None
        The camera whose rays are the ones traced at depth 1 (None: rays of any origin): a
        pinhole's hits need no shadow ray toward a light at its eye
        (:func:`links1.tracing.occluders.lights_at_eye`).
    """

    def __init__(self, scene, max_depth: int | None = None, min_weight: float = DEFAULT_MIN_WEIGHT,
                 light_samples: int = 1, camera=None):
        self.scene = scene
        self.light_samples = int(light_samples)
        if self.light_samples < 1:
            raise ValueError(f"light_samples must be >= 1, got {self.light_samples}")
        self.environments = list(getattr(scene, "environments", ()) or ())
        self.max_depth = scene.max_depth if max_depth is None else int(max_depth)
        if self.max_depth < 1:
            raise ValueError(f"max_depth must be >= 1, got {self.max_depth}")
        self.min_weight = float(min_weight)
        key = scene.content_key()  # one digest for both caches: nothing stale if the scene changed
        self.accel = scene.cached("accel", lambda: Accel(scene.shapes), key)
        self.shapes = scene.shapes
        self.lights = scene.lights
        self.background = np.asarray(scene.background, dtype=np.float64)
        plan = scene_plan(scene, key)
        self.shadow_t = plan.shadow_t
        self.any_reflection = plan.any_reflection
        self.any_transmission = plan.any_transmission
        self.any_emission = plan.any_emission
        self._material_of = plan.material_of
        self._materials = plan.materials
        self._shadow_need = plan.shadow_need
        self._shadow_inner = plan.shadow_inner
        self._shadow_t_light = plan.shadow_t_light
        #: per light: at the camera's eye, so its shadow rays from depth-1 hits need no test
        self._eye_lit = occluders.camera_lights_at_eye(camera, self.shapes, self.lights)
        #: per material: glossy lobes, so BSDF samples join the light samples (None: no glossy
        #: material meets a sampled light, and no hit takes a BSDF sample)
        # (diffuse lobes too, as Mitsuba's direct samples every smooth BSDF; links1_phong keeps
        # the paper's light samples alone)
        self._glossy = np.array([bool(getattr(m, "glossy", False) or getattr(m, "smooth", False)
                                      and type(m).__name__ != "Phong") for m in self._materials])
        if not (self._glossy.any() and any(getattr(lt, "sampled", False) for lt in self.lights)):
            self._glossy = None
        self.stats = TraceStats()

    # ------------------------------------------------------------------ geometry
    def intersect(self, o, d, tmin, tmax, cost) -> Hits:
        t, shape, prim = self.accel.intersect(o, d, tmin, tmax, cost)
        return Hits(t, shape, prim)

    def surface(self, o, d, hits: Hits) -> SurfaceRecord:
        return SurfaceRecord(*self.accel.surface(o, d, hits.t, hits.shape, hits.prim))

    # ------------------------------------------------------------------ tracing
    def trace(self, o, d, tmin, tmax, cost, depth: int = 1, weight=None, keys=None, sample=None):
        """Radiance (N, 3) along rays ``o + t d``, t in (tmin, tmax); ``cost`` (N,) int64 is
        incremented by the ray–primitive tests of each ray's whole tree.

        ``keys`` (N,) uint32: the rays' keys (:func:`links1.maths.sampling.ray_keys`; default 0);
        ``sample = (pixel_keys (N,), i, spp)``: at depth 1, the camera sample the rays belong
        to, so that light samples form one lattice over the pixel's samples.

        Returns ``(radiance, hits, surface)``; the last two describe this level's hits.
        """
        n = o.shape[0]
        radiance = np.zeros((n, 3))
        hits = self.intersect(o, d, tmin, tmax, cost)
        valid = hits.valid
        if np.any(self.background != 0):
            radiance[~valid] = self.background
        if self.environments and not np.all(valid):
            miss = np.nonzero(~valid)[0]
            for env in self.environments:
                radiance[miss] += env.eval(d[miss])
        if keys is None:
            keys = np.zeros(n, dtype=np.uint32)
        if not np.any(valid):
            return radiance, hits, None
        idx = np.nonzero(valid)[0]
        oh, dh = o[idx], d[idx]
        sub = Hits(hits.t[idx], hits.shape[idx], hits.prim[idx])
        rec = self.surface(oh, dh, sub)
        w = None if weight is None else weight[idx]
        if sample is not None and depth == 1:
            sample = (sample[0][idx], sample[1], sample[2])
        else:
            sample = None
        radiance[idx] = self._shade(oh, dh, sub, rec, cost, idx, depth, w, keys[idx], sample)
        full = None
        if depth == 1:
            full = SurfaceRecord(np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3)))
            full.p[idx], full.ng[idx], full.ns[idx] = rec.p, rec.ng, rec.ns
        return radiance, hits, full

    def _light_points(self, light, keys, sample):
        """``(u, v)`` of each light sample ``j`` (list over j) for the hits, keyed as the plugin
        (:func:`links1.maths.sampling.light_samples_uv`)."""
        m = self.light_samples
        if sample is not None:
            pk, i, spp = sample
            return [light_samples_uv(pk, light.light_id, i * m + j, spp * m) for j in range(m)]
        return [light_samples_uv(keys, light.light_id, j, m) for j in range(m)]

    def _shade(self, o, d, hits: Hits, rec: SurfaceRecord, cost, idx, depth, weight, keys, sample):
        """Radiance leaving each hit toward the ray origin (eq. 3.16)."""
        n = o.shape[0]
        wo = -d
        front = dot(rec.ng, wo) > 0.0
        nf = np.where(front[:, None], rec.ns, -rec.ns)  # shading normal facing the viewer
        mat_idx = self._material_of[hits.shape]
        groups = [(k, np.nonzero(mat_idx == k)[0]) for k in np.unique(mat_idx)]
        # each group's material, its textures evaluated at the hits' uv (links1.shading.textures)
        mats = {k: self._bound(self._materials[k], o[g], d[g], hits, g) for k, g in groups}
        # Mitsuba's shading frame (its tangent from the shape's dp_du) where the material turns
        # with it: glossy lobes (anisotropic roughness) and BSDF samples (their directions)
        tangent = {k: self._shading_tangents(o[g], d[g], hits, g, rec.ns[g]) for k, g in groups
                   if getattr(mats[k], "glossy", False) or (self._glossy is not None and self._glossy[k])}

        out = np.zeros((n, 3))
        for k, g in groups:
            out[g] += mats[k].ambient  # eq. (3.11), dic
        if self.any_emission:
            for s in np.unique(hits.shape):
                e = self.shapes[s].emission
                if e is None:
                    continue
                m = (hits.shape == s) & front
                if is_texture(e):   # a textured area emitter: at the hits' uv
                    sel = np.nonzero(m)[0]
                    out[sel] += e.eval(self.shapes[s].uv(o[sel], d[sel], hits.t[sel], hits.prim[sel]))
                else:
                    out[m] += e

        eps = (1.0 + max_abs(rec.p)) * OFFSET_SCALE
        # glossy hits: their light samples are weighted against a BSDF sample (multiple
        # importance sampling, power heuristic; Veach's thesis eq. 9.13)
        glossy = [] if self._glossy is None else [(k, g) for k, g in groups if self._glossy[k]]
        gl = np.concatenate([g for _, g in glossy]) if glossy else None
        m = self.light_samples
        # --- direct light, eq. (3.11), with shadows (3-3-3)
        for j, light in enumerate(self.lights):
            if getattr(light, "sampled", False):   # area / environment: light_samples points each
                inv_m = 1.0 / m
                points = self._light_points(light, keys, sample)
                rays = ([light.sample(rec.p, nf, u, v) + (None,) for u, v in points] if gl is None
                        else [light.sample_pdf(rec.p, nf, u, v) for u, v in points])
            else:
                inv_m = None
                rays = [light.illuminate(rec.p) + (None,)]
            for wi, dist, L, pdf_l in rays:
                f = np.zeros((n, 3))
                for k, g in groups:
                    f[g] = _call(mats[k].eval, wo[g], wi[g], nf[g], rec.ns[g], tangent.get(k))
                contrib = f * L if inv_m is None else f * L * inv_m
                if pdf_l is not None:
                    for k, g in glossy:
                        pdf_b = _call(mats[k].pdf, wo[g], wi[g], nf[g], rec.ns[g], tangent[k])
                        contrib[g] *= power_heuristic(m * pdf_l[g], pdf_b)[:, None]
                self._shadowed(out, contrib, wi, dist, j, hits, rec, eps, cost, idx,
                               aim=isinstance(light, AreaLight), free=depth == 1 and self._eye_lit[j])
        if gl is not None:
            self._bsdf_sampled(out, glossy, mats, tangent, d, nf, rec, eps, cost, idx, keys, sample)

        if depth >= self.max_depth or not (self.any_reflection or self.any_transmission):
            return out
        keys_r, keys_t = child_keys(keys, KEY_REFLECT), child_keys(keys, KEY_REFRACT)

        # --- secondary rays, eq. (3.12)-(3.16)
        r, dr_, t, dt, has_t = self.delta_rays(mats, groups, wo, nf, front, rec.ns)
        wgt = np.ones((n, 3)) if weight is None else weight
        threshold = self.min_weight
        branches = []
        refl = np.nonzero(np.max(r * wgt, axis=1) > threshold if threshold > 0 else np.any(r > 0.0, axis=1))[0]
        if refl.size:
            branches.append(("reflect", refl, dr_[refl], r, keys_r))
        trn = np.nonzero(has_t & (np.max(t * wgt, axis=1) > threshold) if threshold > 0 else has_t)[0]
        if trn.size:
            branches.append(("refract", trn, dt[trn], t, keys_t))  # eq. (3.14)-(3.15)
        for kind, sel, dnew, factor, kk in branches:
            self.stats.rays[kind] += sel.size
            dnew = dnew / np.sqrt(dot(dnew, dnew))[:, None]
            onew = _offset(rec.p[sel], rec.ng[sel], dnew, eps[sel])
            c = np.zeros(sel.size, dtype=np.int64)
            Li, _, _ = self.trace(onew, dnew, np.zeros(sel.size), np.full(sel.size, np.inf), c,
                                  depth + 1, wgt[sel] * factor[sel], kk[sel])
            cost[idx[sel]] += c
            out[sel] += factor[sel] * Li  # eq. (3.13) / (3.16)
        return out

    @staticmethod
    def delta_rays(mats, groups, wo, nf, front, ns):
        """The mirror and refraction rays of hits seen from ``wo`` (eq. 3.12-3.15), by material
        (``groups``: ``(material index, hits)``, ``mats``: the materials bound to them):
        ``(r, mirror direction, t, refracted direction, has_t)``, weights (N, 3) as Mitsuba's
        delta lobes weigh them (``t`` with its radiance scaling). ``nf`` the shading normal facing
        the viewer, ``front`` the viewer on the geometric normal's side, ``ns`` the shading normal;
        a normal or bump map turns the normal the rays leave about
        (:meth:`links1.shading.normalmaps._Perturbed.delta_frame`)."""
        n, d = wo.shape[0], -wo
        r = np.zeros((n, 3))
        t = np.zeros((n, 3))
        eta = np.ones(n)
        scale = np.zeros(n, dtype=bool)
        nd = nf   # the normal the rays leave about: a normal or bump map's turned one where there is one
        kept = []
        for k, g in groups:
            mat = mats[k]
            if not (mat.has_reflection or mat.has_transmission):
                continue
            turned = getattr(mat, "delta_frame", None)
            if turned is None:
                r[g], t[g], eta[g] = mat.specular(wo[g], nf[g], front[g])
            else:   # links1.shading.normalmaps: Mitsuba samples the nested delta lobes turned
                nd = nd.copy() if nd is nf else nd
                nd[g], entering, keep = turned(wo[g], ns[g])
                r[g], t[g], eta[g] = mat.specular(wo[g], nd[g], entering)
                kept.append((g, keep))
            scale[g] = mat.scale_radiance
        cos_i = -dot(d, nd)  # >= 0: nd faces the viewer
        dt, tir = refract(d, nd, eta)
        tir &= np.any(t > 0.0, axis=1)  # total internal reflection: no transmitted ray, its weight goes to the mirror ray
        r = np.where(tir[:, None], r + t, r)
        t = np.where(tir[:, None], 0.0, t)
        dr_ = d + 2.0 * cos_i[:, None] * nd  # eq. (3.12)
        for g, keep in kept:   # rays the turned normal sends across the surface: dropped, as Mitsuba's
            r[g], t[g] = keep(dr_[g], r[g]), keep(dt[g], t[g])
        has_t = np.any(t > 0.0, axis=1)
        t = np.where(scale[:, None], t * (eta * eta)[:, None], t)
        return r, dr_, t, dt, has_t

    def _bsdf_sampled(self, out, glossy, mats, tangent, d, nf, rec, eps, cost, idx, keys, sample):
        """Add the BSDF-sampled part of the direct light at the glossy hits (``glossy``: groups
        ``(material, hits)``): one direction drawn by each hit's material at its BSDF sample
        (:func:`links1.maths.sampling.bsdf_samples_uv`, keyed as one light sample per hit) in
        Mitsuba's shading frame (``tangent`` by material: :meth:`_shading_tangents`), traced to
        the nearest surface.
        Where it meets a sampled area light's front, that light's radiance (a texture at the
        point's uv); where it escapes, each environment's; times ``eval / pdf``, weighted by the
        power heuristic against the light's ``light_samples`` samples (``light.pdf``)."""
        gl = np.concatenate([g for _, g in glossy])
        if sample is not None:
            u1, u, v = bsdf_samples_uv(sample[0], sample[1], sample[2])
        else:
            u1, u, v = bsdf_samples_uv(keys, 0, 1)
        uv = np.stack([u, v], axis=1)
        wo = -d
        wi = np.zeros((gl.size, 3))
        weight = np.zeros((gl.size, 3))
        pdf_b = np.zeros(gl.size)
        at = 0
        for k, g in glossy:
            wi[at:at + g.size], weight[at:at + g.size], pdf_b[at:at + g.size] = \
                _call_sample(mats[k], wo[g], nf[g], rec.ns[g], u1[g], uv[g], tangent[k])
            at += g.size
        ok = (pdf_b > 0) & np.any(weight > 0, axis=1)
        sel, wi, weight, pdf_b = gl[ok], wi[ok], weight[ok], pdf_b[ok]
        if sel.size == 0:
            return
        p = rec.p[sel]
        ob = _offset(p, rec.ng[sel], wi, eps[sel])
        c = np.zeros(sel.size, dtype=np.int64)
        bh = self.intersect(ob, wi, np.zeros(sel.size), np.full(sel.size, np.inf), c)
        cost[idx[sel]] += c
        self.stats.rays["shadow"] += sel.size
        m = self.light_samples
        L = np.zeros((sel.size, 3))
        hit = bh.valid
        if np.any(hit):
            h = np.nonzero(hit)[0]
            sub = Hits(bh.t[h], bh.shape[h], bh.prim[h])
            srf = self.surface(ob[h], wi[h], sub)
            for light in self.lights:
                if not isinstance(light, AreaLight):
                    continue
                on = np.nonzero((sub.shape == light.shape.index) & (dot(srf.ng, wi[h]) < 0.0))[0]
                if on.size == 0:
                    continue
                hh = h[on]
                e = light.shape.emission
                if is_texture(e):
                    e = e.eval(light.shape.uv(ob[hh], wi[hh], sub.t[on], sub.prim[on]))
                to = srf.p[on] - p[hh]
                pdf_l = light.pdf(p[hh], nf[sel[hh]], wi[hh], np.sqrt(dot(to, to)), srf.ng[on])
                L[hh] += e * power_heuristic(pdf_b[hh], m * pdf_l)[:, None]
        miss = np.nonzero(~hit)[0]
        if miss.size:
            for light in self.lights:
                if not isinstance(light, (ConstantEnvironment, EnvironmentMap)):
                    continue
                pdf_l = light.pdf(p[miss], nf[sel[miss]], wi[miss])
                L[miss] += light.eval(wi[miss]) * power_heuristic(pdf_b[miss], m * pdf_l)[:, None]
        out[sel] += weight * L

    def _shading_tangents(self, o, d, hits, sel, ns):
        """Mitsuba's shading-frame tangent ``s`` at hits ``sel`` (rays ``o, d``): the part of
        the shape's ``dp_du`` across the shading normal ``ns`` (``initialize_sh_frame``), or
        ``coordinate_system(ns)``'s where the shape has none."""
        du = np.zeros((sel.size, 3))
        shape = hits.shape[sel]
        for s in np.unique(shape):
            tangents = getattr(self.shapes[s], "tangents", None)   # a shape without dp_du: none
            if tangents is not None:
                m = shape == s
                du[m] = tangents(o[m], d[m], hits.t[sel][m], hits.prim[sel][m])[0]
        s_ = du - ns * dot(ns, du)[:, None]
        ln = np.sqrt(dot(s_, s_))
        ok = ln > 0
        return np.where(ok[:, None], s_ / np.where(ok, ln, 1.0)[:, None], coordinate_system(ns)[0])

    def _shadowed(self, out, contrib, wi, dist, j, hits, rec, eps, cost, idx, aim=False, free=False):
        """Add ``contrib`` of light ``j`` to ``out``, dimmed by the transmittance of the shapes
        its shadow segment crosses (3-3-3), tracing only where an occluder can be (``free``:
        nowhere, the light at the eye of the camera rays these hits are of).

        ``aim``: the light's points lie on a surface (an area emitter). The segment then runs
        from the offset origin to the sampled point itself and stops short of it by that
        point's own offset: from the offset origin along the original ``wi`` a ray meets the
        emitter's plane up to ``eps / cos`` early (the offset's component along the light's
        normal), inside the emitter when the emitter is not convex (and so an occluder): a
        luminaire mesh shadowed itself on points that see it obliquely."""
        lit = np.any(contrib != 0.0, axis=1)
        if free:
            out[lit] += contrib[lit]
            return
        need = self._shadow_need[j][hits.shape] | \
            (self._shadow_inner[j][hits.shape] & (dot(rec.ng, wi) <= 0.0))  # inner side: links1.tracing.occluders
        unblockable = lit & ~need  # no shape can lie between these points and the light
        out[unblockable] += contrib[unblockable]
        shadowed = np.nonzero(lit & need)[0]
        if shadowed.size == 0:
            return
        so = _offset(rec.p[shadowed], rec.ng[shadowed], wi[shadowed], eps[shadowed])
        ws = wi[shadowed]
        smax = dist[shadowed] - 2.0 * eps[shadowed]
        if aim:
            q = rec.p[shadowed] + ws * dist[shadowed, None]
            to = q - so
            length = np.sqrt(dot(to, to))
            ws = to / np.where(length > 0, length, 1.0)[:, None]
            smax = length - 2.0 * np.maximum((1.0 + max_abs(q)) * OFFSET_SCALE, eps[shadowed])
        c = np.zeros(shadowed.size, dtype=np.int64)
        T = self.accel.shadow_transmittance(so, ws, smax, self._shadow_t_light[j], c)
        cost[idx[shadowed]] += c
        self.stats.rays["shadow"] += shadowed.size
        out[shadowed] += contrib[shadowed] * T

    def _bound(self, material, o, d, hits: Hits, sel):
        """``material`` with its textures evaluated at the uv of hits ``sel`` (rays ``o, d``)."""
        if not material.textured:
            return material
        uv = np.zeros((sel.size, 2))
        shape = hits.shape[sel]
        attrs = {k: v for k, v in vars(material).items() if isinstance(v, MeshAttribute)}
        given = {k: np.zeros((sel.size, 3)) for k in attrs}
        frame = needs_frame(material)   # normal and bump maps: the hits' dp_du, dp_dv, ng
        given.update({k: np.zeros((sel.size, 3)) for k in FRAME_KEYS} if frame else {})
        for s in np.unique(shape):
            m = shape == s
            uv[m] = self.shapes[s].uv(o[m], d[m], hits.t[sel][m], hits.prim[sel][m])
            for k, tex in attrs.items():   # mesh attributes: at the hit itself
                given[k][m] = tex.values(self.shapes[s].attribute(tex.attribute, o[m], d[m], hits.prim[sel][m]))
            if frame:
                th, ph = hits.t[sel][m], hits.prim[sel][m]
                given["dp_du"][m], given["dp_dv"][m] = self.shapes[s].tangents(o[m], d[m], th, ph)
                given["ng"][m] = self.shapes[s].surface(o[m], d[m], th, ph)[1]
        return material.at(uv, given)


def refract(d, n, eta):
    """Refracted directions, eq. (3.14)-(3.15), and the total-internal-reflection mask.

    ``d`` (N,3) unit incoming directions, ``n`` (N,3) unit normals facing the incoming ray
    (``d·n <= 0``), ``eta`` (N,) the relative index ``η_i/η_t``. With ``S = η(d − (d·n)n)``
    the transmitted direction is ``S − sqrt(1 − |S|²) n``; ``|S| > 1`` is total internal
    reflection (the returned direction is then meaningless and set to ``d``).
    """
    cos_i = -dot(d, n)
    S = eta[:, None] * (d + cos_i[:, None] * n)  # eq. (3.14): tangential part scaled by η
    s2 = dot(S, S)
    tir = s2 > 1.0
    dt = S - np.sqrt(np.maximum(0.0, 1.0 - s2))[:, None] * n  # eq. (3.15)
    return np.where(tir[:, None], d, dt), tir


def _offset(p, ng, direction, eps):
    """Move ``p`` off the surface along ``ng``, to the side ``direction`` leaves toward."""
    side = np.where(dot(ng, direction) >= 0.0, 1.0, -1.0)
    return p + ng * (side * eps)[:, None]
