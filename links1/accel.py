"""Hierarchical bounding boxes (paper 3-2-4) in float64 numpy.

The root computer of LINKS-1 groups objects under bounding boxes and groups of boxes under
larger boxes; a node computer tests a ray against a box before the objects inside it. Here
that hierarchy is a bounding-volume hierarchy (BVH) built automatically:

* :class:`BVH` is the generic hierarchy over axis-aligned boxes (object-median split along
  the widest axis of the box centres, leaves of at most ``max_leaf`` items), traversed by
  *ray packets*: at every node the subset of rays whose slab test passes is kept and the
  traversal recurses with it; a leaf hands its subset to a callback that tests all of
  them against the leaf's items at once. :class:`links1.shapes.TriangleMesh` uses it over
  its triangles, :class:`Accel` over the shapes of a scene.
* :class:`Accel` answers the scene-level queries of docs/architecture.md: nearest hit,
  any-hit per shape, and the shadow transmittance product ``t1 t2 ... tn`` of 3-3-3.

Determinism
-----------
A ray's result and its ``cost`` entry must not depend on the other rays of the batch (a
window of the film renders the same bits as the full frame). So the traversal order is a
per-ray choice (the near child by the sign of the ray's own direction along the node's
split axis), culling uses the ray's own current nearest distance, and equal distances are
resolved by index (lower primitive / shape index wins), never by visiting order.
"""
from __future__ import annotations

import numpy as np

#: Relative enlargement of the slab test's exit distance (pbrt's 2·gamma(3) idea, with a
#: generous margin): a box is never missed because of rounding.
_SLAB_SLACK = 1e-12


