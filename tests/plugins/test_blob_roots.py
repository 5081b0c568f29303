"""The plugin's ``exact`` blob root finder (blob_roots.py: the march with Newton's step where the
field decreases, the certain root, the bound of the field ahead; Newton in a bracket) against
the float64 core (links1/geometry/blob.py): hit or miss, the hit distance in float32 ulps, and
shadow rays (any hit) blocked exactly where the nearest-hit search hits; rays from outside and
from inside the blob (the exit), a blob with a negative weight, on the candidate lists and on
the all-centres sum."""
from __future__ import annotations

import numpy as np
import pytest

from tests.plugins.test_blob_candidates import _cloud, _rays

pytestmark = pytest.mark.mitsuba


@pytest.mark.slow
@pytest.mark.parametrize("lists", [True, False])
def test_exact_roots_match_core(lists, variant):
    import drjit as dr
    import mitsuba as mi
    from links1.geometry.blob import Blob
    from links1_mitsuba import blob_candidates
    from links1_mitsuba.blob import BlobSpec
    c = _cloud(16, 11)                      # one centre of weight -0.5
    o, d = _rays(c, 3000, 12)
    # rays from inside: from the positive centres, every way (the exit)
    rng = np.random.default_rng(13)
    k = 600
    o[-k:] = c[c[:, 3] > 0][rng.integers(0, 15, k), :3]
    v = rng.normal(size=(k, 3))
    d[-k:] = v / np.linalg.norm(v, axis=1)[:, None]
    old = blob_candidates.LIST_MIN_CENTRES
    blob_candidates.LIST_MIN_CENTRES = 1 if lists else 10 ** 9
    try:
        spec = BlobSpec(0, "b", c, 0.5, "exact")
        assert spec.uses_lists() == lists
        n = len(o)
        O, D = mi.Vector3f(o.T), mi.Vector3f(d.T)
        t, _ = spec.intersect(O, D, mi.Float(0.0), mi.Float(np.inf), dr.ones(mi.Bool, n))
        tsh, _ = spec.intersect(O, D, mi.Float(0.0), mi.Float(np.inf), dr.ones(mi.Bool, n), any_hit=True)
        t, tsh = np.array(t, dtype=np.float64), np.array(tsh, dtype=np.float64)
    finally:
        blob_candidates.LIST_MIN_CENTRES = old
    # the core on the same float32 rays
    o32, d32 = o.astype(np.float32).astype(np.float64), d.astype(np.float32).astype(np.float64)
    t64, _ = Blob(c, 0.5, solver="exact").intersect(o32, d32, np.zeros(n), np.full(n, np.inf))
    hit, hit64 = np.isfinite(t), np.isfinite(t64)
    assert hit64.sum() > n // 3 and hit64[-k:].all()
    assert np.mean(hit != hit64) <= 2e-3            # float32 tangents
    both = hit & hit64
    ulps = np.abs(t[both] - t64[both]) / np.spacing(t64[both].astype(np.float32))
    # measured: median 0.6, 99th percentile 3.5-4.6 ulps (compare.blob_rays)
    assert np.median(ulps) <= 1.0 and np.quantile(ulps, 0.99) <= 8.0
    # shadow rays: blocked exactly where the nearest-hit search hits, at a point past the hit
    assert np.array_equal(np.isfinite(tsh), hit)
    assert np.all(tsh[hit] >= t[hit] * (1 - 1e-5))
