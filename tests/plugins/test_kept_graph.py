"""The kept derivative graph of ``mi.render(scene, params)`` (gradients.py,
``Gradients.render_keeping_graph``; ``Tuning.keep_graph``).

With the graph kept (an explicit choice, ``Tuning.keep_graph``; off by default), where the
frame does not depend on the seed (spp 1: pixel centres; analytic lights only) and is one
block, ``mi.render`` with parameters renders the derivative pass's frame once and keeps its graph, and ``dr.backward`` propagates through it instead of rendering the frame again with
``seed_grad``. The gradients must be those of the second render (the same function of the
parameters, so equal up to float32 rounding of the operations' order: the kernels are the
same, the tolerance below is 1e-5 relative), the frame must not be rendered again, and where
the seed matters, or the frame is several blocks, nothing is kept.
"""
from __future__ import annotations

import numpy as np
import pytest

from .test_geometry_gradients import BLOB
from .test_geometry_gradients import CAMERA as GEO_CAMERA
from .test_gradients import LIGHTS_MOVE, MOVE_KEYS, SHADING, SHADING_KEYS, load

pytestmark = pytest.mark.mitsuba

BLOB_KEYS = ["links1_whitted.blob.centers", "links1_whitted.blob.weights", "links1_whitted.blob.bsdf.diffuse.value"]


def gradients(scene, keys, weights, keep_graph, spp=0, count=None):
    """The reverse gradients of Σ weights · image on ``params[keys]`` (numpy, one per key),
    with ``Tuning.keep_graph``; ``count``: a list that gets one entry per derivative-pass render
    ``render_backward`` makes."""
    import drjit as dr
    import mitsuba as mi

    from links1_mitsuba import tuning
    params = mi.traverse(scene)
    for k in keys:
        dr.enable_grad(params[k])
    with tuning.tuned(keep_graph=keep_graph):
        img = mi.render(scene, params, spp=spp)
        kept = scene.integrator().info()["kept_graph"]
        before = len(count) if count is not None else 0
        dr.backward(dr.sum(img * mi.TensorXf(weights.astype(np.float32)), axis=None))
        renders = (len(count) - before) if count is not None else None
    g = [np.array(dr.grad(params[k]), dtype=np.float64).ravel() for k in keys]
    for k in keys:
        dr.disable_grad(params[k])
    return g, kept, renders


@pytest.fixture
def render_count(monkeypatch):
    """Counts the derivative pass's renders of every ``links1_whitted`` (its gradients'
    ``_render_ad``)."""
    from links1_mitsuba.gradients import Gradients
    cls = Gradients
    calls = []
    orig = cls._render_ad

    def counted(self, *a, **kw):
        calls.append(1)
        return orig(self, *a, **kw)
    monkeypatch.setattr(cls, "_render_ad", counted)
    return calls


def _blob(tmp_path):
    from .test_geometry_gradients import load as geo_load
    return geo_load(tmp_path, BLOB, camera=GEO_CAMERA.format(depth=3))


@pytest.mark.slow
@pytest.mark.parametrize("case", ["shading", "lights", "blob"])
def test_kept_graph_gives_the_gradients_of_a_second_render(variant, render_count, tmp_path, case):
    """Every parameter family (Phong and Mitsuba colours, the lights' values and positions,
    a blob's centres and weights) at once, under a random pixel weighting: the kept graph's
    gradients equal those of the derivative pass rendered again, and the frame is not rendered
    again for ``dr.backward``."""
    if case == "shading":
        scene, keys = load(SHADING, rfilter=""), SHADING_KEYS   # Gaussian film, depth 4
    elif case == "lights":
        scene, keys = load(LIGHTS_MOVE, depth=1), MOVE_KEYS
    else:
        scene, keys = _blob(tmp_path), BLOB_KEYS
    w = np.random.default_rng(5).uniform(0.0, 1.0, (18, 24, 3))
    again, kept0, n0 = gradients(scene, keys, w, keep_graph=False, count=render_count)
    once, kept1, n1 = gradients(scene, keys, w, keep_graph=True, count=render_count)
    assert (kept0, n0) == (False, 1)          # the pass renders the frame in render_backward
    assert (kept1, n1) == (True, 0)           # rendered once, by mi.render
    for k, a, b in zip(keys, again, once):
        assert np.any(a != 0), k
        np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-6 * np.abs(a).max(), err_msg=k)


