"""The ray tree of ``links1_whitted`` (its one home): one level of rays traced and shaded
(``level``: eq. 3.11 under every light, shadow rays, the children of eq. 3.12-3.15), which
children a hit spawns (``children``), and every tree of a launch (``trace_tree``): :class:`Tracer`.

Recursion design (``trace_tree``): two kernels per frame, whatever the depth.

1. The camera level: every sample's ray is intersected (Mitsuba shapes through
   ``scene.ray_intersect``, links1 quadrics and blobs in Dr.Jit, nearest wins) and shaded
   (eq. 3.11 under every light, shadow rays with transmittance); its mirror and refraction
   children are computed.
2. The samples that spawn children are compacted (``dr.compress``, order kept) and one
   symbolic ``dr.while_loop`` traces the rest of their ray trees, one ray per iteration: the
   mirror child (eq. 3.12) is followed next, a refraction child (eq. 3.14-3.15) with a mirror
   sibling waits on a small per-lane stack (Dr.Jit local memory). ``I = I_o + r I_r + t I_t``
   (eq. 3.16) is accumulated as the sum of ``weight · I_o`` over the tree (weight = product of
   the factors down the branch), then scattered back to its sample (one writer per sample).

A branch stops when its weight falls to ``min_weight`` (default 1/255, as the core). Lanes
never interact, so a window renders the same bits as the same pixels of the full frame, and
every run-time input (window offset and width, seed) is an opaque value: the kernels compile
once per scene and are reused for every window and frame.

Why one file of this size: a level's steps (``_surface``, ``_emitted``, ``_direct``,
``_secondary``), the records they hand each other (:class:`Hit`, :class:`Level`) and the
megakernel that calls them inside its symbolic loop are read together; split, each would
import the others' private records.

:class:`Tracer` holds only what it is given (the integrator's parameters, the frame's
switches); the tables and the scene are arguments of each call. Its methods name ``mi.Float``,
``mi.Ray3f``, ... when called, so the class serves every Mitsuba variant.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from links1.maths.sampling import KEY_REFLECT, KEY_REFRACT

from . import intersect, lights, shadow_plan
from .config import Config
from .tuning import Tuning
from .util import INF, gather3, mix32

# tuning.Tuning.skip_misses: direct light (every light's sample, shading and shadow rays) under a
# symbolic ``dr.if_stmt`` on the hit: a packet of escaped rays (sky, 38 % of fig11's camera rays)
# skips it instead of computing it masked


#: where the children are made again in the loop's kernel (``Tracer.trace_tree``'s ``rays``),
#: the camera level computes no lobes: the samples whose hit can spawn are compacted and the
#: loop's kernel tells which spawn (False: level 1 computes them for its ``cr``, ``ct``)
LOBES_IN_LOOP = True

#: the loop's stack (Dr.Jit local memory) written and read under symbolic branches on the lanes
#: that push and pop: a packet without either skips their scatters and gathers (False: every
#: packet runs them masked)
STACK_BRANCH = True


def _push(stk_f, stk_u, sp, o, d, w, depth, key, on):
    """The ray tree's stack (``Tracer.trace_tree``: 9 floats, origin, direction and weight, and
    2 integers, depth and key, an entry) with the entry ``(o, d, w, depth, key)`` written at
    ``sp`` where ``on`` -> ``(stk_f, stk_u)``."""
    def write(stk_f, stk_u, sp, o, d, w, depth, key, on):
        for k, val in enumerate((o.x, o.y, o.z, d.x, d.y, d.z, w.x, w.y, w.z)):
            stk_f.write(val, sp * 9 + k, on)
        stk_u.write(depth, sp * 2, on)
        stk_u.write(key, sp * 2 + 1, on)
        return stk_f, stk_u
    args = (stk_f, stk_u, sp, o, d, w, depth, key, on)
    if not STACK_BRANCH:
        return write(*args)
    return dr.if_stmt(args, on, write, lambda stk_f, stk_u, *rest: (stk_f, stk_u), mode="symbolic",
                      label="links1_push")


def _pop(stk_f, stk_u, top, on):
    """The stack's entry ``top`` where ``on`` (:func:`_push`'s layout) -> ``([o, d, w] as 9 floats,
    depth, key)``; other lanes: zeros."""
    def read(stk_f, stk_u, top, on):
        return (*[stk_f.read(top * 9 + k, on) for k in range(9)], stk_u.read(top * 2, on),
                stk_u.read(top * 2 + 1, on))
    args = (stk_f, stk_u, top, on)
    if STACK_BRANCH:
        zf, zu = dr.zeros(mi.Float, dr.width(top)), dr.zeros(mi.UInt32, dr.width(top))
        got = dr.if_stmt(args, on, read, lambda *a: (*[zf] * 9, zu, zu), mode="symbolic", label="links1_pop")
    else:
        got = read(*args)
    return list(got[:9]), got[9], got[10]


def child_keys(key):
    """The keys of a hit's mirror and refraction children, ``mix(key ^ KEY_REFLECT)`` and
    ``mix(key ^ KEY_REFRACT)`` (links1.maths.sampling.child_keys): one rule for the megakernel
    and the derivative pass's levels."""
    return mix32(key ^ mi.UInt32(KEY_REFLECT)), mix32(key ^ mi.UInt32(KEY_REFRACT))


def _power_heuristic(pdf_a, pdf_b):
    """Veach's power heuristic (β = 2) of strategy a against b, each pdf times its sample
    count; 0 where it is not finite (Mitsuba's ``direct``: ``mis_weight``)."""
    a, b = dr.square(pdf_a), dr.square(pdf_b)
    w = a / (a + b)
    return dr.select(dr.isfinite(w), w, 0.0)


