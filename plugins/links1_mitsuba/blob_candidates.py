"""The candidate centres of a ray's line for :class:`~links1_mitsuba.blob.BlobSpec` (many
centres): from :data:`LIST_MIN_CENTRES` centres on, the ``exact`` solver sums each field
evaluation over the centres whose 3S sphere the ray's line crosses, found once per ray with
a hierarchy of boxes (bvh.py's build, walked stackless in Dr.Jit), as the core does
(links1/geometry/blob.py). A mixin of :class:`~links1_mitsuba.blob.BlobSpec`: its methods
read the spec's tables, constants and field terms.
"""
from __future__ import annotations

import numpy as np

from .shapes import INF

#: From this many centres on, the ``exact`` solver sums each field evaluation over the ray's
#: candidate centres only (found once per ray with a hierarchy of boxes over the 3S spheres, or
#: read from the film cell's or light grid's lists). Measured (``compare.blob_mesh``'s scene,
#: 256², spp 16, frame CPU time): the lists cost 4 % more at 8 centres, save 7 % at 10 (also a
#: blob of 10 whose spheres all overlap, and under a point light) and 29 % at 16.
LIST_MIN_CENTRES = 10
#: Candidate centres per ray held in registers (the field sum is unrolled over them); a ray
#: crossing more sums over its list in local memory (a loop), beyond :data:`LIST_CAP` over all.
SLOTS = 32
#: Slots summed together; a packet skips a group no lane of it fills. An empty slot adds
#: exact zeros (w = 0) to sums that start at +0.0 and so are never -0.0: skipped or added, the
#: same bits, so the group size is a matter of speed only.
SLOT_GROUP = 4
#: Candidate centres per ray held in local memory.
LIST_CAP = 64
#: Centres per leaf of the candidate search's hierarchy (at most 15).
LEAF_CENTRES = 4
#: Cells a side at most of a directional light's grid (:meth:`CandidateLists.dir_lists`).
DIR_SIDE = 256
#: Cells of a directional light's grid per smallest range 3S (a side): the finer, the nearer a
#: cell's list to the centres its lines cross (100 centres, compare.blob_rays' shadow rays from
#: hits: 14.9 entries a list at 8 (square lists), 10.0 at 32, 8.9 crossed).
DIR_CELLS_PER_RANGE = 32
#: List entries over a directional light's grid at most (else coarser cells, halving the sides).
DIR_ENTRIES = 1 << 22
#: :meth:`BlobSpec._consts` columns in the packets of a centre's row in the candidate
#: search's table: ``(x, y, z, 9S²)``, ``(w, S, 3S, 1/(3S²))``, ``(2|w|/(3S), 2|w|/(3S²),
#: 1/(6S²), −2/(3S²))``.
_ROW_PACKETS = [0, 1, 2, 5, 3, 4, 7, 6, 10, 11, 8, 9]


def _depth_first(lo, hi, first, count):
    """Packed node table of :meth:`BlobSpec._collect`: the nodes of a bvh.py ``build``
    (children of node k at first[k], first[k] + 1) renumbered depth-first, left child first,
    8 floats each (see :meth:`BlobSpec.tables`)."""
    pre, work = [], [0]
    while work:
        k = work.pop()
        pre.append(k)
        if count[k] == 0:
            work += [int(first[k]) + 1, int(first[k])]
    size = {}
    for k in reversed(pre):
        size[k] = 1 if count[k] > 0 else 1 + size[int(first[k])] + size[int(first[k]) + 1]
    out = np.zeros((len(pre), 8))
    for at, k in enumerate(pre):
        skip = at + size[k]
        out[at] = [first[k], 0, 0, skip, 0, 0, 0, count[k]] if count[k] > 0 else [*lo[k], skip, *hi[k], 0]
    return out