class BVH:
    """A bounding-volume hierarchy over ``P`` axis-aligned boxes.

    Parameters
    ----------
    lo, hi : (P, 3) float64
        The boxes (finite).
    max_leaf : int
        Largest number of items in a leaf (items whose centres all coincide are split
        by their position in the list instead).

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

    def __init__(self, lo: np.ndarray, hi: np.ndarray, max_leaf: int = 8):
        lo = np.asarray(lo, dtype=np.float64).reshape(-1, 3)
        hi = np.asarray(hi, dtype=np.float64).reshape(-1, 3)
        if lo.shape != hi.shape:
            raise ValueError("BVH: lo and hi must have the same shape")
        if lo.shape[0] == 0:
            raise ValueError("BVH: needs at least one box")
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise ValueError("BVH: boxes must be finite")
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
                order[s:e] = np.sort(items)
                start[nid], count[nid] = s, n
                continue
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


def _sub(a, r):
    return None if a is None else a[r]


class Accel:
    """The scene-level hierarchy of bounding boxes over shapes (paper 3-2-4).

    Shapes whose bounds are not finite (should a shape report them) are kept in a list
    that every ray tests. See the module docstring for determinism rules.

    Parameters
    ----------
    shapes : sequence of links1.shapes.Shape
        ``shape_idx`` in the results is the position in this sequence.
    max_leaf : int
        Shapes per leaf of the hierarchy.
    """

    def __init__(self, shapes, max_leaf: int = 2):
        self.shapes = list(shapes)
        finite, unbounded, lo, hi = [], [], [], []
        for j, s in enumerate(self.shapes):
            blo, bhi = s.bounds()
            blo = np.asarray(blo, dtype=np.float64)
            bhi = np.asarray(bhi, dtype=np.float64)
            if np.all(np.isfinite(blo)) and np.all(np.isfinite(bhi)):
                finite.append(j)
                lo.append(blo)
                hi.append(bhi)
            else:
                unbounded.append(j)
        self._finite = np.array(finite, dtype=np.int64)
        self.unbounded = unbounded
        self.bvh = BVH(np.array(lo), np.array(hi), max_leaf=max_leaf) if finite else None
        # Shape indices in leaf order of the hierarchy.
        self._leaf_shapes = (self._finite[self.bvh.order].tolist() if self.bvh is not None else [])

    def __repr__(self) -> str:
        nodes = len(self.bvh) if self.bvh is not None else 0
        return (f"Accel(shapes={len(self.shapes)}, nodes={nodes}, "
                f"unbounded={len(self.unbounded)})")

    # ------------------------------------------------------------------ helpers
    def _each_leaf(self, o, d, tmin, limit, visit_shape, rays=None):
        """Call ``visit_shape(j, rays)`` for every shape whose box the rays reach; the
        unbounded shapes are visited first, in index order."""
        if rays is None:
            rays = np.arange(o.shape[0], dtype=np.int64)
        for j in self.unbounded:
            r = rays[limit[rays] >= tmin[rays]]
            if r.size:
                visit_shape(j, r)
        if self.bvh is None:
            return
        leaf_shapes = self._leaf_shapes

        def visit_leaf(start, count, r):
            for k in range(start, start + count):
                if k > start:
                    r = r[limit[r] >= tmin[r]]
                    if r.size == 0:
                        return
                visit_shape(leaf_shapes[k], r)

        self.bvh.traverse(o, d, tmin, limit, visit_leaf, rays)

    # ------------------------------------------------------------------ queries
    def intersect(self, o, d, tmin, tmax, cost=None):
        """Nearest hit over all shapes.

        Returns ``(t, shape_idx, prim)``: ``t = inf``, ``shape_idx = -1``, ``prim = -1``
        on a miss. On exactly equal distances the lower shape index wins.
        """
        o = np.asarray(o, dtype=np.float64)
        d = np.asarray(d, dtype=np.float64)
        n = o.shape[0]
        tmin = np.broadcast_to(np.asarray(tmin, dtype=np.float64), (n,))
        tmax = np.broadcast_to(np.asarray(tmax, dtype=np.float64), (n,))
        best_t = np.full(n, np.inf)
        best_s = np.full(n, -1, dtype=np.int64)
        best_p = np.full(n, -1, dtype=np.int64)
        limit = tmax.copy()  # min(tmax, best_t): culls the traversal
        shapes = self.shapes

        def visit_shape(j, r):
            bs = best_s[r]
            lim = limit[r]
            # A lower-index shape may tie with the current best: let it return t == best.
            lim = np.where((bs > j), np.nextafter(lim, np.inf), lim)
            c = None if cost is None else np.zeros(r.size, dtype=np.int64)
            t, prim = shapes[j].intersect(o[r], d[r], tmin[r], lim, c)
            if cost is not None:
                cost[r] += c
            bt = best_t[r]
            win = (t < bt) | ((t == bt) & (j < bs) & np.isfinite(t))
            if win.any():
                w = r[win]
                best_t[w] = t[win]
                best_s[w] = j
                best_p[w] = prim[win]
                limit[w] = t[win]

        self._each_leaf(o, d, tmin, limit, visit_shape)
        return best_t, best_s, best_p

    def any_hit_per_shape(self, o, d, tmin, tmax, cost=None):
        """Yield ``(shape_idx, hit (N,) bool)`` for every shape whose box a segment of
        the batch touches, in increasing shape index."""
        o = np.asarray(o, dtype=np.float64)
        d = np.asarray(d, dtype=np.float64)
        n = o.shape[0]
        tmin = np.broadcast_to(np.asarray(tmin, dtype=np.float64), (n,))
        limit = np.broadcast_to(np.asarray(tmax, dtype=np.float64), (n,)).copy()
        reached: dict[int, list] = {}

        def visit_shape(j, r):
            reached.setdefault(j, []).append(r)

        self._each_leaf(o, d, tmin, limit, visit_shape)
        for j in sorted(reached):
            r = np.sort(np.concatenate(reached[j]))
            c = None if cost is None else np.zeros(r.size, dtype=np.int64)
            h = self.shapes[j].any_hit(o[r], d[r], tmin[r], limit[r], c)
            if cost is not None:
                cost[r] += c
            hit = np.zeros(n, dtype=bool)
            hit[r] = h
            yield j, hit

    def shadow_transmittance(self, o, d, tmax, shadow_t, cost=None):
        """Transmittance (N, 3) of the shadow segments ``o + t d``, ``0 < t < tmax``.

        The product of ``shadow_t[j]`` over every shape ``j`` the segment hits, each shape
        counted once however many times the segment crosses it (3-3-3: ``t1 t2 ... tn``;
        a closed transparent object scales the light once). A ray whose transmittance is
        already zero leaves the traversal (early out); opaque shapes (``shadow_t = 0``)
        make that happen at their first hit.
        """
        o = np.asarray(o, dtype=np.float64)
        d = np.asarray(d, dtype=np.float64)
        n = o.shape[0]
        shadow_t = np.asarray(shadow_t, dtype=np.float64).reshape(-1, 3)
        T = np.ones((n, 3))
        tmin = np.zeros(n)
        limit = np.broadcast_to(np.asarray(tmax, dtype=np.float64), (n,)).copy()
        limit[~(limit > 0)] = -np.inf
        shapes = self.shapes

        def visit_shape(j, r):
            st = shadow_t[j]
            if np.all(st == 1.0):
                return  # fully transparent: cannot change the product
            c = None if cost is None else np.zeros(r.size, dtype=np.int64)
            h = shapes[j].any_hit(o[r], d[r], tmin[r], limit[r], c)
            if cost is not None:
                cost[r] += c
            if h.any():
                w = r[h]
                T[w] *= st  # 3-3-3: L' = t1 t2 ... tn L
                dead = w[np.all(T[w] == 0.0, axis=1)]
                limit[dead] = -np.inf  # early out

        self._each_leaf(o, d, tmin, limit, visit_shape)
        return T
