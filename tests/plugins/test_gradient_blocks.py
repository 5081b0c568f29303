"""The derivative pass of ``links1_whitted`` in blocks of rows.

A block renders its filter border's samples too, so its pixels are the frame's and the loss
``Σ g_p I_p`` splits exactly by blocks: the gradients with blocks equal those of one block up
to the order in which float32 contributions are summed into each parameter's gradient (each
block's sum is added to the running total: a relative difference of a few float32 ulps of the
total, ~1e-6; tolerance 1e-5 relative). Forward mode renders the frame in one block
(``render_forward``'s docstring says why); its blocks are not tested here. A
Gaussian film, so that blocks share border samples, and a budget that cuts the 24x18 film
into 4+ blocks.
"""
from __future__ import annotations

import numpy as np
import pytest

from .test_geometry_gradients import SPHERE
from .test_geometry_gradients import load as load_geo
from .test_gradients import SHADING, load

pytestmark = pytest.mark.mitsuba

BUDGET = 200     # sample lanes: 24 columns (the border clipped) × spp 1 → 8 rows with the border, 4 without


def test_row_blocks_cover_the_window_once_within_the_budget():
    from links1_mitsuba.gradients import row_blocks
    for win, size, border, spp, budget in [((0, 0, 24, 18), (24, 18), 2, 1, BUDGET),
                                            ((3, 5, 10, 7), (24, 18), 1, 4, 200),
                                            ((0, 0, 256, 256), (256, 256), 0, 1, 1 << 18),
                                            ((0, 0, 50, 9), (50, 9), 2, 16, 10)]:
        blocks = row_blocks(win, size, border, spp, budget)
        rows = [y for x0, y0, w, h in blocks for y in range(y0, y0 + h)]
        assert rows == list(range(win[1], win[1] + win[3]))
        assert all((x0, w) == (win[0], win[2]) and h >= 1 for x0, _, w, h in blocks)
        cols = min(size[0], win[0] + win[2] + border) - max(0, win[0] - border)
        for x0, y0, w, h in blocks:
            lanes = cols * (min(size[1], y0 + h + border) - max(0, y0 - border)) * spp
            assert lanes <= budget or h == 1, (win, blocks)
    assert len(row_blocks((0, 0, 256, 256), (256, 256), 0, 1)) == 1     # 256², spp 1: one block
    assert len(row_blocks((0, 0, 1024, 1024), (1024, 1024), 0, 1)) == 8


def _grads(scene, keys, weights, monkeypatch, budget):
    import drjit as dr
    import mitsuba as mi
    from links1_mitsuba import gradients
    monkeypatch.setattr(gradients, "AD_BLOCK_LANES", budget)
    widths = []
    from links1_mitsuba.launch import Launches
    cls = Launches
    real = cls._launch

    def counted(self, tables, scene_, tracer, sid, spp_, seeds, want, mode=dr.ADMode.Primal, compact=False):
        if mode != dr.ADMode.Primal:     # a derivative pass's launch
            widths.append(dr.width(sid))
        return real(self, tables, scene_, tracer, sid, spp_, seeds, want, mode, compact)
    monkeypatch.setattr(cls, "_launch", counted)
    params = mi.traverse(scene)
    for k in keys:
        dr.enable_grad(params[k])
    img = mi.render(scene, params)
    dr.backward(dr.sum(img * mi.TensorXf(weights), axis=None))
    out = {k: np.array(getattr(dr.grad(params[k]), "matrix", dr.grad(params[k])), dtype=np.float64).ravel()
           for k in keys}
    for k in keys:
        dr.disable_grad(params[k])
    monkeypatch.setattr(cls, "_launch", real)
    return out, widths


@pytest.mark.slow
@pytest.mark.parametrize("case", ["shading", "quadric"])
def test_blocks_give_the_gradients_of_one_block(variant, tmp_path, monkeypatch, case):
    if case == "shading":
        scene = load(SHADING, rfilter="")
        keys = ["ball.bsdf.diffuse.value", "lp.position", "mp.intensity.value", "glass.bsdf.transmittance.value"]
    else:
        import links1_mitsuba as lm
        path = tmp_path / "s.xml"
        load_geo(tmp_path, SPHERE)      # the file, with its box filter replaced by the default gaussian
        path.write_text((tmp_path / "scene.xml").read_text().replace('<rfilter type="box"/>', ""))
        scene = lm.load_file(str(path))
        keys = ["links1_whitted.ball.to_world", "lp.L1.value"]
    w = np.random.default_rng(5).normal(size=(18, 24, 3)).astype(np.float32)
    one, w1 = _grads(scene, keys, w, monkeypatch, 1 << 18)
    many, wn = _grads(scene, keys, w, monkeypatch, BUDGET)
    assert len(w1) == 1 and w1[0] == 24 * 18       # one block: the whole film (no border to clip)
    assert len(wn) >= 4 and max(wn) <= BUDGET, wn  # every AD launch within the budget
    for k in keys:
        assert np.abs(one[k]).max() > 1e-3, (k, one[k])
        assert np.allclose(many[k], one[k], rtol=1e-5, atol=1e-5 * np.abs(one[k]).max()), (k, one[k], many[k])


@pytest.mark.slow
def test_reverse_blocks_with_a_parameter_made_from_another(variant, tmp_path, monkeypatch):
    """A links1_quadric's translation ``th`` made into its ``to_world`` before ``mi.render``:
    the edge ``th`` → ``to_world`` serves every block, not only the first (a traversal that
    cleared edges would drop it after the first block)."""
    import mitsuba as mi
    from links1_mitsuba import gradients

    from .test_geometry_gradients import param_grad, transform_of
    scene = load_geo(tmp_path, SPHERE)
    key = "links1_whitted.ball.to_world"
    m0 = np.array(mi.traverse(scene)[key].matrix, dtype=np.float64).reshape(4, 4)
    w = np.random.default_rng(9).normal(size=(18, 24, 3)).astype(np.float32)
    make = (lambda th: transform_of(mi, 1, th, m0))
    one = param_grad(scene, key, make, 0.0, w)
    monkeypatch.setattr(gradients, "AD_BLOCK_LANES", BUDGET)
    split = param_grad(scene, key, make, 0.0, w)
    assert abs(one) > 0.1, one
    assert abs(split - one) <= 1e-5 * abs(one), (one, split)