class CandidateLists:
    """The candidate-list methods of :class:`~links1_mitsuba.blob.BlobSpec`."""

    def uses_lists(self) -> bool:
        """Whether the ``exact`` solver sums over per-ray candidate lists (many centres)."""
        return self.solver == "exact" and len(self.centers) >= LIST_MIN_CENTRES

    def _candidate_tables(self):
        """The candidate search's tables (see :meth:`BlobSpec.tables`): ``rows``, the
        :meth:`_consts` rows in the hierarchy's leaf order, and ``nodes``, the hierarchy."""
        import mitsuba as mi

        from .bvh import build
        from .util import table
        k = self._consts()
        c, R = k[:, :3], k[:, 7]
        # padded so that a sphere the float32 line test finds crossed is never culled
        pad = (1e-3 * R + 1e-5 * np.abs(c).max(1))[:, None]
        order, nlo, nhi, first, count = build(c - R[:, None] - pad, c + R[:, None] + pad,
                                              leaf=LEAF_CENTRES)
        self._leaf_order = np.asarray(order)
        return dict(rows=table(mi.Float, k[order][:, _ROW_PACKETS]),
                    nodes=table(mi.Float, _depth_first(nlo, nhi, first, count)))

    def _row(self, idx, act):
        """Row ``idx`` of the leaf-ordered constants, in :meth:`_consts`'s column order
        (three packet gathers; a packet no caller reads is never loaded)."""
        import drjit as dr
        import mitsuba as mi
        tab = self.tables()["rows"]
        vals = [None] * 12
        for j in range(3):
            pk = dr.gather(mi.Array4f, tab, 3 * idx + j, act)
            for col, v in zip(_ROW_PACKETS[4 * j:4 * j + 4], (pk.x, pk.y, pk.z, pk.w)):
                vals[col] = v
        return vals

    def _collect(self, hit_box, hit_centre, active):
        """Each lane's candidate centres (rows of the leaf-ordered table, increasing) in local
        memory (up to :data:`LIST_CAP`), their number, and whether there were more (the lane
        then sums over all centres).
        ``hit_box(lo, hi, act)`` culls subtrees, ``hit_centre(row, act)`` decides a leaf's
        centres. Stackless: the nodes are in depth-first order, so a crossed inner node goes
        on to the next node (its left child) and anything else to the node after its
        subtree; the walk ends past the last node."""
        import drjit as dr
        import mitsuba as mi
        tab = self.tables()["nodes"]
        end = dr.width(tab) // 8
        n = dr.width(active)
        lst = dr.alloc_local(mi.UInt32, LIST_CAP + 1, mi.UInt32(0))
        k = dr.select(active, mi.UInt32(0), mi.UInt32(end))
        cnt = dr.zeros(mi.UInt32, n)
        ovf = dr.zeros(mi.Bool, n)

        def cond(k, lst, cnt, ovf):
            return k < end

        def body(k, lst, cnt, ovf):
            act = k < end
            lo = dr.gather(mi.Array4f, tab, 2 * k, act)
            hi = dr.gather(mi.Array4f, tab, 2 * k + 1, act)
            num = mi.UInt32(hi.w)
            leaf = act & (num > 0)
            fst = mi.UInt32(dr.select(leaf, lo.x, 0.0))
            for i in range(LEAF_CENTRES):
                take = leaf & (i < num)
                take &= hit_centre(fst + i, take)
                cnt, ovf = self._keep(lst, cnt, ovf, fst + i, take)
            down = hit_box([lo.x, lo.y, lo.z], [hi.x, hi.y, hi.z], act & ~leaf)
            k = dr.select(down, k + 1, mi.UInt32(lo.w))
            return k, lst, cnt, ovf

        _, lst, cnt, ovf = dr.while_loop((k, lst, cnt, ovf), cond, body, label="links1_blob_collect")
        return lst, cnt, ovf

    @staticmethod
    def _keep(lst, cnt, ovf, idx, take):
        """Row ``idx`` appended to the lanes' lists where ``take`` (beyond :data:`LIST_CAP`:
        ``ovf``): the new ``cnt``, ``ovf``."""
        import drjit as dr
        add = take & (cnt < LIST_CAP)
        ovf = ovf | (take & ~add)
        # unmasked (a masked write costs a branch per lane): the entry at cnt is kept
        # only where cnt moves on, and a full list writes to its spare last entry
        lst.write(idx, dr.minimum(cnt, LIST_CAP))
        return dr.select(add, cnt + 1, cnt), ovf

    def _each(self, lst, cnt, ovf, state, fn):
        """Loop ``state = fn(row, state)`` over the lane's candidates in increasing row
        (over all centres where the list overflowed). The list is only read: it is not loop
        state, which would leave the caller's ``lst`` naming this loop's output (Dr.Jit
        updates a loop's state in place), a variable of whatever symbolic scope (the solver's
        loops, its ``dr.if_stmt``) this sum runs in, and a later read of it outside that
        scope (the normal at the hit, in another kernel in a derivative pass) an undefined
        value in the compiled kernel."""
        import drjit as dr
        import mitsuba as mi
        total = dr.select(ovf, mi.UInt32(len(self.centers)), cnt)

        def cond(j, *st):
            return j < total

        def body(j, *st):
            act = j < total
            idx = dr.select(ovf, j, lst.read(j, act & ~ovf))
            return (j + 1, *fn(self._row(idx, act), *st))

        out = dr.while_loop((dr.zeros(mi.UInt32, dr.width(cnt)), *state), cond, body, label="links1_blob_sum")
        return out[1:]

    def _line_candidates(self, u, v, active):
        """:meth:`_collect` for the line ``u + s v``: the centres whose 3S sphere it crosses,
        the only ones whose term ``w_i P(r_i)`` of ``W`` (eq. 3.6/3.7) can be non-zero on the
        line (``P = 0`` from ``r = 3S`` on, eq. 3.9); the root of ``W = T`` (eq. 3.8) is
        sought over their span."""
        import mitsuba as mi
        from .bvh import slab
        inv_v = mi.Vector3f(1.0 / v.x, 1.0 / v.y, 1.0 / v.z)

        def hit_box(lo, hi, act):
            return slab(lo, hi, u, inv_v, mi.Float(-INF), mi.Float(INF), act)[0]

        return self._collect(hit_box, self._crosses(u, v), active)

    def _crosses(self, u, v, s0=None):
        """``hit_centre(idx, act)`` of :meth:`_collect` for the line ``u + s v``: whether it
        crosses centre ``idx``'s 3S sphere (float32, the test of :meth:`_chord`). With ``s0``:
        ``(crosses, bound)``, the bound also of the centre's term of ``W`` from ``u + s0 v`` on
        along the line (:meth:`BlobSpec._term`)."""
        import drjit as dr
        import mitsuba as mi

        def hit_centre(idx, act):
            row = self._row(idx, act)
            rel = mi.Vector3f(*row[:3]) - u
            h2 = dr.squared_norm(dr.cross(rel, v))
            if s0 is None:
                return h2 < row[5]
            peak = self._peak(h2, row)
            return h2 < row[5], self._term(s0, dr.dot(rel, v), h2, *row[3:5], *row[6:10], peak)[2]
        return hit_centre

    def _film_candidates(self, u, v, film, o, d, active):
        """:meth:`_line_candidates` of rays ``o + t d`` (world) whose lines ``film`` lists by
        cell (:class:`BlobFilm`: camera rays from its eye; :class:`BlobDirGrid`: rays along a
        directional light): the same test over their cell's list (a superset of the centres
        the lines of the cell cross, in increasing row) instead of the hierarchy's walk, so
        the same list, count and overflow."""
        import drjit as dr
        import mitsuba as mi
        n = dr.width(active)
        k, end = self._cell_span(film, o, d, active)
        lst = dr.alloc_local(mi.UInt32, LIST_CAP + 1, mi.UInt32(0))
        cnt = dr.zeros(mi.UInt32, n)
        ovf = dr.zeros(mi.Bool, n)
        hit_centre = self._crosses(u, v)

        def cond(k, lst, cnt, ovf):
            return k < end

        def body(k, lst, cnt, ovf):
            act = k < end
            idx = dr.gather(mi.UInt32, film.rows, k, act)
            cnt, ovf = self._keep(lst, cnt, ovf, idx, act & hit_centre(idx, act))
            return k + 1, lst, cnt, ovf

        _, lst, cnt, ovf = dr.while_loop((k, lst, cnt, ovf), cond, body, label="links1_blob_film")
        return lst, cnt, ovf

    def _film_bound(self, u, v, film, o, d, active, s0):
        """A bound of ``W`` from ``u + s0 v`` on along the rays of :meth:`_film_candidates`:
        the sum of :meth:`BlobSpec._term`'s bounds over the centres of the cell's list whose
        3S sphere the line crosses (the list of :meth:`_film_candidates`, not kept)."""
        import drjit as dr
        import mitsuba as mi
        k, end = self._cell_span(film, o, d, active)
        hit_centre = self._crosses(u, v, s0)

        def body(k, bound):
            act = k < end
            take, b = hit_centre(dr.gather(mi.UInt32, film.rows, k, act), act)
            return k + 1, bound + dr.select(act & take, b, 0.0)

        return dr.while_loop((k, dr.zeros(mi.Float, dr.width(active))), lambda k, _: k < end, body,
                             label="links1_blob_bound")[1]

    @staticmethod
    def _cell_span(film, o, d, active):
        """The entries ``[k, end)`` of the cell's list of rays ``o + t d`` in ``film``."""
        import drjit as dr
        import mitsuba as mi
        cell = film.cell(o, d)
        k = dr.gather(mi.UInt32, film.off, cell, active)
        return k, dr.select(active, dr.gather(mi.UInt32, film.off, cell + 1, active), k)

    def film_lists(self, eye, R, window, size, margin, angle):
        """:class:`BlobFilm` of a pinhole camera at ``eye`` (frame ``R``, film ``window`` of
        ``size`` pixels, ``eyegrid``): per film cell the rows whose 3S sphere a camera ray's line
        through the cell can cross, conservative: each sphere in world space around the centre's
        image with 3S (padded as the hierarchy's boxes, and for the float32 line test, relative
        to the distances from the eye) times the transform's largest singular value, plus
        ``margin``; the angular margin ``angle``."""
        from .eyegrid import line_lists
        self.tables()
        k = self._consts()
        m = np.eye(4) if self.to_world is None else np.asarray(self.to_world, dtype=np.float64)
        c = k[:, :3]
        e_obj = np.linalg.inv(m)[:3] @ np.append(np.asarray(eye, dtype=np.float64), 1.0)
        size_o = np.abs(c).max(1) + np.abs(e_obj).max() + np.linalg.norm(c - e_obj, axis=1)
        rad = (k[:, 7] * (1.0 + 1e-3) + 1e-5 * size_o) * np.linalg.svd(m[:3, :3], compute_uv=False)[0] + margin
        # the spheres in the hierarchy's leaf order: the lists' sphere indices are rows, increasing
        # in each cell (the walk's order)
        order = self._leaf_order
        off, rows, frame = line_lists(eye, R, window, size, (c @ m[:3, :3].T + m[:3, 3])[order], rad[order], angle)
        return BlobFilm(off, rows, frame)

    def dir_lists(self, w, extent, margin):
        """:class:`BlobDirGrid` of the lines along the unit direction ``w`` (world, a directional
        light's shadow rays) through points within ``extent`` of the origin in each coordinate:
        per cell of a grid on the plane across ``w`` (:data:`DIR_CELLS_PER_RANGE` cells along
        the smallest range 3S, at most ``DIR_SIDE`` cells a side and about ``DIR_ENTRIES``
        entries, one more cell for a non-finite point) the rows whose
        3S sphere such a line can cross, conservative: the sphere padded as in
        :meth:`film_lists` (relative to ``extent`` for the float32 line test) plus ``margin``,
        listed in every cell within one cell of a cell its disc across ``w`` meets."""
        self.tables()
        k = self._consts()
        m = np.eye(4) if self.to_world is None else np.asarray(self.to_world, dtype=np.float64)
        c = k[:, :3]
        inv = np.linalg.inv(m)
        far = np.linalg.svd(inv[:3, :3], compute_uv=False)[0] * extent * np.sqrt(3.0) + np.abs(inv[:3, 3]).max() * 2
        rad = (k[:, 7] * (1.0 + 1e-3) + 1e-5 * (np.abs(c).max(1) + 3.0 * far)) \
            * np.linalg.svd(m[:3, :3], compute_uv=False)[0] + margin
        w = np.asarray(w, dtype=np.float64)
        w = w / np.linalg.norm(w)
        e1 = np.cross(w, [1.0, 0.0, 0.0] if abs(w[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(w, e1)
        cw = c @ m[:3, :3].T + m[:3, 3]
        a, b = cw @ e1, cw @ e2
        u0, v0 = float((a - rad).min()), float((b - rad).min())
        span = max(float((a + rad).max()) - u0, float((b + rad).max()) - v0)
        N = int(min(DIR_SIDE, max(1, np.ceil(span / (rad.min() / DIR_CELLS_PER_RANGE)))))
        while N > 1 and len(c) * (2.0 * rad.max() * N / span + 3.0) ** 2 > DIR_ENTRIES:
            N //= 2
        scale = N / span

        def cells(x, x0):
            return np.clip(np.floor((x - x0) * scale).astype(np.int64), 0, N - 1)
        iu0, iu1 = np.maximum(cells(a - rad, u0) - 1, 0), np.minimum(cells(a + rad, u0) + 1, N - 1)
        iv0, iv1 = np.maximum(cells(b - rad, v0) - 1, 0), np.minimum(cells(b + rad, v0) + 1, N - 1)
        cu, per = iu1 - iu0 + 1, (iu1 - iu0 + 1) * (iv1 - iv0 + 1)
        objs = np.repeat(np.arange(len(c)), per)
        j = np.arange(objs.size) - np.repeat(np.cumsum(per) - per, per)
        iu = np.repeat(iu0, per) + j % np.repeat(cu, per)
        iv = np.repeat(iv0, per) + j // np.repeat(cu, per)
        # of the sphere's square of cells, those within one cell of a cell its disc meets (the
        # kernel's float32 cell of a point errs by one at most; the border cells reach beyond)
        def gap(i, x, x0):
            lo = np.where(i > 0, x0 + (i - 1) / scale, -np.inf)
            hi = np.where(i < N - 1, x0 + (i + 2) / scale, np.inf)
            return np.maximum(np.maximum(lo - x, x - hi), 0.0)
        du, dv = gap(iu, np.repeat(a, per), u0), gap(iv, np.repeat(b, per), v0)
        near = du * du + dv * dv <= np.repeat(rad, per) ** 2
        objs, cl = objs[near], (iv * N + iu)[near]
        cl = np.concatenate([cl, np.full(len(c), N * N)])        # a non-finite point: every centre
        objs = np.concatenate([objs, np.arange(len(c))])
        pos = np.empty(len(self.centers), dtype=np.int64)
        pos[self._leaf_order] = np.arange(len(self.centers))
        rows = pos[objs]
        order = np.lexsort((rows, cl))
        off = np.zeros(N * N + 2, dtype=np.int64)
        np.add.at(off, cl + 1, 1)
        return BlobDirGrid(np.cumsum(off), rows[order], (e1, e2, u0, v0, scale, N))


    def _setup_lists(self, u, v, active, found=None):
        """The candidate lists of the rays' lines, the first :data:`SLOTS` of them in
        registers, and the span and the bounds over them: the sums of :meth:`_setup`, over
        the centres that add non-zero terms, in the hierarchy's leaf order (so the same to
        float32 rounding, not bit for bit). ``found``: the lists, when already made
        (:meth:`_film_candidates`)."""
        import drjit as dr
        import mitsuba as mi
        n = dr.width(active)
        lst, cnt, ovf = self._line_candidates(u, v, active) if found is None else found
        many = ovf | (cnt > SLOTS)
        st = (dr.full(mi.Float, INF, n), dr.full(mi.Float, -INF, n), dr.zeros(mi.Float, n), dr.zeros(mi.Float, n))
        slots = []
        for g in range(0, SLOTS, SLOT_GROUP):
            def group(*st, g=g):
                out = []
                for j in range(g, g + SLOT_GROUP):
                    # an empty slot reads zeros: no crossing, and w = 0 adds exactly zero
                    row = self._row(lst.read(j), (j < cnt) & ~many)
                    tau, h2, *st = self._chord(u, v, row, *st)
                    out += [tau, h2, *row[3:5], *row[6:10], self._peak(h2, row)]
                return (*st, *out)

            def empty(*st):   # slots no lane of the packet fills: zeros, as an empty slot
                return (*st, *[dr.zeros(mi.Float, n) for _ in range(9 * SLOT_GROUP)])
            # the next slots only in packets where some lane has that many candidates
            res = group(*st) if g == 0 else dr.if_stmt(st, (cnt > g) & ~many, group, empty)
            st = res[:4]
            slots += [tuple(res[4 + 9 * j:13 + 9 * j]) for j in range(SLOT_GROUP)]

        def span(row, enter, leave, Lb, Gb):
            return self._chord(u, v, row, enter, leave, Lb, Gb)[2:]

        def by_list(*st):
            return self._each(lst, cnt, ovf, st, span)

        st = dr.if_stmt(tuple(st), many, by_list, lambda *st: st)
        return (lst, cnt, ovf, many, slots), *st

    def _field_lists(self, u, v, cands, s):
        """:meth:`_field` over the lane's candidate centres (the same terms, in leaf order):
        ``W``, ``dW/ds`` and the bound ``B`` of ``W`` from ``s`` on."""
        import drjit as dr
        import mitsuba as mi
        lst, cnt, ovf, many, slots = cands
        acc = self._field(slots[:SLOT_GROUP], s)
        for g in range(SLOT_GROUP, len(slots), SLOT_GROUP):
            # the next slots only in packets where some lane has that many candidates
            def more(*acc, g=g):
                return self._field(slots[g:g + SLOT_GROUP], s, *acc)
            acc = dr.if_stmt(acc, (cnt > g) & ~many, more, lambda *acc: acc)

        def term(row, W, dW, B):
            tau, h2 = self._chord(u, v, row, 0.0, 0.0, 0.0, 0.0)[:2]
            Wk, dWk, Bk = self._term(s, tau, h2, *row[3:5], *row[6:10], self._peak(h2, row))
            return W + Wk, dW + dWk, B + Bk

        def by_list(*acc):
            return self._each(lst, cnt, ovf, tuple(dr.zeros(mi.Float, dr.width(s)) for _ in range(3)), term)

        return dr.if_stmt(acc, many, by_list, lambda *acc: acc)


class BlobFilm:
    """The candidate rows of a blob per cell of a pinhole camera's film
    (:meth:`CandidateLists.film_lists`): ``off`` (CSR offsets over the cells, UInt32), ``rows``
    (UInt32) and the grid's frame (``eyegrid.film_cell`` reads ``frame``, ``u0``, ``v0``,
    ``su``, ``sv``, ``nu``, ``nv``, ``kappa``)."""

    def __init__(self, off, rows, frame):
        import mitsuba as mi

        from .util import table
        R, u0, v0, su, sv, self.nu, self.nv, self.kappa = frame
        self.frame = [[float(x) for x in row] for row in R]
        self.u0, self.v0, self.su, self.sv = float(u0), float(v0), float(su), float(sv)
        self.entries = int(len(rows))
        self.off = table(mi.UInt32, np.asarray(off, dtype=np.uint32))
        self.rows = table(mi.UInt32, np.asarray(rows if len(rows) else [0], dtype=np.uint32))

    def cell(self, o, d):
        """The film cell of camera rays along world ``d`` (``eyegrid.film_cell``)."""
        from .eyegrid import film_cell
        return film_cell(self, d)


class BlobDirGrid:
    """The candidate rows of a blob per cell of a grid across a directional light's direction
    (:meth:`CandidateLists.dir_lists`): ``off``, ``rows`` as :class:`BlobFilm`'s, the plane's
    axes ``e1``, ``e2``, its corner ``u0``, ``v0``, cells per unit ``scale`` and per side
    ``N`` (cell ``N²``: a non-finite point)."""

    def __init__(self, off, rows, grid):
        import mitsuba as mi

        from .util import table
        e1, e2, u0, v0, scale, self.N = grid
        self.e1, self.e2 = [float(x) for x in e1], [float(x) for x in e2]
        self.u0, self.v0, self.scale = float(u0), float(v0), float(scale)
        self.entries = int(len(rows))
        self.off = table(mi.UInt32, np.asarray(off, dtype=np.uint32))
        self.rows = table(mi.UInt32, np.asarray(rows if len(rows) else [0], dtype=np.uint32))

    def cell(self, o, d):
        """The cell of lines through world points ``o`` (along the grid's direction)."""
        import drjit as dr
        import mitsuba as mi
        N = self.N
        iu = dr.floor((dr.dot(o, mi.Vector3f(*self.e1)) - self.u0) * self.scale)
        iv = dr.floor((dr.dot(o, mi.Vector3f(*self.e2)) - self.v0) * self.scale)
        ok = dr.isfinite(iu) & dr.isfinite(iv)
        iu, iv = dr.clip(iu, 0.0, N - 1.0), dr.clip(iv, 0.0, N - 1.0)
        return dr.select(ok, mi.UInt32(iv) * N + mi.UInt32(iu), N * N)
