"""Adaptive anti-aliasing in links1_whitted: the same lattice, keys and decisions as
the core (links1.tracing.adaptive.render_adaptive_window), one launch per refinement level."""
from __future__ import annotations

import os

import numpy as np
import pytest

from .conftest import SCENES

pytestmark = pytest.mark.mitsuba
KW = dict(params={"res": 32}, adaptive=0.03, adaptive_depth=2, aovs=("samples", "cost", "depth"))


def rel_mse(a, b):
    return float(np.sum((a - b) ** 2) / max(np.sum(b ** 2), 1e-30))


@pytest.mark.slow
@pytest.mark.parametrize("scene", ["lights.xml", "fig4.xml", "shadows.xml", "many.xml"])
def test_plugin_refines_as_the_core_does(variant, scene):
    from links1_app.renderers import make_renderer
    path = os.path.join(SCENES, scene)
    core = make_renderer("core", path, **KW).render()
    plug = make_renderer("mitsuba", path, **KW).render()
    assert plug.shape == core.shape == (32, 32, 6)
    same = plug[..., 3] == core[..., 3]
    # decisions can differ only where a corner difference sits at the threshold (float32)
    assert same.mean() >= 0.99, same.mean()
    assert (core[..., 3] > 4).sum() >= 20   # edges were refined
    assert rel_mse(plug[..., :3], core[..., :3]) < 1e-5
    hit = core[..., 5] > 0
    np.testing.assert_allclose(plug[..., 5][hit], core[..., 5][hit], rtol=1e-5)   # depth at the centres


def test_plugin_windows_and_batches_equal_the_full_frame(variant):
    from links1_app.renderers import make_renderer
    r = make_renderer("mitsuba", os.path.join(SCENES, "lights.xml"), **KW)
    full = r.render()
    wins = [(0, 0, 13, 9), (13, 0, 19, 9), (0, 9, 32, 23), (7, 4, 3, 17)]
    for win, part in zip(wins, r.render_batch(wins)):
        x0, y0, w, h = win
        assert np.array_equal(part, full[y0:y0 + h, x0:x0 + w]), win


def test_scene_integrator_refuses_adaptive(variant):
    from links1_app.renderers import make_renderer
    with pytest.raises(Exception, match="links1_whitted"):
        make_renderer("mitsuba", os.path.join(SCENES, "mitsuba_direct.xml"), integrator="scene", adaptive=0.1)


def test_integrator_parameters_adaptive_in_mi_render(variant, tmp_path):
    """``<float name="adaptive">`` on links1_whitted: ``mi.render`` renders adaptively, the
    same image as MitsubaRenderer(adaptive=...)."""
    import mitsuba as mi

    from links1_app.renderers import make_renderer
    from links1_mitsuba import load_file
    src = open(os.path.join(SCENES, "lights.xml")).read().replace(
        '<integer name="max_depth" value="1"/>',
        '<integer name="max_depth" value="1"/><float name="adaptive" value="0.03"/>'
        '<integer name="adaptive_depth" value="2"/><string name="aovs" value="samples"/>')
    p = tmp_path / "lights_adaptive.xml"
    p.write_text(src.replace('filename="include/', f'filename="{SCENES}/include/'))
    scene = load_file(str(p), params={"res": 32})
    img = np.array(mi.render(scene), dtype=np.float64)
    ref = make_renderer("mitsuba", os.path.join(SCENES, "lights.xml"), params={"res": 32}, adaptive=0.03,
                        adaptive_depth=2, aovs=("samples",)).render()
    assert img.shape == ref.shape == (32, 32, 4)
    assert (img[..., 3] > 4).any()
    np.testing.assert_allclose(img, ref, rtol=1e-6, atol=1e-7)
    with pytest.raises(Exception, match="adaptive_depth needs adaptive"):
        mi.load_dict({"type": "links1_whitted", "adaptive_depth": 2})


