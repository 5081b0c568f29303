"""The scene's accelerator (paper 3-2-4) in float64 numpy: the hierarchy of bounding boxes
over a scene's shapes and the scene-level ray queries.

The root computer of LINKS-1 groups objects under bounding boxes and groups of boxes under
larger boxes; a node computer tests a ray against a box before the objects inside it.
:class:`Accel` builds that hierarchy over the shapes of a scene with the shape-agnostic
:class:`links1.geometry.bvh.BVH` (which :class:`links1.geometry.shapes.TriangleMesh` also uses over its
triangles) and answers the scene-level queries of docs/architecture.md: nearest hit, any-hit
per shape, and the shadow transmittance product ``t1 t2 ... tn`` of 3-3-3.

Of the BVH's two traversals (same bits and costs, :mod:`links1.geometry.bvh`) ``Accel`` picks the
packet one when a batch has at least :data:`PACKET_RAYS_PER_LEAF` rays per leaf, else the
lock-step one, in which all plain :class:`links1.geometry.shapes.Quadric` shapes of a batch of
(ray, shape) pairs are intersected in one vectorised call (``_QuadricSet``, the same
arithmetic per pair), so the cost per frame no longer grows with the number of nodes visited.

Determinism
-----------
A ray's result and its ``cost`` entry must not depend on the other rays of the batch (a
window of the film renders the same bits as the full frame): the BVH's traversal order and
culling are per ray (:mod:`links1.geometry.bvh`), and equal distances are resolved by index (lower
shape index wins), never by visiting order.
"""
from __future__ import annotations

import numpy as np

from .bvh import BVH
from .base import _finite_or_zero
from .quadrics import clip_interval, quadric_first_hit, quadric_roots
from .shapes import Quadric
from ..maths.vec import normalize

#: Traversals of :class:`Accel` (they give the same bits and costs; only speed differs).
TRAVERSALS = ("auto", "packet", "lockstep")
#: ``"auto"`` uses the packet traversal when a batch has at least this many rays per leaf
#: of the hierarchy (large coherent packets), else the lock-step one (many small packets).
PACKET_RAYS_PER_LEAF = 200


def _sub(a, r):
    return None if a is None else a[r]


def _batchable_quadric(s) -> bool:
    return type(s) is Quadric and not ({"intersect", "any_hit", "_hits", "_intervals"} & set(vars(s)))


def _mv(A, x):
    """``A[i] @ x[i]`` per row, written out like :func:`links1.maths.vec.matvec` (same bits)."""
    return np.stack([A[:, r, 0] * x[:, 0] + A[:, r, 1] * x[:, 1] + A[:, r, 2] * x[:, 2]
                     for r in range(3)], axis=-1)