@dataclass(eq=False)
class Hit:
    """The surface record of one level's rays (:meth:`Tracer._surface`): the winner of the
    nearest-hit search and what shading reads of it (Mitsuba's interaction record and BSDF,
    the Phong coefficients: None where the scene has none), with the BSDF factor of eq. (3.11)
    (:meth:`f_eval`) and the ray offset (:meth:`offset`)."""

    tables: object                  # the tables (prepared.Prepared)
    ad: bool                        # a derivative pass's level
    n: int                          # lanes
    o: mi.Point3f
    d: mi.Vector3f
    t: mi.Float
    slot: mi.Int32                  # -1: a miss
    uslot: mi.UInt32
    hit: mi.Bool
    prim: mi.UInt32
    si: mi.SurfaceInteraction3f     # Embree's record (Mitsuba's shapes)
    p: mi.Point3f
    ng: mi.Vector3f                 # geometric normal
    ns: mi.Vector3f                 # shading normal
    wo: mi.Vector3f
    front: mi.Bool
    nf: mi.Vector3f                 # shading normal on the ray's side
    mits: mi.Bool                   # a Mitsuba shape won
    eps: mi.Float | None = None     # ray offset (tables.py's OFFSET_EPS)
    sif: mi.SurfaceInteraction3f | None = None   # the record for BSDF calls, links1 winners filled in
    bsdf: mi.BSDFPtr | None = None
    is_ph: mi.Bool | None = None
    mb: mi.Bool | None = None       # a Mitsuba BSDF's hit
    ctx: mi.BSDFContext | None = None
    ph: mi.Bool | None = None       # a links1_phong hit, and its coefficients (eq. 3.11)
    dif: mi.Color3f | None = None
    spe: mi.Color3f | None = None
    expo: mi.Float | None = None
    #: glossy hits and the BSDF-sample context of multiple importance sampling, or None
    glossy: mi.Bool | None = None
    ctx_s: mi.BSDFContext | None = None
    #: the hits whose BSDF is called (``mb`` less ``lam``)
    mcall: mi.Bool | None = None
    #: a ``diffuse`` BSDF of one reflectance (tables.lam, evaluated in :meth:`_lambert`): its
    #: reflectance, cos θ_i > 0 (a twosided's |cos θ_i|), a twosided's back side (wo.z turned)
    lam: mi.Bool | None = None
    lam_rgb: mi.Color3f | None = None
    lam_front: mi.Bool | None = None
    lam_flip: mi.Bool | None = None

    def f_eval(self, wi):
        """Factor multiplying L_s for light direction wi (eq. 3.11 / Mitsuba BSDF)."""
        tables, ad, n, nf, wo, ph = self.tables, self.ad, self.n, self.nf, self.wo, self.ph
        dif, spe, expo, bsdf, ctx, sif = self.dif, self.spe, self.expo, self.bsdf, self.ctx, self.sif
        f = dr.zeros(mi.Color3f, n)
        if tables.any_phong:
            cos_theta = dr.dot(nf, wi)
            mirror = nf * (2.0 * cos_theta) - wi
            cos_phi = dr.maximum(dr.dot(mirror, wo), 0.0)
            if ad:   # d/dn cos^n = cos^n ln cos: no 0 * ln 0 (NaN) where cos_phi = 0
                cp_ = dr.select(cos_phi > 0, cos_phi, 1.0)
                sp = dr.select(expo > 0, dr.select(cos_phi > 0, dr.power(cp_, expo), 0.0), 1.0)
            else:
                sp = dr.select(expo > 0, dr.power(cos_phi, expo), 1.0)
            fp = dif * dr.maximum(cos_theta, 0.0) + spe * sp
            f = dr.select(ph & (cos_theta > 0), fp, f)
        if not tables.all_phong:
            wo_l = sif.to_local(wi)
            if self.lam is not None:
                f = dr.select(self.lam, self._lambert(wo_l), f)
            if self.lam is None or not tables.all_lam:   # a packet of such hits calls no BSDF
                fm = bsdf.eval(ctx, sif, wo_l, self.mcall)
                f = dr.select(self.mcall, fm, f)
        return f

    def _lambert(self, wo_l):
        """A ``diffuse`` BSDF of one reflectance at the light direction ``wo_l`` (local), the
        float operations of Mitsuba 3.9.1's ``SmoothDiffuse::eval`` (diffuse.cpp): cos θ_i =
        wi.z and cos θ_o = wo.z both > 0, ``reflectance * InvPi * cos θ_o``; in a ``twosided``
        (twosided.cpp, one BSDF for both sides): wo.z = mulsign(wo.z, wi.z), wi.z = |wi.z|."""
        co = wo_l.z
        if self.tables.any_lam_two:
            co = dr.select(self.lam_flip, -co, co)
        return dr.select(self.lam_front & (co > 0), self.lam_rgb * dr.inv_pi * co, 0.0)

    def offset(self, direction):
        """The origin of a ray from the hit toward ``direction``: off the surface on that side by
        ``eps`` (relative to 1 + max|p|, per shape: tables.py's OFFSET_EPS)."""
        p, ng, eps = self.p, self.ng, self.eps
        side = dr.select(dr.dot(ng, direction) >= 0, 1.0, -1.0)
        return p + ng * (side * eps)


@dataclass(eq=False)
class Level:
    """What one level of rays gives (:meth:`Tracer.level`): its radiance ``L`` (eq. 3.11),
    ray-primitive tests ``cost``, shadow rays ``n_shadow``, the hit (``t``, ``slot``, ``ns``,
    ``hit``) and, when it spawns, the children of eq. (3.12)-(3.16): mirror and refraction
    weights ``r``, ``tw``, whether each exists (``has_r``, ``has_t``), directions and origins."""

    L: mi.Color3f                   # eq. (3.11): I_o of each lane
    cost: mi.UInt32                 # ray-primitive tests
    t: mi.Float
    slot: mi.Int32
    ns: mi.Vector3f
    hit: mi.Bool
    n_shadow: mi.UInt32             # shadow rays traced
    # -- the children (when the level spawns them): eq. (3.12)-(3.15)
    r: mi.Color3f | None = None     # mirror weight
    tw: mi.Color3f | None = None    # refraction weight
    has_r: mi.Bool | None = None
    has_t: mi.Bool | None = None
    dir_r: mi.Vector3f | None = None
    dir_t: mi.Vector3f | None = None
    o_r: mi.Point3f | None = None
    o_t: mi.Point3f | None = None


