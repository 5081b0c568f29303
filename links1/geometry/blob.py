"""The weight-function surface of LINKS-1 (paper 3-2-3, eq. 3.6-3.9), float64 numpy.

Each centre ``P_i`` carries a weight ``w_i`` (negative weights carve) and an effective
range ``S_i``; the field is ``W(x) = sum_i w_i P(|x - P_i|)`` (eq. 3.6/3.7) with the
piecewise-quadratic kernel of eq. (3.9)::

    P(r) = 1 - r^2 / (3 S^2)        0 <= r < S
    P(r) = (r - 3S)^2 / (6 S^2)     S <= r < 3S
    P(r) = 0                        r >= 3S

and the surface is ``W(x) = T`` (eq. 3.8); the inside is ``W > T``. The outward normal is
``-grad W / |grad W|`` (docs/method.md §3.3, Choice), ``-d`` where the gradient vanishes (pinch point).

Ray set-up (shared by both solvers)
-----------------------------------
The world ray goes to object space (``to_world``'s inverse), then to *normalised* units in
which the largest ``S`` is 1 (so a blob of any size, 1e-20 or 1e20, is solved the same
way), its direction is made unit (distances are converted back to world units at the end),
and its origin is moved to the ray's closest approach to the centroid of the positive
centres, so that a far camera loses nothing. Along the ray ``r_i^2 = (t - tau_i)^2 +
h_i^2`` with ``tau_i = (P_i - o).d`` and ``h_i = |(o - P_i) x d|`` (no cancellation).
A centre's ``3S`` sphere cuts the ray in a chord; the field can reach ``T > 0`` only
inside the chords of positive centres: their union is the ray's *span*.

Solvers
-------
``"exact"`` (default)
    A root finder that can never step over a root (Kalra & Barr's LG-surfaces, see
    docs numerics): with ``F = s (T - W)`` (``s = +1`` from outside, ``-1`` when the
    segment starts inside, which then finds the exit), ``L = sum |w_i| 2/(3 S_i)`` and
    ``G = sum |w_i| 2/(3 S_i^2)`` over the centres whose ``3S`` sphere the ray crosses
    (bounds of ``|W'|`` and ``|W''|`` along the ray), the step ``h = max(F/L, h2)`` with
    ``h2`` the first zero of the lower bound ``F + F' h - G h^2/2`` keeps ``F > 0``; it
    tends to Newton's step near a simple root (quadratic convergence). Gaps between
    chords are jumped. When the step falls below ``1e-7`` (normalised units) the solver
    probes one step ahead; a sign change brackets the root, which secant steps with the
    Illinois safeguard refine to float64 precision. Bounded: at most
    :data:`MAX_MARCH` marching and :data:`MAX_REFINE` refinement evaluations per ray; a
    ray that exhausts the march (a ray grazing the surface tangentially) is a miss.
``"paper"``
    The paper's own method (3-2-3 ii-iii): every positive centre's chord (inside the ray
    segment) is sampled at ``samples`` evenly spaced points, so a span crossed by more
    centres gets more samples; the sorted samples are taken in consecutive triples, a
    quadratic ``W*`` interpolates each triple, and the first solution of ``W* = T`` is
    the hit. Its error falls as ``samples`` grows; it can miss thin features.

Only the centres whose ``3S`` sphere a ray crosses can contribute along it: they are
compacted once per ray into a padded (n, kmax) candidate list sorted by centre index
(:meth:`Blob._candidates`), and every field evaluation sums over those only, left to
right in centre index order, so an evaluation costs O(centres met), not O(all centres).
From :data:`BVH_MIN_CENTRES` centres on, the crossed centres themselves are found with a
hierarchy of boxes over the 3S spheres (``links1.geometry.bvh.BVH.traverse_pairs``; same pairs, same
bits as testing every centre), and the normal sums over them too.

``cost`` gets +1 per field evaluation per ray (the contract's blob rule).
"""
from __future__ import annotations

import numpy as np

