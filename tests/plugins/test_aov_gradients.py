"""Gradients through ``links1_whitted`` with AOVs: the AOV channels are detached.

``mi.render`` with parameters and an integrator that writes AOVs (``aovs="depth,id"``) hands
``render_backward`` a gradient of 3 + AOV channels and expects ``render_forward`` to return as
many. The colour channels' derivatives are those of the same integrator without AOVs (forward:
bit for bit; backward: to float32 rounding, the parameter's gradient being a sum that the
threads of a reverse pass add in any order); the AOV channels carry none (forward: zeros;
backward: their gradient is dropped).
"""
from __future__ import annotations

import numpy as np

KEY = "ball.bsdf.reflectance.value"


def _scene(mi):
    t = mi.ScalarTransform4f()
    return mi.load_dict({
        "type": "scene",
        "sensor": {"type": "perspective", "fov": 40,
                   "to_world": t.look_at(origin=[0, 2, 5], target=[0, 0.5, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 32, "height": 24, "rfilter": {"type": "box"}}},
        "floor": {"type": "rectangle", "to_world": t.rotate([1, 0, 0], -90).scale(5),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.5, 0.5, 0.5]}}},
        "ball": {"type": "sphere", "center": [0, 0.7, 0], "radius": 0.7,
                 "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.2, 0.4, 0.7]}}},
        "light": {"type": "point", "position": [2, 4, 3], "intensity": {"type": "rgb", "value": [30, 30, 30]}},
    })


def _gradient(mode: str, aovs: str):
    """d loss / d the ball's reflectance (backward) or d image / d its red (forward)."""
    import drjit as dr
    import mitsuba as mi
    scene = _scene(mi)
    integrator = mi.load_dict({"type": "links1_whitted", "aovs": aovs})
    params = mi.traverse(scene)
    dr.enable_grad(params[KEY])
    params.update()
    if mode == "forward":
        dr.set_grad(params[KEY], mi.Color3f(1, 0, 0))
    img = mi.render(scene, params, integrator=integrator, spp=2, seed=3, seed_grad=5)
    if mode == "forward":
        dr.forward_to(img)
        return np.array(dr.grad(img))
    dr.backward(dr.sum(img[..., :3], axis=None))
    return np.array(dr.grad(params[KEY]))


def test_reverse_mode_with_aovs_equals_reverse_mode_without(variant):
    plain, with_aovs = _gradient("backward", ""), _gradient("backward", "depth,id")
    assert np.all(np.isfinite(plain)) and np.abs(plain).max() > 0
    # (a sum over every pixel's samples, which the threads add in any order: two runs of the
    # same render were 1 ulp apart in 1 of 10 tries)
    np.testing.assert_allclose(with_aovs, plain, rtol=1e-5, atol=0)


def test_forward_mode_with_aovs_has_zero_aov_channels(variant):
    plain, with_aovs = _gradient("forward", ""), _gradient("forward", "depth,id")
    assert plain.shape == (24, 32, 3) and with_aovs.shape == (24, 32, 5)
    assert np.abs(plain).max() > 0
    np.testing.assert_array_equal(with_aovs[..., :3], plain)
    assert not np.any(with_aovs[..., 3:])
