"""Validation a: links1_whitted (float32) against the float64 core on every scenes/ file."""
from __future__ import annotations

import glob
import os
import warnings

import numpy as np
import pytest

from .conftest import SCENES

pytestmark = pytest.mark.mitsuba

SCENE_FILES = sorted(glob.glob(os.path.join(SCENES, "*.xml")))
RES = 64


def _core():
    try:
        from links1.scene.loader import load_scene
        from links1.tracing.render import render
    except ImportError as exc:  # pragma: no cover - core not there yet
        pytest.skip(f"the core renderer is not available: {exc}")
    return load_scene, render


@pytest.mark.slow
@pytest.mark.skipif(not SCENE_FILES, reason="no scenes/*.xml")
@pytest.mark.parametrize("path", SCENE_FILES, ids=[os.path.basename(p) for p in SCENE_FILES])
def test_plugin_matches_core(variant, path):
    load_scene, render = _core()
    from links1_mitsuba import MitsubaRenderer
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = MitsubaRenderer(path, params={"res": RES}, aovs=("id",))
        scene = load_scene(path, res=str(RES))
    for spp in (1, 4):
        plug = r.integrator.render_window(r.scene, None, spp=spp, seed=0, aovs=("id",))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            core = render(scene, spp=spp, seed=0, aovs=("id",))
        assert plug.shape == core.shape
        a, b = plug[..., :3], core[..., :3]
        assert np.all(np.isfinite(a))
        rel_mse = float(np.sum((a - b) ** 2) / max(np.sum(b ** 2), 1e-30))
        hit_a, hit_b = plug[..., 3] >= 0, core[..., 3] >= 0
        disagree = float(np.mean(hit_a != hit_b))
        assert rel_mse <= 1e-5, f"{os.path.basename(path)} spp={spp}: relative MSE {rel_mse:.3g}"
        assert disagree <= 5e-4, f"{os.path.basename(path)} spp={spp}: hit/miss differs on {disagree:.3%}"
        # ids compared on every pixel both renderers hit (not only when hit/miss agrees
        # everywhere); where one misses, the miss is counted above
        both = hit_a & hit_b
        wrong_id = int(np.count_nonzero(plug[..., 3][both] != core[..., 3][both]))
        assert both.any() and wrong_id <= 5e-4 * both.size, \
            f"{os.path.basename(path)} spp={spp}: shape id differs on {wrong_id} of {int(both.sum())} pixels"
        assert np.array_equal(plug[..., 3][~hit_a & ~hit_b], core[..., 3][~hit_a & ~hit_b])  # both -1
