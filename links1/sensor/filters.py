"""Reconstruction filters as Mitsuba 3.9.1 has them, and the gather that applies them.

A pixel's value is Mitsuba's ``ImageBlock`` estimate: every sample ``s`` at film position
``p_s`` (in pixels) adds ``f(x + 0.5 - p_s.x) · f(y + 0.5 - p_s.y)`` times its value to pixel
``(x, y)`` and the same weight to the pixel's weight; the film divides the two (a zero weight
divides by 1). Filters are separable and vanish beyond their radius. Box (radius 1/2) is
Mitsuba's fast path: a sample adds weight 1 to the pixel it lies in, so the pixel value is the
mean of its own samples.

Filters and their parameters (Mitsuba's names and defaults; ``radius`` in pixels):

=============  =======================  ==========================================
``box``        radius 0.5               1 in [-1/2, 1/2)
``tent``       ``radius`` (1)           ``max(0, 1 - |x| / radius)``
``gaussian``   ``stddev`` (0.5), r = 4σ ``max(0, exp(-x²/2σ²) - exp(-r²/2σ²))``
``mitchell``   ``B``, ``C`` (1/3, 1/3)  Mitchell-Netravali cubic, radius 2
``catmullrom`` radius 2                 Mitchell-Netravali with B = 0, C = 1/2
``lanczos``    ``lobes`` (3) = radius   ``sinc(x) sinc(x / lobes)``
=============  =======================  ==========================================

Mitsuba's CUDA variants evaluate the Gaussian with ``exp`` as above; its LLVM variants use a
polynomial fit of it (measured: within 4.2e-4). This module evaluates the exact function in
float64 for both renderers.

Determinism: :class:`FilterGather` sums every output pixel's samples in one fixed order
(per neighbour row, then column, the neighbour's samples in sample order, summed apart, then
added to the pixel) with elementwise float64 operations,
so a window of the film equals the same pixels of the full frame bit for bit whatever the
window. A window needs the samples of a border of :attr:`Filter.border` pixels around it
(:meth:`FilterGather.sample_window`); samples are keyed by full-film pixel
(:mod:`links1.maths.sampling`), so a border sample is the same value a neighbouring window computes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..maths.sampling import sample_offsets

#: Mitsuba's ``math::RayEpsilon<float>`` (1500 float32 machine epsilons): the slack in its border size.
_RAY_EPS32 = 1500 * 2.0 ** -24

#: Filter types and their parameters with Mitsuba's defaults.
FILTERS = {
    "box": {},
    "tent": {"radius": 1.0},
    "gaussian": {"stddev": 0.5},
    "mitchell": {"B": 1.0 / 3.0, "C": 1.0 / 3.0},
    "catmullrom": {},
    "lanczos": {"lobes": 3},
}

#: Mitsuba's filter when a film names none.
DEFAULT_FILTER = "gaussian"


@dataclass(frozen=True)
class Filter:
    """A reconstruction filter: ``name`` (a key of :data:`FILTERS`) and its parameters."""

    name: str = DEFAULT_FILTER
    params: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.name not in FILTERS:
            raise ValueError(f"unknown reconstruction filter {self.name!r}; choose from {', '.join(FILTERS)}")
        full = dict(FILTERS[self.name])
        for k, v in self.params.items():
            if k not in full:
                raise ValueError(f"reconstruction filter {self.name!r} has no parameter {k!r}")
            full[k] = v
        if self.name == "lanczos":
            full["lobes"] = int(full["lobes"])
        for k, v in full.items():
            if not (math.isfinite(v) and (v > 0 or k in ("B", "C"))):
                raise ValueError(f"reconstruction filter {self.name!r}: {k} must be a positive number, got {v}")
        object.__setattr__(self, "params", full)

    @property
    def radius(self) -> float:
        p = self.params
        return {"box": 0.5, "tent": p.get("radius"), "gaussian": 4.0 * p.get("stddev", 0.0),
                "mitchell": 2.0, "catmullrom": 2.0, "lanczos": float(p.get("lobes", 0))}[self.name]

    @property
    def is_box(self) -> bool:
        """Mitsuba's test: the box filter is the only one of radius 1/2."""
        return self.radius == 0.5

    @property
    def border(self) -> int:
        """Pixels of samples a window needs on each side (Mitsuba's ``border_size``)."""
        return 0 if self.is_box else int(math.ceil(self.radius - 0.5 - 2.0 * _RAY_EPS32))

    def eval(self, x) -> np.ndarray:
        """The 1-D filter at offsets ``x`` (pixels), float64."""
        x = np.abs(np.asarray(x, dtype=np.float64))
        p, r = self.params, self.radius
        if self.name == "box":  # Mitsuba's fast path: weight 1 in the sample's own pixel
            return np.where(x <= 0.5, 1.0, 0.0)
        if self.name == "tent":
            return np.maximum(0.0, 1.0 - x / r)
        if self.name == "gaussian":
            a = -1.0 / (2.0 * p["stddev"] ** 2)
            return np.maximum(0.0, np.exp(a * x * x) - math.exp(a * r * r))
        if self.name == "lanczos":
            tiny = x < np.finfo(np.float32).eps  # Mitsuba's limit: 1
            x1 = np.pi * np.where(tiny, 1.0, x)
            x2 = x1 / r
            v = np.sin(x1) * np.sin(x2) / (x1 * x2)
            return np.where(tiny, 1.0, np.where(x > r, 0.0, v))
        b, c = (p["B"], p["C"]) if self.name == "mitchell" else (0.0, 0.5)
        x2, x3 = x * x, x * x * x
        near = (12 - 9 * b - 6 * c) * x3 + (-18 + 12 * b + 6 * c) * x2 + (6 - 2 * b)
        far = (-b - 6 * c) * x3 + (6 * b + 30 * c) * x2 + (-12 * b - 48 * c) * x + (8 * b + 24 * c)
        return np.where(x < 2.0, np.where(x < 1.0, near, far) / 6.0, 0.0)

    def eval32(self, x) -> np.ndarray:
        """The weights of ``links1_mitsuba``'s float32 film: :meth:`eval` (float64) rounded to
        float32 (a float32 ``exp`` near the radius, ``exp(a x²) - exp(a r²)``, would cancel to a
        few significant bits)."""
        return self.eval(x).astype(np.float32)

    def describe(self) -> str:
        return self.name + "".join(f" {k}={v:g}" for k, v in self.params.items())

    @classmethod
    def from_mitsuba(cls, rfilter) -> "Filter":
        """The filter of a Mitsuba ``ReconstructionFilter`` object (its class and parameters)."""
        text = str(rfilter)
        name = {"BoxFilter": "box", "TentFilter": "tent", "GaussianFilter": "gaussian",
                "MitchellNetravaliFilter": "mitchell", "CatmullRomFilter": "catmullrom",
                "LanczosSincFilter": "lanczos"}.get(text.split("[")[0])
        if name is None:
            raise ValueError(f"unsupported reconstruction filter {text!r}")
        radius = float(rfilter.radius())
        if name == "tent":
            return cls(name, {"radius": radius})
        if name == "gaussian":
            return cls(name, {"stddev": radius / 4.0})
        if name == "lanczos":
            return cls(name, {"lobes": int(round(radius))})
        if name == "mitchell":  # Mitsuba prints B and C with 6 decimals
            kv = dict(part.split("=") for part in text[text.index("[") + 1:-1].replace(" ", "").split(","))
            bc = {k: float(kv[k]) for k in ("B", "C")}
            return cls(name, {k: (1.0 / 3.0 if abs(v - 1.0 / 3.0) < 1e-6 else v) for k, v in bc.items()})
        return cls(name)