class _QuadricSet:
    """All the scene's :class:`links1.geometry.shapes.Quadric` shapes as arrays, intersected over
    (ray, quadric) pairs in one vectorised call: per pair the exact arithmetic of
    ``Quadric._intervals`` / ``Quadric._hits`` (same bits), clip planes padded with the
    no-op plane ``0.y <= 1``."""

    def __init__(self, quads):
        self.A = np.array([q.A for q in quads], dtype=np.float64).reshape(-1, 3, 3)
        self.m = np.array([q.m for q in quads], dtype=np.float64).reshape(-1, 3)
        self.sphere = np.array([q.kind == "sphere" for q in quads])
        self.capped = np.array([q.capped for q in quads])
        C = max((len(q.clips) for q in quads), default=0)
        self.cn = np.zeros((len(quads), C, 3))
        self.ch = np.ones((len(quads), C))
        self.capn = np.zeros((len(quads), C, 3))
        for i, q in enumerate(quads):
            for j, (nv, h) in enumerate(q.clips):
                self.cn[i, j] = nv
                self.ch[i, j] = h
                self.capn[i, j] = q._cap_normals[j]

    def surface(self, qi, o, d, t, prim):
        """``Quadric.surface`` of rays ``o, d`` (m, 3) hitting quadric ``qi`` (m,) at
        ``t`` (finite), ``prim``: the same bits, all quadrics at once."""
        p = o + t[:, None] * d
        A = self.A[qi]
        y = _mv(A, p - self.m[qi])
        cyl = ~self.sphere[qi]
        if cyl.any():
            y = np.where(cyl[:, None], y * np.array([1.0, 1.0, 0.0]), y)
        ng = normalize(_mv(A.transpose(0, 2, 1), y))
        cap = prim >= 1
        if cap.any():
            ng[cap] = self.capn[qi[cap], prim[cap] - 1]
        return p, ng, ng.copy()

    @staticmethod
    def _terms(u, v, sph):
        if sph is True or sph is False:
            return _QuadricSet._terms_one(u, v, sph)
        u0, u1, u2 = u[:, 0], u[:, 1], u[:, 2]
        v0, v1, v2 = v[:, 0], v[:, 1], v[:, 2]
        cz = u0 * v1 - u1 * v0
        a = np.where(sph, v0 * v0 + v1 * v1 + v2 * v2, v0 * v0 + v1 * v1)
        b = np.where(sph, u0 * v0 + u1 * v1 + u2 * v2, u0 * v0 + u1 * v1)
        c = np.where(sph, (u0 * u0 + u1 * u1 + u2 * u2) - 1.0, u0 * u0 + u1 * u1 - 1.0)
        cx = u1 * v2 - u2 * v1
        cy = u2 * v0 - u0 * v2
        cr2 = np.where(sph, cx * cx + cy * cy + cz * cz, cz * cz)
        return a, b, c, cr2

    @staticmethod
    def _terms_one(u, v, sphere):
        u0, u1, u2 = u[:, 0], u[:, 1], u[:, 2]
        v0, v1, v2 = v[:, 0], v[:, 1], v[:, 2]
        cz = u0 * v1 - u1 * v0
        if sphere:
            cx = u1 * v2 - u2 * v1
            cy = u2 * v0 - u0 * v2
            return (v0 * v0 + v1 * v1 + v2 * v2, u0 * v0 + u1 * v1 + u2 * v2,
                    (u0 * u0 + u1 * u1 + u2 * u2) - 1.0, cx * cx + cy * cy + cz * cz)
        return v0 * v0 + v1 * v1, u0 * v0 + u1 * v1, u0 * u0 + u1 * u1 - 1.0, cz * cz

    def hits(self, qi, o, d, tmin, tmax):
        """``(t, prim)`` of rays ``o, d`` (m, 3) each against quadric ``qi`` (m,)."""
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            return self._hits(qi, o, d, tmin, tmax)

    def _hits(self, qi, o, d, tmin, tmax):
        A, m, sph = self.A[qi], self.m[qi], self.sphere[qi]
        if sph.all():
            sph = True
        elif not sph.any():
            sph = False
        u = _mv(A, o - m)
        v = _mv(A, d)
        a, b, _, _ = self._terms(u, v, sph)
        pos = a > 0
        s = np.where(pos, -b / np.where(pos, a, 1.0), 0.0)
        o2 = o + s[:, None] * d
        u = _mv(A, o2 - m)
        a, b, c, cr2 = self._terms(u, v, sph)
        disc = a - cr2
        q_lo, q_hi = quadric_roots(a, b, c, disc, pos)
        c_in, c_out, j_in, j_out = clip_interval(
            u, v, ((self.cn[qi, j], self.ch[qi, j]) for j in range(self.cn.shape[1])))
        return quadric_first_hit(s, q_lo, q_hi, c_in, c_out, j_in, j_out, self.capped[qi],
                                 tmin, tmax)