def test_plugin_applies_the_films_filter_as_the_core(variant, tmp_path):
    """A Gaussian film: the plugin reconstructs the filtered image as the core does (the same
    decisions, values to float32), tiles equal the full frame, and the filter changes the image."""
    from links1_app.renderers import make_renderer
    inc = open(os.path.join(SCENES, "include", "camera.xml")).read()
    assert '<rfilter type="box"/>' in inc
    (tmp_path / "include").mkdir()
    (tmp_path / "include" / "camera.xml").write_text(inc.replace('<rfilter type="box"/>', '<rfilter type="gaussian"/>'))
    (tmp_path / "s.xml").write_text(open(os.path.join(SCENES, "lights.xml")).read())
    core = make_renderer("core", str(tmp_path / "s.xml"), **KW).render()
    r = make_renderer("mitsuba", str(tmp_path / "s.xml"), **KW)
    plug = r.render()
    boxed = make_renderer("mitsuba", os.path.join(SCENES, "lights.xml"), **KW).render()
    assert (plug[..., 3] == core[..., 3]).mean() >= 0.99
    assert rel_mse(plug[..., :3], core[..., :3]) < 1e-5
    assert rel_mse(plug[..., :3], boxed[..., :3]) > 1e-4      # the filter is not the box
    wins = [(0, 0, 13, 9), (13, 0, 19, 9), (0, 9, 32, 23), (7, 4, 3, 17)]
    for win, part in zip(wins, r.render_batch(wins)):
        x0, y0, w, h = win
        assert np.array_equal(part, plug[y0:y0 + h, x0:x0 + w]), win


def test_points_launch_records_once_whatever_the_inputs_alignment(variant):
    """trace_points replays one recording for any point count and any alignment of the numpy
    inputs (a mapped input whose alignment changes makes drjit.freeze record again)."""
    from links1_app.renderers import make_renderer
    r = make_renderer("mitsuba", os.path.join(SCENES, "shadows.xml"), params={"res": 32}, adaptive=0.03)
    rng = np.random.default_rng(1)

    def offset(a, off):   # a copy of a starting `off` bytes past a 64-byte boundary
        buf = np.empty(a.nbytes + 128, dtype=np.uint8)
        start = -buf.ctypes.data % 64 + off
        out = buf[start:start + a.nbytes].view(a.dtype)
        out[:] = a
        return out
    for n, off in [(5000, 0), (5000, 4), (7000, 8), (5000, 0), (300, 4)]:
        xf, yf = (offset(rng.random(n).astype(np.float32), off) for _ in range(2))
        keys = offset(np.arange(n, dtype=np.uint32), off)
        L, _ = r.integrator.trace_points(r.scene, xf, yf, keys)
        assert np.isfinite(L).all() and L.shape == (n, 3)
    # one recording for the five calls (three alignments), or one more: Dr.Jit's freeze also
    # records again, rarely and at random, when an input's memory moved (tests/plugins/
    # test_tuning.py; seen here once in a run of this file after others)
    assert r.integrator.info()["point_recordings"] <= 2


def test_table_rebuild_drops_the_points_recording(variant):
    """A rebuild of the scene's tables drops both frozen launches' recordings: they are keyed on
    ``id(P)``, which a new ``P`` may share with a dead one, so a kept points recording could be
    replayed with the old tables' Python-side values (the window launch's was already dropped).
    The adaptive image after the rebuild equals the one before (the same scene)."""
    from links1_app.renderers import make_renderer
    from links1_mitsuba.tuning import tuned
    r = make_renderer("mitsuba", os.path.join(SCENES, "shadows.xml"), params={"res": 24}, adaptive=0.03)
    integ = r.integrator
    before = integ.render_adaptive(r.scene, threshold=0.03, depth=2)
    assert integ.info()["point_launch"] is not None
    builds = integ.info()["scene_builds"]
    with tuned(bvh_min=integ.prepare(r.scene).tuning.bvh_min + 1):
        integ.prepare(r.scene)
        assert integ.info()["scene_builds"] == builds + 1
        assert integ.info()["launch"] is None and integ.info()["point_launch"] is None
        assert np.array_equal(integ.render_adaptive(r.scene, threshold=0.03, depth=2), before)