BOX = Filter("box")


class FilterGather:
    """Filtered pixels of ``window = (x0, y0, w, h)`` from the samples of :attr:`sample_window`.

    Feed the samples one layer at a time with :meth:`add` (a layer: one sample per pixel of the
    sample window, e.g. sample index ``i`` of every pixel), then read :meth:`result`. The order
    of the layers is the summation order; callers add sample 0, 1, ... ``spp - 1``.

    The fixed order, in two steps: :meth:`add` sums, for every pixel ``q`` of the sample window
    and neighbour offset ``(dy, dx)``, the weighted values and the weights ``q``'s samples give
    the pixel ``(dy, dx)`` away from it, layer after layer (a record of ``q`` depends only on its
    own samples); :meth:`result` adds a pixel's records from its neighbours on the film in
    ascending ``dy``, then ``dx``. With one layer this is the order ``(dy, dx)`` of the terms
    themselves.

    ``dtype``: of the weights, sums and the division (float64: the core's images; float32: the
    arithmetic of ``links1_mitsuba``'s device film, whose sample offsets are the float32 rounding
    of the float64 ones, as its camera rays have them).
    """

    def __init__(self, filt: Filter, window, film_size, dtype=np.float64):
        self.filter = filt
        self.dtype = np.dtype(dtype)
        self.window = tuple(int(v) for v in window)
        W, H = (int(v) for v in film_size)
        x0, y0, w, h = self.window
        b = filt.border
        sx0, sy0 = max(0, x0 - b), max(0, y0 - b)
        sx1, sy1 = min(W, x0 + w + b), min(H, y0 + h + b)
        self.sample_window = (sx0, sy0, sx1 - sx0, sy1 - sy0)
        nb = 2 * b + 1
        #: per neighbour offset (dy, dx) and sample-window pixel: Σ w·value and Σ w
        self._num = None
        self._den = np.zeros((nb, nb, sy1 - sy0, sx1 - sx0), dtype=self.dtype)

    def inner(self, a: np.ndarray) -> np.ndarray:
        """The window's own pixels of an array over the sample window (first two axes)."""
        x0, y0, w, h = self.window
        sx0, sy0 = self.sample_window[:2]
        return a[y0 - sy0:y0 - sy0 + h, x0 - sx0:x0 - sx0 + w]

    def add(self, values: np.ndarray, offx: np.ndarray, offy: np.ndarray, weight=None) -> None:
        """One layer of samples: ``values (sh, sw, C)``, their offsets in their pixel
        ``offx, offy (sh, sw)`` in [0, 1), optionally a per-sample factor ``weight (sh, sw)``
        (0 leaves a sample out)."""
        dt = self.dtype
        values = np.asarray(values, dtype=dt)
        if self._num is None:
            self._num = np.zeros(self._den.shape + values.shape[2:], dtype=dt)
        b = self.filter.border
        # float32: the device film's weights (Filter.eval32) at the offsets (exact in float64)
        f = self.filter.eval if dt == np.float64 else self.filter.eval32
        offx = np.asarray(offx, dtype=dt).astype(np.float64)
        offy = np.asarray(offy, dtype=dt).astype(np.float64)
        # the 1-D weights of every sample towards the pixel dx (dy) columns (rows) away from it
        wxs = [f(0.5 - dx - offx) for dx in range(-b, b + 1)]
        wys = [f(0.5 - dy - offy) if weight is None else f(0.5 - dy - offy) * weight
               for dy in range(-b, b + 1)]
        for iy, wy in enumerate(wys):
            for ix, wx in enumerate(wxs):
                wgt = wy * wx
                self._num[iy, ix] += wgt[:, :, None] * values
                self._den[iy, ix] += wgt

    def result(self) -> np.ndarray:
        """``(h, w, C)``: weighted sum over summed weights (a zero weight divides by 1)."""
        x0, y0, w, h = self.window
        sx0, sy0, sw, sh = self.sample_window
        b = self.filter.border
        num, den = np.zeros((h, w) + self._num.shape[4:], dtype=self.dtype), np.zeros((h, w), dtype=self.dtype)
        for dy in range(-b, b + 1):
            # rows of the window whose neighbour row y + dy lies on the film
            ya, yb = max(0, sy0 - (y0 + dy)), min(h, sy0 + sh - (y0 + dy))
            if ya >= yb:
                continue
            rs = slice(y0 + dy + ya - sy0, y0 + dy + yb - sy0)
            for dx in range(-b, b + 1):
                xa, xb = max(0, sx0 - (x0 + dx)), min(w, sx0 + sw - (x0 + dx))
                if xa >= xb:
                    continue
                cs = slice(x0 + dx + xa - sx0, x0 + dx + xb - sx0)
                num[ya:yb, xa:xb] += self._num[dy + b, dx + b, rs, cs]
                den[ya:yb, xa:xb] += self._den[dy + b, dx + b, rs, cs]
        return num / np.where(den == 0.0, 1.0, den)[:, :, None]


def filter_samples(filt: Filter, window, film_size, values: np.ndarray, origin, spp: int,
                   seed: int, dtype=np.float64) -> np.ndarray:
    """Filtered pixels ``(h, w, C)`` of ``window`` from every sample of a traced block.

    ``values (th, tw, spp, C)``: the samples (pattern of :mod:`links1.maths.sampling` with ``spp`` and
    ``seed``) of the pixels of a block whose top-left pixel is ``origin = (tx0, ty0)`` (it may
    start off the film) and which covers the window's :attr:`FilterGather.sample_window`.
    ``dtype``: the gather's arithmetic (:class:`FilterGather`).
    """
    gather = FilterGather(filt, window, film_size, dtype)
    sx0, sy0, sw, sh = gather.sample_window
    r0, c0 = sy0 - int(origin[1]), sx0 - int(origin[0])
    block = np.asarray(values)[r0:r0 + sh, c0:c0 + sw]
    py, px = np.mgrid[sy0:sy0 + sh, sx0:sx0 + sw]
    for i in range(spp):
        ox, oy = sample_offsets(px, py, i, spp, seed, int(film_size[0]))   # rounded to dtype by add
        gather.add(block[:, :, i], ox, oy)
    return gather.result()