class Accel:
    """The scene-level hierarchy of bounding boxes over shapes (paper 3-2-4).

    Shapes whose bounds are not finite (should a shape report them) are kept in a list
    that every ray tests. See the module docstring for determinism rules.

    Parameters
    ----------
    shapes : sequence of links1.geometry.base.Shape
        ``shape_idx`` in the results is the position in this sequence.
    max_leaf : int
        Shapes per leaf of the hierarchy.
    """

    def __init__(self, shapes, max_leaf: int = 2, traversal: str = "auto"):
        if traversal not in TRAVERSALS:
            raise ValueError(f"Accel: traversal must be one of {TRAVERSALS}, got {traversal!r}")
        self.traversal = traversal
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
        self._leaf_arr = np.array(self._leaf_shapes, dtype=np.int64)
        # The plain quadrics are intersected together over (ray, quadric) pairs.
        self._qslot = np.full(len(self.shapes), -1, dtype=np.int64)
        quads = []
        for j, s in enumerate(self.shapes):
            if _batchable_quadric(s):
                self._qslot[j] = len(quads)
                quads.append(s)
        self._quads = _QuadricSet(quads) if quads else None

    def __repr__(self) -> str:
        nodes = len(self.bvh) if self.bvh is not None else 0
        return (f"Accel(shapes={len(self.shapes)}, nodes={nodes}, "
                f"unbounded={len(self.unbounded)})")

    # ------------------------------------------------------------------ helpers
    def _each_pair(self, o, d, tmin, limit, visit):
        """Call ``visit(r, j)`` with rays ``r`` (increasing, unique) and the shapes ``j``
        (one per ray) whose box they reach, per ray in the order of the depth-first,
        near-child-first traversal; the unbounded shapes are visited first, in index
        order."""
        rays = np.arange(o.shape[0], dtype=np.int64)
        for j in self.unbounded:
            r = rays[limit[rays] >= tmin[rays]]
            if r.size:
                visit(r, np.full(r.size, j, dtype=np.int64))
        if self.bvh is None:
            return
        leaf = self._leaf_arr
        mode = self.traversal
        if mode == "auto":
            n_leaves = max(1, (len(self.bvh) + 1) // 2)
            mode = "packet" if rays.size >= PACKET_RAYS_PER_LEAF * n_leaves else "lockstep"
        if mode == "lockstep":
            self.bvh.traverse_pairs(o, d, tmin, limit, lambda r, k: visit(r, leaf[k]), rays)
            return

        def visit_leaf(start, count, r):
            for k in range(start, start + count):
                if k > start:
                    r = r[limit[r] >= tmin[r]]
                    if r.size == 0:
                        return
                visit(r, np.full(r.size, leaf[k], dtype=np.int64))

        self.bvh.traverse(o, d, tmin, limit, visit_leaf, rays)

    def _groups(self, j):
        """Positions in ``j`` of the batched quadrics, and (shape, positions) of the rest."""
        slot = self._qslot[j]
        if j.size and j[0] == j[-1] and np.all(j == j[0]):
            # One shape (always so in the packet traversal): its own call, scalar operands.
            return slot, np.zeros(0, dtype=np.int64), [(int(j[0]), np.arange(j.size))]
        q = slot >= 0
        qpos = np.nonzero(q)[0]
        rest = []
        if qpos.size < j.size:
            opos = np.nonzero(~q)[0]
            js = j[opos]
            if js.size and np.all(js == js[0]):
                rest.append((int(js[0]), opos))
            else:
                order = np.argsort(js, kind="stable")
                js_s = js[order]
                cut = np.nonzero(np.diff(js_s))[0] + 1
                for part in np.split(order, cut):
                    rest.append((int(js[part[0]]), opos[part]))
        return slot, qpos, rest

    def _test_pairs(self, r, j, o, d, tmin, tmax, cost, any_hit=False):
        """Intersect ray ``r[i]`` with shape ``j[i]`` (segment ``tmin[r], tmax``);
        returns ``t`` (or hit bools for ``any_hit``) and adds to ``cost[r]``."""
        m = r.size
        out = np.zeros(m, dtype=bool) if any_hit else np.full(m, np.inf)
        prim = None if any_hit else np.full(m, -1, dtype=np.int64)
        slot, qpos, rest = self._groups(j)
        if qpos.size:
            rr = r[qpos]
            t, p = self._quads.hits(slot[qpos], o[rr], d[rr], tmin[rr], tmax[qpos])
            if any_hit:
                out[qpos] = np.isfinite(t)
            else:
                out[qpos] = t
                prim[qpos] = p
            if cost is not None:
                cost[rr] += 1
        for jj, pos in rest:
            rr = r[pos]
            c = None if cost is None else np.zeros(rr.size, dtype=np.int64)
            if any_hit:
                out[pos] = self.shapes[jj].any_hit(o[rr], d[rr], tmin[rr], tmax[pos], c)
            else:
                t, p = self.shapes[jj].intersect(o[rr], d[rr], tmin[rr], tmax[pos], c)
                out[pos] = t
                prim[pos] = p
            if cost is not None:
                cost[rr] += c
        return out, prim

    # ------------------------------------------------------------------ queries
    def surface(self, o, d, t, shape_idx, prim):
        """``(p, ng, ns)`` (N, 3) of hits ``shape_idx >= 0`` (the shapes' own ``surface``,
        same bits; zeros where ``shape_idx < 0``): the plain quadrics all in one call, the
        other shapes one call each (grouped by sorting, not one mask per shape)."""
        o = np.asarray(o, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(d, dtype=np.float64).reshape(-1, 3)
        t = _finite_or_zero(t)
        shape_idx = np.asarray(shape_idx, dtype=np.int64)
        prim = np.asarray(prim, dtype=np.int64)
        n = o.shape[0]
        p, ng, ns = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
        hit = np.nonzero(shape_idx >= 0)[0]
        if hit.size == 0:
            return p, ng, ns
        j = shape_idx[hit]
        slot, qpos, rest = self._groups(j)
        if qpos.size:
            rr = hit[qpos]
            p[rr], ng[rr], ns[rr] = self._quads.surface(slot[qpos], o[rr], d[rr], t[rr], prim[rr])
        for jj, pos in rest:
            rr = hit[pos]
            p[rr], ng[rr], ns[rr] = self.shapes[jj].surface(o[rr], d[rr], t[rr], prim[rr])
        return p, ng, ns

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

        def visit(r, j):
            bs = best_s[r]
            lim = limit[r]
            # A lower-index shape may tie with the current best: let it return t == best.
            lim = np.where((bs > j), np.nextafter(lim, np.inf), lim)
            t, prim = self._test_pairs(r, j, o, d, tmin, lim, cost)
            bt = best_t[r]
            win = (t < bt) | ((t == bt) & (j < bs) & np.isfinite(t))
            if win.any():
                w = r[win]
                best_t[w] = t[win]
                best_s[w] = j[win]
                best_p[w] = prim[win]
                limit[w] = t[win]

        self._each_pair(o, d, tmin, limit, visit)
        return best_t, best_s, best_p

    def any_hit_per_shape(self, o, d, tmin, tmax, cost=None):
        """Yield ``(shape_idx, hit (N,) bool)`` for every shape whose box a segment of
        the batch touches, in increasing shape index."""
        o = np.asarray(o, dtype=np.float64)
        d = np.asarray(d, dtype=np.float64)
        n = o.shape[0]
        tmin = np.broadcast_to(np.asarray(tmin, dtype=np.float64), (n,))
        limit = np.broadcast_to(np.asarray(tmax, dtype=np.float64), (n,)).copy()
        rs, js = [], []

        def visit(r, j):
            rs.append(r)
            js.append(j)

        self._each_pair(o, d, tmin, limit, visit)
        reached: dict[int, list] = {}
        if rs:
            rr, jj = np.concatenate(rs), np.concatenate(js)
            order = np.lexsort((rr, jj))
            rr, jj = rr[order], jj[order]
            cut = np.nonzero(np.diff(jj))[0] + 1
            for part_r, part_j in zip(np.split(rr, cut), np.split(jj, cut)):
                reached[int(part_j[0])] = [part_r]
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
        opaque_or_tinted = ~np.all(shadow_t == 1.0, axis=1)

        def visit(r, j):
            keep = opaque_or_tinted[j]  # fully transparent: cannot change the product
            if not keep.all():
                r, j = r[keep], j[keep]
                if r.size == 0:
                    return
            h, _ = self._test_pairs(r, j, o, d, tmin, limit[r], cost, any_hit=True)
            if h.any():
                w = r[h]
                T[w] *= shadow_t[j[h]]  # 3-3-3: L' = t1 t2 ... tn L
                dead = w[np.all(T[w] == 0.0, axis=1)]
                limit[dead] = -np.inf  # early out

        self._each_pair(o, d, tmin, limit, visit)
        return T
