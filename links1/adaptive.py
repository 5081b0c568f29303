"""Adaptive anti-aliasing on a global lattice of sub-pixel points (POV-Ray's ``+AM2`` idea,
made deterministic and partition-independent).

The lattice
    With depth ``D`` the film of ``W x H`` pixels carries the lattice points
    ``(i, j)``, ``0 <= i <= W * 2**D``, ``0 <= j <= H * 2**D``, at film position
    ``(i / 2**D, j / 2**D)`` pixels (exact in float64). A point's value depends on ``(i, j)``
    only (its key is ``j * (W * 2**D + 1) + i``), so a point on the edge of a pixel, a
    window or a partition unit has the same value in every unit that samples it.

The refinement
    Every pixel starts as one square whose four corners are lattice points (shared with its
    neighbours). A square of side ``s`` lattice steps is split into four of side ``s / 2``
    (five new points: edge midpoints and centre) when its corner values differ by more than
    ``threshold`` in the colour metric below, until the side is one step (pixel depth ``D``:
    a ``(2**D + 1)²`` lattice over the pixel). The decision depends on the square's own
    corners only, so it is the same whatever window or unit renders the pixel.

Colour metric
    ``max over channels of (max - min over the 4 corners)`` of the tone-mapped value
    ``v / (1 + v)`` (Reinhard; maps radiance in [0, inf) to [0, 1), so the threshold is a
    fraction of display range and bright HDR values do not refine everything). POV-Ray's
    ``+A0.3`` corresponds to ``threshold=0.3`` here on LDR images.

Reconstruction
    With a box filter a pixel's value is the sum over its leaf squares of ``area * mean of its
    4 corners`` (the box integral of the corner average; areas are powers of two, so the sum
    is exact up to the additions, done in one fixed order per pixel). With any other of the
    film's filters (:mod:`links1.filters`) each leaf carries the bilinear interpolant of its
    corners and a pixel is the filter-weighted integral of that interpolant over the leaves
    in the filter's reach, divided by the filter's integral over them (:class:`FilteredLeaves`):
    what Mitsuba's film estimates from random samples, computed on the adaptive
    reconstruction. A unit then also refines a border of pixels around itself, as uniform
    renders trace a border of samples.
"""
from __future__ import annotations

import numpy as np

from .aovs import AOVS
from .errors import UsageError
from .sampling import lattice_keys

#: Largest supported depth (a (2**8+1)² lattice per pixel; keys stay well inside int64).
MAX_DEPTH = 8
#: Default refinement depth (a pixel holds up to (2**D + 1)² points).
DEFAULT_ADAPTIVE_DEPTH = 2


def check_options(threshold, depth) -> tuple[float, int]:
    """Validated ``(threshold, depth)``: threshold >= 0 and finite, 0 <= depth <= MAX_DEPTH."""
    try:
        t, d = float(threshold), int(depth)
    except (TypeError, ValueError):
        raise UsageError(f"adaptive threshold/depth must be numbers, got {threshold!r}, {depth!r}") from None
    if not np.isfinite(t) or t < 0:
        raise UsageError(f"adaptive threshold must be a finite number >= 0, got {threshold!r}")
    if not 0 <= d <= MAX_DEPTH:
        raise UsageError(f"adaptive depth must be in 0..{MAX_DEPTH}, got {depth!r}")
    return t, d


def tonemap(v: np.ndarray) -> np.ndarray:
    """The metric's tone map ``v / (1 + v)`` (negative values clamp to 0)."""
    v = np.maximum(v, 0.0)
    return v / (1.0 + v)


def spread(t: np.ndarray) -> np.ndarray:
    """``t`` (4, ..., C): tone-mapped corner values -> the metric: max over channels of
    (max - min over the 4 corners)."""
    return np.max(np.maximum(np.maximum(t[0], t[1]), np.maximum(t[2], t[3]))
                  - np.minimum(np.minimum(t[0], t[1]), np.minimum(t[2], t[3])), axis=-1)


def _unique_sorted(a: np.ndarray):
    """``(unique values of a 1-D integer array, sorted; index of each element's value in them)``
    by one stable sort (numpy 2's hash-based ``np.unique`` is several times slower on the
    millions of lattice keys of a large film)."""
    order = np.argsort(a, kind="stable")
    srt = a[order]
    first = np.ones(a.size, dtype=bool)
    np.not_equal(srt[1:], srt[:-1], out=first[1:])
    inv = np.empty(a.size, dtype=np.int64)
    inv[order] = np.cumsum(first) - 1
    return srt[first], inv


