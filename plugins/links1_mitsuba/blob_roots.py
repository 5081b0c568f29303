"""The root finders of :class:`~links1_mitsuba.blob.BlobSpec` along a ray (eq. 3.8):
``exact``, a march whose steps never jump over a root then Newton / secant refinement, and
``paper``, the paper's span sampling with piecewise quadratic interpolation (3-2-3), the
float64 core's algorithms (links1/geometry/blob.py) in Dr.Jit float32. A mixin of
:class:`~links1_mitsuba.blob.BlobSpec`: its methods read the spec's constants and field.
"""
from __future__ import annotations

import numpy as np

from .shapes import INF

#: Largest number of refinements (Newton or secant steps) of a bracketed blob root.
MAX_REFINE = 24
#: The refinement's target, relative to float32 resolution of the distance (``2e-7 (1 + |s|)``):
#: Newton's point is taken once its error bound ``G h²/|F'|`` is below this share of it.
NEWTON_TOL = 1.0 / 16.0


class RootSolvers:
    """The root finders of :class:`~links1_mitsuba.blob.BlobSpec`."""

    def _exact(self, field_at, start, end, sgn, run, W0, dW0, B0, n_eval, Lb, Gb, any_hit=False):
        """The first root of ``F = sgn (T - W) = 0`` in ``[start, end)`` (eq. 3.8), ``W0``,
        ``dW0`` the field at ``start`` and ``B0`` a bound of ``W`` from there on; ``Lb``, ``Gb``
        bound ``|F'|``, ``|F''|`` along the ray (docs/numerics.md, step bounds). From outside
        (``sgn = 1``) the march ends, a miss, where the bound ``B`` of ``W`` from the point on
        (``field_at``'s third value) is below ``T``. One loop, a march (:func:`_march_step`) and then a
        bracket ``[a, b]``, ``F(a) > 0 >= F(b)``, refined by Newton steps from the last point
        where they stay inside, else the bracket's secant; done when Newton's point is within
        :data:`NEWTON_TOL` of float32 resolution (its error ``~ G h²/|F'|``; from the march,
        where a root is certain, ``hu - h2``) or the bracket within float32 resolution (its
        secant point), or after :data:`MAX_REFINE` refinements. ``any_hit``:
        :meth:`_any_root`. A ray that grazes the surface never brackets a root: a miss, as in
        the float64 core. Returns ``(t, n_eval)`` (object units; ``inf``: no root)."""
        import drjit as dr
        import mitsuba as mi
        T = self._threshold()
        probe = self._probe()
        Lb = dr.maximum(Lb, 1e-30)
        Gb = dr.maximum(Gb, 1e-30)
        F = sgn * (T - W0)
        Fp = -sgn * dW0
        run = run & ~_clear(sgn, B0, T)
        if any_hit:
            return self._any_root(field_at, start, end, sgn, run, F, Fp, n_eval, Lb, Gb)
        max_steps = self.max_steps
        n = dr.width(start)
        s = mi.Float(start)
        a, fa = mi.Float(s), mi.Float(F)
        b, fb = dr.full(mi.Float, INF, n), dr.zeros(mi.Float, n)
        brk = dr.zeros(mi.Bool, n)
        t = dr.full(mi.Float, INF, n)
        it = dr.full(mi.UInt32, 1, n)       # march evaluations (the one at start)
        k = dr.zeros(mi.UInt32, n)          # refinements

        def cond(s, F, Fp, a, fa, b, fb, brk, t, run, it, k, n_eval):
            return run

        def body(s, F, Fp, a, fa, b, fb, brk, t, run, it, k, n_eval):
            tol = 2e-7 * (1.0 + dr.abs(s))
            dN = -F / dr.select(Fp != 0, Fp, 1.0)            # Newton's step
            xN = s + dN
            # march: stops at a certain root within float32 resolution (Newton's point)
            safe, step, sure, h2, hu = _march_step(F, Fp, Lb, Gb, probe)
            near = ~brk & sure & (hu - h2 <= tol * NEWTON_TOL)
            t = dr.select(run & near & (xN < end), dr.clip(xN, s + h2, s + hu), t)
            miss = ~brk & ((s + safe >= end) | (it >= max_steps))
            # bracket: Newton inside it, else its secant
            sec = dr.clip(a + fa * ((b - a) / dr.select(fa != fb, fa - fb, 1.0)), a, b)
            inside = (Fp != 0) & (xN > a) & (xN < b)
            small = (Fp != 0) & (Gb * dr.square(dN) <= tol * NEWTON_TOL * dr.abs(Fp))
            narrow = (b - a <= tol) | (k >= MAX_REFINE)
            t = dr.select(run & brk & (small | narrow), dr.select(small, dr.clip(xN, a, b), sec), t)
            go = run & ~dr.select(brk, small | narrow, near | miss)
            x = dr.select(brk, dr.select(inside, xN, sec), dr.minimum(s + step, end))
            W, dW, B = field_at(x)
            n_eval += dr.select(go, mi.UInt32(1), 0)
            Fx = sgn * (T - W)
            pos = Fx > 0
            go_on = ~(pos & ~brk & _clear(sgn, B, T))     # no root from x on: a miss
            it += dr.select(go & ~brk, mi.UInt32(1), 0)
            k += dr.select(go & brk, mi.UInt32(1), 0)
            a = dr.select(go & pos, x, a)
            fa = dr.select(go & pos, Fx, fa)
            b = dr.select(go & ~pos, x, b)
            fb = dr.select(go & ~pos, Fx, fb)
            brk = brk | (go & ~pos)
            zero = go & (Fx == 0)
            t = dr.select(zero, x, t)
            s = dr.select(go, x, s)
            F = dr.select(go, Fx, F)
            Fp = dr.select(go, -sgn * dW, Fp)
            run = go & ~zero & go_on
            return s, F, Fp, a, fa, b, fb, brk, t, run, it, k, n_eval

        out = dr.while_loop((s, F, Fp, a, fa, b, fb, brk, t, run, it, k, n_eval), cond, body)
        return out[8], out[12]

    def _any_root(self, field_at, start, end, sgn, run, F, Fp, n_eval, Lb, Gb):
        """Whether ``F`` (at ``start``: ``F``, ``Fp``) has a root in ``[start, end)``, for a
        shadow ray: the march of :meth:`_exact`, stopped at the first point with ``F <= 0``
        or past a certain root (:func:`_march_step`'s ``s + hu``), either a point past the
        root inside the interval (its exact place is not sought), or, a miss, where the bound
        of ``W`` from the point on is below ``T`` (from outside). ``(t, n_eval)``."""
        import drjit as dr
        import mitsuba as mi
        T = self._threshold()
        probe = self._probe()
        max_steps = self.max_steps
        s = mi.Float(start)
        t = dr.full(mi.Float, INF, dr.width(start))
        it = dr.full(mi.UInt32, 1, dr.width(start))

        def cond(s, F, Fp, t, run, it, n_eval):
            return run

        def body(s, F, Fp, t, run, it, n_eval):
            safe, step, sure, _, hu = _march_step(F, Fp, Lb, Gb, probe)
            past = sure & (s + hu < end)
            t = dr.select(run & past, s + hu, t)
            go = run & ~past & (s + safe < end) & (it < max_steps)
            x = dr.minimum(s + step, end)
            W, dW, B = field_at(x)
            n_eval += dr.select(go, mi.UInt32(1), 0)
            it += 1
            F = dr.select(go, sgn * (T - W), F)
            Fp = dr.select(go, -sgn * dW, Fp)
            root = go & (F <= 0)
            t = dr.select(root, x, t)
            s = dr.select(go, x, s)
            run = go & ~root & ~_clear(sgn, B, T)
            return s, F, Fp, t, run, it, n_eval

        out = dr.while_loop((s, F, Fp, t, run, it, n_eval), cond, body)
        return out[3], out[6]

    def _paper(self, per, s_lo, s_hi, run):
        """The paper's span sampling and piecewise quadratic interpolation (3-2-3), the
        float64 core's algorithm (links1/geometry/blob.py ``_solve_paper``) in float32.

        Every positive centre's chord (cut to the ray segment) gets ``samples`` evenly spaced
        points (``linspace(0, 1, samples)``); the samples of all chords, in increasing order
        (a k-way merge of the chords' already sorted samples), are taken in triples (0,1,2),
        (2,3,4), ...; the quadratic through each (divided differences, Newton form) gives the
        first root of ``W* = T`` on ``[t_2j, t_2j+2]``. With an even count and no root yet,
        the last interval uses the triple (c-3, c-2, c-1); two samples give a line. One
        field evaluation per sample (the core's count)."""
        import drjit as dr
        import mitsuba as mi
        T = self._threshold()
        M = int(self.samples)
        step = float(np.linspace(0.0, 1.0, M)[1]) if M > 1 else 0.0
        n = dr.width(s_lo)
        hi_cap = dr.minimum(s_hi, float(np.finfo(np.float32).max))
        bases, widths, nxs, js = [], [], [], []
        cnt = dr.zeros(mi.UInt32, n)
        for i, (tau, h2, w, S, *_) in enumerate(per):
            if not self.centers[i, 3] > 0:   # the sign of a weight is structure (a literal)
                continue
            R2 = self._value(12 * i + 5)      # 9S² (_consts)
            half = dr.sqrt(dr.maximum(R2 - h2, 0.0))
            cross = h2 < R2
            lo = dr.maximum(dr.select(cross, tau - half, INF), s_lo)
            hi = dr.minimum(dr.select(cross, tau + half, -INF), hi_cap)
            valid = run & (lo < hi)
            base = dr.select(valid, lo, INF)
            width = dr.select(valid, hi - lo, 0.0)
            bases.append(base)
            widths.append(width)
            nxs.append(mi.Float(base))                       # next sample of this chord
            js.append(dr.zeros(mi.UInt32, n))                # its index in 0..M-1
            cnt += dr.select(valid, mi.UInt32(M), 0)
        if not bases:
            return dr.full(mi.Float, INF, n), dr.zeros(mi.UInt32, n)

        i = dr.zeros(mi.UInt32, n)
        x0, x1, x2 = dr.zeros(mi.Float, n), dr.zeros(mi.Float, n), dr.zeros(mi.Float, n)
        y0, y1, y2 = dr.zeros(mi.Float, n), dr.zeros(mi.Float, n), dr.zeros(mi.Float, n)
        best = dr.full(mi.Float, INF, n)
        active = cnt > 0

        def cond(i, nxs, js, x0, x1, x2, y0, y1, y2, best, active):
            return active

        def body(i, nxs, js, x0, x1, x2, y0, y1, y2, best, active):
            # the smallest pending sample (k-way merge of the chords' sorted samples)
            t = nxs[0]
            for nx in nxs[1:]:
                t = dr.minimum(t, nx)
            taken = dr.zeros(mi.Bool, dr.width(t))
            nxs, js = list(nxs), list(js)
            for k in range(len(nxs)):
                pick = active & ~taken & (nxs[k] == t)
                taken = taken | pick
                j = js[k] + 1
                f = dr.select(j >= M - 1, 1.0, mi.Float(j) * step)
                nx = dr.select(j < M, bases[k] + widths[k] * f, INF)
                nxs[k] = dr.select(pick, nx, nxs[k])
                js[k] = dr.select(pick, j, js[k])
            W = self._field(per, t)[0]
            y = W - T
            # sliding window of the last three samples
            x0, x1, x2 = x1, x2, mi.Float(t)
            y0, y1, y2 = y1, y2, y
            tri = active & (i >= 2) & ((i & 1) == 0) & (best == INF)
            r = _quad_root32(x0, x1, x2, y0, y1, y2, x0, x2)
            best = dr.select(tri, r, best)
            i = i + dr.select(active, mi.UInt32(1), 0)
            active = active & (i < cnt)
            return i, nxs, js, x0, x1, x2, y0, y1, y2, best, active

        i, nxs, js, x0, x1, x2, y0, y1, y2, best, active = dr.while_loop(
            (i, nxs, js, x0, x1, x2, y0, y1, y2, best, active), cond, body)
        # tail of an even count: the last interval [t_c-2, t_c-1] (two samples: a line)
        tail = (cnt >= 2) & ((cnt & 1) == 0) & (best == INF)
        line = cnt == 2
        # (c-3, c-2, c-1) on [t_c-2, t_c-1]; two samples: (t0, t1, t1) on [t0, t1]
        tx0, tx1 = dr.select(line, x1, x0), dr.select(line, x2, x1)
        ty0, ty1 = dr.select(line, y1, y0), dr.select(line, y2, y1)
        r = _quad_root32(tx0, tx1, x2, ty0, ty1, y2, x1, x2)
        best = dr.select(tail, r, best)
        ok = dr.isfinite(best) & (best > s_lo) & (best < s_hi)
        return dr.select(ok, best, INF), cnt


