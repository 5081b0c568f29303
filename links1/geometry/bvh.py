"""The shape-agnostic bounding-volume hierarchy (paper 3-2-4) in float64 numpy.

:class:`BVH` is the generic hierarchy over axis-aligned boxes (object-median split along the
widest axis of the box centres, or the surface-area heuristic; leaves of at most ``max_leaf``
items): the one builder of links1, also of the Mitsuba plugin's Dr.Jit hierarchies
(:func:`links1_mitsuba.bvh.build`: SAH, over its quadrics and blob centres). It knows boxes only:
:class:`links1.geometry.shapes.TriangleMesh` builds one over its triangles, :class:`links1.geometry.accel.Accel`
over the shapes of a scene, :class:`links1.geometry.blob.Blob` over its centres' spheres.

Two traversals give the same bits and costs. The *packet* one (``BVH.traverse``) keeps, at
every node, the subset of rays whose slab test passes and recurses with it; a leaf hands its
subset to a callback that tests all of them against the leaf's items at once: a Python cost
per (node, packet), cheap when packets are large. The *lock-step* one
(``BVH.traverse_pairs``) keeps a stack per ray and advances all rays one node per step
(vectorised slab tests over (ray, node) pairs), handing the leaves' (ray, item) pairs over in
batches. In the lock-step one a ray that reaches a leaf waits there until every ray of the
batch has (then they all visit their leaves in one round), and once at most
:data:`SCALAR_RAYS` rays are left (or a packet has that many rays) they walk on in Python
floats (``_walk_one``): small batches (windows of a few pixels) no longer pay a round of
numpy calls per tree node. Each ray's own order of pops, culls and visits is the
same in every walk.

Determinism
-----------
A ray's result and its ``cost`` entry must not depend on the other rays of the batch (a
window of the film renders the same bits as the full frame). So the traversal order is a
per-ray choice (the near child by the sign of the ray's own direction along the node's
split axis), and culling uses the ray's own current nearest distance; the callers resolve
equal distances by index, never by visiting order.
"""
from __future__ import annotations

import math

import numpy as np

#: Relative enlargement of the slab test's exit distance (pbrt's 2·gamma(3) idea, with a
#: generous margin): a box is never missed because of rounding.
_SLAB_SLACK = 1e-12

#: The lock-step traversal hands a ray over to a plain Python walk (scalar slab tests, no
#: numpy call per node) once at most this many rays are left: one numpy step per node costs
#: tens of microseconds however few rays take it, a scalar node a few.
SCALAR_RAYS = 1
#: Up to this many rays in a lock-step step, both children's slab tests take one call.
_ONE_SLAB_CALL = 64


def keep_nearest(t, items, r, best_t, best_p, limit, any_hit: bool) -> None:
    """Fold a leaf's distances ``t`` (R, c) of rays ``r`` (R,) against ``items`` (c,) (``inf``
    where missed, already cut to each ray's segment) into ``best_t``/``best_p``: each ray's
    first minimum wins when nearer than its best, or as near with a lower item index; its
    ``limit`` follows (``-inf`` once an any-hit ray has a hit)."""
    k = np.argmin(t, axis=1)  # first minimum: lowest index inside the leaf
    tk = t[np.arange(r.size), k]
    pk = items[k]
    bt = best_t[r]
    win = (tk < bt) | ((tk == bt) & (pk < best_p[r]) & np.isfinite(tk))
    win &= tk <= limit[r]
    if win.any():
        w = r[win]
        best_t[w] = tk[win]
        best_p[w] = pk[win]
        limit[w] = -np.inf if any_hit else tk[win]


def nearest_hits(bvh, o, d, tmin, tmax, cost, any_hit: bool, leaf_times):
    """The nearest hit of each ray over ``bvh``'s items: ``leaf_times(s, c, r)`` gives the
    distances (R, c) of rays ``r`` to the leaf's items ``bvh.order[s:s+c]`` (``inf`` where
    missed or outside the ray's ``(tmin, tmax)``). Returns ``(t, item)``, ``inf``/-1 on a
    miss; ``cost`` gets +1 per ray-item test; ``any_hit`` stops a ray at its first hit."""
    n = o.shape[0]
    best_t = np.full(n, np.inf)
    best_p = np.full(n, -1, dtype=np.int64)
    limit = np.array(tmax, dtype=np.float64)

    def visit_leaf(s, c, r):
        if cost is not None:
            cost[r] += c
        keep_nearest(leaf_times(s, c, r), bvh.order[s:s + c], r, best_t, best_p, limit, any_hit)

    bvh.traverse(o, d, tmin, limit, visit_leaf)
    return best_t, best_p