class _Refinement:
    """The refinement of the pixels of ``window`` (module doc).

    Points: every lattice point traced so far, in one table (``PV (N, C)`` values, ``PT (N,
    C')`` tone-mapped colour, ``PK (N,)`` keys); a square is the table rows of its 4 corners.
    Level 0 is the grid of the pixels' corners, rows ``0 .. (h+1)(w+1) - 1`` row by row (= key
    order); ``split0 (h, w)``: the pixels refined. :meth:`levels` yields the deeper levels,
    ``(pid, sx, sy, s, ci, leaf)`` each: the squares of that level (pixel index in the window,
    row by row; top-left lattice point; side ``s`` lattice steps), the rows ``ci (4, n)`` of
    their corners ``(sx, sy), (sx+s, sy), (sx, sy+s), (sx+s, sy+s)`` and which are leaves. A
    pixel's squares keep one order whatever the window (squares are compacted and split in
    array order), so sums over them are window-independent.

    Every lattice point is traced once: a split square's five new points (edge midpoints and
    centre: odd multiples of half its side, so no earlier level has them) are shared only with
    squares of the same level, and each level evaluates its distinct new points, in key order.
    A child square's corner rows come from its parent and the level's new points: no lookup by
    key, and only row indices are copied from level to level."""

    def __init__(self, sample, film_size, depth, window, threshold, summed):
        x0, y0, w, h = window
        self.sample, self.threshold, self.summed = sample, threshold, summed
        self.S = S = 1 << depth
        self.stride = np.int64(film_size[0] * S + 1)
        self.window = window
        gj, gi = np.divmod(np.arange((h + 1) * (w + 1), dtype=np.int64), w + 1)
        gi, gj = (gi + x0) * S, (gj + y0) * S
        self.PK = gj * self.stride + gi
        self.PV, self.PT = self._evaluate(gi, gj, self.PK)
        self.V = self.PV.reshape(h + 1, w + 1, -1)
        self.split0 = spread(self.quad(self.PT.reshape(h + 1, w + 1, -1))) > threshold if S > 1 \
            else np.zeros((h, w), dtype=bool)

    def _evaluate(self, i, j, keys):
        vals = np.asarray(self.sample(i, j, self.S, keys), dtype=np.float64)
        # the summed channels (counts, not colour) take no part in the decision
        return vals, tonemap(vals[:, :vals.shape[1] - self.summed])

    @staticmethod
    def quad(g):
        """The 4 corner views ``(4, h, w, ...)`` of a grid ``(h+1, w+1, ...)`` (no copy)."""
        return (g[:-1, :-1], g[:-1, 1:], g[1:, :-1], g[1:, 1:])

    def leaves0(self):
        """The level-0 leaves: ``(pid, sx, sy, s, v (4, n, C))``."""
        x0, y0, w, h = self.window
        leaf = ~self.split0
        pid = np.flatnonzero(leaf)
        pys, pxs = np.divmod(pid, w)
        v = np.stack([q[leaf] for q in self.quad(self.V)])
        return pid, (pxs + x0) * self.S, (pys + y0) * self.S, self.S, v

    def levels(self):
        x0, y0, w, h = self.window
        S, stride = self.S, self.stride
        pid = np.flatnonzero(self.split0)
        pys, pxs = np.divmod(pid, w)
        sx, sy = (pxs + x0) * S, (pys + y0) * S
        rows = np.arange((h + 1) * (w + 1), dtype=np.int64).reshape(h + 1, w + 1)
        ci = np.stack([q[self.split0] for q in self.quad(rows)])
        self.new_points = []
        s = S
        while len(pid):
            h2 = s // 2
            # the new points: top, left, centre, right and bottom midpoints of each square
            ni = np.concatenate([sx + h2, sx, sx + h2, sx + s, sx + h2])
            nj = np.concatenate([sy, sy + h2, sy + h2, sy + h2, sy + s])
            uk, inv = _unique_sorted(nj * stride + ni)
            uj, ui = np.divmod(uk, stride)
            U, UT = self._evaluate(ui, uj, uk)
            self.new_points.append((np.tile(pid, 5), inv + len(self.PK)))
            top, left, cen, right, bot = (inv + len(self.PK)).reshape(5, len(sx))
            self.PK = np.concatenate([self.PK, uk])
            self.PV = np.concatenate([self.PV, U])
            self.PT = np.concatenate([self.PT, UT])
            c0, c1, c2, c3 = ci
            # the corners of the 4 children: top-left, top-right, bottom-left, bottom-right
            ci = np.stack([np.concatenate(c) for c in ((c0, top, left, cen), (top, c1, cen, right),
                                                       (left, cen, c2, bot), (cen, right, bot, c3))])
            sx = np.concatenate([sx, sx + h2, sx, sx + h2])
            sy = np.concatenate([sy, sy, sy + h2, sy + h2])
            pid = np.tile(pid, 4)
            s = h2
            split = spread(self.PT[ci]) > self.threshold if s > 1 else np.zeros(len(pid), dtype=bool)
            yield pid, sx, sy, s, ci, ~split
            sx, sy, pid, ci = sx[split], sy[split], pid[split], ci[:, split]


