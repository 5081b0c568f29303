"""Reconstruction filters against Mitsuba: the weights of links1/sensor/filters.py are Mitsuba's own
filters, and both renderers meet Mitsuba's ``direct`` on a delta-light diffuse scene per filter
(relMSE against a 1024-spp ``direct`` reference within 2x of ``direct``'s own at equal spp)."""
from __future__ import annotations

import numpy as np
import pytest

from links1.imaging.diff import relmse
from links1.sensor.filters import FILTERS, Filter

from tests.scenes import integrator, perspective, scene, whitted

from .conftest import cli_variant
from .test_vs_mitsuba_integrators import DIFFUSE

pytestmark = pytest.mark.mitsuba

RES, SPP = 32, 16
# diffuse shapes and the point light only: with one emitter Mitsuba's ``direct`` has no
# light-selection noise, its error is the pixel sampling the filters act on
POINT_LIT = DIFFUSE[:DIFFUSE.index('<emitter type="directional"')]


RFILTERS = {"box": '<rfilter type="box"/>', "tent": '<rfilter type="tent"/>', "gaussian": "",
            "mitchell": '<rfilter type="mitchell"/>', "catmullrom": '<rfilter type="catmullrom"/>',
            "lanczos": '<rfilter type="lanczos"/>'}


def scene_xml(rfilter: str, method: str) -> str:
    return scene(perspective("0, 2.5, 6", "0, 0.7, 0", fov=40, width=RES, spp=None, rfilter=rfilter),
                 method, POINT_LIT)


def direct(rfilter, spp, seed):
    import mitsuba as mi
    sc = mi.load_string(scene_xml(rfilter, integrator("direct", bsdf_samples=0)))
    return np.array(mi.render(sc, spp=spp, seed=seed), dtype=np.float64)[..., :3]


def write_scene(tmp_path, rfilter):
    path = tmp_path / "filtered.xml"
    path.write_text(scene_xml(rfilter, whitted(1)))
    return str(path)


def test_weights_radius_border_are_mitsubas(variant):
    import mitsuba as mi
    x = np.linspace(-3.2, 3.2, 257)
    for name in FILTERS:
        for params in ({}, {"tent": {"radius": 1.5}, "gaussian": {"stddev": 0.3},
                            "mitchell": {"B": 0.2, "C": 0.4}, "lanczos": {"lobes": 2}}.get(name, {})):
            mf = mi.load_dict({"type": name, **params})
            ours = Filter(name, params)
            assert (ours.radius, ours.border) == (pytest.approx(mf.radius(), rel=1e-7), mf.border_size())
            back = Filter.from_mitsuba(mf)  # what the plugin reads from the film
            assert back.name == name and back.params == pytest.approx(ours.params, rel=1e-6)
            if name == "box":  # Mitsuba's box has its fast path (no filter evaluation)
                continue
            # Mitsuba evaluates in float32; its LLVM variants replace the gaussian's exp by a
            # degree-9 polynomial fit (measured: within 4.2e-4 of exp; CUDA uses exp itself)
            tol = 5e-4 if name == "gaussian" else 5e-6
            np.testing.assert_allclose(ours.eval(x), np.array(mf.eval(mi.Float(x))), rtol=0, atol=tol)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(RFILTERS))
def test_per_filter_within_2x_of_direct(variant, tmp_path, name):
    from links1_app.renderers import make_renderer
    rf = RFILTERS[name]
    ref = direct(rf, 1024, seed=1)
    theirs = relmse(direct(rf, SPP, seed=2), ref)
    path = write_scene(tmp_path, rf)
    core = make_renderer("core", path, spp=SPP).render()
    plugin = make_renderer("mitsuba", path, spp=SPP).render()
    assert relmse(core, ref) <= 2 * theirs, (relmse(core, ref), theirs)
    assert relmse(plugin, ref) <= 2 * theirs, (relmse(plugin, ref), theirs)
    # core (float64) and plugin (float32) see the same samples and weights
    np.testing.assert_allclose(plugin, core, rtol=0, atol=1e-5)
    if name == "gaussian":  # the test has teeth: a box-filtered image misses the reference
        box = make_renderer("core", write_scene(tmp_path, RFILTERS["box"]), spp=SPP).render()
        assert relmse(box, ref) > 2 * theirs


@pytest.mark.slow
@pytest.mark.parametrize("name", ["gaussian", "lanczos"])
def test_windows_and_batches_equal_full_frame(tmp_path, name, renderer_kind):
    """One window, or a batch of windows in one launch (render_batch), equals the same pixels of
    the full frame bit for bit: each window gathers its own border samples."""
    kind = renderer_kind
    from links1_app.renderers import make_renderer
    r = make_renderer(kind, write_scene(tmp_path, RFILTERS[name]), spp=4, aovs=("depth", "cost"))
    full = r.render()
    wins = [(0, 0, 8, 8), (8, 0, 8, 8), (12, 20, 20, 12), (1, 3, 30, 5)]
    for (x0, y0, w, h), batched in zip(wins, r.render_batch(wins)):
        assert np.array_equal(r.render((x0, y0, w, h)), full[y0:y0 + h, x0:x0 + w])
        assert np.array_equal(batched, full[y0:y0 + h, x0:x0 + w])


@pytest.mark.slow
def test_cli_workers_2_equal_one_process_with_lanczos(tmp_path, renderer_kind):
    """Units of a partitioned render gather the samples of their borders: two worker processes
    assemble the one-process image bit for bit."""
    kind = renderer_kind
    from links1_app.cli import main
    from links1.imaging.image import read_image
    path = write_scene(tmp_path, RFILTERS["lanczos"])
    a, b = tmp_path / "a.exr", tmp_path / "b.exr"
    base = ["render", path, "--renderer", kind, "--spp", "4", "--no-progress", *cli_variant(kind)]
    assert main(base + ["-o", str(a), "--workers", "0"]) == 0
    assert main(base + ["-o", str(b), "--workers", "2", "--partition", "subscreen"]) == 0
    ia, ib = (np.asarray(im[0] if isinstance(im, tuple) else im) for im in (read_image(a), read_image(b)))
    assert ia.shape == (RES, RES, 3) and np.array_equal(ia, ib)
