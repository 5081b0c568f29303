"""The root finders of :class:`~links1_mitsuba.blob.BlobSpec` along a ray (eq. 3.8):
``exact``, a march whose steps never jump over a root then secant refinement, and
``paper``, the paper's span sampling with piecewise quadratic interpolation (3-2-3), the
float64 core's algorithms (links1/geometry/blob.py) in Dr.Jit float32. A mixin of
:class:`~links1_mitsuba.blob.BlobSpec`: its methods read the spec's constants and field.
"""
from __future__ import annotations

import numpy as np

from .shapes import INF

#: Largest number of secant refinements of a bracketed blob root.
MAX_REFINE = 24


class RootSolvers:
    """The root finders of :class:`~links1_mitsuba.blob.BlobSpec`."""

    def _exact(self, field_at, start, end, sgn, run, n_eval, Lb, Gb, eps, any_hit=False):
        """March with steps that never jump over a root (docs/numerics.md, step bounds); once the step
        falls below ``probe`` it probes ``max(2h, probe)`` ahead; a sign change brackets the
        root, refined by secant steps with the Illinois safeguard (as the core). A ray that
        grazes the surface never brackets a root: a miss, as in the float64 core."""
        import drjit as dr
        import mitsuba as mi
        T = self._threshold()
        probe = self._probe()
        Lb = dr.maximum(Lb, 1e-30)
        Gb = dr.maximum(Gb, 1e-30)
        max_steps = self.max_steps
        n = dr.width(start)
        s = mi.Float(start)
        s_prev = mi.Float(start)
        f_prev = dr.full(mi.Float, 1.0, n)
        found = dr.zeros(mi.Bool, n)
        it = dr.zeros(mi.UInt32, n)

        def cond(s, s_prev, f_prev, found, run, it, n_eval):
            return run

        def body(s, s_prev, f_prev, found, run, it, n_eval):
            W, dW = field_at(s)
            n_eval += dr.select(run, mi.UInt32(1), 0)
            F = sgn * (T - W)
            Fp = -sgn * dW
            root = run & (F <= 0) & (it > 0)
            found = found | root
            Fpos = dr.maximum(F, 0.0)
            disc = dr.safe_sqrt(dr.square(Fp) + 2.0 * Gb * Fpos)
            h2 = dr.select(Fp < 0, 2.0 * Fpos / dr.maximum(disc - Fp, 1e-30), (Fp + disc) / Gb)
            h = dr.maximum(Fpos / Lb, h2)
            step = dr.select(h < probe, dr.maximum(2.0 * h, probe), h)
            it += 1
            go = run & ~root
            s_prev = dr.select(go, s, s_prev)
            f_prev = dr.select(go, F, f_prev)
            s = dr.select(go, s + step, s)
            run = go & (s < end) & (it < max_steps)
            return s, s_prev, f_prev, found, run, it, n_eval

        s, s_prev, f_prev, found, run, it, n_eval = dr.while_loop(
            (s, s_prev, f_prev, found, run, it, n_eval), cond, body)
        if any_hit:
            return dr.select(found, s, INF), n_eval
        # bracket [a, b] with F(a) > 0 >= F(b): secant steps with the Illinois safeguard
        a, b = mi.Float(s_prev), mi.Float(s)
        fa = f_prev
        Wb, _ = field_at(b)
        fb = sgn * (T - Wb)
        last = dr.zeros(mi.Int32, n)
        k = dr.zeros(mi.UInt32, n)
        act = found & (fb != 0) & (a < b)

        def cond2(a, b, fa, fb, last, k, act, n_eval):
            return act

        def body2(a, b, fa, fb, last, k, act, n_eval):
            x = dr.clip(a + fa * ((b - a) / (fa - fb)), a, b)
            W, _ = field_at(x)
            n_eval += dr.select(act, mi.UInt32(1), 0)
            fx = sgn * (T - W)
            up = fx > 0
            na = dr.select(up, x, a)
            nb = dr.select(up, b, x)
            nfa = dr.select(up, fx, dr.select(last == -1, 0.5 * fa, fa))
            nfb = dr.select(up, dr.select(last == 1, 0.5 * fb, fb), fx)
            a = dr.select(act, na, a)
            b = dr.select(act, nb, b)
            fa = dr.select(act, nfa, fa)
            fb = dr.select(act, nfb, fb)
            last = dr.select(act, dr.select(up, 1, -1), last)
            k += 1
            act = act & (fx != 0) & (b - a > 2e-7 * (1.0 + dr.abs(b))) & (k < MAX_REFINE)
            return a, b, fa, fb, last, k, act, n_eval

        a, b, fa, fb, last, k, act, n_eval = dr.while_loop(
            (a, b, fa, fb, last, k, act, n_eval), cond2, body2)
        # final estimate: secant on the bracket (b itself when F(b) == 0)
        x = dr.select(fb == 0, b, dr.clip(a + fa * ((b - a) / dr.select(fa != fb, fa - fb, 1.0)), a, b))
        return dr.select(found, x, INF), n_eval

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
            W, _ = self._field(per, t)
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