def render_adaptive(sample, window, film_size, threshold, depth, summed=0, rfilter=None):
    """Adaptive render of ``window = (x0, y0, w, h)`` of a film of ``film_size = (W, H)`` pixels.

    ``sample(i, j, step, keys)`` -> (n, C) values of the lattice points ``(i, j)`` (int64
    arrays; film position ``(i / step, j / step)`` pixels, row 0 at the top; ``keys`` their
    global keys) must depend on ``(i, j)`` only.

    ``rfilter``: the film's reconstruction filter (:class:`links1.filters.Filter`; default and
    ``box``: each pixel's box integral). Another filter also refines the pixels of a border of
    :attr:`~links1.filters.Filter.border` pixels around the window (their decisions depend on
    their own corners only, so they are those of the neighbouring units) and reconstructs each
    pixel from the leaves under its filter (:class:`FilteredLeaves`).

    Returns ``(values (h, w, C), samples (h, w) int64)``: the pixel values (module doc) and
    the number of distinct lattice points each pixel's leaf squares use. With ``summed = k``
    the last ``k`` channels of ``sample`` (e.g. a ray count) are not reconstructed but summed
    over those distinct points: ``(values (h, w, C - k), samples, sums (h, w, k))``.
    """
    threshold, depth = check_options(threshold, depth)
    x0, y0, w, h = (int(v) for v in window)
    S = 1 << depth
    box = rfilter is None or rfilter.is_box
    if box:
        sw = (x0, y0, w, h)
    else:   # the window and the border of pixels whose leaves reach it (clipped to the film)
        b = rfilter.border
        sx0, sy0 = max(0, x0 - b), max(0, y0 - b)
        sw = (sx0, sy0, min(film_size[0], x0 + w + b) - sx0, min(film_size[1], y0 + h + b) - sy0)
        filtered = FilteredLeaves(rfilter, depth, sw)
    n = sw[2] * sw[3]
    ref = _Refinement(sample, film_size, depth, sw, threshold, summed)
    C = ref.V.shape[-1] - summed
    if box:   # level 0: a leaf pixel is its corner mean (0.25 * area 1, as below)
        V0, V1, V2, V3 = (q[..., :C] for q in ref.quad(ref.V))
        acc = np.where(ref.split0[..., None], 0.0, (V0 + V1 + V2 + V3) * 0.25).reshape(n, C)
    else:
        pid, sx, sy, s, v = ref.leaves0()
        filtered.add(pid, sx, sy, s, v[..., :C])
    # refined pixels are accumulated in a compact index (cid) and scattered back at the end
    refined = ref.split0.ravel()
    cid_of = np.cumsum(refined) - 1
    m = int(refined.sum())
    acc_r = np.zeros((m, C))
    for pid, sx, sy, s, ci, leaf in ref.levels():
        pid, cl = pid[leaf], ci[:, leaf]
        v = ref.PV[cl]   # (4, leaves, C + summed)
        if box:
            area = (s / S) ** 2  # a power of two: exact
            contrib = (v[0, :, :C] + v[1, :, :C] + v[2, :, :C] + v[3, :, :C]) * (0.25 * area)
            cid = cid_of[pid]
            for c in range(C):   # per level: the pixel's leaves summed in array order
                acc_r[:, c] += np.bincount(cid, weights=contrib[:, c], minlength=m)
        else:
            filtered.add(pid, sx[leaf], sy[leaf], s, v[..., :C])
    if box:
        acc[refined] = acc_r
    values = acc if box else filtered.result()
    # the distinct lattice points a pixel's leaves use: its 4 corners, then per level the
    # distinct points its splits created (summed channels: counts, added in that order)
    samples = np.full(n, 4, dtype=np.int64)
    if summed:
        Q = [q[..., C:] for q in ref.quad(ref.V)]
        sums = (((Q[0] + Q[1]) + Q[2]) + Q[3]).reshape(n, summed)
    samples_r, sums_r = samples[refined], sums[refined] if summed else None
    for pid, row in ref.new_points:
        pairs, _ = _unique_sorted(cid_of[pid] * np.int64(len(ref.PK)) + row)
        p, r = np.divmod(pairs, np.int64(len(ref.PK)))
        samples_r += np.bincount(p, minlength=m)
        for c in range(summed):
            sums_r[:, c] += np.bincount(p, weights=ref.PV[r, C + c], minlength=m)
    samples[refined] = samples_r
    if summed:
        sums[refined] = sums_r
    out = [values, samples] + ([sums] if summed else [])
    # the window's own pixels of the sample window
    ox, oy = x0 - sw[0], y0 - sw[1]
    out = [a.reshape(sw[3], sw[2], -1)[oy:oy + h, ox:ox + w] for a in out]
    out[1] = out[1][..., 0]
    return tuple(out)


