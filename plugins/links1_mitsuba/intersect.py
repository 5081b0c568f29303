"""Intersection in ``links1_whitted`` (its one home): the nearest hit of each ray over Mitsuba's
shapes (``scene.ray_intersect``) and the links1 quadrics and blobs in Dr.Jit, nearest wins, ties
to the lower slot (``_nearest``); the transmittance of shadow rays (3-3-3) through the links1
shapes (``_shadow_custom``) and Mitsuba's (``_shadow_mitsuba``), each shape counted once; the
uv of hits on textured links1 quadrics (``_custom_uv``). Many links1 quadrics go under a BVH
(:mod:`links1_mitsuba.bvh`).

:class:`Intersect` is a base class of the ``Engine`` (engine.py); its methods name
``mi.Float``, ``mi.Ray3f``, ... when called, so the class serves every Mitsuba variant.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from .shapes import quadric_uv
from .util import INF, c3, gather3, next_up

# the switches read here (preliminary, box_cull, eye_buffer, split) are fields of
# tuning.Tuning, read while tracing: a frozen launch is keyed on them (launch.py)


class Intersect:
    """Nearest hits, shadow transmittance, uv of custom hits."""

    __slots__ = ()

    # -------------------------------------------------------------- geometry
    def _nearest(self, P, scene, o, d, tmin, tmax, active, cost, camera=False, coherent=False, ad=False):
        """Nearest hit over Mitsuba shapes and custom shapes: (t, slot, si, prim, custom_won).
        ``camera``: the rays start at a pinhole camera's eye (its buffer replaces the BVH).
        ``ad``: a derivative pass's rays (the links1 shapes' hits found on primal values).
        ``coherent``: the camera's rays, neighbours in the lanes (Embree's coherent mode, as
        Mitsuba's own integrators trace their camera rays: ~1.2-2x faster for spp 16 eye rays;
        a ray that meets an edge shared by two triangles at the same distance may get the other
        one, as in Mitsuba)."""
        if P.any_mitsuba_shapes:
            ray = mi.Ray3f(o + d * tmin, d, tmax - tmin)
            si = scene.ray_intersect(ray, mi.RayFlags.All, bool(coherent), active)
            valid = active & si.is_valid()
            t = dr.select(valid, si.t + tmin, INF)
            reg = dr.reinterpret_array(mi.UInt32, si.shape)
            slot = dr.select(valid, dr.gather(mi.Int32, P.reg_to_slot, reg, valid), -1)
            cost += dr.select(active, mi.UInt32(1), 0)
        else:
            si = dr.zeros(mi.SurfaceInteraction3f, dr.width(o))
            t = dr.full(mi.Float, INF, dr.width(o))
            slot = dr.full(mi.Int32, -1, dr.width(o))
        prim = dr.zeros(mi.UInt32, dr.width(o))
        if ad:
            # a derivative pass: the links1 shapes' hits on primal values (re-attached by
            # gradients._surface_ad: implicit differentiation, not through the solvers)
            with dr.suspend_grad():
                t, slot, prim = self._nearest_custom(P, o, d, tmin, tmax, active, cost, camera, t, slot, prim)
            return t, slot, si, prim
        t, slot, prim = self._nearest_custom(P, o, d, tmin, tmax, active, cost, camera, t, slot, prim)
        return t, slot, si, prim

    def _nearest_custom(self, P, o, d, tmin, tmax, active, cost, camera, t, slot, prim):
        """:meth:`_nearest` over the links1 shapes, from the Mitsuba hit ``(t, slot, prim)``."""
        # ties at the same distance go to the lower slot (file order), as in the core
        # (links1.geometry.accel): a shape after the current best may not tie, one before it may
        for spec in P.custom_unrolled:
            tt = dr.minimum(t, tmax)
            tt = dr.select(slot > spec.slot, next_up(tt), tt)
            if spec.__class__.__name__ == "BlobSpec":
                tc, pc = spec.intersect(o, d, tmin, tt, active, cost)
            else:
                tc, pc = spec.intersect(o, d, tmin, tt, active)
                cost += dr.select(active, mi.UInt32(1), 0)
            better = (tc < t) | ((tc == t) & (slot > spec.slot))
            t = dr.select(better, tc, t)
            slot = dr.select(better, spec.slot, slot)
            prim = dr.select(better, pc, prim)
        if P.bvh is not None:
            eye = P.eye_buf if camera and self.current_tuning().eye_buffer else None
            tq, q, part, found = (eye or P.bvh).nearest(o, d, tmin, next_up(dr.minimum(t, tmax)), active, cost)
            sq = mi.Int32(dr.gather(mi.UInt32, P.bvh.slot, q, found))
            better = found & ((tq < t) | ((tq == t) & ((slot < 0) | (sq < slot))))
            t = dr.select(better, tq, t)
            slot = dr.select(better, sq, slot)
            prim = dr.select(better, part, prim)
        return t, slot, prim

    def _shadow_custom(self, P, o, d, smax, active, cost, specs=None, light=None):
        """Transmittance (3-3-3) through the links1 shapes: product of shadow_t over the
        shapes the segment hits, once per shape. The BVH's quadrics through the light
        buffer of analytic light ``light`` where it has one (lightbuffer.py), else the BVH."""
        T = dr.select(active, mi.Color3f(1.0), mi.Color3f(0.0))
        specs = P.custom if specs is None else specs
        if P.bvh is not None:
            if any(sp.slot in P.bvh_slots for sp in specs):
                lb = P.lbuf[light] if light is not None and light < len(P.lbuf) else None
                if lb is not None:
                    T = lb.transmittance(o, d, smax, active, cost)
                else:
                    T = P.bvh.transmittance(o, d, smax, active, cost)
            specs = [sp for sp in specs if sp.slot not in P.bvh_slots]
        for spec in specs:
            st = P.shadow_t_np[spec.slot]
            act = active & (dr.max(T) > 0)
            if spec.__class__.__name__ == "BlobSpec":
                tc, _ = spec.intersect(o, d, 0.0, smax, act, cost, any_hit=True)
            else:
                tc, _ = spec.intersect(o, d, 0.0, smax, act)
                cost += dr.select(act, mi.UInt32(1), 0)
            hit = act & (tc < INF)
            T = dr.select(hit, T * c3(st), T)
        return T

    @staticmethod
    def _meets_boxes(o, d, smax, boxes, own):
        """Lanes whose segment ``o + t d``, 0 <= t <= smax, can meet one of ``boxes``
        (``shadow_plan.occluder_boxes``): a slab test made conservative in float32 (Ize 2013: the
        far distance widened by 1 + 2 gamma_3; the segment's end by 2^-16); a zero
        direction component is replaced by 1e-30 (no 0 * inf). A convex shape's box is skipped where the ray leaves that shape
        on its outer side (``own``: the hit's slot there, else -1; the rule of
        ``shadow_plan.plan_occluders``)."""
        widen = 1.0 + 2.0 * (3.0 * 2.0 ** -24) / (1.0 - 3.0 * 2.0 ** -24)
        inv = [1.0 / dr.select(d[k] == 0, 1e-30, d[k]) for k in range(3)]
        far_max = smax * (1.0 + 2.0 ** -16)   # Mitsuba's t at a segment's end: its own rounding
        meet = dr.zeros(mi.Bool, dr.width(o))
        for lo, hi, sl, convex in boxes:
            near, far = mi.Float(0.0), far_max
            for k in range(3):
                t0 = (lo[k] - o[k]) * inv[k]
                t1 = (hi[k] - o[k]) * inv[k]
                near = dr.maximum(near, dr.minimum(t0, t1))
                far = dr.minimum(far, dr.maximum(t0, t1) * widen)
            m = near <= far
            if convex:
                m &= own != sl
            meet |= m
        return meet

    def _shadow_mitsuba(self, P, scene, o, d, smax, active, T, cost, light=None, own=None):
        """Continue the transmittance ``T`` through Mitsuba's shapes (once per shape): per
        group of shapes (:meth:`_shadow_groups`) its query, which a packet whose segments
        meet none of the group's occluder boxes of ``light`` skips (``P.occ_boxes``;
        ``own``: see :meth:`_meets_boxes`)."""
        if not P.any_mitsuba_shapes:
            return T
        boxes = P.occ_boxes[light] if self.current_tuning().box_cull and light is not None else None
        occ = P.occ_mslots[light] if light is not None else None
        inc = dr.zeros(mi.UInt32, dr.width(o))
        for slots, query in self._shadow_groups(P, scene, o, d, smax, occ):
            mine = None if boxes is None else [b for b in boxes if slots is None or b[2] in slots]
            if mine is not None and not mine:
                continue                       # none of these shapes can shadow this light
            run = active & (dr.max(T) > 0)
            if mine is None:
                T, inc = query(T, inc, run)
            else:
                run &= self._meets_boxes(o, d, smax, mine, own)
                T, inc = dr.if_stmt((T, inc), run, lambda T, inc, q=query, r=run: q(T, inc, r),
                                    lambda T, inc: (T, inc), mode="symbolic", label="links1_shadow_boxes")
        cost += inc
        return T

    def _shadow_groups(self, P, scene, o, d, smax, occ):
        """``[(slots, query)]``: the Mitsuba shapes a shadow segment is tested against, by
        group (``slots`` None: all of them), ``query(T, tests, lanes) -> (T, tests)``. With
        ``P.shadow_split`` (``shadow_plan.shadow_split``) an any-hit query on the opaque shapes'
        sub-scene (T = 0) and one on each transparent shape's (T times its transmittance),
        skipping groups that cannot occlude (``occ``: the light's occluder slots); else the
        scene with :meth:`_shadow_embree`."""
        split = P.shadow_split if self.current_tuning().split else None
        if split is None:
            return [(None, lambda T, inc, run: self._shadow_embree(P, scene, o, d, smax, run, T, inc))]
        ray = mi.Ray3f(o, d, smax, 0.0, mi.Color0f())

        def any_hit(sub, st):
            def query(T, inc, run):
                hit = sub.ray_test(ray, active=run)
                return (dr.select(hit, 0.0 if st is None else T * c3(st), T),
                        inc + dr.select(run, mi.UInt32(1), 0))
            return query
        groups = []
        if split["opaque"] is not None and (occ is None or occ & split["opaque_slots"]):
            groups.append((split["opaque_slots"], any_hit(split["opaque"], None)))
        groups += [(frozenset([sl]), any_hit(sub, st)) for sub, sl, st in split["trans"] if occ is None or sl in occ]
        return groups

    def _shadow_embree(self, P, scene, o, d, smax, act, T, inc):
        """Shadow segments of the lanes ``act`` through the whole scene: one any-hit test, or
        with transparent shapes the walk over the crossings, nearest first -> (T, tests)."""
        if not P.any_transparent_mitsuba:
            occluded = scene.ray_test(mi.Ray3f(o, d, smax, 0.0, mi.Color0f()), active=act)  # (o, d, x) would set time, not maxt
            return dr.select(occluded, 0.0, T), inc + dr.select(act, mi.UInt32(1), 0)
        reg_to_slot, bits_t, words_t, sh_t = P.reg_to_slot, P.trans_bits, P.trans_words, P.shadow_t
        nwords, max_crossings = P.trans_nwords, P.max_crossings
        preliminary = self.current_tuning().preliminary

        def cond(o, tleft, T, seen, run, it, cost):
            return run

        def body(o, tleft, T, seen, run, it, cost):
            ray = mi.Ray3f(o, d, tleft, 0.0, mi.Color0f())
            if preliminary:
                # the full surface record only where the ray goes on (a transparent hit):
                # scene.ray_intersect is this preliminary test plus compute_surface_interaction
                pi = scene.ray_intersect_preliminary(ray, active=run)
                hit = run & pi.is_valid()
                shape = pi.shape
            else:
                si = scene.ray_intersect(ray, active=run)
                hit = run & si.is_valid()
                shape = si.shape
            cost += dr.select(run, mi.UInt32(1), 0)
            reg = dr.reinterpret_array(mi.UInt32, shape)
            slot = dr.gather(mi.Int32, reg_to_slot, reg, hit)
            bit = dr.gather(mi.UInt32, bits_t, mi.UInt32(slot), hit)
            word = dr.gather(mi.UInt32, words_t, mi.UInt32(slot), hit)
            opaque = hit & (bit == 0)
            if preliminary:
                si = pi.compute_surface_interaction(ray, mi.RayFlags.All, hit & ~opaque)
            mine = [hit & (bit != 0) & (word == k) for k in range(nwords)]
            new = hit & mi.Bool(False)
            for k in range(nwords):
                new = new | (mine[k] & ((seen[k] & bit) == 0))
            T = dr.select(opaque, 0.0, T)
            T = dr.select(new, T * gather3(sh_t, mi.UInt32(slot), new), T)
            seen = [dr.select(new & mine[k], seen[k] | bit, seen[k]) for k in range(nwords)]
            nxt = si.spawn_ray(d)
            tleft = dr.select(hit, tleft - si.t, tleft)
            o = dr.select(hit, nxt.o, o)
            it += 1
            run = hit & ~opaque & (it < max_crossings) & (tleft > 0)
            return o, tleft, T, seen, run, it, cost

        n = dr.width(o)
        state = (mi.Point3f(o), mi.Float(smax), T, [dr.zeros(mi.UInt32, n) for _ in range(nwords)], mi.Bool(act),
                 dr.zeros(mi.UInt32, n), dr.zeros(mi.UInt32, n))
        o, tleft, T, seen, run, it, c_loop = dr.while_loop(state, cond, body)
        return T, inc + c_loop

    def _custom_uv(self, P, o, d, t, prim, slot, uslot, hit):
        """uv of the hits on links1_quadric shapes with textured BSDFs (0 elsewhere)."""
        uv = mi.Point2f(0.0)
        if not P.uv_slots:
            return uv
        for spec in P.custom_unrolled:
            if spec.slot in P.uv_slots:
                uv = dr.select(slot == spec.slot, spec.uv(o, d, t, prim), uv)
        if P.bvh is not None and P.uv_slots & P.bvh_slots:
            qi = dr.gather(mi.Int32, P.bvh.slot_to_q, uslot, hit)
            m = hit & (qi >= 0)
            uv = dr.select(m, quadric_uv(*P.bvh.object_point(mi.UInt32(dr.maximum(qi, 0)), o, d, t, m)), uv)
        return uv