from .base import Shape, _finite_or_zero, check_to_world
from .bvh import BVH
from ..maths.vec import cross, dot, matvec, normalize

#: Largest number of marching evaluations of the exact solver per ray.
MAX_MARCH = 200
#: Largest number of bracket-refinement evaluations per ray.
MAX_REFINE = 40
#: Step (normalised units, largest S = 1) below which the exact solver probes for a bracket.
PROBE_STEP = 1e-7
#: Smallest allowed S_i / max(S): below it S^2 leaves float64's range.
MIN_S_RATIO = 1e-100
#: Rays per chunk x centres (x samples) kept in memory at once.
_CHUNK_ELEMS = 1 << 19
#: From this many centres on, a ray's crossed centres are found with a hierarchy of
#: boxes over the 3S spheres instead of testing every centre.
BVH_MIN_CENTRES = 160
#: Assumed number of centres met per ray when sizing chunks on the hierarchy path.
_MET_GUESS = 64

SOLVERS = ("exact", "paper")


class Blob(Shape):
    """Weight-function surface ("metaball", paper 3-2-3).

    Parameters
    ----------
    centers : (K, 5) array_like
        Rows ``x y z w S``: object-space centre, weight (may be negative), range (> 0).
    threshold : float
        ``T > 0``: the surface is ``W = T`` (eq. 3.8).
    solver : "exact" | "paper"
        See the module docstring.
    samples : int
        Samples per centre chord for the ``"paper"`` solver (>= 3).
    to_world : (4, 4) or None
        Object-to-world transform.
    name : str
    """

    def __init__(self, centers, threshold, solver: str = "exact", samples: int = 8,
                 to_world=None, name: str = ""):
        super().__init__(name)
        what = f"blob {name!r}"
        c = np.array(centers, dtype=np.float64)
        if c.ndim == 1 and c.size % 5 == 0 and c.size > 0:
            c = c.reshape(-1, 5)
        if c.ndim != 2 or c.shape[1] != 5 or c.shape[0] == 0:
            raise ValueError(f"{what}: centers must be a non-empty (K, 5) array of "
                             f"'x y z w S' rows, got shape {c.shape}")
        if not np.all(np.isfinite(c)):
            raise ValueError(f"{what}: centers must be finite")
        S = c[:, 4]
        if not np.all(S > 0):
            raise ValueError(f"{what}: every effective range S must be > 0, got "
                             f"{S[~(S > 0)].tolist()}")
        if not np.any(c[:, 3] > 0):
            raise ValueError(f"{what}: needs at least one centre with weight w > 0 "
                             "(otherwise W <= 0 < T everywhere: no surface)")
        try:
            T = float(threshold)
        except (TypeError, ValueError):
            raise ValueError(f"{what}: threshold must be a number, got {threshold!r}") from None
        if not (np.isfinite(T) and T > 0):
            raise ValueError(f"{what}: threshold T must be finite and > 0, got {T}")
        if solver not in SOLVERS:
            raise ValueError(f"{what}: solver must be one of {SOLVERS}, got {solver!r}")
        samples = int(samples)
        if samples < 3:
            raise ValueError(f"{what}: samples must be >= 3, got {samples}")
        s0 = float(S.max())
        if np.any(S < MIN_S_RATIO * s0):
            raise ValueError(f"{what}: ranges S span more than 1e100 (min {S.min()}, "
                             f"max {s0}): out of float64's range")

        self.centers = c
        self.threshold = T
        self.solver = solver
        self.samples = samples
        self.to_world = check_to_world(to_world, what)
        self.A = np.linalg.inv(self.to_world[:3, :3])
        self.m = self.to_world[:3, 3].copy()
        self.closed = True

        # Normalised object units: the largest S is 1 (numerics stress case 15).
        self._s0 = s0
        self._p = c[:, :3] / s0
        self._w = c[:, 3].copy()
        self._S = S / s0
        self._pos = self._w > 0
        self._ref = self._p[self._pos].mean(axis=0)  # origin shift target
        S_ = self._S
        self._inv3s2 = 1.0 / (3.0 * S_ * S_)
        self._lip = np.abs(self._w) * 2.0 / (3.0 * S_)          # |w| max|P'|
        self._curv = np.abs(self._w) * 2.0 / (3.0 * S_ * S_)    # |w| max|P''|
        # Per-centre data with one padding entry at index K (an exact zero term).
        self._w_pad = np.append(self._w, 0.0)
        self._S_pad = np.append(S_, 1.0)
        self._k_pad = np.append(self._inv3s2, 1.0)
        self._lip_pad = np.append(self._lip, 0.0)
        self._curv_pad = np.append(self._curv, 0.0)
        self._pos_pad = np.append(self._pos, False)
        self._nine = 9.0 * S_ * S_
        # Hierarchy over the centres' 3S spheres (normalised units), slightly enlarged so
        # that a crossed sphere's box is never missed; the exact test h^2 < 9 S^2 follows.
        self._centre_bvh = None
        if c.shape[0] >= BVH_MIN_CENTRES:
            R = 3.0 * S_ * (1.0 + 1e-9)
            self._centre_bvh = BVH(self._p - R[:, None], self._p + R[:, None], max_leaf=4)

        # World bounds: union of the positive centres' 3S spheres (W <= 0 elsewhere).
        lin = self.to_world[:3, :3]
        ext = np.sqrt(np.sum(lin ** 2, axis=1))
        P = c[self._pos, :3]
        R = 3.0 * S[self._pos]
        cw = P @ lin.T + self.m
        self._bounds = ((cw - R[:, None] * ext).min(axis=0), (cw + R[:, None] * ext).max(axis=0))

    def _repr_extra(self) -> str:
        return (f"centers={self.centers.shape[0]}, threshold={self.threshold}, "
                f"solver={self.solver!r}" + (f", samples={self.samples}" if self.solver == "paper" else ""))

    @property
    def nbytes(self) -> int:
        return int(self.centers.nbytes + 16 * 8)

    def bounds(self):
        return self._bounds[0].copy(), self._bounds[1].copy()

    # ------------------------------------------------------------------ set-up
    def _to_local(self, o, d):
        """Normalised object-space rays: shifted origin, unit direction, the shift
        ``ts`` and the scale ``lam`` (t_local = t_world * lam - ts)."""
        u = matvec(self.A, o - self.m) / self._s0
        v = matvec(self.A, d) / self._s0
        lam = np.sqrt(dot(v, v))
        dn = v / lam[:, None]
        ts = dot(self._ref - u, dn)
        o2 = u + ts[:, None] * dn
        return o2, dn, lam, ts

    def _ray_centres(self, o2, dn):
        """tau (N, K), h^2 (N, K) for every centre."""
        rel = o2[:, None, :] - self._p[None, :, :]          # o - P_i
        tau = -dot(rel, dn[:, None, :])                       # (P_i - o).d
        cr = cross(rel, np.broadcast_to(dn[:, None, :], rel.shape))
        h2 = dot(cr, cr)                                      # |(o - P_i) x d|^2
        return tau, h2

    def _field(self, t, cand):
        """W and dW/dt at distances ``t`` (n,) or (n, M) along the rays; eq. (3.6)-(3.9).

        ``cand`` = ``(tau, h2, w, S, k)``, each (n, kmax): the ray's candidate centres
        (those whose ``3S`` sphere it crosses, see :meth:`_candidates`), padded with
        ``w = 0``. The sums run over the candidates only, in increasing centre index,
        strictly left to right (``cumsum``), so the padding (exact zeros) and the
        batch's ``kmax`` never change a bit.
        """
        tau, hh, w, S, k = cand
        if t.ndim == 1:              # (n,) points
            dt = t[:, None] - tau
        else:                        # (n, M) points
            dt = t[:, :, None] - tau[:, None, :]
            hh, w, S, k = hh[:, None, :], w[:, None, :], S[:, None, :], k[:, None, :]
        with np.errstate(invalid="ignore", over="ignore"):
            r2 = dt * dt + hh
            r = np.sqrt(r2)
            inner = r < S
            outer = (~inner) & (r < 3.0 * S)
            # eq. (3.9): P(r) piecewise quadratic; g = P'(r)/r (no 0/0 at a centre).
            q = r - 3.0 * S
            P = np.where(inner, 1.0 - r2 * k, np.where(outer, 0.5 * q * q * k, 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            g = np.where(inner, -2.0 * k, np.where(outer, (q / r) * k, 0.0))
        W = np.cumsum(w * P, axis=-1)[..., -1]           # eq. (3.6)/(3.7): W = sum w_i P(r_i)
        dW = np.cumsum(w * g * dt, axis=-1)[..., -1]     # dW/dt = sum w_i g(r_i) (t - tau_i)
        return W, dW

    # ------------------------------------------------------------------ queries
    def intersect(self, o, d, tmin, tmax, cost=None):
        o = np.asarray(o, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(d, dtype=np.float64).reshape(-1, 3)
        n = o.shape[0]
        tmin = np.broadcast_to(np.asarray(tmin, dtype=np.float64), (n,))
        tmax = np.broadcast_to(np.asarray(tmax, dtype=np.float64), (n,))
        t_out = np.full(n, np.inf)
        if n == 0:
            return t_out, np.full(0, -1, dtype=np.int64)
        K = self._p.shape[0] if self._centre_bvh is None else _MET_GUESS
        per = K * (self.samples if self.solver == "paper" else 1)
        chunk = max(1, _CHUNK_ELEMS // max(per, 1))
        solve = self._solve_exact if self.solver == "exact" else self._solve_paper
        for a in range(0, n, chunk):
            b = min(n, a + chunk)
            c = None if cost is None else np.zeros(b - a, dtype=np.int64)
            t_out[a:b] = solve(o[a:b], d[a:b], tmin[a:b], tmax[a:b], c)
            if cost is not None:
                cost[a:b] += c
        prim = np.where(np.isfinite(t_out), 0, -1).astype(np.int64)
        return t_out, prim

    def _local_segment(self, o, d, tmin, tmax):
        o2, dn, lam, ts = self._to_local(o, d)
        with np.errstate(invalid="ignore"):
            lo = tmin * lam - ts
            hi = tmax * lam - ts
        if self._centre_bvh is None:
            tau, h2 = self._ray_centres(o2, dn)
            crossed = h2 < self._nine
            rr, cc = np.nonzero(crossed)             # row-major: centre index increasing
            pairs = rr, cc, tau[rr, cc], h2[rr, cc]
        else:
            pairs = self._crossed_pairs(o2, dn)
        return lam, ts, lo, hi, self._candidates(o2.shape[0], *pairs)

    def _crossed_pairs(self, o2, dn):
        """(ray, centre, tau, h^2) of every centre whose 3S sphere the line crosses, found
        with the hierarchy over the spheres; sorted by ray, then centre index. The same
        arithmetic per pair as :meth:`_ray_centres` (same bits)."""
        n = o2.shape[0]
        rs, ks = [], []

        def visit(r, k):
            rs.append(r)
            ks.append(k)

        big = np.finfo(np.float64).max
        self._centre_bvh.traverse_pairs(o2, dn, np.full(n, -big), np.full(n, big), visit)
        if not rs:
            e = np.zeros(0, dtype=np.int64)
            return e, e, np.zeros(0), np.zeros(0)
        rr = np.concatenate(rs)
        cc = self._centre_bvh.order[np.concatenate(ks)]
        rel = o2[rr] - self._p[cc]                            # o - P_i
        dr = dn[rr]
        tau = -dot(rel, dr)                                   # (P_i - o).d
        cr = cross(rel, dr)
        h2 = dot(cr, cr)                                      # |(o - P_i) x d|^2
        keep = h2 < self._nine[cc]
        rr, cc, tau, h2 = rr[keep], cc[keep], tau[keep], h2[keep]
        order = np.lexsort((cc, rr))
        return rr[order], cc[order], tau[order], h2[order]

    def _candidates(self, n, rr, cc, tau_v, h2_v):
        """Compact each ray's centres whose ``3S`` sphere it crosses (``h^2 < 9 S^2``;
        only these can contribute to W along the ray), given as pairs ``(rr, cc)`` sorted
        by ray then centre index with their ``tau``, ``h^2``, into (n, kmax) arrays:
        ``cand = (tau, h2, w, S, k)`` padded with ``w = 0``, ``h2 = inf`` (an exact zero
        term), the chords ``c_lo``/``c_hi`` (inf/-inf on padding), the validity mask."""
        K = self._p.shape[0]
        cnt = np.bincount(rr, minlength=n)
        kmax = max(int(cnt.max()) if n else 0, 1)
        first = np.cumsum(cnt) - cnt
        slot = np.arange(rr.size) - first[rr]
        idx = np.full((n, kmax), K, dtype=np.int64)  # K: the padding entry
        idx[rr, slot] = cc
        valid = idx < K
        tau_c = np.zeros((n, kmax))
        h2_c = np.full((n, kmax), np.inf)
        tau_c[rr, slot] = tau_v
        h2_c[rr, slot] = h2_v
        w_c = self._w_pad[idx]
        S_c = self._S_pad[idx]
        k_c = self._k_pad[idx]
        half = np.sqrt(np.maximum(9.0 * S_c * S_c - h2_c, 0.0))
        c_lo = np.where(valid, tau_c - half, np.inf)
        c_hi = np.where(valid, tau_c + half, -np.inf)
        return (tau_c, h2_c, w_c, S_c, k_c), idx, valid, c_lo, c_hi

    def _solve_exact(self, o, d, tmin, tmax, cost):
        n = o.shape[0]
        lam, ts, seg_lo, seg_hi, (cand, idx, valid, c_lo, c_hi) = self._local_segment(o, d, tmin, tmax)
        pos = self._pos_pad[idx]
        p_lo = np.where(pos, c_lo, np.inf)      # chords of positive centres: the span
        p_hi = np.where(pos, c_hi, -np.inf)
        # Bounds on |W'| and |W''| over the crossed centres (left-to-right sums).
        Lb = np.cumsum(self._lip_pad[idx], axis=1)[:, -1]
        Gb = np.cumsum(self._curv_pad[idx], axis=1)[:, -1]
        T = self.threshold
        result = np.full(n, np.inf)

        def covered(t, idx):
            return np.any((p_lo[idx] <= t[:, None]) & (t[:, None] <= p_hi[idx]), axis=1)

        def next_start(t, idx):
            s = p_lo[idx]
            return np.min(np.where(s > t[:, None], s, np.inf), axis=1)

        # Start: the segment's start if a chord covers it, else the next chord start.
        idx = np.arange(n)
        t = seg_lo.copy()
        cov = covered(t, idx)
        t = np.where(cov, t, next_start(t, idx))
        act = np.nonzero(np.isfinite(t) & (t < seg_hi))[0]
        t = t[act]
        sign = np.zeros(act.size)            # 0: side not yet known
        t_prev = t.copy()
        f_prev = np.full(act.size, np.nan)
        fa_l, fb_l, idx_l, s_l = [], [], [], []
        a_l, b_l = [], []

        for _ in range(MAX_MARCH):
            if act.size == 0:
                break
            W, dW = self._field(t, tuple(x[act] for x in cand))
            if cost is not None:
                cost[act] += 1
            new = sign == 0
            if new.any():
                inside = (W > T) | ((W == T) & (dW > 0))
                sign = np.where(new, np.where(inside, -1.0, 1.0), sign)
            F = sign * (T - W)   # eq. (3.8): the surface is F = 0; F > 0 on the ray's start side
            dF = -sign * dW
            # A sign change: the root lies in [t_prev, t] (only after a probe, or F == 0).
            root = (F <= 0) & ~new
            at_start = (F <= 0) & new        # W == T at the very start: step on
            if root.any():
                idx_l.append(act[root])
                a_l.append(t_prev[root]); b_l.append(t[root])
                fa_l.append(f_prev[root]); fb_l.append(F[root]); s_l.append(sign[root])
            # Step that never jumps over a root (numerics: LG bound).
            L = Lb[act]
            G = Gb[act]
            Fp = np.maximum(F, 0.0)
            disc = np.sqrt(dF * dF + 2.0 * G * Fp)
            with np.errstate(divide="ignore", invalid="ignore"):
                h2s = np.where(dF < 0, 2.0 * Fp / (disc - dF), (dF + disc) / G)
                h = np.maximum(Fp / L, np.where(np.isfinite(h2s), h2s, 0.0))
            h = np.where(at_start, PROBE_STEP, h)
            small = h < PROBE_STEP
            step = np.where(small, np.maximum(2.0 * h, 1e-15 * (1.0 + np.abs(t))), h)
            t_prev = t
            f_prev = F
            t = t + step
            # Outside a chord (only reachable from outside): jump to the next chord.
            keep = ~root
            out = ~covered(t, act)
            if out.any():
                jumped = next_start(t[out], act[out])
                t = t.copy()
                t[out] = jumped
                f_prev = f_prev.copy()
                f_prev[out] = np.nan
            keep &= np.isfinite(t) & (t < seg_hi[act])
            act, t, sign, t_prev, f_prev = (act[keep], t[keep], sign[keep],
                                            t_prev[keep], f_prev[keep])
        # Rays still marching after MAX_MARCH evaluations: treated as misses (tangent).

        if idx_l:
            ridx = np.concatenate(idx_l)
            result[ridx] = self._refine(ridx, np.concatenate(a_l), np.concatenate(b_l),
                                        np.concatenate(fa_l), np.concatenate(fb_l),
                                        np.concatenate(s_l), cand, cost)
        # Back to world units.
        t_world = (result + ts) / lam
        ok = np.isfinite(t_world) & (t_world > tmin) & (t_world < tmax)
        return np.where(ok, t_world, np.inf)

    def _refine(self, ridx, a, b, fa, fb, sgn, cand, cost):
        """Refine brackets ``F(a) > 0 >= F(b)`` (``F = sgn (T - W)``) of rays ``ridx`` by
        secant steps with the Illinois safeguard; returns the roots (local units)."""
        T = self.threshold
        # A bracket without a known F(a) (cannot happen after a march step; defensive)
        # or with F(b) == 0 exactly is already resolved at b.
        done = (fb == 0) | ~np.isfinite(fa)
        res = np.where(done, b, np.inf)
        fa = np.where(np.isfinite(fa), fa, 1.0)
        last = np.zeros(ridx.size, dtype=np.int8)  # which end moved last: +1 a, -1 b
        act = np.nonzero(~done)[0]
        for it in range(MAX_REFINE + 1):
            aa, bb, Fa, Fb = a[act], b[act], fa[act], fb[act]
            x = np.minimum(np.maximum(aa + Fa * ((bb - aa) / (Fa - Fb)), aa), bb)
            conv = (bb - aa) <= 4e-16 * (1.0 + np.maximum(np.abs(aa), np.abs(bb)))
            res[act] = x  # current estimate (final for converged brackets)
            act, x = act[~conv], x[~conv]
            if act.size == 0 or it == MAX_REFINE:
                break
            W, _dW = self._field(x, tuple(c[ridx[act]] for c in cand))
            if cost is not None:
                cost[ridx[act]] += 1  # ridx is unique per call
            Fx = sgn[act] * (T - W)
            hit0 = Fx == 0
            res[act[hit0]] = x[hit0]
            up = Fx > 0
            aa, bb, Fa, Fb, la = a[act], b[act], fa[act], fb[act], last[act]
            a[act] = np.where(up, x, aa)
            b[act] = np.where(up, bb, x)
            # Illinois: when the same end moves twice, halve the other end's value.
            fa[act] = np.where(up, Fx, np.where(la == -1, 0.5 * Fa, Fa))
            fb[act] = np.where(up, np.where(la == 1, 0.5 * Fb, Fb), Fx)
            last[act] = np.where(up, 1, -1)
            act = act[~hit0]
        return res

    def _solve_paper(self, o, d, tmin, tmax, cost):
        """The paper's span sampling and piecewise quadratic interpolation (3-2-3)."""
        n = o.shape[0]
        lam, ts, seg_lo, seg_hi, (cand, idx, valid, c_lo, c_hi) = self._local_segment(o, d, tmin, tmax)
        T = self.threshold
        M = self.samples
        # (i) spans: the positive centres' chords (crossed ones; others are empty), cut
        # to the ray segment.
        pos = self._pos_pad[idx]
        lo = np.maximum(np.where(pos, c_lo, np.inf), seg_lo[:, None])
        hi = np.minimum(np.where(pos, c_hi, -np.inf),
                        np.minimum(seg_hi, np.finfo(np.float64).max)[:, None])
        valid = lo < hi
        # (ii) `samples` points per chord: more centres on the span, more samples.
        f = np.linspace(0.0, 1.0, M)
        width = np.where(valid, hi - lo, 0.0)
        base = np.where(valid, lo, np.inf)
        tt = (base[:, :, None] + width[:, :, None] * f[None, None, :]).reshape(n, -1)
        tt = np.sort(tt, axis=1)
        fin = np.isfinite(tt)
        cnt = fin.sum(axis=1)
        if cost is not None:
            cost += cnt
        # Field at the finite samples only (one evaluation each).
        fv = np.full(tt.shape, np.nan)
        rr, cc = np.nonzero(fin)
        if rr.size:
            Wv, _ = self._field(tt[rr, cc], tuple(x[rr] for x in cand))
            fv[rr, cc] = Wv - T
        # (iii) quadratics W* through consecutive triples, first solution of W* = T.
        result = _first_quadratic_root(tt, fv, cnt)
        t_world = (result + ts) / lam
        ok = np.isfinite(t_world) & (t_world > tmin) & (t_world < tmax)
        return np.where(ok, t_world, np.inf)

    def surface(self, o, d, t, prim):
        o = np.asarray(o, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(d, dtype=np.float64).reshape(-1, 3)
        t = _finite_or_zero(t)
        p = o + t[:, None] * d
        o2, dn, lam, ts = self._to_local(o, d)
        x = o2 + (t * lam - ts)[:, None] * dn            # the hit, normalised object units
        if self._centre_bvh is None:
            P, w, S, k = self._p[None, :, :], self._w, self._S, self._inv3s2
        else:
            # Only the centres whose 3S sphere the ray crosses can be within 3S of a point
            # on it; the others add exact zeros to the (left-to-right) sum below.
            idx = self._candidates(o.shape[0], *self._crossed_pairs(o2, dn))[1]
            P = np.append(self._p, [[0.0, 0.0, 0.0]], axis=0)[idx]
            w, S, k = self._w_pad[idx], self._S_pad[idx], self._k_pad[idx]
        rel = x[:, None, :] - P                           # x - P_i
        r2 = dot(rel, rel)
        r = np.sqrt(r2)
        inner = r < S
        outer = (~inner) & (r < 3.0 * S)
        with np.errstate(divide="ignore", invalid="ignore"):
            g = np.where(inner, -2.0 * k, np.where(outer, ((r - 3.0 * S) / r) * k, 0.0))
        # grad W = sum w g (x - P_i), summed left to right in centre index order
        grad = np.cumsum((w * g)[:, :, None] * rel, axis=1)[:, -1, :]
        gl = np.sqrt(dot(grad, grad))
        scale = np.sum(self._lip) + 1e-300
        flat = ~(gl > 1e-12 * scale)                      # pinch point: no direction
        n_obj = -grad                                     # outward: -grad W (Decision)
        ng = normalize(matvec(self.A.T, n_obj))           # object normal -> world: A^T n
        ng = np.where(flat[:, None], -d, ng)
        return p, ng, ng.copy()


def _first_quadratic_root(tt, fv, cnt):
    """First solution of ``W* - T = 0`` of quadratics through consecutive sample triples.

    ``tt`` (n, M) sorted sample distances (``inf`` past the last), ``fv`` (n, M) the
    values ``W - T`` there, ``cnt`` (n,) the number of samples. Triples (0,1,2),
    (2,3,4), ... each cover ``[t_2j, t_2j+2]``; when the count is even the last interval
    ``[t_c-2, t_c-1]`` uses the triple (c-3, c-2, c-1); two samples give a line.
    """
    n, M = tt.shape
    best = np.full(n, np.inf)
    if M >= 3:
        x0, x1, x2 = tt[:, 0:M - 2:2], tt[:, 1:M - 1:2], tt[:, 2:M:2]
        y0, y1, y2 = fv[:, 0:M - 2:2], fv[:, 1:M - 1:2], fv[:, 2:M:2]
        ok = np.isfinite(x2)
        with np.errstate(invalid="ignore"):
            r = _quad_root(np.where(ok, x0, 0.0), np.where(ok, x1, 1.0), np.where(ok, x2, 2.0),
                           np.where(ok, y0, 1.0), np.where(ok, y1, 1.0), np.where(ok, y2, 1.0),
                           np.where(ok, x0, 0.0), np.where(ok, x2, 2.0))
        r = np.where(ok, r, np.inf)
        best = r.min(axis=1)  # segments are ordered: the smallest root is the first
    # Tail of an even count (the last interval not covered by a triple).
    tail = (cnt >= 2) & (cnt % 2 == 0) & ~np.isfinite(best)
    rows = np.nonzero(tail)[0]
    if rows.size:
        c = cnt[rows]
        line = c == 2  # two samples: (t0, t1, t1) makes the quadratic a line
        i0 = np.where(line, 0, c - 3)
        i1 = c - 2
        i2 = c - 1
        x0, x1, x2 = tt[rows, i0], tt[rows, np.where(line, 1, i1)], tt[rows, i2]
        y0, y1, y2 = fv[rows, i0], fv[rows, np.where(line, 1, i1)], fv[rows, i2]
        best[rows] = _quad_root(x0, x1, x2, y0, y1, y2, tt[rows, i1], x2)
    return best


def _quad_root(x0, x1, x2, y0, y1, y2, a, b):
    """Smallest t in [a, b] where the quadratic through (x_i, y_i) is zero (inf if none)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        d01 = np.where(x1 != x0, (y1 - y0) / (x1 - x0), 0.0)
        d12 = np.where(x2 != x1, (y2 - y1) / (x2 - x1), d01)
        c2 = np.where(x2 != x0, (d12 - d01) / (x2 - x0), 0.0)
        # Newton form around a: f(a + s) = f(a) + f'(a) s + c2 s^2.
        fa = y0 + (a - x0) * (d01 + c2 * (a - x1))
        fpa = d01 + c2 * ((a - x0) + (a - x1))
        disc = fpa * fpa - 4.0 * c2 * fa
        sq = np.sqrt(np.maximum(disc, 0.0))
        q = -0.5 * (fpa + np.copysign(sq, fpa))
        r1 = np.where(q != 0, fa / q, np.where(fa == 0, 0.0, np.inf))
        r2 = np.where(c2 != 0, q / c2, np.inf)
        lin = np.where(fpa != 0, -fa / fpa, np.where(fa == 0, 0.0, np.inf))
        quad = c2 != 0
        r1 = np.where(quad, np.where(disc >= 0, r1, np.inf), lin)
        r2 = np.where(quad & (disc >= 0), r2, np.inf)
        L = b - a
        tol = 1e-12 * np.abs(L)
        ok1 = (r1 >= -tol) & (r1 <= L + tol)
        ok2 = (r2 >= -tol) & (r2 <= L + tol)
        s = np.minimum(np.where(ok1, r1, np.inf), np.where(ok2, r2, np.inf))
        s = np.clip(s, 0.0, np.where(np.isfinite(L), L, 0.0))
        return np.where(ok1 | ok2, a + s, np.inf)