#: Gauss-Legendre nodes per piece of a leaf's side in :func:`_leaf_weights_1d`: exact for the
#: polynomial filters (box, tent of radius 1, mitchell, catmullrom) on the pieces between their
#: knots, and within 1e-12 of the Gaussian's and Lanczos' integrals.
GAUSS_NODES = 12


def _leaf_weights_1d(rfilter, depth):
    """``(depth + 1, (2 b + 1) S, 2)``: the 1-D filter integrals of the two corner hats of a leaf
    side, ``[d, k + b S]`` for the side of ``S >> d`` lattice steps starting ``k`` steps from the
    left (top) edge of the pixel whose filter it is (``S = 2**depth``, ``b`` the filter border):
    ``∫ f(x - 1/2) (1 - u) dx`` and ``∫ f(x - 1/2) u dx`` over the side (x in pixels from the
    pixel's edge, ``u`` the fraction along the side). Sides are split at the half-pixel lines,
    where the Mitsuba filters have their knots, and each piece is integrated with
    :data:`GAUSS_NODES` Gauss-Legendre nodes."""
    S, b = 1 << depth, rfilter.border
    gx, gw = np.polynomial.legendre.leggauss(GAUSS_NODES)
    k = np.arange(-b * S, (b + 1) * S, dtype=np.float64)
    table = np.zeros((depth + 1, len(k), 2))
    for d in range(depth + 1):
        s = float(S >> d)
        a0, a1 = k / S, (k + s) / S            # the side, in pixels from the pixel's edge
        # a whole-pixel side straddles the pixel's half line (smaller sides end on it)
        cuts = [a0, a0 + 0.5, a1] if s == S else [a0, a1]
        for lo, hi in zip(cuts[:-1], cuts[1:]):
            half = 0.5 * (hi - lo)
            x = (lo + hi)[:, None] * 0.5 + half[:, None] * gx[None, :]       # (nk, nodes)
            fx = rfilter.eval(x - 0.5) * (half[:, None] * gw[None, :])
            u = (x - a0[:, None]) / (a1 - a0)[:, None]
            table[d, :, 0] += (fx * (1.0 - u)).sum(axis=1)
            table[d, :, 1] += (fx * u).sum(axis=1)
    return table