def _area(lo, hi):
    """Half the surface area of boxes ``lo, hi`` (..., 3) (empty: 0)."""
    e = np.maximum(hi - lo, 0.0)
    return e[..., 0] * e[..., 1] + e[..., 1] * e[..., 2] + e[..., 2] * e[..., 0]


def _sah_split(idx, lo, hi, cen):
    """Surface-area-heuristic split of the items ``idx`` (a sweep over their centres sorted on
    each axis, stable): ``(idx reordered, number of items in the left child, axis)``."""
    best = (np.inf, None, None, 0)
    k = len(idx)
    for ax in range(3):
        srt = idx[np.argsort(cen[idx, ax], kind="stable")]
        l_lo = np.minimum.accumulate(lo[srt], axis=0)
        l_hi = np.maximum.accumulate(hi[srt], axis=0)
        r_lo = np.minimum.accumulate(lo[srt][::-1], axis=0)[::-1]
        r_hi = np.maximum.accumulate(hi[srt][::-1], axis=0)[::-1]
        i = np.arange(1, k)
        cost = _area(l_lo[:-1], l_hi[:-1]) * i + _area(r_lo[1:], r_hi[1:]) * (k - i)
        j = int(np.argmin(cost))
        if cost[j] < best[0]:
            best = (cost[j], srt, j + 1, ax)
    return best[1], best[2], best[3]


