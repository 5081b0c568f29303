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

from .errors import UsageError

#: Largest supported depth (a (2**8+1)² lattice per pixel; keys stay well inside int64).
MAX_DEPTH = 8


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


def differs(corners: np.ndarray, threshold: float) -> np.ndarray:
    """``corners`` (4, n, C) -> (n,) bool: refine where the tone-mapped corner values differ
    by more than ``threshold`` in some channel."""
    t = tonemap(corners)
    return np.max(t.max(axis=0) - t.min(axis=0), axis=1) > threshold


class Lattice:
    """Values of lattice points, evaluated once each and looked up by key."""

    def __init__(self, sample, film_size, depth):
        self.sample, self.step = sample, 1 << depth
        self.stride = np.int64(film_size[0] * self.step + 1)
        self.keys = np.zeros(0, dtype=np.int64)  # sorted
        self.values = None
        self.evaluated = 0

    def key(self, i, j):
        return np.asarray(j, dtype=np.int64) * self.stride + np.asarray(i, dtype=np.int64)

    def lookup(self, keys: np.ndarray) -> np.ndarray:
        """Values of the points ``keys`` (any shape), evaluating the new ones (in key order)."""
        flat = keys.ravel()
        new = _sorted_unique(flat)
        if len(self.keys):   # drop the points already evaluated (new stays sorted)
            at = np.minimum(np.searchsorted(self.keys, new), len(self.keys) - 1)
            new = new[self.keys[at] != new]
        if len(new):
            j, i = np.divmod(new, self.stride)
            vals = np.asarray(self.sample(i, j, self.step, new), dtype=np.float64)
            self.evaluated += len(new)
            if self.values is None:
                self.keys, self.values = new, vals
            else:
                keys_all = np.concatenate([self.keys, new])
                order = np.argsort(keys_all, kind="stable")
                self.keys = keys_all[order]
                self.values = np.concatenate([self.values, vals])[order]
        return self.values[np.searchsorted(self.keys, flat)].reshape(*keys.shape, -1)


def _sorted_unique(a: np.ndarray) -> np.ndarray:
    """``np.unique`` of a 1-D integer array by one sort (numpy 2's hash-based unique is
    several times slower on the millions of lattice keys of a large film)."""
    a = np.sort(a, kind="stable")
    if a.size == 0:
        return a
    keep = np.empty(a.size, dtype=bool)
    keep[0] = True
    np.not_equal(a[1:], a[:-1], out=keep[1:])
    return a[keep]


def _unique_pairs(pid, key, nkeys):
    """Distinct ``(pid, key)`` rows, sorted: one int64 per pair when it fits (a 1-D sort is an
    order of magnitude faster than numpy's row-wise unique), else row-wise."""
    if (int(pid.max(initial=0)) + 1) * int(nkeys) < 2 ** 62:
        c = _sorted_unique(pid.astype(np.int64) * np.int64(nkeys) + key)
        return np.stack(np.divmod(c, np.int64(nkeys)), axis=1)
    return np.unique(np.stack([pid, key], axis=1), axis=0)


def _refine(lat, window, threshold, summed):
    """The refinement of the pixels of ``window`` (module doc), one level at a time.

    Yields ``(pid, sx, sy, s, v, corners, leaf)`` per level: the squares of that level (pixel
    index in the window, row by row; top-left lattice point; side ``s`` lattice steps), their
    corner values ``v (4, n, C)`` and keys ``corners (4, n)`` (corners ``(sx, sy), (sx+s, sy),
    (sx, sy+s), (sx+s, sy+s)``) and which are leaves. A pixel's squares keep one order whatever the window (squares are
    compacted and split in array order), so sums over them are window-independent."""
    x0, y0, w, h = window
    S = lat.step
    pys, pxs = np.divmod(np.arange(w * h, dtype=np.int64), w)
    sx, sy, pid = (pxs + x0) * S, (pys + y0) * S, np.arange(w * h, dtype=np.int64)
    s = S
    while len(pid):
        corners = np.stack([lat.key(sx, sy), lat.key(sx + s, sy), lat.key(sx, sy + s), lat.key(sx + s, sy + s)])
        v = lat.lookup(corners)  # (4, n, C)
        # the summed channels (counts, not colour) take no part in the decision
        split = differs(v[..., :v.shape[-1] - summed], threshold) if s > 1 else np.zeros(len(pid), dtype=bool)
        yield pid, sx, sy, s, v, corners, ~split
        h2 = s // 2
        sx, sy, pid = sx[split], sy[split], pid[split]
        sx = np.concatenate([sx, sx + h2, sx, sx + h2])
        sy = np.concatenate([sy, sy, sy + h2, sy + h2])
        pid = np.tile(pid, 4)
        s = h2


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
    lat = Lattice(sample, film_size, depth)
    S = lat.step
    box = rfilter is None or rfilter.is_box
    if box:
        sw = (x0, y0, w, h)
    else:   # the window and the border of pixels whose leaves reach it (clipped to the film)
        b = rfilter.border
        sx0, sy0 = max(0, x0 - b), max(0, y0 - b)
        sw = (sx0, sy0, min(film_size[0], x0 + w + b) - sx0, min(film_size[1], y0 + h + b) - sy0)
        filtered = FilteredLeaves(rfilter, depth, sw)
    n = sw[2] * sw[3]
    acc = None
    used_pid, used_key = [], []
    for pid, sx, sy, s, v, corners, leaf in _refine(lat, sw, threshold, summed):
        C = v.shape[-1] - summed
        if box:
            if acc is None:
                acc = np.zeros((n, C))
            area = (s / S) ** 2  # a power of two: exact
            contrib = (v[0, leaf] + v[1, leaf] + v[2, leaf] + v[3, leaf]) * (0.25 * area)
            for c in range(C):   # per level: the pixel's leaves summed in array order
                acc[:, c] += np.bincount(pid[leaf], weights=contrib[:, c], minlength=n)
        else:
            filtered.add(pid[leaf], sx[leaf], sy[leaf], s, v[:, leaf, :C])
        used_pid.append(np.repeat(pid[leaf][None], 4, axis=0).ravel())
        used_key.append(corners[:, leaf].ravel())
    values = acc if box else filtered.result()
    pairs = _unique_pairs(np.concatenate(used_pid), np.concatenate(used_key), lat.stride * (film_size[1] * S + 1))
    samples = np.bincount(pairs[:, 0], minlength=n).astype(np.int64)
    out = [values, samples]
    if summed:
        sums = np.zeros((n, summed))
        extra = lat.lookup(pairs[:, 1])[:, -summed:]
        for c in range(summed):
            sums[:, c] = np.bincount(pairs[:, 0], weights=extra[:, c], minlength=n)
        out.append(sums)
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
