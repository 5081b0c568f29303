"""The shared sample pattern: pixel centres at spp 1, one sample per stratum, keyed by pixel."""
from __future__ import annotations

import numpy as np
import pytest

from links1.maths.sampling import mix32, sample_offsets, strata


def lowbias32_reference(x: int) -> int:
    """Chris Wellons' lowbias32 with Python integers (an independent oracle)."""
    x &= 0xFFFFFFFF
    x ^= x >> 16
    x = (x * 0x7FEB352D) & 0xFFFFFFFF
    x ^= x >> 15
    x = (x * 0x846CA68B) & 0xFFFFFFFF
    x ^= x >> 16
    return x


def test_mix32_matches_reference():
    xs = np.array([0, 1, 2, 12345, 0xFFFFFFFF, 0xDEADBEEF], dtype=np.uint32)
    assert [int(v) for v in mix32(xs)] == [lowbias32_reference(int(v)) for v in xs]


def test_spp1_is_the_pixel_centre():
    ox, oy = sample_offsets(np.arange(5), np.arange(5), 0, 1, seed=9, film_width=5)
    assert np.all(ox == 0.5) and np.all(oy == 0.5)


@pytest.mark.parametrize("spp", [4, 9, 16, 64])
def test_one_sample_per_stratum(spp):
    k = strata(spp)
    assert k * k == spp
    px, py = np.array([3, 17]), np.array([5, 2])
    cells = {(0,): set(), (1,): set()}
    for i in range(spp):
        ox, oy = sample_offsets(px, py, i, spp, seed=1, film_width=32)
        assert np.all((ox >= 0) & (ox < 1) & (oy >= 0) & (oy < 1))
        for j in range(2):
            cells[(j,)].add((int(ox[j] * k), int(oy[j] * k)))
    for j in range(2):
        assert len(cells[(j,)]) == spp


def test_pattern_depends_on_pixel_seed_and_index_only():
    a = sample_offsets(np.array([7]), np.array([3]), 2, 16, seed=5, film_width=64)
    b = sample_offsets(np.array([1, 7, 9]), np.array([0, 3, 4]), 2, 16, seed=5, film_width=64)
    assert a[0][0] == b[0][1] and a[1][0] == b[1][1]
    c = sample_offsets(np.array([7]), np.array([3]), 2, 16, seed=6, film_width=64)
    assert (a[0][0], a[1][0]) != (c[0][0], c[1][0])
