"""The deterministic sample pattern shared by the core and the Mitsuba plugins.

Exact definition (the plugins reproduce it with Dr.Jit ``UInt32`` arithmetic):

* ``spp == 1``: one sample at the pixel centre, offset ``(0.5, 0.5)``.
* ``spp > 1``: ``k = ceil(sqrt(spp))`` strata per axis; sample ``i`` (0-based) lies in stratum
  ``(i mod k, (i div k))`` and is jittered inside it by two 24-bit hashes::

      key  = mix(mix(mix(seed) ^ (py * film_width + px)) ^ (2 * i + axis))   # uint32, wraps
      u    = (key >> 8) * 2**-24                                              # in [0, 1)
      off  = (stratum + u) / k

  where ``mix`` is Chris Wellons' ``lowbias32``, ``(px, py)`` the pixel in the *full film*
  (so a crop window renders the same samples as the full frame) and ``axis`` 0 for x, 1 for y.
* Film coordinates: ``x_film = (px + off_x) / film_width``, ``y_film = (py + off_y) / film_height``,
  row 0 at the top (Mitsuba's convention). Samples are averaged with equal weights (box filter).
"""
from __future__ import annotations

import math

import numpy as np

_M1 = np.uint32(0x7FEB352D)
_M2 = np.uint32(0x846CA68B)


def mix32(x: np.ndarray) -> np.ndarray:
    """lowbias32 integer hash on uint32 (wrapping arithmetic)."""
    x = np.asarray(x, dtype=np.uint32)
    with np.errstate(over="ignore"):
        x = x ^ (x >> np.uint32(16))
        x = x * _M1
        x = x ^ (x >> np.uint32(15))
        x = x * _M2
        x = x ^ (x >> np.uint32(16))
    return x


def strata(spp: int) -> int:
    return max(1, math.ceil(math.sqrt(spp)))


def sample_offsets(px: np.ndarray, py: np.ndarray, i: int, spp: int, seed: int,
                   film_width: int) -> tuple[np.ndarray, np.ndarray]:
    """Offsets in [0, 1)² inside pixel ``(px, py)`` of sample ``i`` out of ``spp``."""
    px = np.asarray(px)
    if spp == 1:
        h = np.full(px.shape, 0.5)
        return h, h.copy()
    k = strata(spp)
    sx, sy = i % k, i // k
    base = mix32(np.uint32(seed & 0xFFFFFFFF)) ^ (np.asarray(py, dtype=np.uint32) * np.uint32(film_width)
                                                  + np.asarray(px, dtype=np.uint32))
    base = mix32(base)
    ux = (mix32(base ^ np.uint32(2 * i)) >> np.uint32(8)).astype(np.float64) * 2.0 ** -24
    uy = (mix32(base ^ np.uint32(2 * i + 1)) >> np.uint32(8)).astype(np.float64) * 2.0 ** -24
    return (sx + ux) / k, (sy + uy) / k
