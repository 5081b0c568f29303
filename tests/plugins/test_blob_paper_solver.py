"""The plugin's ``paper`` blob solver (float32 Dr.Jit) against the float64 core's
(links1/geometry/blob.py ``_solve_paper``): same span samples, same quadratic fits and root choice,
same number of field evaluations per ray."""
from __future__ import annotations

import os
import warnings

import numpy as np
import pytest

from .conftest import SCENES

pytestmark = pytest.mark.mitsuba

FIG6A = [[-1.0, 0.8, 0.0, 1.0, 0.55], [0.0, 1.0, 0.1, 1.0, 0.5], [1.0, 0.8, 0.0, 1.0, 0.55],
         [0.3, 0.55, 0.8, 0.8, 0.45], [-0.3, 1.8, -0.1, 0.9, 0.45]]
CARVED = FIG6A + [[0.0, 0.9, 0.3, -0.6, 0.35]]


def _rays(n, seed):
    rng = np.random.default_rng(seed)
    o = np.array([0.0, 1.0, 5.0]) + rng.normal(size=(n, 3)) * 0.05
    tgt = np.array([0.0, 1.0, 0.0]) + rng.uniform(-2.0, 2.0, size=(n, 3)) * [1.0, 1.0, 0.3]
    d = tgt - o
    return o, d / np.linalg.norm(d, axis=1)[:, None]


@pytest.mark.parametrize("centers,threshold,samples,to_world", [
    (FIG6A, 0.5, 8, None),
    (FIG6A, 0.3, 3, None),
    (CARVED, 0.4, 5, None),
    (FIG6A, 0.5, 8, np.diag([2.0, 0.5, 1.5, 1.0])),
], ids=["fig6a-8", "fig6a-3", "carved-5", "scaled-8"])
def test_paper_solver_matches_core_rays(centers, threshold, samples, to_world, variant):
    import drjit as dr
    import mitsuba as mi
    from links1.geometry.blob import Blob
    from links1_mitsuba.blob import BlobSpec

    c = np.array(centers, dtype=np.float64)
    n = 3000
    o, d = _rays(n, samples)
    core = Blob(c, threshold, solver="paper", samples=samples, to_world=to_world)
    cost_c = np.zeros(n, dtype=np.int64)
    tc, _ = core.intersect(o, d, np.zeros(n), np.full(n, np.inf), cost_c)
    spec = BlobSpec(0, "b", c, threshold, "paper", samples, to_world)
    cost_m = dr.zeros(mi.UInt32, n)
    tm, _ = spec.intersect(mi.Vector3f(o.T), mi.Vector3f(d.T), mi.Float(0.0), mi.Float(np.inf),
                           dr.ones(mi.Bool, n), cost_m)
    tm, cost_m = np.array(tm, dtype=np.float64), np.array(cost_m, dtype=np.int64)
    hc, hm = np.isfinite(tc), np.isfinite(tm)
    assert hc.sum() > n // 10
    assert np.mean(hc != hm) <= 2e-3
    both = hc & hm
    assert np.max(np.abs(tm[both] - tc[both]) / tc[both]) <= 1e-4
    # one field evaluation per sample: `samples` per positive chord met, as the core counts
    assert np.array_equal(cost_m, cost_c)
    assert cost_c.max() <= samples * int(np.sum(c[:, 3] > 0))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["fig6a.xml", "fig6b.xml"])
def test_paper_solver_primary_hits_match_core(name, variant):
    from links1_app.renderers import make_renderer
    path = os.path.join(SCENES, name)
    if not os.path.exists(path):
        pytest.skip(f"no {name}")
    params = {"res": "64", "solver": "paper"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        plug = make_renderer("mitsuba", path, params=params, aovs=("id",)).render()
        core = make_renderer("core", path, params=params, aovs=("id",)).render()
    assert plug.shape == core.shape
    assert np.all(np.isfinite(plug[..., :3]))
    hit_a, hit_b = plug[..., 3] >= 0, core[..., 3] >= 0
    assert float(np.mean(hit_a != hit_b)) <= 5e-4
    assert float(np.mean(plug[..., 3] != core[..., 3])) <= 5e-4
