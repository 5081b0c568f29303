"""Reconstruction filters (links1/sensor/filters.py): closed-form weights, Mitsuba's ImageBlock gather
(checked against a brute-force per-pixel sum), and windows equal to the full frame bit for bit."""
from __future__ import annotations

import math

import numpy as np
import pytest

from links1.sensor.filters import FILTERS, Filter, FilterGather
from links1.scene.loader import load_string
from links1.tracing.render import render


def test_closed_form_weights():
    g = math.exp(-8.0)  # Mitsuba's gaussian: exp(-x^2 / 2 sigma^2) minus its value at radius 4 sigma
    assert Filter("gaussian").eval([0.0, 0.5, 2.0, 2.5]) == pytest.approx([1 - g, math.exp(-0.5) - g, 0, 0])
    assert Filter("tent", {"radius": 2.0}).eval([0.0, 1.0, -1.5, 2.0]) == pytest.approx([1, 0.5, 0.25, 0])
    # Mitchell-Netravali B = C = 1/3: 8/9 at 0, 1/18 at 1, 0 from 2 on
    assert Filter("mitchell").eval([0.0, 1.0, -1.0, 2.0]) == pytest.approx([8 / 9, 1 / 18, 1 / 18, 0])
    # Catmull-Rom interpolates: 1 at 0, 0 at the other integers
    assert Filter("catmullrom").eval([0.0, 1.0, 2.0]) == pytest.approx([1, 0, 0], abs=1e-15)
    x = 0.3
    lanczos = math.sin(math.pi * x) * math.sin(math.pi * x / 3) / (math.pi * x * math.pi * x / 3)
    assert Filter("lanczos").eval([0.0, x, 1.0, 2.0, 3.5]) == pytest.approx([1, lanczos, 0, 0, 0], abs=1e-15)


@pytest.mark.parametrize("name", ["mitchell", "catmullrom"])
def test_cubic_filters_are_partitions_of_unity(name):
    x = np.linspace(0.0, 1.0, 17)
    total = sum(Filter(name).eval(x - k) for k in range(-3, 4))
    np.testing.assert_allclose(total, 1.0, rtol=0, atol=1e-14)


def test_radius_and_border_as_mitsuba():
    # Mitsuba: border = ceil(radius - 0.5 - 2 RayEpsilon)
    assert [(Filter(n).radius, Filter(n).border) for n in FILTERS] == \
        [(0.5, 0), (1.0, 1), (2.0, 2), (2.0, 2), (2.0, 2), (3.0, 3)]
    assert Filter("tent", {"radius": 1.5}).border == 1
    with pytest.raises(ValueError, match="no parameter 'sigma'"):
        Filter("gaussian", {"sigma": 1.0})


def brute_force(filt, values, offx, offy, W, H):
    """Mitsuba's ImageBlock::put, one sample at a time: the sample at film position p adds
    f(x - (p - 1/2)) per axis to the pixels x in [ceil(p - 1/2 - r), floor(p - 1/2 + r)]."""
    r = filt.radius
    num, den = np.zeros((H, W, values.shape[-1])), np.zeros((H, W))
    for jy in range(H):
        for jx in range(W):
            for s in range(values.shape[2]):
                px, py = jx + offx[jy, jx, s] - 0.5, jy + offy[jy, jx, s] - 0.5
                for iy in range(max(0, math.ceil(py - r)), min(H - 1, math.floor(py + r)) + 1):
                    for ix in range(max(0, math.ceil(px - r)), min(W - 1, math.floor(px + r)) + 1):
                        w = float(filt.eval(ix - px)) * float(filt.eval(iy - py))
                        num[iy, ix] += w * values[jy, jx, s]
                        den[iy, ix] += w
    return num / np.where(den == 0, 1, den)[:, :, None]


@pytest.mark.parametrize("name", ["box", "tent", "gaussian", "lanczos"])
def test_gather_equals_mitsubas_splatting(name):
    rng = np.random.default_rng(7)
    W, H, spp = 9, 7, 3
    vals = rng.random((H, W, spp, 2))
    ox, oy = rng.random((H, W, spp)), rng.random((H, W, spp))
    filt = Filter(name)
    expect = brute_force(filt, vals, ox, oy, W, H)
    for window in [(0, 0, W, H), (2, 1, 4, 5), (6, 4, 3, 3)]:
        g = FilterGather(filt, window, (W, H))
        sx0, sy0, sw, sh = g.sample_window
        for s in range(spp):
            g.add(vals[sy0:sy0 + sh, sx0:sx0 + sw, s], ox[sy0:sy0 + sh, sx0:sx0 + sw, s],
                  oy[sy0:sy0 + sh, sx0:sx0 + sw, s])
        x0, y0, w, h = window
        np.testing.assert_allclose(g.result(), expect[y0:y0 + h, x0:x0 + w], rtol=1e-12, atol=1e-15)


SCENE = """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="40"/>
    <transform name="to_world"><lookat origin="0,0,5" target="0,0,0" up="0,1,0"/></transform>
    <film type="hdrfilm"><integer name="width" value="23"/><integer name="height" value="17"/>{rf}</film>
  </sensor>
  <shape type="sphere"><float name="radius" value="1"/><bsdf type="diffuse"/></shape>
  <emitter type="point"><point name="position" value="2,3,4"/><rgb name="intensity" value="20"/></emitter>
</scene>"""


@pytest.mark.parametrize("rf", ["", '<rfilter type="lanczos"/>'])
def test_windows_equal_the_full_frame(rf):
    scene = load_string(SCENE.format(rf=rf))
    assert scene.camera.rfilter.border >= 2
    full = render(scene, spp=4, seed=5, aovs=("depth", "cost"))
    for x0, y0, w, h in [(0, 0, 5, 4), (4, 3, 11, 9), (18, 12, 5, 5), (1, 0, 22, 17)]:
        part = render(scene, spp=4, seed=5, window=(x0, y0, w, h), aovs=("depth", "cost"))
        assert np.array_equal(part, full[y0:y0 + h, x0:x0 + w])


def test_filter_blurs_edges_and_weights_are_normalised():
    box = render(load_string(SCENE.format(rf='<rfilter type="box"/>')), spp=4, seed=5)
    gauss = render(load_string(SCENE.format(rf="")), spp=4, seed=5)
    assert np.abs(box - gauss).max() > 1e-2  # the silhouette is blurred
    # a constant image stays constant up to the film's edges and corners (Mitsuba divides by
    # the summed weights), also with lanczos' negative lobes
    for name in ("gaussian", "lanczos"):
        g = FilterGather(Filter(name), (0, 0, 6, 5), (6, 5))
        rng = np.random.default_rng(1)
        for _ in range(2):
            g.add(np.full((5, 6, 1), 0.25), rng.random((5, 6)), rng.random((5, 6)))
        np.testing.assert_allclose(g.result(), 0.25, rtol=1e-14)