@pytest.mark.slow
def test_no_graph_kept_where_the_seed_matters_or_over_blocks(variant, render_count, monkeypatch):
    """spp 2 (the samples' places depend on the seed, and seed_grad is another seed), an area
    light (sampled), and a frame of several blocks render the derivative pass again in
    render_backward, and their gradients still flow."""
    from links1_mitsuba import gradients as grad_mod
    w = np.ones((18, 24, 3))
    scene = load(SHADING)
    g, kept, n = gradients(scene, ["ball.bsdf.diffuse.value"], w, keep_graph=True, spp=2, count=render_count)
    assert (kept, n) == (False, 1) and np.all(g[0] > 0)
    area = SHADING.replace('<emitter type="point" id="mp">', """<shape type="rectangle"><transform name="to_world">
        <rotate x="1" angle="90"/><translate y="4"/></transform><emitter type="area"><rgb name="radiance" value="2"/>
        </emitter></shape><emitter type="point" id="mp">""")
    g, kept, n = gradients(load(area), ["ball.bsdf.diffuse.value"], w, keep_graph=True, count=render_count)
    assert (kept, n) == (False, 1) and np.all(g[0] > 0)
    monkeypatch.setattr(grad_mod, "AD_BLOCK_LANES", 24 * 5)   # 18 rows of 24: several blocks
    g, kept, n = gradients(scene, ["ball.bsdf.diffuse.value"], w, keep_graph=True, count=render_count)
    assert kept is False and n > 1 and np.all(g[0] > 0)


@pytest.mark.slow
def test_a_kept_graph_is_dropped_by_the_next_frame_and_by_forward_mode(variant):
    """A graph nobody propagated is dropped by the next render (no graph outlives its frame),
    and forward mode after a kept frame differentiates as usual (its tangents would otherwise
    enter the kept graph, outside the pass's dr.isolate_grad scope)."""
    import drjit as dr
    import mitsuba as mi

    from links1_mitsuba import tuning
    scene = load(SHADING)
    integ = scene.integrator()
    params = mi.traverse(scene)
    key = "ball.bsdf.diffuse.value"
    dr.enable_grad(params[key])
    with tuning.tuned(keep_graph=True):
        mi.render(scene, params)
        assert integ.info()["kept_graph"]
        dr.disable_grad(params[key])
        mi.render(scene)                                # a frame with nothing attached
        assert not integ.info()["kept_graph"]
        dr.enable_grad(params[key])
        img = mi.render(scene, params)
        assert integ.info()["kept_graph"]
    mi.render(scene, params)                            # keeping it is a choice: off by default
    assert not integ.info()["kept_graph"]
    img = None
    with tuning.tuned(keep_graph=True):
        img = mi.render(scene, params)
    dr.set_grad(params[key], mi.Color3f(1.0, 0.0, 0.0))
    dr.forward_to(img)
    tangent = np.array(dr.grad(img), dtype=np.float64)
    assert not integ.info()["kept_graph"]
    dr.disable_grad(params[key])
    g, _, _ = gradients(scene, [key], np.ones((18, 24, 3)), keep_graph=True)
    # the dot-product test: Σ (J e_r) = (Jᵀ 1) · e_r
    np.testing.assert_allclose(tangent.sum(), g[0][0], rtol=1e-4)


@pytest.mark.slow
def test_two_frames_then_one_backward(variant, render_count):
    """Two sensors' frames rendered before one dr.backward of their losses' sum: the second
    render drops the first's kept graph, so the first frame's pass is rendered again (the
    sensor is checked) and the gradient is the sum of the two frames' own gradients."""
    import drjit as dr
    import mitsuba as mi
    from tests import scenes

    from .test_gradients import camera
    second = scenes.perspective("2, 2.5, 5", "0, 0.5, 0", fov=40, width=24, height=18, rfilter="")
    scene = mi.load_string(scenes.scene(camera(4, rfilter=""), second, SHADING))
    assert len(scene.sensors()) == 2
    keys = ["ball.bsdf.diffuse.value", "lp.position"]
    params = mi.traverse(scene)

    def grads(sensors):
        for k in keys:
            dr.enable_grad(params[k])
        loss = sum(dr.sum(mi.render(scene, params, sensor=s), axis=None) for s in sensors)
        dr.backward(loss)
        g = [np.array(dr.grad(params[k]), dtype=np.float64).ravel() for k in keys]
        for k in keys:
            dr.disable_grad(params[k])
        return g
    from links1_mitsuba import tuning
    with tuning.tuned(keep_graph=True):
        a, b = grads([0]), grads([1])
        n = len(render_count)
        both = grads([0, 1])
    assert len(render_count) - n == 1      # the first frame's pass rendered again, the second kept
    for k, ga, gb, g in zip(keys, a, b, both):
        assert np.any(ga != 0) and np.any(gb != 0), k
        np.testing.assert_allclose(g, ga + gb, rtol=1e-5, atol=1e-6 * np.abs(g).max(), err_msg=k)