def _quad_root32(x0, x1, x2, y0, y1, y2, a, b):
    """Smallest t in [a, b] where the quadratic through (x_i, y_i) is zero (inf if none):
    links1/geometry/blob.py ``_quad_root``, the same arithmetic in Dr.Jit float32."""
    import drjit as dr
    d01 = dr.select(x1 != x0, (y1 - y0) / dr.select(x1 != x0, x1 - x0, 1.0), 0.0)
    d12 = dr.select(x2 != x1, (y2 - y1) / dr.select(x2 != x1, x2 - x1, 1.0), d01)
    c2 = dr.select(x2 != x0, (d12 - d01) / dr.select(x2 != x0, x2 - x0, 1.0), 0.0)
    # Newton form around a: f(a + s) = f(a) + f'(a) s + c2 s^2.
    fa = y0 + (a - x0) * (d01 + c2 * (a - x1))
    fpa = d01 + c2 * ((a - x0) + (a - x1))
    disc = fpa * fpa - 4.0 * c2 * fa
    sq = dr.sqrt(dr.maximum(disc, 0.0))
    q = -0.5 * (fpa + dr.copysign(sq, fpa))
    r1 = dr.select(q != 0, fa / dr.select(q != 0, q, 1.0), dr.select(fa == 0, 0.0, INF))
    r2 = dr.select(c2 != 0, q / dr.select(c2 != 0, c2, 1.0), INF)
    lin = dr.select(fpa != 0, -fa / dr.select(fpa != 0, fpa, 1.0), dr.select(fa == 0, 0.0, INF))
    quad = c2 != 0
    r1 = dr.select(quad, dr.select(disc >= 0, r1, INF), lin)
    r2 = dr.select(quad & (disc >= 0), r2, INF)
    L = b - a
    tol = 1e-12 * dr.abs(L)
    ok1 = (r1 >= -tol) & (r1 <= L + tol)
    ok2 = (r2 >= -tol) & (r2 <= L + tol)
    s = dr.minimum(dr.select(ok1, r1, INF), dr.select(ok2, r2, INF))
    s = dr.clip(s, 0.0, dr.select(dr.isfinite(L), L, 0.0))
    return dr.select(ok1 | ok2, a + s, INF)