class BVH:
    """A bounding-volume hierarchy over ``P`` axis-aligned boxes.

    Parameters
    ----------
    lo, hi : (P, 3) float64
        The boxes (finite).
    max_leaf : int
        Largest number of items in a leaf (items whose centres all coincide are split
        by their position in the list instead).
    split : str
        ``"median"`` (the core's trees): half the items on each side along the widest axis of
        their centres, each leaf's items sorted by index (ties resolved by index);
        ``"sah"`` (the plugin's Dr.Jit trees, walked by every lane of a kernel): the cut of
        least surface-area cost over the centres sorted along each axis, leaves in that order.

    Attributes
    ----------
    order : (P,) int64
        Item indices in leaf order; a leaf owns ``order[start:start + count]``. Inside a
        leaf the items are sorted by index, so "first minimum" means "lowest index".
    node_lo, node_hi : (M, 3)    node boxes (slightly padded)
    left, right : (M,) int64     children (-1 for a leaf)
    axis : (M,) int64            split axis of an interior node
    start, count : (M,) int64    item range of a leaf (count 0 for an interior node)
    """

    def __init__(self, lo: np.ndarray, hi: np.ndarray, max_leaf: int = 8, split: str = "median"):
        lo = np.asarray(lo, dtype=np.float64).reshape(-1, 3)
        hi = np.asarray(hi, dtype=np.float64).reshape(-1, 3)
        if lo.shape != hi.shape:
            raise ValueError("BVH: lo and hi must have the same shape")
        if lo.shape[0] == 0:
            raise ValueError("BVH: needs at least one box")
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise ValueError("BVH: boxes must be finite")
        if split not in ("median", "sah"):
            raise ValueError(f"BVH: split must be 'median' or 'sah', got {split!r}")
        self.max_leaf = max(1, int(max_leaf))
        cen = 0.5 * (lo + hi)
        order = np.arange(lo.shape[0], dtype=np.int64)
        node_lo, node_hi, left, right, axis, start, count = [], [], [], [], [], [], []

        def new_node():
            node_lo.append(None), node_hi.append(None)
            left.append(-1), right.append(-1), axis.append(0), start.append(0), count.append(0)
            return len(left) - 1

        root = new_node()
        stack = [(root, 0, lo.shape[0])]
        while stack:
            nid, s, e = stack.pop()
            items = order[s:e]
            blo = lo[items].min(axis=0)
            bhi = hi[items].max(axis=0)
            pad = 1e-13 * (np.abs(blo) + np.abs(bhi)) + 1e-300
            node_lo[nid], node_hi[nid] = blo - pad, bhi + pad
            n = e - s
            if n <= self.max_leaf:
                if split == "median":
                    order[s:e] = np.sort(items)
                start[nid], count[nid] = s, n
                continue
            if split == "sah":
                order[s:e], mid, ax = _sah_split(items, lo, hi, cen)
            else:
                c = cen[items]
                ext = c.max(axis=0) - c.min(axis=0)
                ax = int(np.argmax(ext))
                mid = n // 2
                if ext[ax] > 0:
                    part = np.argpartition(c[:, ax], mid, kind="introselect")
                    order[s:e] = items[part]
                # else: all centres coincide; split by position in the list.
            axis[nid] = ax
            lc, rc = new_node(), new_node()
            left[nid], right[nid] = lc, rc
            stack.append((rc, s + mid, e))
            stack.append((lc, s, s + mid))

        self.order = order
        self.node_lo = np.array(node_lo)
        self.node_hi = np.array(node_hi)
        self.left = np.array(left, dtype=np.int64)
        self.right = np.array(right, dtype=np.int64)
        self.axis = np.array(axis, dtype=np.int64)
        self.start = np.array(start, dtype=np.int64)
        self.count = np.array(count, dtype=np.int64)
        # Depth of the tree (parents are created before their children): bounds the
        # per-ray stacks of traverse_pairs.
        depth = np.zeros(len(left), dtype=np.int64)
        for nid, (lc, rc) in enumerate(zip(left, right)):
            if lc >= 0:
                depth[lc] = depth[rc] = depth[nid] + 1
        self.depth = int(depth.max())
        # Scalar per-node data as Python lists: faster to index in the traversal loop.
        self._lo = self.node_lo.tolist()
        self._hi = self.node_hi.tolist()
        self._left = self.left.tolist()
        self._right = self.right.tolist()
        self._axis = self.axis.tolist()
        self._start = self.start.tolist()
        self._count = self.count.tolist()

    @property
    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in (self.order, self.node_lo, self.node_hi, self.left,
                                          self.right, self.axis, self.start, self.count)))

    def __len__(self) -> int:
        return len(self._left)

    # ------------------------------------------------------------------ traversal
    def traverse(self, o: np.ndarray, d: np.ndarray, tmin: np.ndarray, limit: np.ndarray,
                 visit_leaf, rays: np.ndarray | None = None) -> None:
        """Packet traversal.

        Parameters
        ----------
        o, d : (N, 3)      ray origins and directions
        tmin : (N,)        lower end of each ray's segment
        limit : (N,)       upper end; **read at every node**, so the caller may lower it
                           (nearest hit so far) or set it to ``-inf`` (ray finished) from
                           inside ``visit_leaf`` to cull the rest of the traversal.
        visit_leaf : callable(start, count, rays)
                           called with the leaf's item range in :attr:`order` and the
                           global indices (int64, increasing) of the rays that reach it.
        rays : (R,) int64, optional
                           the rays to trace (default: all).
        """
        n = o.shape[0]
        if rays is None:
            rays = np.arange(n, dtype=np.int64)
        if rays.size == 0:
            return
        ox, oy, oz = o[:, 0], o[:, 1], o[:, 2]
        # A zero direction component gets a huge finite reciprocal instead of inf, so
        # that (lo - o) * inv is never 0 * inf = NaN (origin on a slab plane).
        inv = 1.0 / np.where(d == 0, 1e-300, d)
        ix, iy, iz = inv[:, 0], inv[:, 1], inv[:, 2]
        dirpos = [d[:, 0] >= 0, d[:, 1] >= 0, d[:, 2] >= 0]
        lo_l, hi_l = self._lo, self._hi

        def slab(node, px, py, pz, qx, qy, qz, t0, t1):
            """Entry distance (inf where the box is missed) for a packet."""
            lo, hi = lo_l[node], hi_l[node]
            with np.errstate(over="ignore"):
                ax0 = (lo[0] - px) * qx
                ax1 = (hi[0] - px) * qx
                ay0 = (lo[1] - py) * qy
                ay1 = (hi[1] - py) * qy
                az0 = (lo[2] - pz) * qz
                az1 = (hi[2] - pz) * qz
            mn, mx = np.minimum, np.maximum
            tn = mx(mx(mn(ax0, ax1), mn(ay0, ay1)), mx(mn(az0, az1), t0))
            tf = mn(mn(mx(ax0, ax1), mx(ay0, ay1)), mx(az0, az1))
            tf = mn(tf * np.where(tf > 0, 1.0 + _SLAB_SLACK, 1.0 - _SLAB_SLACK), t1)
            return np.where(tn <= tf, tn, np.inf)

        # Root box.
        tn = slab(0, ox[rays], oy[rays], oz[rays], ix[rays], iy[rays], iz[rays],
                  tmin[rays], limit[rays])
        keep = np.isfinite(tn)
        stack = [(0, rays[keep], tn[keep])]
        left, right, axis = self._left, self._right, self._axis
        start, count = self._start, self._count
        # A one-ray packet walks its subtree in Python scalars (same order, see
        # _walk_one): that needs finite operands.
        scalar_ok = dirpos_rows = None
        while stack:
            node, r, tn = stack.pop()
            # Re-cull with the current limits (lowered by hits found since the push).
            lim = limit[r]
            m = tn <= lim
            if not m.all():
                r, lim = r[m], lim[m]
                if r.size == 0:
                    continue
            c = count[node]
            if c:
                visit_leaf(start[node], c, r)
                continue
            if r.size <= SCALAR_RAYS and scalar_ok is None:
                scalar_ok = np.isfinite(o).all(axis=1) & np.isfinite(inv).all(axis=1) & np.isfinite(tmin)
                dirpos_rows = d >= 0
            if r.size <= SCALAR_RAYS and scalar_ok[r].all():
                # The subtree's entries lie on top of the stack and are all popped before
                # anything below them: walking it here keeps the order of the visits.
                for g_a, tn_a in zip(r.tolist(), tn[m].tolist() if not m.all() else tn.tolist()):
                    rr = np.array([g_a], dtype=np.int64)
                    self._walk_one(g_a, [(node, tn_a)], o, inv, dirpos_rows, tmin, limit,
                                   lambda nd, rr=rr: visit_leaf(start[nd], count[nd], rr))
                continue
            px, py, pz = ox[r], oy[r], oz[r]
            qx, qy, qz = ix[r], iy[r], iz[r]
            t0 = tmin[r]
            lc, rc = left[node], right[node]
            tl = slab(lc, px, py, pz, qx, qy, qz, t0, lim)
            tr = slab(rc, px, py, pz, qx, qy, qz, t0, lim)
            hl = np.isfinite(tl)
            hr = np.isfinite(tr)
            pos = dirpos[axis[node]][r]
            neg = ~pos
            # Far children first (popped last), near children last; per ray, the near
            # subtree is finished before its far one is popped.
            for child, mask, tc in ((rc, hr & pos, tr), (lc, hl & neg, tl),
                                    (lc, hl & pos, tl), (rc, hr & neg, tr)):
                if mask.any():
                    stack.append((child, r[mask], tc[mask]))


    def _slab_many(self, node, P, Q, t0, t1):
        """Entry distance (inf where missed) of rays (P origins, Q reciprocal directions)
        each against its own node ``node`` (m,): the same arithmetic as ``traverse``."""
        with np.errstate(over="ignore"):
            # the per-axis products of ``traverse``, the three axes in one call
            a0 = (self.node_lo[node] - P) * Q
            a1 = (self.node_hi[node] - P) * Q
        mn, mx = np.minimum, np.maximum
        near, far = mn(a0, a1), mx(a0, a1)
        tn = mx(mx(near[:, 0], near[:, 1]), mx(near[:, 2], t0))
        tf = mn(mn(far[:, 0], far[:, 1]), far[:, 2])
        tf = mn(tf * np.where(tf > 0, 1.0 + _SLAB_SLACK, 1.0 - _SLAB_SLACK), t1)
        return np.where(tn <= tf, tn, np.inf)

    def _walk_one(self, g, stack, o, inv, dirpos, tmin, limit, on_leaf):
        """The rest of ray ``g``'s depth-first walk from its ``stack`` of (node, entry
        distance) pairs (bottom first) in Python scalars: the pops, culls against the
        current ``limit[g]``, pushes (far child first, near child on top) and slab
        arithmetic of :meth:`traverse` and :meth:`traverse_pairs` for one ray, with no
        numpy call per node (IEEE float64 either way; the caller makes sure that no operand
        is NaN or infinite, so min / max need no NaN rule and a product is never NaN).
        ``on_leaf(node)`` is called for every leaf the ray reaches (its box not culled)."""
        lo_l, hi_l = self._lo, self._hi
        left, right, axis, count = self._left, self._right, self._axis, self._count
        px, py, pz = (float(v) for v in o[g])
        qx, qy, qz = (float(v) for v in inv[g])
        dp = [bool(v) for v in dirpos[g]]
        t0 = float(tmin[g])
        up, down = 1.0 + _SLAB_SLACK, 1.0 - _SLAB_SLACK
        inf = math.inf

        def slab(node, t1):
            lo, hi = lo_l[node], hi_l[node]
            ax0 = (lo[0] - px) * qx
            ax1 = (hi[0] - px) * qx
            ay0 = (lo[1] - py) * qy
            ay1 = (hi[1] - py) * qy
            az0 = (lo[2] - pz) * qz
            az1 = (hi[2] - pz) * qz
            tn = max(min(ax0, ax1), min(ay0, ay1), min(az0, az1), t0)
            tf = min(max(ax0, ax1), max(ay0, ay1), max(az0, az1))
            tf = min(tf * (up if tf > 0 else down), t1)
            return tn if tn <= tf else inf

        while stack:
            node, tnode = stack.pop()
            lim = float(limit[g])
            if not tnode <= lim:           # re-cull with the current limit
                continue
            if count[node]:
                on_leaf(node)
                continue
            lc, rc = left[node], right[node]
            tl, tr = slab(lc, lim), slab(rc, lim)
            if dp[axis[node]]:
                pairs = ((rc, tr), (lc, tl))
            else:
                pairs = ((lc, tl), (rc, tr))
            for child, tc in pairs:        # far child pushed first, near child on top
                if tc != inf:
                    stack.append((child, tc))

    def traverse_pairs(self, o: np.ndarray, d: np.ndarray, tmin: np.ndarray, limit: np.ndarray,
                       visit, rays: np.ndarray | None = None) -> None:
        """Lock-step traversal: every ray walks the tree depth first with its own stack
        (exactly the per-ray order, culling and ``limit`` reads of :meth:`traverse`), and
        all rays advance together, one node each per step, in a few numpy calls whatever
        the number of nodes or how the rays spread over them.

        ``visit(r, k)`` is called for the leaf items reached: ``r`` (m,) int64 the rays
        (increasing, each at most once per call), ``k`` (m,) their item positions in
        :attr:`order`; a ray's items of one leaf come in successive calls, in order, and a
        ray whose ``limit`` fell below its ``tmin`` stops visiting the rest of that leaf.
        ``limit`` is read at every node, so ``visit`` may lower it or set it to ``-inf``.
        """
        n = o.shape[0]
        if rays is None:
            rays = np.arange(n, dtype=np.int64)
        if rays.size == 0:
            return
        inv = 1.0 / np.where(d == 0, 1e-300, d)
        dirpos = d >= 0
        g = rays
        tn = self._slab_many(np.zeros(g.size, dtype=np.int64), o[g], inv[g], tmin[g], limit[g])
        ok = np.isfinite(tn)
        g, tn = g[ok], tn[ok]
        R = g.size
        if R == 0:
            return
        D = self.depth + 2
        stk = np.zeros((R, D), dtype=np.int64)
        stt = np.zeros((R, D))
        stt[:, 0] = tn
        sp = np.ones(R, dtype=np.int64)
        left, right, axis, start, count = self.left, self.right, self.axis, self.start, self.count
        act = np.arange(R)
        og, qg, t0g, dpg = o[g], inv[g], tmin[g], dirpos[g]
        wt = act[:0]                       # rays waiting at a leaf (not yet popped)
        scalar_ok = None
        while act.size or wt.size:
            if act.size + wt.size <= SCALAR_RAYS:
                if scalar_ok is None:
                    # The scalar walk needs finite, non-NaN operands (then no slab value is NaN).
                    scalar_ok = (np.isfinite(og).all(axis=1) & np.isfinite(qg).all(axis=1)
                                 & np.isfinite(t0g))
                rest = np.sort(np.concatenate((act, wt)))
                if scalar_ok[rest].all() and not np.isnan(limit[g[rest]]).any():
                    start_l = self._start
                    for a in rest.tolist():
                        n_a, g_a = int(sp[a]), int(g[a])
                        gr = np.array([g_a], dtype=np.int64)

                        def on_leaf(node):
                            st = start_l[node]
                            for i in range(self._count[node]):
                                if i > 0 and not limit[g_a] >= tmin[g_a]:
                                    break
                                visit(gr, np.array([st + i], dtype=np.int64))

                        self._walk_one(g_a, list(zip(stk[a, :n_a].tolist(), stt[a, :n_a].tolist())),
                                       o, inv, dirpos, tmin, limit, on_leaf)
                    return
            if act.size == 0:
                # Every ray waits at a leaf: all pop it and visit together (one round of
                # visits for the batch instead of one per step in which a ray reaches one).
                wt = np.sort(wt)
                top = sp[wt] - 1
                sp[wt] = top
                node = stk[wt, top]
                gl = g[wt]
                st = start[node]
                cl = count[node]
                alive = np.ones(gl.size, dtype=bool)
                for i in range(int(cl.max())):
                    if i > 0:
                        alive &= limit[gl] >= tmin[gl]
                    sel = alive & (cl > i)
                    if sel.any():
                        visit(gl[sel], st[sel] + i)
                act, wt = wt[sp[wt] > 0], wt[:0]
                continue
            top = sp[act] - 1
            node = stk[act, top]
            tnode = stt[act, top]
            lim = limit[g[act]]
            live = tnode <= lim            # re-cull with the current limit
            cnt = count[node]
            leaf = live & (cnt > 0)
            if leaf.any():
                # A ray at a live leaf waits (keeps it on its stack) while the others walk:
                # its pops, and the limit each reads, stay in its own order (only a visit
                # of the ray itself changes its limit), so nothing but the timing changes.
                wt = np.concatenate((wt, act[leaf]))
                go = ~leaf
                act, top, node, lim, live, cnt = act[go], top[go], node[go], lim[go], live[go], cnt[go]
            sp[act] = top
            inner = live & (cnt == 0)
            if inner.any():
                ii = act[inner]
                nd = node[inner]
                li = lim[inner]
                lc, rc = left[nd], right[nd]
                m = ii.size
                if m <= _ONE_SLAB_CALL:
                    # both children in one call (fewer numpy calls): rows [0, m) the left
                    i2 = np.concatenate((ii, ii))
                    T = self._slab_many(np.concatenate((lc, rc)), og[i2], qg[i2], t0g[i2],
                                        np.concatenate((li, li)))
                    tl, tr = T[:m], T[m:]
                else:
                    P, Q, t0 = og[ii], qg[ii], t0g[ii]
                    tl = self._slab_many(lc, P, Q, t0, li)
                    tr = self._slab_many(rc, P, Q, t0, li)
                pos = dpg[ii, axis[nd]]
                # Per ray: far child pushed first, near child on top (popped first). A
                # child is written to the slot above the stack either way and counted
                # only where its box is hit (that slot is < D: a stack holds <= depth + 1).
                far, near = np.where(pos, rc, lc), np.where(pos, lc, rc)
                tf, tnr = np.where(pos, tr, tl), np.where(pos, tl, tr)
                sp_i = sp[ii]
                for child, tc in ((far, tf), (near, tnr)):
                    stk[ii, sp_i] = child
                    stt[ii, sp_i] = tc
                    sp_i = sp_i + np.isfinite(tc)
                sp[ii] = sp_i
            act = act[sp[act] > 0]
