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
    A pixel's value is the sum over its leaf squares of ``area * mean of its 4 corners``
    (the box integral of the corner average; areas are powers of two, so the sum is exact up
    to the additions, done in one fixed order per pixel). This is the filter of adaptive
    renders: the film's reconstruction filter is not applied (``links1.render`` warns).
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


def render_adaptive(sample, window, film_size, threshold, depth, summed=0):
    """Adaptive render of ``window = (x0, y0, w, h)`` of a film of ``film_size = (W, H)`` pixels.

    ``sample(i, j, step, keys)`` -> (n, C) values of the lattice points ``(i, j)`` (int64
    arrays; film position ``(i / step, j / step)`` pixels, row 0 at the top; ``keys`` their
    global keys) must depend on ``(i, j)`` only.

    Returns ``(values (h, w, C), samples (h, w) int64)``: the pixel values (module doc) and
    the number of distinct lattice points each pixel's leaf squares use. With ``summed = k``
    the last ``k`` channels of ``sample`` (e.g. a ray count) are not reconstructed but summed
    over those distinct points: ``(values (h, w, C - k), samples, sums (h, w, k))``.
    """
    threshold, depth = check_options(threshold, depth)
    x0, y0, w, h = (int(v) for v in window)
    lat = Lattice(sample, film_size, depth)
    S = lat.step
    pys, pxs = np.divmod(np.arange(w * h, dtype=np.int64), w)
    sx, sy, pid = (pxs + x0) * S, (pys + y0) * S, np.arange(w * h, dtype=np.int64)
    acc = None
    used_pid, used_key = [], []
    s = S
    while len(pid):
        corners = np.stack([lat.key(sx, sy), lat.key(sx + s, sy), lat.key(sx, sy + s), lat.key(sx + s, sy + s)])
        v = lat.lookup(corners)  # (4, n, C)
        if acc is None:
            acc = np.zeros((w * h, v.shape[-1]))
        # the summed channels (counts, not colour) take no part in the decision
        split = differs(v[..., :v.shape[-1] - summed], threshold) if s > 1 else np.zeros(len(pid), dtype=bool)
        leaf = ~split
        area = (s / S) ** 2  # a power of two: exact
        contrib = (v[0, leaf] + v[1, leaf] + v[2, leaf] + v[3, leaf]) * (0.25 * area)
        for c in range(contrib.shape[1]):   # per level: the pixel's leaves summed in array order
            acc[:, c] += np.bincount(pid[leaf], weights=contrib[:, c], minlength=w * h)
        used_pid.append(np.repeat(pid[leaf][None], 4, axis=0).ravel())
        used_key.append(corners[:, leaf].ravel())
        h2 = s // 2
        sx, sy, pid = sx[split], sy[split], pid[split]
        sx = np.concatenate([sx, sx + h2, sx, sx + h2])
        sy = np.concatenate([sy, sy, sy + h2, sy + h2])
        pid = np.tile(pid, 4)
        s = h2
    pairs = _unique_pairs(np.concatenate(used_pid), np.concatenate(used_key), lat.stride * (film_size[1] * S + 1))
    samples = np.bincount(pairs[:, 0], minlength=w * h).reshape(h, w).astype(np.int64)
    if not summed:
        return acc.reshape(h, w, -1), samples
    C = acc.shape[1]
    sums = np.zeros((w * h, summed))
    extra = lat.lookup(pairs[:, 1])[:, C - summed:]
    for c in range(summed):
        sums[:, c] = np.bincount(pairs[:, 0], weights=extra[:, c], minlength=w * h)
    return acc[:, :C - summed].reshape(h, w, -1), samples, sums.reshape(h, w, summed)