class Tracer:
    """One level, the children of a hit, the ray trees of a launch, with the integrator's
    parameters ``config`` (:class:`~.config.Config`: ``max_depth``, ``min_weight``, ``light_samples``,
    read when tracing) and the switches ``tuning`` (:class:`~.tuning.Tuning`) of the frame it
    traces (made per frame by the engine: ``Engine.tracer``). The lights and intersections it
    calls are plain functions (lights.py, intersect.py)."""

    __slots__ = ("config", "tuning")

    def __init__(self, config: Config, tuning: Tuning):
        self.config = config
        self.tuning = tuning

    # -------------------------------------------------------------- one level
    def level(self, tables, scene, o, d, tmin, tmax, key, depth, spawn, active=None, symbolic=True,
               sample=None, later=None, ad=False, keep=None):
        """Trace and shade one ray per lane (inside the megakernel's loop when ``symbolic``).
        ``sample``: the camera sample of a primary hit (see :func:`.lights.light_uv`). ``later``
        (a derivative pass): a list that takes the shadow tests' results the pass keeps in
        memory, for the caller to evaluate (``raytree_ad.trace_tree_ad``: after it has read
        which rays the level spawns, so that reading waits for the hits' kernel only). ``ad``:
        a derivative pass's level (gradients.py: attached tables, no symbolic branches, visibility
        on primal values). ``keep``: a list that takes the nearest hits' preliminary hits
        (``intersect.nearest``'s ``keep``). Returns a :class:`Level`: :meth:`_surface`,
        :meth:`_emitted`, :meth:`_direct` under every light, :meth:`_secondary` when it spawns
        (``spawn``)."""
        n = dr.width(o)
        if active is None:
            active = dr.full(mi.Bool, True, n)
        cost = dr.zeros(mi.UInt32, n)
        n_shadow = dr.zeros(mi.UInt32, n)
        h = self._surface(tables, scene, o, d, tmin, tmax, active, cost, depth, symbolic, ad, keep=keep)
        out = self._emitted(tables, scene, h)
        # ---- direct light with shadows (eq. 3.11, 3-3-3). Shadow rays of all lights are
        # built and evaluated together, then handed to Mitsuba's ray tests (each test
        # evaluates its inputs: building them first avoids recomputing shared work).
        skip = self.tuning.skip_misses and not ad  # under a symbolic if on the hit (no dr.eval inside it)

        # the camera rays' hits' shadow rays in Embree's coherent mode (Tuning.coherent_shadows)
        # where no BSDF has delta lobes: frames 0.95x on the teapot and data_instancing, 1.00x on
        # cbox_point, but 1.04x on the mirror/glass scenes (delta_bsdfs, cbox_mirror_glass)
        coherent = depth == 1 and not tables.any_specular
        # the camera rays' hits: no shadow ray toward a light at a pinhole's eye (not in a
        # derivative pass, whose lights may be attached values)
        free = shadow_plan.eye_lights(tables) if depth == 1 and not ad and self.tuning.eye_lights else None

        def direct(out, cost, n_shadow):
            return self._direct(tables, scene, h, key, sample, symbolic, skip, later, out, cost, n_shadow,
                                coherent=coherent, free=free)

        if skip:
            # (a hit whose BSDF has delta lobes alone gets no direct light: the packets of such
            # hits skip it too)
            lit = h.hit if tables.all_shaded else h.hit & dr.gather(mi.Bool, tables.shaded, h.uslot, h.hit)
            out, cost, n_shadow = dr.if_stmt((out, cost, n_shadow), lit, direct,
                                             lambda out, cost, n_shadow: (out, cost, n_shadow),
                                             mode="symbolic", label="links1_direct")
        else:
            out, cost, n_shadow = direct(out, cost, n_shadow)
        res = Level(L=out, cost=cost, t=h.t, slot=h.slot, ns=h.ns, hit=h.hit, n_shadow=n_shadow)
        if spawn:
            self._secondary(tables, h, res, branch=symbolic and not ad)
        return res

    def _surface(self, tables, scene, o, d, tmin, tmax, active, cost, depth, symbolic, ad, pi=None,
                 keep=None) -> Hit:
        """The nearest hit of each ray (Mitsuba's and the links1 shapes', ``cost`` counting the
        tests) and its surface record: position, geometric and shading normals, Mitsuba's
        interaction record and BSDF where the scene has Mitsuba BSDFs or emitters, the Phong
        coefficients where it has ``links1_phong``, the ray offset's scale. ``pi``, ``keep``:
        ``intersect.nearest``'s (the preliminary hits found before; a list that takes them)."""
        n = dr.width(o)
        if tables.any_mitsuba_shapes and not symbolic:
            dr.eval(o, d, tmin, tmax)
        # level 1 is the camera's rays (from its eye when it is a pinhole)
        eye = depth == 1 and tables.perspective and self.tuning.eye_buffer
        t, slot, si, prim = intersect.nearest(tables, scene, o, d, tmin, tmax, active, cost,
                                              eye=eye, coherent=depth == 1, ad=ad, pi=pi, keep=keep)
        if ad and not symbolic and tables.custom and not tables.any_mitsuba_shapes:
            # a derivative pass through links1 shapes: the search's results (detached) kept in
            # memory, so that each kernel of the AD traversal reads them instead of marching
            # again (with Mitsuba's shapes they are evaluated below)
            dr.eval(t, slot, prim)
        hit = slot >= 0
        uslot = mi.UInt32(dr.maximum(slot, 0))
        # ---- surface record of the winner
        p = o + d * t
        if tables.any_mitsuba_shapes:
            ng, ns = mi.Vector3f(si.n), mi.Vector3f(si.sh_frame.n)
            mits = hit & si.is_valid() & (dr.abs(si.t + tmin - t) <= 0.0)
            p = dr.select(mits, si.p, p)
        else:
            ng = dr.zeros(mi.Vector3f, n)
            ns = dr.zeros(mi.Vector3f, n)
            mits = dr.full(mi.Bool, False, n)
        # a derivative pass with geometry: the links1 shapes' normals on primal values, as their
        # hits (moving_hits below puts in the attached ones of every shape or ray that moves; a
        # blob's sum over a ray's candidate list is a loop, which reverse mode cannot take)
        moving = ad and getattr(tables, "geo_ad", None) is not None
        for spec in tables.custom_unrolled:
            m = slot == spec.slot
            # in the kernel of _nearest's search: a shape may reuse what it found (a blob its candidates)
            with dr.suspend_grad(when=moving):
                nc = spec.normal(o, d, t, prim, reuse=True)
            ng = dr.select(m, nc, ng)
            ns = dr.select(m, nc, ns)
        if tables.bvh is not None:
            qi = dr.gather(mi.Int32, tables.bvh.slot_to_q, uslot, hit)
            m = hit & (qi >= 0)
            nc = tables.bvh.normal(mi.UInt32(dr.maximum(qi, 0)), o, d, t, prim, m)
            ng = dr.select(m, nc, ng)
            ns = dr.select(m, nc, ns)
        if ad and getattr(tables, "geo_ad", None) is not None:
            # a derivative pass with geometry: the hits move with the surfaces (gradients.py)
            t, p, ng, ns = intersect.moving_hits(tables, o, d, t, slot, prim, p, ng, ns)
        wo = -d
        front = dr.dot(ng, wo) > 0
        nf = dr.select(front, ns, -ns)
        # a BSDF call or Mitsuba emitter reads Mitsuba's whole surface record (need_si below)
        need_si = not tables.all_phong or tables.any_mitsuba_emission
        if tables.any_mitsuba_shapes and not symbolic:
            # a derivative pass keeps the hits in memory, and what reads Embree's record later,
            # ``mits`` or the record itself for the BSDF calls and their derivatives (~40 floats
            # a lane, only then): unevaluated, each kernel of the AD traversal would trace
            # again. Launched here, the kernel runs while the rest of the level is traced (made
            # in one kernel with the shadow tests instead, a 256² iteration of the inverse
            # benchmark's light case was 0.1-0.3 ms slower: that overlap lost)
            dr.eval(t, slot, prim, p, ng, ns, nf, cost, *(([mits, si] if need_si else [mits]) if ad else []))
        # Mitsuba-side interaction record for BSDF calls (custom winners filled in)
        if need_si:
            sif = mi.SurfaceInteraction3f(si)
            cw = hit & ~mits
            sif.p = dr.select(cw, p, si.p)
            # (ng is si.n's value wherever no links1 shape won: the select kept for a
            # derivative pass's graph alone)
            sif.n = dr.select(cw, mi.Normal3f(ng), si.n) if ad else mi.Normal3f(ng)
            frame_c = mi.Frame3f(ns)
            sif.sh_frame = mi.Frame3f(dr.select(cw, frame_c.s, si.sh_frame.s),
                                      dr.select(cw, frame_c.t, si.sh_frame.t),
                                      dr.select(cw, frame_c.n, si.sh_frame.n))
            sif.t = dr.select(hit, t, INF)
            sif.uv = dr.select(cw, intersect.custom_uv(tables, o, d, t, prim, slot, uslot, hit), si.uv)
            sif.wi = sif.to_local(wo)
            bsdf = dr.gather(mi.BSDFPtr, tables.bsdf_ptr, uslot, hit)
            # (no links1_phong: no gather of its flags)
            is_ph = dr.gather(mi.Bool, tables.is_phong, uslot, hit) if tables.any_phong else dr.zeros(mi.Bool, n)
            mb = hit & ~is_ph
            ctx = mi.BSDFContext()
        # Phong parameters
        if tables.any_phong:
            ph = hit if tables.all_phong else hit & is_ph
            dif = gather3(tables.dif, uslot, ph)
            spe = gather3(tables.spe, uslot, ph)
            expo = dr.gather(mi.Float, tables.expo, uslot, ph)
        h = Hit(tables, ad, n, o, d, t, slot, uslot, hit, prim, si, p, ng, ns, wo, front, nf, mits)
        if need_si:
            h.sif, h.bsdf, h.is_ph, h.mb, h.ctx, h.mcall = sif, bsdf, is_ph, mb, ctx, mb
        # diffuse BSDFs of one reflectance (tables.lam): evaluated in f_eval, not called; a
        # derivative pass calls them (Mitsuba differentiates the reflectance: its sums' order)
        if need_si and tables.any_lam and not ad:
            # every Mitsuba BSDF such a diffuse: each of their hits is one, no gather of the flags
            lam = h.lam = mb if tables.all_lam else mb & dr.gather(mi.Bool, tables.lam, uslot, mb)
            h.mcall = mb & ~lam
            h.lam_rgb = gather3(tables.lam_rgb, uslot, lam)
            ci = sif.wi.z
            if tables.any_lam_two:
                two = dr.gather(mi.Bool, tables.lam_two, uslot, lam)
                h.lam_flip = two & (ci < 0)
                ci = dr.select(two, dr.abs(ci), ci)
            h.lam_front = lam & (ci > 0)
        if tables.any_phong:
            h.ph, h.dif, h.spe, h.expo = ph, dif, spe, expo
        # ray offsets (relative to 1 + max|p|), per shape: see OFFSET_EPS (tables.py)
        eps_scale = dr.gather(mi.Float, tables.eps_table, uslot, hit)
        h.eps = (1.0 + dr.max(dr.abs(p))) * eps_scale
        # glossy Mitsuba BSDFs under area and environment lights: light samples and one BSDF
        # sample combined by multiple importance sampling (power heuristic, Mitsuba's ``direct``)
        if tables.any_mis and not ad:
            h.glossy = h.mb & dr.gather(mi.Bool, tables.glossy, uslot, h.mb)
            h.ctx_s = mi.BSDFContext()
            h.ctx_s.type_mask = +mi.BSDFFlags.Smooth   # the delta lobes are the ray tree's
        return h

    def _emitted(self, tables, scene, h):
        """What a level's rays see besides direct light: the background of escaping rays
        (Mitsuba's constant / envmap), ambient light (eq. 3.11), the links1 shapes' and
        Mitsuba's emission."""
        n, hit, uslot, mits, wo, front = h.n, h.hit, h.uslot, h.mits, h.wo, h.front
        si, sif = h.si, h.sif
        out = dr.zeros(mi.Color3f, n)
        # ---- escaping rays: background (Mitsuba constant / envmap)
        if tables.env is not None:
            sim = dr.zeros(mi.SurfaceInteraction3f, n)
            sim.wi = wo
            sim.t = mi.Float(INF)
            out = dr.select(hit, out, tables.env.eval(sim, ~hit))
        # ---- ambient (eq. 3.11, dic) and emission
        if tables.any_ambient:
            out += dr.select(hit, gather3(tables.amb, uslot, hit), 0.0)
        if tables.any_custom_emission:
            out += dr.select(hit & front & ~mits, gather3(tables.custom_emission, uslot, hit), 0.0)
        if tables.any_mitsuba_emission:
            emits = mits & dr.gather(mi.Bool, tables.mitsuba_emits, uslot, mits)
            em = si.emitter(scene, emits)
            out += dr.select(emits, em.eval(sif, emits), 0.0)
        return out

    def _direct(self, tables, scene, h, key, sample, symbolic, skip, later, out, cost, n_shadow, coherent=False,
                free=None):
        """Direct light with shadows (eq. 3.11, 3-3-3) added to ``out``: every analytic light,
        ``light_samples`` samples of each area and environment light (with a BSDF sample and
        multiple importance sampling at glossy hits), their shadow rays built together and
        handed to the ray tests (``coherent``: the hits are the camera rays', neighbours in the
        lanes: ``intersect.shadow_mitsuba``'s; ``free``: per analytic light, True where no hit
        needs a shadow ray toward it, ``shadow_plan.eye_lights``). Returns ``(out, cost, n_shadow)``."""
        n, hit, slot, uslot, p, ng, nf, eps, ad = h.n, h.hit, h.slot, h.uslot, h.p, h.ng, h.nf, h.eps, h.ad
        bsdf, sif, glossy, ctx_s = h.bsdf, h.sif, h.glossy, h.ctx_s
        f_eval, offset = h.f_eval, h.offset
        mis = glossy is not None
        pending = []

        def need_of(j, lit, wi):
            """Lanes that need a shadow ray toward light j (tables.shadow_need: shadow_plan.plan_occluders)."""
            if not tables.any_shadow[j]:
                return dr.zeros(mi.Bool, n)
            if tables.shadow_need[j] is None:
                return lit
            need = dr.gather(mi.Bool, tables.shadow_need[j], uslot, lit)
            if tables.shadow_inner[j] is not None:  # light on the inner side of a closed convex shape
                need |= dr.gather(mi.Bool, tables.shadow_inner[j], uslot, lit) & (dr.dot(ng, wi) <= 0)
            return lit & need

        def shadow(j, so, wi, smax, lit, contrib):
            nonlocal n_shadow
            if not tables.any_shadow[j] or (free is not None and j < len(free) and free[j]):
                # nothing can shadow this light (at the eye: the camera ray backwards)
                return None, lit, None
            need = need_of(j, lit, wi)
            n_shadow = n_shadow + dr.select(need, mi.UInt32(1), 0)
            T = intersect.shadow_custom(tables, so, wi, smax, need, cost, tables.occ_custom[j], light=j)
            return T, need, tables.occ_mitsuba[j]

        def own_outer(wi):
            """The hit's slot where the shadow ray leaves it on the outer side, else -1."""
            return dr.select(hit & (dr.dot(ng, wi) > 0), slot, -1)

        for jl, L in enumerate(tables.lights):
            wi, dist, Ls = lights.light_at(L, p)
            contrib = f_eval(wi) * Ls
            lit = hit & (dr.max(contrib) > 0)
            so, smax = offset(wi), dist - 2.0 * eps
            if ad:   # visibility on primal values (the shadow ray's place is attached)
                so, wi, smax = dr.detach(so), dr.detach(wi), dr.detach(smax)
            T, need, occ_m = shadow(jl, so, wi, smax, lit, contrib)
            pending.append((contrib, so, wi, smax, lit, need, T, occ_m, jl))
        m_inv = 1.0 / self.config.light_samples
        sampled = [(len(tables.lights) + j, tab, tab["id"]) for j, tab in enumerate(tables.area_tab)]
        sampled += [(len(tables.lights) + len(tables.area) + k, env, lid) for k, env in enumerate(tables.consts)
                    for lid in [env.light_id]]
        for jsh, tab, lid in sampled:          # area lights and environments (links1.shading.lights)
            for js in range(self.config.light_samples):
                u, v = lights.light_uv(key, sample, lid, js, self.config.light_samples)
                if isinstance(tab, dict):
                    wi, dist, Lw, pdf_l = lights.sample_area(tab, p, u, v)
                    # Mitsuba's ray tests include the emitter: stop short of it as Mitsuba does
                    smax = dist * (1.0 - mi.math.ShadowEpsilon) - 2.0 * eps
                else:
                    wi, Lw, pdf_l = lights.sample_env(tab, nf, u, v)
                    smax = dr.full(mi.Float, INF, n)
                contrib = f_eval(wi) * Lw * m_inv
                if mis:
                    pdf_b = bsdf.pdf(ctx_s, sif, sif.to_local(wi), glossy)
                    contrib *= dr.select(glossy, _power_heuristic(self.config.light_samples * pdf_l, pdf_b), 1.0)
                lit = hit & (dr.max(contrib) > 0)
                so = offset(wi)
                if ad:
                    so, wi, smax = dr.detach(so), dr.detach(wi), dr.detach(smax)
                T, need, occ_m = shadow(jsh, so, wi, smax, lit, contrib)
                pending.append((contrib, so, wi, smax, lit, need, T, occ_m, jsh))
        if mis:
            sampler_b, opacity_b = self._unmasked(tables, bsdf, sif, uslot, glossy)
            L_b, n_b = self._bsdf_sample_light(tables, scene, key, sample, sampler_b, ctx_s, sif, glossy,
                                               p, nf, offset, cost, opacity_b)
            out += L_b
            n_shadow = n_shadow + n_b
        if not symbolic:
            # in one kernel: a derivative pass's shadow tests through links1 shapes (kept, as
            # the hits above), and the inputs of Mitsuba's ray tests where one follows; with
            # no such test, the tests go to ``later`` (the caller evaluates them)
            ev = [tup[6] for tup in pending if tup[6] is not None] if ad and tables.custom else []
            if tables.any_mitsuba_shapes and not skip and any(tup[7] for tup in pending):
                ev += [out, cost, *[x for tup in pending for x in tup[:6]]]
            elif later is not None:
                later.extend(ev)
                ev = []
            if ev:
                dr.eval(*ev)
        tested = []                     # Mitsuba's ray tests, light by light
        for k, (contrib, so, wi, smax, lit, need, T, occ_m, j) in enumerate(pending):
            if T is not None and tables.any_mitsuba_shapes and occ_m:
                T = intersect.shadow_mitsuba(tables, scene, so, wi, smax, need, T, cost, self.tuning, light=j,
                                             own=own_outer(wi), coherent=coherent)
                pending[k] = (contrib, so, wi, smax, lit, need, T, occ_m, j)
                tested.append(T)
        if ad and not symbolic and tested:   # the ray tests kept (as the hits above), in one kernel
            dr.eval(*tested)
        for contrib, so, wi, smax, lit, need, T, occ_m, j in pending:
            if T is None:               # nothing can shadow this light
                out += dr.select(lit, contrib, 0.0)
                continue
            out += dr.select(lit, contrib * dr.select(need, T, 1.0), 0.0)
        return out, cost, n_shadow

    def _secondary(self, tables, h, res, branch=False):
        """The children of each hit, eq. (3.12)-(3.16): Phong mirror and refraction weights and
        directions, and Mitsuba BSDFs' delta lobes (mirror, glass, the straight-through
        ``Null`` lobe), set on ``res`` with their origins. ``branch``: the lobes under a
        symbolic ``dr.if_stmt`` on the hits whose slot has one (``tables.spawns``)."""
        n, d, hit, uslot, offset = h.n, h.d, h.hit, h.uslot, h.offset
        zero = (dr.zeros(mi.Color3f, n), dr.zeros(mi.Color3f, n), dr.zeros(mi.Vector3f, n),
                dr.zeros(mi.Vector3f, n))
        if branch:
            spawns = hit & dr.gather(mi.Bool, tables.spawns, uslot, hit)
            r, tw, dir_r, dir_t = dr.if_stmt(zero, spawns, lambda *z: self._lobes(tables, h, *z),
                                             lambda *z: z, mode="symbolic", label="links1_lobes")
        else:
            r, tw, dir_r, dir_t = self._lobes(tables, h, *zero)
        has_r = hit & (dr.max(r) > 0)
        has_tt = hit & (dr.max(tw) > 0)
        dir_r = dr.normalize(dir_r)
        dir_t = dr.normalize(dir_t)
        res.r, res.tw, res.has_r, res.has_t = r, tw, has_r, has_tt
        res.dir_r, res.dir_t, res.o_r, res.o_t = dir_r, dir_t, offset(dir_r), offset(dir_t)

    def _lobes(self, tables, h, r, tw, dir_r, dir_t):
        """The mirror and refraction weights and directions ``(r, tw, dir_r, dir_t)`` of the
        hits (:meth:`_secondary`), from zeros."""
        d, nf, front, uslot = h.d, h.nf, h.front, h.uslot
        ph, mb, bsdf, sif = h.ph, h.mb, h.bsdf, h.sif
        if tables.any_phong_r or tables.any_phong_t:
            cos_i = -dr.dot(d, nf)
            dir_r = d + nf * (2.0 * cos_i)                                  # eq. (3.12)
            r = dr.select(ph, gather3(tables.refl, uslot, ph), r)
            if tables.any_phong_t:
                tt = gather3(tables.trans, uslot, ph)
                ior = dr.gather(mi.Float, tables.ior, uslot, ph)
                eta = dr.select(front, 1.0 / ior, ior)                        # η = η_i/η_t
                S = (d + nf * cos_i) * eta                                     # eq. (3.14)
                s2 = dr.squared_norm(S)
                has_t = ph & (dr.max(tt) > 0)
                tir = has_t & (s2 > 1.0)
                r = dr.select(tir, r + tt, r)
                tw = dr.select(has_t & ~tir, tt, 0.0)
                dir_t = S - nf * dr.safe_sqrt(1.0 - s2)                       # eq. (3.15)
        if tables.any_mitsuba_delta:
            lobes = [(mi.BSDFFlags.DeltaReflection, "r")] if tables.any_mitsuba_dr else []
            if tables.any_mitsuba_dt:
                lobes.append((mi.BSDFFlags.DeltaTransmission, "t"))
            sampler, opacity = bsdf, None
            if tables.any_mitsuba_dr or tables.any_mitsuba_dt:
                sampler, opacity = self._unmasked(tables, bsdf, sif, uslot, mb)
            for flag, which in lobes:   # only the delta lobes some BSDF of the scene has
                for c, table in tables.delta_components[which]:
                    # one component at a time (a blendbsdf's nested ones, weighted by its weight)
                    act = mb & dr.gather(mi.Bool, table, uslot, mb)
                    cx = mi.BSDFContext()
                    cx.type_mask = +flag
                    cx.component = c
                    bs, w = sampler.sample(cx, sif, mi.Float(0.5), mi.Point2f(0.5, 0.5), act)
                    ok = act & (bs.pdf > 0) & (dr.max(w) > 0) & \
                        ((bs.sampled_type & mi.UInt32(+flag)) != 0)
                    if opacity is not None:
                        w = w * opacity
                    dw = sif.to_world(bs.wo)
                    if which == "r":
                        r = dr.select(ok, r + w, r)
                        dir_r = dr.select(ok, dw, dir_r)
                    else:
                        tw = dr.select(ok, tw + w, tw)
                        dir_t = dr.select(ok, dw, dir_t)
            if tables.any_mitsuba_null:
                # the straight-through delta lobe (Mitsuba's BSDFFlags::Null: thindielectric's
                # transmission T' = 1 - R', R' = 2R/(1+R); a mask's 1 - opacity; null): weight
                # eval_null_transmission, direction unchanged, as Mitsuba's path follows it
                act = mb & dr.gather(mi.Bool, tables.has_null, uslot, mb)
                wn = bsdf.eval_null_transmission(sif, act)
                ok = act & (dr.max(wn) > 0)
                tw = dr.select(ok, wn, tw)
                dir_t = dr.select(ok, d, dir_t)
        return r, tw, dir_r, dir_t

    @staticmethod
    def _unmasked(tables, bsdf, sif, uslot, active):
        """``(sampler, opacity)``: where a slot's BSDF is a ``mask``, its nested BSDF and the
        opacity, ``(1 - null(mask)) / (1 - null(nested))`` (Mitsuba's mask: null = 1 - a (1 -
        null')); its lobes are the nested one's times the opacity. Mitsuba's ``mask.sample``
        cannot sample the nested lobes alone (asked for them only, it returns its null lobe).
        ``(bsdf, None)`` in a scene without masks."""
        if not tables.any_mask:
            return bsdf, None
        sampler = dr.gather(mi.BSDFPtr, tables.inner_ptr, uslot, active)
        om = dr.sum(1.0 - bsdf.eval_null_transmission(sif, active))
        on = dr.sum(1.0 - sampler.eval_null_transmission(sif, active))
        return sampler, dr.select(on > 0, om / dr.maximum(on, 1e-30), 0.0)

    def _bsdf_sample_light(self, tables, scene, key, sample, bsdf, ctx, sif, active, p, nf, offset, cost,
                           opacity=None):
        """The BSDF-sampled part of the direct light at glossy hits ``active``: one direction
        drawn by the BSDF's smooth lobes at the hit's BSDF sample (:meth:`_bsdf_uv`), traced
        (nearest hit over every shape); where it meets a sampled area light's front or escapes to
        an environment light, that light's radiance times the BSDF's weight, weighted by the
        power heuristic against that light's ``light_samples`` samples (their pdf:
        :meth:`_area_pdf`, :meth:`_env_eval_pdf`). Returns (radiance, rays traced)."""
        n = dr.width(p)
        u1, u, v = lights.bsdf_uv(key, sample)
        bs, weight = bsdf.sample(ctx, sif, u1, mi.Point2f(u, v), active)
        if opacity is not None:    # a mask's nested lobes (its pdf is the nested one's: mask.pdf)
            weight = weight * opacity
        wi = sif.to_world(bs.wo)
        ok = active & (bs.pdf > 0) & (dr.max(weight) > 0)
        t, slot, si, _ = intersect.nearest(tables, scene, offset(wi), wi, dr.zeros(mi.Float, n),
                                           dr.full(mi.Float, INF, n), ok, cost)
        m = self.config.light_samples
        out = dr.zeros(mi.Color3f, n)
        for tab in tables.area_tab:
            if tab["slot"] is None:
                continue
            on = ok & (slot == tab["slot"]) & (dr.dot(si.n, wi) < 0)   # the light's front side
            pdf_l = lights.area_pdf(tab, p, wi, dr.norm(si.p - p), si.n)
            Le = si.emitter(scene, on).eval(si, on)   # Mitsuba's own radiance there (a texture too)
            out += dr.select(on, weight * Le * _power_heuristic(bs.pdf, m * pdf_l), 0.0)
        if tables.consts:
            on = ok & (slot < 0)
            for env in tables.consts:
                Le, pdf_l = lights.env_eval_pdf(env, nf, wi)
                out += dr.select(on, weight * Le * _power_heuristic(bs.pdf, m * pdf_l), 0.0)
        return out, dr.select(ok, mi.UInt32(1), 0)

    # -------------------------------------------------------------- the tree
    def children(self, res, act, wgt, depth):
        """Which children a hit spawns (eq. 3.12-3.16, ``max_depth``, weight threshold as
        the core) and their weights in the pixel."""
        md, mw = self.config.max_depth, float(self.config.min_weight)
        deeper = act & (depth < md)
        w_r, w_t = wgt * res.r, wgt * res.tw
        cr = deeper & res.has_r
        ct = deeper & res.has_t
        if mw > 0:
            cr &= dr.max(w_r) > mw
            ct &= dr.max(w_t) > mw
        return cr, ct, w_r, w_t

    def _remade_children(self, tables, scene, rays, kept):
        """The children of camera rays ``rays = (o, d, tmin, tmax, key)`` from their preliminary
        hits (``intersect.kept_hit``'s arrays ``kept``, at the same lanes): level 1's record
        (:meth:`_surface`) and children (:meth:`_secondary`, :meth:`children`) made again with
        the same operations -> ``((cr, ct), (o_r, d_r, w_r, key_r, o_t, d_t, w_t, key_t))``, with
        ``cr``, ``ct`` the lanes with a mirror and a refraction child (:meth:`children`)."""
        o, d, tmin, tmax, key = rays
        m = dr.width(kept[2])
        h = self._surface(tables, scene, o, d, tmin, tmax, dr.full(mi.Bool, True, m), dr.zeros(mi.UInt32, m), 1,
                          True, False, pi=intersect.remade_hit(kept))
        res = Level(L=None, cost=None, t=h.t, slot=h.slot, ns=h.ns, hit=h.hit, n_shadow=None)
        self._secondary(tables, h, res)
        cr, ct, w_r, w_t = self.children(res, res.hit, mi.Color3f(1.0), mi.UInt32(1))
        key_r, key_t = child_keys(key)
        return (cr, ct), (res.o_r, res.dir_r, w_r, key_r, res.o_t, res.dir_t, w_t, key_t)

    def trace_tree(self, tables, scene, o, d, tmin, tmax, key, want_aovs, sample, frozen=None, rays=None):
        """All ray trees: the camera level in one kernel, the rest in a "megakernel".

        Level 1 (every sample) is straight-line code. The samples whose hit spawns a
        mirror or refraction ray are compacted (``dr.compress``), and one symbolic
        ``dr.while_loop`` traces the rest of their trees, one ray per iteration: the mirror
        child (eq. 3.12) is followed next, a refraction child (eq. 3.14-3.15) with a mirror
        sibling waits on a small per-lane stack (Dr.Jit local memory, at most
        ``max_depth - 1`` entries). ``I = I_o + r I_r + t I_t`` (eq. 3.16) is accumulated as
        ``Σ weight · I_o`` with the weight the product of the factors down the tree (the
        core's sum in another order). Lanes never interact and the compaction keeps the
        order of samples, so a window renders the same bits as the full frame; the window
        is a run-time value (no recompilation). Returns ``(RGB, cost, t0, slot0, ns0,
        counters)`` with ``counters`` the arrays ``launch.counts`` sums (no read-back here).
        ``sample``: the camera sample of the rays (``launch.camera_rays``; None: the rays' keys
        alone, as ``trace_points``).

        ``frozen``: the sample count as an opaque ``UInt32`` when traced inside
        :func:`drjit.freeze` (``Launches``' frozen launches), so no Python decision may depend on data:
        the compaction always keeps the last two samples too (a lane without children starts
        inactive and adds exact zeros, the same bits as no lane), so the loop exists whatever
        the recorded pixels held (two lanes: a recording with one would treat the loop's
        arrays as scalars and replay wrongly).

        ``rays``: the camera rays of some of the lanes, ``rays(idx) -> (o, d, tmin, tmax, key)``,
        the same values as the arguments' at ``idx`` (None: not given). With it, where the
        kernel makes the nearest hit's record from the preliminary hit (``intersect.remakes``),
        the camera level stores of each hit only its preliminary hit (six arrays:
        ``intersect.kept_hit``) instead of its children's origins, directions, weights and
        keys (20 arrays, of every sample, where the children are those of about a quarter of
        them), and the loop's kernel makes level 1's record and children again on the
        compacted lanes (:meth:`_remade_children`: the same operations, the same bits). The
        camera level then computes no lobes (:data:`LOBES_IN_LOOP`): the samples whose hit is
        on a slot that can spawn (``Prepared.spawns``) are compacted, those without a child
        start inactive in the loop, and the counters of level 1's children (``cr``, ``ct``)
        are arrays of the compacted lanes.
        """
        n = dr.width(o)
        md = self.config.max_depth
        spawn = md > 1 and tables.any_specular
        one = mi.UInt32(1)
        remake = spawn and rays is not None and intersect.remakes(tables)
        keep = [] if remake else None
        # (remade: the children's lobes too are computed in the loop's kernel alone)
        lobes1 = not (remake and LOBES_IN_LOOP)
        res = self.level(tables, scene, o, d, tmin, tmax, key, 1, spawn and lobes1, sample=sample, keep=keep)
        aov = (res.t, res.slot, res.ns) if want_aovs else ()
        if not spawn:
            rgb = mi.Color3f(res.L)
            dr.eval(rgb, res.cost, res.n_shadow, *aov)
            return rgb, res.cost, res.t, res.slot, res.ns, dict(nsh1=res.n_shadow)
        act = res.hit
        has_t = tables.any_phong_t or tables.any_mitsuba_dt or tables.any_mitsuba_null
        if lobes1:
            cr, ct, w_r, w_t = self.children(res, act, mi.Color3f(1.0), mi.UInt32(1))
            split, flags = cr | ct, (cr, ct)
        else:   # the hits on slots that can spawn (Prepared.spawns): the loop's kernel tells
            split = act & dr.gather(mi.Bool, tables.spawns, mi.UInt32(dr.maximum(res.slot, 0)), act)
            flags = (split,)
        if remake:  # the children made again from the hit in the loop's kernel
            kids = intersect.kept_hit(keep[0])
        else:
            key_r, key_t = child_keys(key)
            if has_t:
                kids = (res.o_r, res.dir_r, w_r, key_r, res.o_t, res.dir_t, w_t, key_t)
            else:       # no refraction anywhere: no refraction children to store
                kids = (res.o_r, res.dir_r, w_r, key_r)
        L1, cost1, nsh1 = res.L, res.cost, res.n_shadow
        dr.eval(L1, cost1, nsh1, *flags, *aov, *kids)                  # kernel 1: level 1
        if frozen is not None:  # the last two samples always: a width of 1 would record as a scalar
            ar = dr.arange(mi.UInt32, n)
            idx = dr.compress(split | (ar + 2 >= frozen))  # n: an input, not a literal
        else:
            idx = dr.compress(split)
        m = dr.width(idx)
        # (the counters of level 1's children: of every lane, or of the compacted ones)
        counters = dict(nsh1=nsh1, cr=cr, ct=ct) if lobes1 else dict(nsh1=nsh1)
        if m == 0:
            return L1, cost1, res.t, res.slot, res.ns, counters
        g = lambda x: dr.gather(type(x), x, idx)  # noqa: E731
        ch = [g(x) for x in kids]
        if remake:
            made, ch = self._remade_children(tables, scene, rays(idx), ch)
        o_r, d_r, wr, kr = ch[:4]
        o_t, d_t, wt, kt = ch[4:] if has_t else ch[:4]
        if lobes1:
            gr, gt = g(cr), g(ct)
        else:
            gr, gt = made
            counters.update(cr=gr, ct=gt)
        push = gr & gt
        K = md - 1
        stk_f = dr.alloc_local(mi.Float, 9 * K, mi.Float(0.0))   # o, d, weight per entry
        stk_u = dr.alloc_local(mi.UInt32, 2 * K, mi.UInt32(0))   # depth, key per entry
        zu = dr.zeros(mi.UInt32, m)
        if has_t:
            stk_f, stk_u = _push(stk_f, stk_u, zu, o_t, d_t, wt, zu + 2, kt, push)
        state = dict(o=mi.Point3f(dr.select(gr, o_r, o_t)), d=mi.Vector3f(dr.select(gr, d_r, d_t)),
                     wgt=mi.Color3f(dr.select(gr, wr, wt)),
                     depth=zu + 2, key=dr.select(gr, kr, kt), L=dr.zeros(mi.Color3f, m),
                     cost=mi.UInt32(zu), sp=dr.select(push, one, 0), active=gr | gt,
                     nsh=mi.UInt32(zu), nr=mi.UInt32(zu), nt=mi.UInt32(zu))
        names = list(state)

        def cond(stk_f, stk_u, *vals):
            return vals[names.index("active")]

        def body(stk_f, stk_u, *vals):
            v = dict(zip(names, vals))
            act = v["active"]
            mm = dr.width(v["o"])
            res = self.level(tables, scene, v["o"], v["d"], dr.zeros(mi.Float, mm), dr.full(mi.Float, INF, mm),
                              v["key"], 0, True, active=act)
            wgt = v["wgt"]
            L = v["L"] + wgt * res.L
            cost = v["cost"] + res.cost
            cr, ct, w_r, w_t = self.children(res, act, wgt, v["depth"])
            key_r, key_t = child_keys(v["key"])
            sp = v["sp"]
            push = cr & ct
            if has_t:
                stk_f, stk_u = _push(stk_f, stk_u, sp, res.o_t, res.dir_t, w_t, v["depth"] + 1, key_t, push)
            pop = act & ~cr & ~ct & (sp > 0)
            fp, dp, kp = _pop(stk_f, stk_u, dr.select(pop, sp - 1, 0), pop)
            o_n = dr.select(cr, res.o_r, dr.select(ct, res.o_t, mi.Point3f(fp[0], fp[1], fp[2])))
            d_n = dr.select(cr, res.dir_r, dr.select(ct, res.dir_t, mi.Vector3f(fp[3], fp[4], fp[5])))
            w_n = dr.select(cr, w_r, dr.select(ct, w_t, mi.Color3f(fp[6], fp[7], fp[8])))
            depth_n = dr.select(cr | ct, v["depth"] + 1, dp)
            key_n = dr.select(cr, key_r, dr.select(ct, key_t, kp))
            sp = dr.select(push, sp + 1, dr.select(pop, sp - 1, sp))
            out = dict(o=mi.Point3f(o_n), d=mi.Vector3f(d_n), wgt=mi.Color3f(w_n), depth=depth_n, key=key_n, L=L, cost=cost, sp=sp,
                       active=cr | ct | pop, nsh=v["nsh"] + res.n_shadow,
                       nr=v["nr"] + dr.select(cr, one, 0), nt=v["nt"] + dr.select(ct, one, 0))
            return (stk_f, stk_u, *[out[k] for k in names])

        result = dr.while_loop((stk_f, stk_u, *[state[k] for k in names]), cond, body,
                               label="links1_whitted")
        v = dict(zip(names, result[2:]))
        # materialise the loop's outputs, and the sums with level 1's, in one kernel first:
        # scatters into arrays of another size are scheduled as their own kernel, which would
        # re-run the loop
        L_sum, cost_sum = g(L1) + v["L"], g(cost1) + v["cost"]
        dr.eval(L_sum, cost_sum, v["nsh"], v["nr"], v["nt"], *([] if lobes1 else [gr, gt]))   # kernel 2: the trees
        # one child forest per sample (idx is unique: no races). The scatter targets are the
        # level-1 arrays themselves, whose width is the input's at every replay (a zeros(n)
        # target would keep the recorded width; a scatter_add would force freeze to dry-run),
        # with no other reference left, so that the scatter writes them in place (a target
        # still referenced, or read by a pending gather, is copied first: n lanes a channel)
        total, cost = L1, cost1
        del L1, cost1
        res.L = res.cost = None
        dr.scatter(total, L_sum, idx)
        dr.scatter(cost, cost_sum, idx)
        dr.eval(total, cost)
        counters.update(nr=v["nr"], nt=v["nt"], nsh2=v["nsh"])
        return total, cost, res.t, res.slot, res.ns, counters
