"""The derivative pass over the samples that see something (``raytree_ad.trace_tree_ad``).

Where no environment shines and no ray spawns children, the pass traces the camera rays that
hit something alone (``raytree_ad._seeing``) and puts their trees back in their lanes, the
others 0. Its gradients must be those of the pass over every sample (``SEEING_MAX`` below 0:
the trees of all lanes, as the primal traces them; checked against finite differences and the
float64 core by the other gradient tests), in reverse and forward mode, up to float32 rounding
of the sums' order (reverse-mode scatter-adds run in any order: 1e-5 relative), for geometry
(a quadric's and a blob's), shading and light parameters at once.
"""
from __future__ import annotations

import numpy as np
import pytest

from tests.scenes import perspective, scene, whitted

from .test_geometry_gradients import LIGHTS

pytestmark = pytest.mark.mitsuba

# a Phong quadric sphere and a blob before black (no floor: most camera rays escape)
BODY = f"""
  <shape type="links1_quadric" id="ball"><string name="kind" value="sphere"/>
    <transform name="to_world"><scale value="0.8"/><translate x="-0.9" y="1.2" z="0.2"/></transform>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.5, 0.4, 0.3"/><rgb name="specular" value="0.3"/>
      <rgb name="reflectance" value="0"/><float name="exponent" value="12"/></bsdf></shape>
  <shape type="links1_blob" id="blob">
    <string name="centers" value="0.8 1.2 0 1 0.6,  1.2 1.6 0.2 0.8 0.5"/>
    <float name="threshold" value="0.5"/>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.3, 0.5, 0.4"/><rgb name="specular" value="0.2"/>
      <rgb name="reflectance" value="0"/></bsdf></shape>
  {LIGHTS}"""

KEYS = ["links1_whitted.ball.to_world", "links1_whitted.blob.centers", "links1_whitted.ball.bsdf.diffuse.value",
        "lp.position", "mp.position"]


def _load(rfilter="box"):
    import links1_mitsuba as lm
    camera = perspective("0, 3, 6", "0, 1.2, 0", fov=40, width=24, height=18, spp=2, rfilter=rfilter)
    return lm.load_string(scene(whitted(1) + camera, BODY))


def _reverse(sc, weights):
    import drjit as dr
    import mitsuba as mi
    params = mi.traverse(sc)
    for k in KEYS:
        dr.enable_grad(params[k])
    img = mi.render(sc, params, seed=3)
    dr.backward(dr.sum(img * mi.TensorXf(weights), axis=None))
    out = [np.array(_flat(dr.grad(params[k])), dtype=np.float64) for k in KEYS]
    for k in KEYS:
        dr.disable_grad(params[k])
    return out


def _flat(v):
    """A Dr.Jit value (a transform: its matrix) as a flat numpy array."""
    return np.ravel(np.array(v.matrix if hasattr(v, "matrix") else v))


def _forward(sc, key):
    import drjit as dr
    import mitsuba as mi
    params = mi.traverse(sc)
    v = params[key]
    dr.enable_grad(v)
    dr.set_grad(v, type(v)(*[1.0] * dr.size_v(v)) if dr.size_v(v) > 1 else 1.0)
    params.update()
    img = mi.render(sc, params, seed=3)
    dr.forward_to(img)
    g = np.array(dr.grad(img), dtype=np.float64)
    dr.disable_grad(v)
    return g


@pytest.mark.slow
@pytest.mark.parametrize("rfilter", ["box", "gaussian"])
def test_the_seeing_samples_alone_give_the_gradients_of_all(variant, monkeypatch, rfilter):
    """Reverse mode with either filter (a box filter's pass sums the seeing samples into their
    pixels, raytree_ad.SEEING_FILM; another filter's puts them back in every lane by a scatter,
    raytree_ad.SCATTERED_BACK, and reconstructs), then forward mode: the forward passes follow
    reverse ones on the same scene, so a film value kept from a reverse pass (the gaussian's
    weight sums) must carry no gradient into them."""
    from links1_mitsuba import raytree_ad
    sc = _load(rfilter)
    weights = np.random.default_rng(11).uniform(0.0, 1.0, (18, 24, 3)).astype(np.float32)
    traced = []
    real = raytree_ad._seeing
    monkeypatch.setattr(raytree_ad, "_seeing", lambda *a: traced.append(real(*a)) or traced[-1])
    seeing_r = _reverse(sc, weights)
    seeing_f = _forward(sc, "lp.position")
    assert traced and all(t is not None for t in traced)           # the pass took the seeing lanes
    lanes = [len(np.asarray(t[0])) for t in traced]
    assert 0 < min(lanes) and max(lanes) < 0.5 * 18 * 24 * 2        # most camera rays escape here
    monkeypatch.setattr(raytree_ad, "SEEING_MAX", -1.0)            # every lane traced
    all_r = _reverse(sc, weights)
    for k, a, b in zip(KEYS, seeing_r, all_r):
        assert np.any(b != 0), k
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6 * np.abs(b).max(), err_msg=k)
    all_f = _forward(sc, "lp.position")
    assert np.any(all_f != 0)
    np.testing.assert_allclose(seeing_f, all_f, rtol=1e-5, atol=1e-7)


