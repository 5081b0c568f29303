"""Hierarchical bounding boxes (paper 3-2-4) over links1 quadrics, traversed in Dr.Jit.

Mitsuba 3.9.1 cannot hold Python shapes, so links1 quadrics are not in Mitsuba's own BVH.
With many of them (``scenes/many.xml``: 300) testing every quadric on every ray dominates the
frame, and unrolling one code block per quadric makes the kernel grow with the scene. This
module keeps the quadrics in tables (one row per quadric, read with ``dr.gather``) under a
binary BVH in flat node arrays; a ray walks it in a symbolic loop with a small per-lane stack
(Dr.Jit local memory), testing only the quadrics whose boxes it crosses. The intersection is
the same arithmetic as :meth:`links1_mitsuba.shapes.QuadricSpec.intersect` (same float32
constants), so a quadric gives the same bits whichever path tests it.

Layout: node ``k`` has a box ``lo``/``hi``; ``count > 0``: a leaf with quadrics
``[first, first + count)`` of the permuted table; ``count == 0``: an inner node whose
children are nodes ``first`` and ``first + 1``. On the Dr.Jit side a node is one 64-byte
line holding its children's boxes (:func:`pack_nodes`), a quadric one line too, in 64-byte
aligned tables (:func:`util.table`).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from links1.geometry.bvh import BVH

from .util import checked_index, quadric_roots, table

INF = float("inf")
LEAF = 1          #: quadrics per leaf (one intersection per loop iteration)
STACK = 64        #: traversal stack entries per lane (depth of a median-split tree + 1)


def build(lo, hi, leaf=LEAF):
    """SAH BVH over boxes ``lo, hi`` (N, 3), built by the core's one builder
    (:class:`links1.geometry.bvh.BVH`, ``split="sah"``) and given in this module's layout:
    ``(order, node_lo, node_hi, first, count)`` (an inner node's children are ``first`` and
    ``first + 1``, as the core allocates them)."""
    t = BVH(lo, hi, max_leaf=leaf, split="sah")
    inner = t.count == 0
    assert np.all(t.right[inner] == t.left[inner] + 1)
    first = np.where(inner, t.left, t.start).astype(np.uint32)
    return t.order, t.node_lo, t.node_hi, first, t.count.astype(np.uint32)


def tree_depth(first, count):
    depth, work = 0, [(0, 1)]
    while work:
        k, dep = work.pop()
        depth = max(depth, dep)
        if count[k] == 0:
            work += [(int(first[k]), dep + 1), (int(first[k]) + 1, dep + 1)]
    return depth


def pack_nodes(node_lo, node_hi, first, count):
    """One 64-byte line of floats per node ``k``: the boxes of its children ``first[k]``,
    ``first[k] + 1`` as packets ``(lo_l, first)``, ``(hi_l, count)``, ``(lo_r, 0)``,
    ``(hi_r, 0)`` (``first``/``count`` of node ``k`` itself, as float bits; the boxes are zero
    in a leaf's line). A walk step reads one node with four packet gathers from one cache
    line, all addressed by the node it stands on: no second, dependent read of the children's
    boxes (14 % fewer kernel ms than node records with separate box tables, many.xml)."""
    line = np.zeros((len(first), 4, 4), dtype=np.float32)
    inner = count == 0
    fl = first[inner].astype(np.int64)
    line[inner, 0, :3], line[inner, 1, :3] = node_lo[fl], node_hi[fl]
    line[inner, 2, :3], line[inner, 3, :3] = node_lo[fl + 1], node_hi[fl + 1]
    line[:, 0, 3] = np.asarray(first, dtype=np.uint32).view(np.float32)
    line[:, 1, 3] = np.asarray(count, dtype=np.uint32).view(np.float32)
    return line


def slab(lo, hi, o, inv_d, tmin, tmax, act):
    """Ray–box slab test in Dr.Jit: (crossed within (tmin, tmax), entry t). ``lo``/``hi``
    are per-axis lists of Floats, ``inv_d`` = 1/d per component."""
    t0, t1 = tmin, tmax
    for c, (oc, ic) in enumerate(((o.x, inv_d.x), (o.y, inv_d.y), (o.z, inv_d.z))):
        ta = (lo[c] - oc) * ic
        tb = (hi[c] - oc) * ic
        # NaN (0 * inf on a slab face) must not cull: minimum/maximum keep the other
        t0 = dr.maximum(t0, dr.select(dr.isnan(ta) | dr.isnan(tb), -INF, dr.minimum(ta, tb)))
        t1 = dr.minimum(t1, dr.select(dr.isnan(ta) | dr.isnan(tb), INF, dr.maximum(ta, tb)))
    # a box is crossed when its slab interval meets (tmin, tmax); slack for float32
    slack = 1e-5 * (dr.abs(t0) + dr.abs(t1)) + 1e-30
    return act & (t0 <= t1 + slack), t0


class QuadricBVH:
    """Quadric table + BVH; ``specs`` are :class:`QuadricSpec` with finite bounds."""

    def __init__(self, specs, shadow_t):
        bl = np.array([s.bounds()[0] for s in specs])
        bh = np.array([s.bounds()[1] for s in specs])
        order, nlo, nhi, first, count = build(bl, bh, LEAF)
        if tree_depth(first, count) + 1 > STACK:
            raise ValueError("BVH too deep")
        specs = [specs[i] for i in order]
        self.specs = specs
        self.n = len(specs)
        self.kc = max(len(s.clips) for s in specs)
        nq = self.n
        # per quadric one 64-byte line: the 3x4 inverse transform, then (qz, 0, 0, 0)
        inv = np.zeros((nq, 4, 4))
        inv[:, :3, :] = [np.array(s.inv)[:3, :4] for s in specs]
        nm = np.array([np.array(s.normal_mat).ravel() for s in specs])            # (n, 9)
        inv[:, 3, 0] = [1.0 if s.kind == "sphere" else 0.0 for s in specs]
        clips = np.zeros((nq, max(self.kc, 1), 4))
        clips[:, :, 3] = 1.0                                                    # 0·x <= 1: no plane
        for i, s in enumerate(specs):
            for j, (nrm, h) in enumerate(s.clips):
                clips[i, j, :3] = nrm
                clips[i, j, 3] = h
        self.any_capped = any(s.capped and s.clips for s in specs)
        capped = np.array([bool(s.capped) for s in specs])
        slot = np.array([s.slot for s in specs], dtype=np.int64)
        slot = checked_index(slot, len(shadow_t), "bvh slot").astype(np.uint32)
        st = np.array([shadow_t[s.slot] for s in specs], dtype=np.float64)
        self.any_transparent = bool(np.any(st > 0))
        F = lambda a: table(mi.Float, a)  # noqa: E731
        self.inv, self.nm, self.clips = F(inv), F(nm), F(clips)
        self.capped = mi.Bool(capped)
        self.slot = table(mi.UInt32, slot)
        self.st = F(st)
        self.line = F(pack_nodes(nlo, nhi, first, count))
        self.root = (nlo[0].tolist(), nhi[0].tolist())
        self.nnodes = len(first)
        self.slot_to_q = None   # set by the integrator (slot -> row)

    # ------------------------------------------------------------ one quadric
    def _rows(self, q, act):
        # the 3x4 inverse transform and qz, a row per packet gather (the same values as 13 gathers)
        rows = [dr.gather(mi.Array4f, self.inv, q * 4 + i, act) for i in range(4)]
        return [[r.x, r.y, r.z, r.w] for r in rows[:3]], rows[3].x

    def _clip(self, q, j, act):
        K = max(self.kc, 1)
        return [dr.gather(mi.Float, self.clips, (q * K + j) * 4 + c, act) for c in range(4)]

    @staticmethod
    def _qform(qz, x, y):
        return x.x * y.x + x.y * y.y + qz * (x.z * y.z)

    def offer(self, q, o, d, tmin, res, active=None):
        """The nearest-hit state ``res = (t, row, part, found)`` after testing row ``q``
        (lanes ``active``, all when None): a tie with the best so far is let through and
        the lower slot wins (file order, as ``intersect.nearest``). One rule for the
        walk's leaves and the eye buffer's lists."""
        best_t, best_q, best_part, found = res
        lim = dr.select(found, dr.reinterpret_array(mi.Float, dr.reinterpret_array(mi.UInt32, best_t) + 1),
                        best_t)
        tq, pq = self.intersect(q, o, d, tmin, lim, True if active is None else active)
        h = tq < lim if active is None else active & (tq < lim)
        s_new = dr.gather(mi.UInt32, self.slot, q, h)
        s_old = dr.gather(mi.UInt32, self.slot, best_q, h & found)
        better = h & ((tq < best_t) | ((tq == best_t) & found & (s_new < s_old)))
        return (dr.select(better, tq, best_t), dr.select(better, q, best_q), dr.select(better, pq, best_part),
                found | better)

    def intersect(self, q, o, d, tmin, tmax, act):
        """QuadricSpec.intersect with gathered parameters: (t, part)."""
        a, qz = self._rows(q, act)
        u = mi.Vector3f(*[a[i][0] * o.x + a[i][1] * o.y + a[i][2] * o.z + a[i][3] for i in range(3)])
        v = mi.Vector3f(*[a[i][0] * d.x + a[i][1] * d.y + a[i][2] * d.z for i in range(3)])
        # sphere: qform = dot; cylinder: x, y only (qz = 0 drops z exactly)
        hit, tn, tf = quadric_roots(lambda x, y: self._qform(qz, x, y), u, v)   # eq. (3.5)
        hit &= act
        planes = [self._clip(q, j, act) for j in range(self.kc)]

        def inside(x, skip=-1):
            ok = mi.Bool(True)
            for j, (nx, ny, nz, h) in enumerate(planes):
                if j != skip:
                    ok &= nx * x.x + ny * x.y + nz * x.z <= h
            return ok
        ok_n = hit & (tn > tmin) & (tn < tmax) & inside(u + v * tn)
        ok_f = hit & (tf > tmin) & (tf < tmax) & inside(u + v * tf)
        t = dr.select(ok_n, tn, dr.select(ok_f, tf, INF))
        part = dr.zeros(mi.UInt32, dr.width(t))
        if self.any_capped:
            cap = dr.gather(mi.Bool, self.capped, q, act)
            for j, (nx, ny, nz, h) in enumerate(planes):
                den = nx * v.x + ny * v.y + nz * v.z
                num = h - (nx * u.x + ny * u.y + nz * u.z)
                tc = num / dr.select(den != 0, den, 1.0)
                x = u + v * tc
                ok = act & cap & (den != 0) & (tc > tmin) & (tc < tmax) & (tc < t) \
                    & (self._qform(qz, x, x) <= 1.0) & inside(x, skip=j)
                t = dr.select(ok, tc, t)
                part = dr.select(ok, j + 1, part)
        return t, part

    def normal(self, q, o, d, t, part, act):
        """The unit world normal of row ``q`` at ``o + t d`` (cap ``part``) on lanes ``act``,
        computed under a symbolic ``dr.if_stmt`` on ``act``: a packet with no quadric hit skips
        its 13 gathers and the transform (the same values on ``act``; elsewhere zero). Where the
        ray carries derivatives (a derivative pass), the straight-line code."""
        if dr.grad_enabled((o, d, t)):
            return self._normal(q, o, d, t, part, act)
        return dr.if_stmt((q, o, d, t, part, act), act, self._normal,
                          lambda q, o, d, t, part, act: dr.zeros(mi.Vector3f, dr.width(t)),
                          mode="symbolic", label="links1_bvh_normal")

    def _normal(self, q, o, d, t, part, act):
        a, qz = self._rows(q, act)
        u = mi.Vector3f(*[a[i][0] * o.x + a[i][1] * o.y + a[i][2] * o.z + a[i][3] for i in range(3)])
        v = mi.Vector3f(*[a[i][0] * d.x + a[i][1] * d.y + a[i][2] * d.z for i in range(3)])
        x = u + v * t
        n_obj = mi.Vector3f(x.x, x.y, x.z * qz)
        if self.any_capped:
            for j in range(self.kc):
                nx, ny, nz, _ = self._clip(q, j, act)
                n_obj = dr.select(part == j + 1, mi.Vector3f(nx, ny, nz), n_obj)
        m = [dr.gather(mi.Float, self.nm, q * 9 + k, act) for k in range(9)]
        nw = mi.Vector3f(*[m[3 * i] * n_obj.x + m[3 * i + 1] * n_obj.y + m[3 * i + 2] * n_obj.z
                           for i in range(3)])
        return dr.normalize(nw)

    def object_point(self, q, o, d, t, act):
        """The hit ``o + t d`` in quadric ``q``'s object space and its ``qz`` (1: sphere, 0:
        cylinder), with gathered parameters: what ``shapes.quadric_uv`` takes (QuadricSpec.uv;
        the caller applies it)."""
        a, qz = self._rows(q, act)
        u = mi.Vector3f(*[a[i][0] * o.x + a[i][1] * o.y + a[i][2] * o.z + a[i][3] for i in range(3)])
        v = mi.Vector3f(*[a[i][0] * d.x + a[i][1] * d.y + a[i][2] * d.z for i in range(3)])
        return u + v * t, qz

    # ------------------------------------------------------------ traversal
    def _walk(self, o, d, tmin, tmax, active, cost, shadow, steps=None):
        """One node per iteration, held in a register (no stack round trip on the way
        down): a leaf tests its quadric, then the walk pops; an inner node tests both
        children's boxes and goes on to the nearer one crossed, pushing the other.
        ``steps`` (a UInt32, benchmarks only: None traces no counter): += the iterations."""
        inv_d = mi.Vector3f(1.0 / d.x, 1.0 / d.y, 1.0 / d.z)
        n = dr.width(o)
        stack = dr.alloc_local(mi.UInt32, STACK, mi.UInt32(0))
        root_hit, _ = slab([mi.Float(v) for v in self.root[0]], [mi.Float(v) for v in self.root[1]],
                           o, inv_d, tmin, tmax, active)
        node = dr.zeros(mi.UInt32, n)
        live = mi.Bool(root_hit)
        sp = dr.zeros(mi.UInt32, n)
        c = dr.zeros(mi.UInt32, n) if steps is None else (dr.zeros(mi.UInt32, n), dr.zeros(mi.UInt32, n))
        if shadow:
            res = (dr.select(active, mi.Color3f(1.0), mi.Color3f(0.0)),)
        else:
            res = (mi.Float(tmax), dr.zeros(mi.UInt32, n), dr.zeros(mi.UInt32, n), dr.zeros(mi.Bool, n))

        def cond(stack, node, live, sp, c, res):
            return live & (dr.max(res[0]) > 0) if shadow else live

        def body(stack, node, live, sp, c, res):
            act = mi.Bool(live)
            pk = [dr.gather(mi.Array4f, self.line, node * 4 + i, act) for i in range(4)]  # pack_nodes
            fst = dr.reinterpret_array(mi.UInt32, pk[0].w)
            cnt = dr.reinterpret_array(mi.UInt32, pk[1].w)
            leaf = act & (cnt > 0)
            inner = act & (cnt == 0)

            # Symbolic conditionals: a packet whose lanes are all inner nodes (or all
            # leaves) skips the other block entirely (the LLVM backend branches per packet).
            def leaf_fn(fst, c, res):
                c = c + 1 if steps is None else (c[0] + 1, c[1])
                if shadow:
                    (T,) = res
                    tq, _ = self.intersect(fst, o, d, tmin, tmax, True)
                    h = tq < tmax
                    return fst, c, (dr.select(h, T * dr.gather(mi.Color3f, self.st, fst, h), T),)
                return fst, c, self.offer(fst, o, d, tmin, res)

            def keep(*args):
                return args

            fst, c, res = dr.if_stmt((fst, c, res), leaf, leaf_fn, keep)

            def inner_fn(pk, res):
                # both children's boxes (against the nearest hit so far)
                lim = tmax if shadow else res[0]
                hl, tl = slab(pk[0][:3], pk[1][:3], o, inv_d, tmin, lim, True)
                hr, tr = slab(pk[2][:3], pk[3][:3], o, inv_d, tmin, lim, True)
                return hl, hr, tl <= tr

            def no_inner(pk, res):
                z = dr.zeros(mi.Bool, dr.width(pk[0]))
                return z, z, z

            hl, hr, near_l = dr.if_stmt((pk, res), inner, inner_fn, no_inner)
            hl &= inner
            hr &= inner
            both = hl & hr
            down = hl | hr
            near = dr.select(both, dr.select(near_l, fst, fst + 1), dr.select(hl, fst, fst + 1))
            stack.write(dr.select(near_l, fst + 1, fst), sp, both)
            sp = dr.select(both, sp + 1, sp)
            pop = act & ~down & (sp > 0)
            sp = dr.select(pop, sp - 1, sp)
            node = dr.select(down, near, stack.read(sp, pop))
            if steps is not None:
                c = (c[0], c[1] + 1)
            return stack, node, down | pop, sp, c, res

        st = dr.while_loop((stack, node, live, sp, c, res), cond, body, label="links1_bvh")
        c, res = st[4], st[5]
        if steps is not None:
            steps += c[1]
            c = c[0]
        if cost is not None:
            cost += c
        if shadow:
            return None, None, None, None, res[0]
        return res + (None,)

    def nearest(self, o, d, tmin, tmax, active, cost, steps=None):
        """(t (inf on a miss), row q, part, found); ``steps``: see :meth:`_walk`."""
        t, q, part, found, _ = self._walk(o, d, tmin, tmax, active, cost, shadow=False, steps=steps)
        return dr.select(found, t, INF), q, part, found

    def transmittance(self, o, d, smax, active, cost):
        """Product of shadow_t over the quadrics the segment (0, smax) hits (each once)."""
        _, _, _, _, T = self._walk(o, d, mi.Float(0.0), smax, active, cost, shadow=True)
        return T
