"""``links1_blob`` for Mitsuba: the weight-function surface (eq. 3.6-3.9) intersected in
Dr.Jit by ``links1_whitted``. :class:`BlobSpec` holds the centres and their tables, the
field and its terms, the nearest hit and the normal; its candidate-centre search (many
centres) is :mod:`links1_mitsuba.blob_candidates`, its root finders (``exact``, ``paper``)
:mod:`links1_mitsuba.blob_roots`. Numerically stable forms follow docs/numerics.md.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from links1.scene.params import blob_centers, read, transform_problem

from .blob_candidates import CandidateLists
from .blob_roots import RootSolvers
from .registered import check_properties
from .shapes import INF, _matrix, table_value

#: Blob march: probe step relative to the largest S (float32 analogue of the core's).
PROBE_REL = 1e-4


@dataclass
class BlobSpec(CandidateLists, RootSolvers):
    """``links1_blob``: weight-function surface ``Σ w_i P(r_i) = threshold`` (eq. 3.6–3.9).

    ``centers`` (N, 5) rows ``x y z w S`` in object space; ``to_world`` optional. The
    ``exact`` solver steps along the ray with the Lipschitz/curvature bound of
    docs/numerics.md (never jumps over a root, Newton-fast near one); ``paper`` samples the
    span ``samples`` times per crossed centre and solves a quadratic per segment. With
    :data:`LIST_MIN_CENTRES` centres or more, ``exact`` sums each field evaluation over the
    ray's candidate centres only (its line crosses their 3S sphere; the others add exact
    zeros), found once per ray (:meth:`_collect`), as the core does."""

    slot: int
    name: str
    centers: np.ndarray
    threshold: float
    solver: str = "exact"
    samples: int = 8
    to_world: np.ndarray | None = None
    emission: np.ndarray | None = None
    max_steps: int = 256
    #: ``FILE:LINE`` of its element (set by the loader), for messages after the load
    where: str | None = field(default=None, repr=False, compare=False)
    _tables: dict | None = field(default=None, init=False, repr=False, compare=False)
    _values_cache: object = field(default=None, init=False, repr=False, compare=False)
    # the last nearest-hit search's ray (o, d) and candidate lists, for :meth:`normal`
    _line: tuple | None = field(default=None, init=False, repr=False, compare=False)
    # the centres in the candidate hierarchy's leaf order (its rows), for :meth:`film_lists`
    _leaf_order: object = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self):
        m = np.eye(4) if self.to_world is None else self.to_world
        self.inv = np.linalg.inv(m).tolist()
        self.normal_mat = np.linalg.inv(m)[:3, :3].T.tolist()
        self.centers = np.asarray(self.centers, dtype=np.float64)

    @classmethod
    def from_props(cls, slot, props):
        check_properties("shape", "links1_blob", props)
        try:
            c = blob_centers(str(props["centers"]) if ("centers" in props) else "")
        except ValueError as exc:
            raise ValueError(f"links1_blob: {exc}") from None
        thr = read("links1_blob", "threshold", float(props["threshold"]) if ("threshold" in props) else None)
        solver = read("links1_blob", "solver", str(props["solver"]) if ("solver" in props) else None)
        samples = read("links1_blob", "samples", int(props["samples"]) if ("samples" in props) else None)
        m = _matrix(props)
        if m is not None and (problem := transform_problem(m)) is not None:
            raise ValueError(f"links1_blob: {problem}")
        return cls(slot, props.id(), c, thr, solver, samples, _matrix(props))

    def bounds(self):
        c = self.centers
        lo = (c[:, :3] - 3 * c[:, 4:5]).min(0)
        hi = (c[:, :3] + 3 * c[:, 4:5]).max(0)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        m = np.eye(4) if self.to_world is None else self.to_world
        w = corners @ m[:3, :3].T + m[:3, 3]
        return w.min(0), w.max(0)

    def nbytes(self) -> int:
        return int(self.centers.nbytes) + 64

    # ------------------------------------------------------------------ Dr.Jit
    def _consts(self):
        """Per-centre constants, one row each: x y z w S 9S² 1/(3S²) 3S 1/(6S²) −2/(3S²)
        2|w|/(3S) 2|w|/(3S²) (float64, rounded once to float32 wherever they are used)."""
        x, y, z, w, S = self.centers.T
        inv3s2 = 1.0 / (3.0 * S * S)
        return np.c_[x, y, z, w, S, 9.0 * S * S, inv3s2, 3.0 * S, 0.5 * inv3s2, -2.0 * inv3s2,
                     np.abs(w) * 2.0 / (3.0 * S), np.abs(w) * 2.0 / (3.0 * S * S)]

    def _values(self):
        """The constants a ``params.update()`` may change, one flat float64 row: the
        :meth:`_consts` rows (12 per centre), the 3x4 inverse transform, the normal matrix
        (3x3), the threshold and the march's probe step. The kernels gather them from a
        Dr.Jit table (:meth:`tables`, ``"values"``) instead of taking them as literals, so new
        values (same count) replay the same kernels; float32 rounding of
        each is that of the literal it replaces (same bits)."""
        probe = PROBE_REL * float(self.centers[:, 4].max())
        return np.concatenate([self._consts().ravel(), np.asarray(self.inv)[:3].ravel(),
                               np.asarray(self.normal_mat).ravel(), [float(self.threshold), probe]])

    def _value(self, k):
        """Entry ``k`` of the ``"values"`` table (:meth:`_values`): :func:`table_value`."""
        return table_value(self, k)

    def literals(self) -> tuple:
        """The values its kernels take as Python literals (the others, centres, weights,
        radii, threshold and transform, they gather from :meth:`tables`): the centre count, the
        solver and its settings. A geometry update that changes none of these (of any shape)
        nor its tables' sizes replays the frozen launches (``launch.literal_key``)."""
        return (len(self.centers), self.solver, int(self.samples), int(self.max_steps), self.uses_lists())

    def _crow(self, i):
        """Centre ``i``'s :meth:`_consts` row, gathered (12 Floats)."""
        return [self._value(12 * i + c) for c in range(12)]

    def _mats(self):
        """The inverse transform's 3x4 rows and the normal matrix's 3x3, gathered."""
        base = 12 * len(self.centers)
        a = [[self._value(base + 4 * i + j) for j in range(4)] for i in range(3)]
        m = [[self._value(base + 12 + 3 * i + j) for j in range(3)] for i in range(3)]
        return a, m

    def _threshold(self):
        return self._value(12 * len(self.centers) + 21)

    def _probe(self):
        return self._value(12 * len(self.centers) + 22)

    def _unit_ray(self, o, d):
        """Object-space origin, unit direction and the length scale of ``d``."""
        import drjit as dr
        import mitsuba as mi
        a = self._mats()[0]
        u = mi.Vector3f(*[a[i][0] * o.x + a[i][1] * o.y + a[i][2] * o.z + a[i][3] for i in range(3)])
        v = mi.Vector3f(*[a[i][0] * d.x + a[i][1] * d.y + a[i][2] * d.z for i in range(3)])
        scale = dr.norm(v)
        return u, v / scale, scale

    @staticmethod
    def _chord(u, v, row, enter, leave, Lb, Gb):
        """One centre against the ray's line: (τ, h², the span and the derivative bounds
        updated where the line crosses its 3S sphere)."""
        import drjit as dr
        import mitsuba as mi
        x, y, z, _, _, R2, _, _, _, _, lb, gb = row
        rel = mi.Vector3f(x, y, z) - u
        tau = dr.dot(rel, v)
        h2 = dr.squared_norm(dr.cross(rel, v))   # no cancellation (docs/numerics.md)
        cross = h2 < R2
        half = dr.sqrt(dr.maximum(R2 - h2, 0.0))
        enter = dr.select(cross, dr.minimum(enter, tau - half), enter)
        leave = dr.select(cross, dr.maximum(leave, tau + half), leave)
        return tau, h2, enter, leave, Lb + dr.select(cross, lb, 0.0), Gb + dr.select(cross, gb, 0.0)

    def _setup(self, o, d, tmin, tmax):
        """Object-space unit ray and per-centre (τ, h², constants) plus the span and bounds."""
        import drjit as dr
        import mitsuba as mi
        u, v, scale = self._unit_ray(o, d)
        s_lo, s_hi = tmin * scale, tmax * scale
        enter, leave = mi.Float(INF), mi.Float(-INF)
        Lb, Gb = mi.Float(0.0), mi.Float(0.0)
        per = []
        for i in range(len(self.centers)):
            row = self._crow(i)
            tau, h2, enter, leave, Lb, Gb = self._chord(u, v, row, enter, leave, Lb, Gb)
            per.append((tau, h2, *row[3:5], *row[6:10], self._peak(h2, row)))
        start = dr.maximum(s_lo, enter)
        end = dr.minimum(s_hi, leave)
        return scale, per, start, end, Lb, Gb

    def tables(self):
        """Dr.Jit tables of the blob, built once: ``"values"``, the constants of
        :meth:`_values` (every blob); and with :data:`LIST_MIN_CENTRES` centres or more
        those of the candidate search: a hierarchy of boxes over the centres' 3S spheres (up to
        :data:`LEAF_CENTRES` centres per leaf, bvh.py's SAH build) in depth-first order, and
        the constants of :meth:`_consts` in its leaf order, so that the walk meets the
        candidates in increasing row. Both are packets of 4 floats, read with packet gathers:
        a centre's row as ``(x, y, z, 9S²)`` (all the line test reads), ``(w, S, 3S,
        1/(3S²))`` and ``(2|w|/(3S), 2|w|/(3S²), 1/(6S²), −2/(3S²))``; an inner node as
        ``(lo, skip)`` and ``(hi, 0)``, a leaf as ``(first, 0, 0, skip)`` and ``(0, 0, 0,
        count)``, where ``skip`` is the node after its subtree (small integers, exact in
        float32)."""
        if self._tables is None:
            import mitsuba as mi

            from .util import table
            self._tables = {"values": table(mi.Float, self._values())}
        if self.uses_lists() and "rows" not in self._tables:
            self._tables.update(self._candidate_tables())
        return self._tables

    @staticmethod
    def _peak(h2, row):
        """The largest value of centre ``row``'s term ``w P(r)`` (eq. 3.9) along a line at
        distance ``sqrt(h2)`` from it, ``w P(sqrt(h2))`` (0 for a negative weight): the bound
        :meth:`_term` gives ahead of the point of closest approach."""
        import drjit as dr
        _, _, _, w, S, _, inv3s2, S3, half = row[:9]
        r = dr.sqrt(h2)
        P = dr.select(r < S, 1.0 - h2 * inv3s2, dr.select(r < S3, dr.square(r - S3) * half, 0.0))
        return dr.maximum(w, 0.0) * P

    @staticmethod
    def _term(s, tau, h2, w, S, inv3s2, S3, half, m2, peak):
        """One centre's ``w P(r)`` and ``w dP/ds`` at ``s`` (eq. 3.9), and a bound of ``w P``
        from ``s`` on along the ray: ``w P(r)`` itself past the point of closest approach
        ``tau`` (where ``r`` grows), ``peak`` (:meth:`_peak`) before it, 0 for a negative
        weight. The constants are the centre's row of :meth:`_consts` (Python floats or
        gathered Floats: the same float32 values, so both give the same bits)."""
        import drjit as dr
        dt = s - tau
        r2 = dr.square(dt) + h2
        r = dr.sqrt(r2)
        inner = r < S
        outer = r < S3
        P = dr.select(inner, 1.0 - r2 * inv3s2, dr.select(outer, dr.square(r - S3) * half, 0.0))  # eq. (3.9)
        g = dr.select(inner, m2, dr.select(outer, (1.0 - S3 / dr.maximum(r, 1e-30)) * inv3s2, 0.0))
        wP = w * P
        return wP, w * g * dt, dr.select(dt < 0, peak, dr.maximum(wP, 0.0))

    @staticmethod
    def _field(per, s, W=0.0, dW=0.0, B=0.0):
        """W(s) and dW/ds along the unit object-space ray (eq. 3.6–3.9), the terms of
        ``per`` added in order to ``W``, ``dW``; and ``B``, a bound of ``W`` from ``s`` on
        along the ray (the sum of :meth:`_term`'s bounds)."""
        import mitsuba as mi
        W = mi.Float(W)
        dW = mi.Float(dW)
        B = mi.Float(B)
        for tau, h2, *c in per:
            Wk, dWk, Bk = BlobSpec._term(s, tau, h2, *c)
            W += Wk
            dW += dWk
            B += Bk
        return W, dW, B

    def intersect(self, o, d, tmin, tmax, active, cost=None, any_hit=False, film=None):
        """Nearest root of ``W = threshold`` in (tmin, tmax): ``(t, prim=0)``; ``cost`` += evaluations.
        ``any_hit`` (shadow rays): the first bracketed root is enough, its exact place is not
        refined (the returned t is then a point past the root, still inside the interval).
        ``film``: the candidate centres by cell of the rays' lines (the same lists as the
        walk's): a :class:`BlobFilm` of the pinhole camera whose eye they leave
        (:meth:`film_lists`), or a :class:`BlobDirGrid` of the directional light they go
        toward (:meth:`dir_lists`)."""
        import drjit as dr
        import mitsuba as mi
        from .blob_roots import _clear
        T = self._threshold()
        lists = self.uses_lists()
        u, v, scale = self._unit_ray(o, d)
        s_lo, s_hi = tmin * scale, tmax * scale   # the segment, as in _setup
        found = gate = None
        if lists and film is not None and any_hit:
            # a shadow ray: a bound of W from its start on, over its list; where it is below
            # T no root follows (a miss), and a packet of such rays skips the list, set-up and
            # march (the list is made only where some lane of the packet goes on)
            gate = active & ~_clear(1.0, self._film_bound(u, v, film, o, d, active, s_lo), T)
        elif lists and film is not None:
            found = self._film_candidates(u, v, film, o, d, active)

        def search(active):
            if lists:
                made = found if gate is None else self._film_candidates(u, v, film, o, d, active)
                cands, enter, leave, Lb, Gb = self._setup_lists(u, v, active, made)
                # kept for the normal at this ray's hit (raytree.py calls normal(o, d, ...) next)
                self._line = None if any_hit else (o, d, cands[:3])
                start, end = dr.maximum(s_lo, enter), dr.minimum(s_hi, leave)
                per = None

                def field_at(s):
                    return self._field_lists(u, v, cands, s)
            else:
                _, per, start, end, Lb, Gb = self._setup(o, d, tmin, tmax)

                def field_at(s):
                    return BlobSpec._field(per, s)
            run = active & (start < end)

            def solve(start, end, Lb, Gb):
                if self.solver == "paper":
                    return self._paper(per, s_lo, s_hi, run)
                W0, dW0, B0 = field_at(start)
                inside = (W0 > T) | ((W0 == T) & (dW0 > 0))
                sgn = dr.select(inside, -1.0, 1.0)
                n_eval = dr.select(run, mi.UInt32(1), mi.UInt32(0))
                return self._exact(field_at, start, end, sgn, run, W0, dW0, B0, n_eval, Lb, Gb, any_hit)

            # symbolic conditional: a packet of rays that all miss the centres' spheres skips the solver
            return dr.if_stmt((start, end, Lb, Gb), run, solve, _none)

        if gate is None:
            t_obj, n_eval = search(active)
        else:
            self._line = None
            t_obj, n_eval = dr.if_stmt((gate,), gate, search, _none)
        if cost is not None:
            cost += n_eval
        t = t_obj / scale
        return dr.select(dr.isfinite(t_obj), t, INF), dr.zeros(mi.UInt32, dr.width(t))

    def normal(self, o, d, t, prim, reuse=False):
        """Outward normal ``-∇W/|∇W|`` (fallback ``-d`` where the gradient vanishes).
        ``reuse``: sum over the candidates of the last nearest-hit :meth:`intersect` of the same
        ``o``, ``d`` (no walk); only for a caller that evaluates the normal in the kernel of
        that search (its candidate list is a local array of that kernel), as raytree.py does."""
        import drjit as dr
        import mitsuba as mi
        a, m = self._mats()
        p = o + d * t
        x = mi.Vector3f(*[a[i][0] * p.x + a[i][1] * p.y + a[i][2] * p.z + a[i][3] for i in range(3)])

        def grad(row, g):
            cx, cy, cz, w, S, _, inv3s2, S3, _, m2 = row[:10]
            rel = x - mi.Vector3f(cx, cy, cz)
            r = dr.norm(rel)
            gr = dr.select(r < S, m2, dr.select(r < S3, (1.0 - S3 / dr.maximum(r, 1e-30)) * inv3s2, 0.0))
            return (g + rel * (w * gr),)

        line, self._line = self._line, None
        if reuse and self.uses_lists() and line is not None and line[0] is o and line[1] is d:
            # the nearest-hit search's candidates of this ray: every centre whose 3S sphere
            # its line crosses, so every centre that adds a non-zero term at the hit point,
            # in the same increasing row as the point walk below (the others add exact zeros)
            # (only where there is a hit: a ray that misses sums nothing)
            lst, cnt, ovf = line[2]
            hit = dr.isfinite(t)
            g, = self._each(lst, dr.select(hit, cnt, 0), ovf & hit, (dr.zeros(mi.Vector3f, dr.width(x)),), grad)
        elif self.uses_lists():
            # the centres whose 3S sphere holds the point (the others add exactly zero)
            def hit_box(lo, hi, act):
                return act & (lo[0] <= x.x) & (x.x <= hi[0]) & (lo[1] <= x.y) & (x.y <= hi[1]) \
                    & (lo[2] <= x.z) & (x.z <= hi[2])

            def hit_centre(idx, act):
                # the point within the 3S sphere (padded: a term r < 3S in float32 is kept)
                row = self._row(idx, act)
                return dr.squared_norm(x - mi.Vector3f(*row[:3])) < row[5] * (1.0 + 1e-4)

            cands = self._collect(hit_box, hit_centre, dr.isfinite(t))
            g, = self._each(*cands, (dr.zeros(mi.Vector3f, dr.width(x)),), grad)
        else:
            g = mi.Vector3f(0.0)
            for i in range(len(self.centers)):
                g, = grad(self._crow(i), g)
        nw = -mi.Vector3f(*[m[i][0] * g.x + m[i][1] * g.y + m[i][2] * g.z for i in range(3)])
        ln = dr.norm(nw)
        return dr.select(ln > 1e-20, nw / dr.maximum(ln, 1e-30), -d)


def _none(x, *_):
    """No root: ``(inf, 0 evaluations)`` (the false branch of :meth:`BlobSpec.intersect`'s
    conditionals)."""
    import drjit as dr
    import mitsuba as mi
    return dr.full(mi.Float, INF, dr.width(x)), dr.zeros(mi.UInt32, dr.width(x))