def _march_step(F, Fp, Lb, Gb, probe):
    """The march's step from a point with ``F > 0``, ``F' = Fp``, given bounds ``Lb`` of
    ``|F'|`` and ``Gb`` of ``|F''|`` (docs/numerics.md, step bounds): ``(safe, step, sure, h2,
    hu)``. ``safe = max(F/L, h2)``, ``h2`` the first zero of ``F + F'h - Gh²/2``, never passes
    the first root (once below ``probe``: ``max(2h, probe)``, a probe ahead). ``step``: where
    ``F' < 0``, on to Newton's step ``-F/F'`` as far as ``-F'/G``, where ``F`` still decreases:
    a point there with ``F > 0`` has no root before it, one with ``F <= 0`` brackets a single
    root. ``sure``: ``F' < 0`` and ``F'² >= 2GF``, a root certain in ``[s + h2, s + hu]``,
    ``hu`` the first zero of ``F + F'h + Gh²/2``."""
    import drjit as dr
    down = Fp < 0
    Fpos = dr.maximum(F, 0.0)
    disc = dr.safe_sqrt(dr.square(Fp) + 2.0 * Gb * Fpos)
    h2 = dr.select(down, 2.0 * Fpos / dr.maximum(disc - Fp, 1e-30), (Fp + disc) / Gb)
    h = dr.maximum(Fpos / Lb, h2)
    safe = dr.select(h < probe, dr.maximum(2.0 * h, probe), h)
    step = dr.select(down, dr.maximum(safe, dr.minimum(Fpos / dr.maximum(-Fp, 1e-30), -Fp / Gb)), safe)
    du = dr.square(Fp) - 2.0 * Gb * Fpos
    sure = down & (F > 0) & (du >= 0)
    hu = 2.0 * Fpos / dr.maximum(dr.safe_sqrt(du) - Fp, 1e-30)
    return safe, step, sure, h2, hu


def _clear(sgn, B, T):
    """No root from the point on, seen from outside (``sgn = 1``): the bound ``B`` of ``W``
    there and beyond (:meth:`BlobSpec._term`) is below ``T``, by more than float32 rounding of
    its sum."""
    return (sgn > 0) & (B * (1.0 + 1e-5) < T)