def test_seeing_blocks_cover_the_window_once_within_the_budget():
    """Blocks counted in the lanes the pass puts on the AD tape: the seeing samples where few
    of a block's camera rays hit something, else all of them; each block's lanes at most the
    budget (or one row), its samples at most SEEING_CAP budgets, the rows each once in order."""
    from links1_mitsuba import raytree_ad
    from links1_mitsuba.gradients import SEEING_CAP, seeing_blocks
    rng = np.random.default_rng(3)
    for w, h, spp, budget in ((64, 48, 4, 3000), (32, 100, 1, 500), (16, 16, 2, 10)):
        hits = rng.integers(0, w * spp + 1, h) * (rng.uniform(size=h) < 0.5)
        blocks = seeing_blocks((5, 7, w, h), hits, spp, budget)
        assert [b[1] for b in blocks] == list(np.cumsum([7] + [b[3] for b in blocks[:-1]]))
        assert sum(b[3] for b in blocks) == h and all(b[0] == 5 and b[2] == w and b[3] >= 1 for b in blocks)
        for x0, y0, _, bh in blocks:
            lanes, seen = bh * w * spp, int(hits[y0 - 7:y0 - 7 + bh].sum())
            taped = seen if raytree_ad.seeing_alone(lanes, seen) else lanes
            assert bh == 1 or (taped <= budget and lanes <= SEEING_CAP * budget)
    # few hits: one block of more samples than the budget; all hit: blocks of the budget's lanes
    assert len(seeing_blocks((0, 0, 256, 256), np.full(256, 100), 4)) == 1
    assert len(seeing_blocks((0, 0, 256, 256), np.full(256, 1024), 4)) == 2


@pytest.mark.slow
@pytest.mark.parametrize("budget, blocks", [(300, 1), (200, 2)])
def test_blocks_take_the_hits_counted_before_the_pass(variant, monkeypatch, budget, blocks):
    """Where the window is more than one block of rows, the pass counts its camera rays' hits
    first (its own tables) and each block takes its part of that mask (raytree_ad.SEEING): the
    window's camera rays are traced for their hits once a pass, not once more in each block;
    a block that takes the seeing lanes found there makes their rays from their sample ids
    (raytree_ad.RAYS_OF_SEEING); the blocks' gradients are those of the pass over every lane
    (rtol 1e-5, as above)."""
    from links1_mitsuba import gradients, launch, raytree_ad
    sc = _load()
    weights = np.random.default_rng(5).uniform(0.0, 1.0, (18, 24, 3)).astype(np.float32)
    monkeypatch.setattr(gradients, "AD_BLOCK_LANES", budget)
    traced, seen, made = [], [], []
    real_hits, real_seeing = raytree_ad.hits, raytree_ad._seeing
    counting = lambda *a: traced.append(1) or real_hits(*a)   # noqa: E731
    monkeypatch.setattr(raytree_ad, "hits", counting)
    monkeypatch.setattr(launch, "hits", counting)
    monkeypatch.setattr(raytree_ad, "_seeing", lambda *a: made.append(a[8:] == (True,)) or
                        seen.append(real_seeing(*a)) or seen[-1])
    got = _reverse(sc, weights)
    assert len(traced) == 1                                   # the window's camera rays, once
    assert len(seen) == blocks and all(s is not None for s in seen)
    assert made == [blocks == 1] * blocks     # the one block's rays made from its lanes' sample ids
    assert sum(len(np.asarray(s[0])) for s in seen) < 0.5 * 18 * 24 * 2
    monkeypatch.setattr(raytree_ad, "SEEING_MAX", -1.0)      # every lane traced, in one block
    monkeypatch.setattr(gradients, "AD_BLOCK_LANES", 1 << 17)
    ref = _reverse(sc, weights)
    for k, a, b in zip(KEYS, got, ref):
        assert np.any(b != 0), k
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6 * np.abs(b).max(), err_msg=k)


@pytest.mark.slow
def test_seeing_film_is_the_box_film_of_every_lane(variant, monkeypatch):
    """A reverse-mode pass's frame made from its seeing samples summed into their pixels
    (``raytree_ad.SEEING_FILM``) is the box film of every lane (film.reconstruct, the others'
    RGB 0), bit for bit, and its gradients are those of that film (rtol 1e-5, as above)."""
    import drjit as dr
    from links1_mitsuba import gradients, raytree_ad
    sc = _load()
    weights = np.random.default_rng(7).uniform(0.0, 1.0, (18, 24, 3)).astype(np.float32)
    real, frames = gradients.Gradients._render_ad, []

    def kept(self, *a, **k):
        img = real(self, *a, **k)
        frames.append(np.array(dr.detach(img)))
        return img
    monkeypatch.setattr(gradients.Gradients, "_render_ad", kept)
    got = []
    for on in (True, False):
        monkeypatch.setattr(raytree_ad, "SEEING_FILM", on)
        got.append(_reverse(sc, weights))
    assert len(frames) == 2 and np.any(frames[1] != 0)
    assert np.array_equal(frames[0], frames[1])
    for k, a, b in zip(KEYS, *got):
        assert np.any(b != 0), k
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6 * np.abs(b).max(), err_msg=k)