class FilteredLeaves:
    """Pixels of a sample window reconstructed from adaptive leaves under a filter ``f``.

    A leaf square carries the bilinear interpolant of its four corner values; pixel ``q``'s
    value is ``Σ ∫∫ f(x - c_q) f(y - c_q) L_bilinear / Σ ∫∫ f f`` over the leaves within the
    filter's reach (``c_q`` the pixel centre), the integral Mitsuba's film estimates from
    samples (:mod:`links1.filters`), here evaluated on the adaptive reconstruction: the leaves
    tile the film, so the denominator is the filter's integral over the film around ``q``.
    The filter is separable and the interpolant bilinear, so a leaf's weights are products of
    the 1-D integrals of :func:`_leaf_weights_1d`. For a box filter this is the box integral of
    the corner means (the default path of :func:`render_adaptive`).

    Determinism: ``q`` receives, per level and per offset ``(dx, dy)`` (both in one fixed
    order), the leaves of the single pixel ``q - (dx, dy)`` in that pixel's own leaf order, so
    a pixel's value is the same bits in every window that contains it.
    """

    def __init__(self, rfilter, depth, sample_window):
        self.b, self.S = rfilter.border, 1 << depth
        self.table = _leaf_weights_1d(rfilter, depth)
        self.sw = sample_window
        self.num = None
        self.den = np.zeros(sample_window[2] * sample_window[3])

    def add(self, pid, sx, sy, s, v):
        """The leaves of one level: pixel index in the sample window ``pid``, top-left lattice
        point ``(sx, sy)``, side ``s`` steps, corner values ``v (4, n, C)``."""
        X0, Y0, sw, sh = self.sw
        S, b = self.S, self.b
        if self.num is None:
            self.num = np.zeros((sw * sh, v.shape[-1]))
        d = int(round(np.log2(S // s)))
        py, px = np.divmod(pid, sw)
        for dy in range(-b, b + 1):
            ty = py + dy
            for dx in range(-b, b + 1):
                tx = px + dx
                ok = (tx >= 0) & (tx < sw) & (ty >= 0) & (ty < sh)
                if not ok.any():
                    continue
                # the side's start in steps from the target pixel's edge
                wx = self.table[d, sx[ok] - (tx[ok] + X0) * S + b * S]     # (n, 2)
                wy = self.table[d, sy[ok] - (ty[ok] + Y0) * S + b * S]
                t = ty[ok] * sw + tx[ok]
                vv = v[:, ok]
                wts = (wx[:, 0] * wy[:, 0], wx[:, 1] * wy[:, 0], wx[:, 0] * wy[:, 1], wx[:, 1] * wy[:, 1])
                contrib = vv[0] * wts[0][:, None] + vv[1] * wts[1][:, None] + vv[2] * wts[2][:, None] \
                    + vv[3] * wts[3][:, None]
                for c in range(contrib.shape[1]):
                    self.num[:, c] += np.bincount(t, weights=contrib[:, c], minlength=sw * sh)
                self.den += np.bincount(t, weights=(wx[:, 0] + wx[:, 1]) * (wy[:, 0] + wy[:, 1]), minlength=sw * sh)

    def result(self):
        """``(n, C)``: weighted sums over summed weights (a zero weight divides by 1)."""
        return self.num / np.where(self.den == 0.0, 1.0, self.den)[:, None]


def render_adaptive_window(trace_points, centre_aovs, win, film_size, threshold, depth, seed, aovs,
                           bar=None, rfilter=None) -> np.ndarray:
    """Adaptive anti-aliasing of window ``win`` with any renderer (the core's
    :func:`links1.render.render`, ``links1_whitted``'s ``render_adaptive``): lattice point
    ``(i, j)`` is the camera ray through film position ``(i, j) / 2**depth`` pixels, its ray
    tree keyed by :func:`links1.sampling.lattice_keys` (a function of the point and the seed
    alone, so every window and renderer traces the same tree).

    ``trace_points(xf, yf, keys) -> (L (n, 3), cost (n,))`` traces rays through film fractions
    ``(xf, yf)``; ``centre_aovs(win, names) -> (h, w, k)`` renders the AOVs ``names`` (of depth,
    normal, id) at the pixel centres. Returns ``(h, w, 3 + AOV channels)``: cost summed over the
    pixel's lattice points, samples = their number. ``bar``: a progress bar (``update(n)``,
    ``close()``, e.g. tqdm's) told of every traced point and closed when the refinement ends.
    ``rfilter``: the film's reconstruction filter (:class:`links1.filters.Filter`; default box)."""
    threshold, depth = check_options(threshold, depth)
    W, H = film_size

    def sample(i, j, step, keys):
        L, cost = trace_points(i / step / W, j / step / H, lattice_keys(keys, seed))
        if bar is not None:
            bar.update(len(i))
        return np.concatenate([np.asarray(L, dtype=np.float64), np.asarray(cost, dtype=np.float64)[:, None]], axis=1)

    rgb, samples, cost = render_adaptive(sample, win, (W, H), threshold, depth, summed=1, rfilter=rfilter)
    if bar is not None:
        bar.close()
    centre = [a for a in aovs if a in ("depth", "normal", "id")]
    parts = {}
    if centre:
        c, at = centre_aovs(win, centre), 0
        for a in centre:
            parts[a] = c[..., at:at + len(AOVS[a])]
            at += len(AOVS[a])
    chans = [rgb]
    for a in aovs:
        chans.append(parts[a] if a in parts else cost if a == "cost" else samples[..., None].astype(np.float64))
    return np.concatenate(chans, axis=2)
