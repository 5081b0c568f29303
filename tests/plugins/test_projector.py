"""Mitsuba's ``projector`` emitter in both renderers: a delta light projecting an image.

A projector 3 units above a diffuse floor (albedo 0.8) looks straight down through a frustum
of horizontal field of view 50° and the aspect of its 5 x 3 ``bitmap`` (nearest filter),
``scale`` 2. Mitsuba's ``Projector::sample_direction`` gives a point at ``(x, y, z)`` in the
light's frame ``π · scale · irradiance(uv) / (z² cos θ)``, so straight below it the floor's
radiance is ``0.8 · 2 · irradiance(1/2, 1/2) / 9`` (the centre cell), and the lit patch is
``2 · 3 tan 25°`` wide and ``3/5`` of that deep. Both renderers match Mitsuba's own ``direct``
(bsdf_samples 0): exactly where a pixel sees one cell, and over the whole image within 1.5x
its relMSE at the same spp (the only noise is the pixel footprint across the cells' edges);
and each other."""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from links1_app.renderers import make_renderer

from tests import scenes

from .conftest import assert_both_match_mitsuba_direct, mitsuba_direct

pytestmark = pytest.mark.mitsuba

W = H = 40
CELLS = np.array([[[1.0, 0.2, 0.1], [0.3, 0.9, 0.2], [0.1, 0.2, 1.0], [0.8, 0.8, 0.1], [0.4, 0.1, 0.6]],
                  [[0.2, 0.5, 0.9], [0.9, 0.9, 0.9], [0.6, 0.3, 0.2], [0.1, 0.7, 0.7], [1.0, 0.5, 0.0]],
                  [[0.5, 0.5, 0.5], [0.0, 0.3, 0.6], [0.7, 0.1, 0.3], [0.2, 0.2, 0.9], [0.6, 0.9, 0.3]]])
SCENE = scenes.scene(scenes.integrator("direct", bsdf_samples=0),
                     scenes.perspective("0, 4, 0.01", "0, 0, 0", up="0, 0, -1", fov=50, width=W, height=H,
                                        spp=None), """
  <emitter type="projector"><float name="fov" value="50"/><float name="scale" value="2"/>
    <texture name="irradiance" type="bitmap"><string name="filename" value="{image}"/>
      <string name="filter_type" value="nearest"/></texture>
    <transform name="to_world"><lookat origin="0, 3, 0" target="0, 0, 0" up="0, 0, 1"/></transform></emitter>
  <shape type="rectangle"><transform name="to_world"><scale value="5"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.8"/></bsdf></shape>""")


@pytest.fixture
def scene(tmp_path, llvm):
    import mitsuba as mi
    image = tmp_path / "cells.exr"
    mi.Bitmap(CELLS.astype(np.float32)).write(str(image))
    path = tmp_path / "projector.xml"
    path.write_text(SCENE.format(W=W, H=H, image=image))
    return str(path)


def _render(kind, path, spp):
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # nothing ignored
        return np.asarray(make_renderer(kind, path, spp=spp, max_depth=1).render(), dtype=np.float64)[..., :3]


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["core", "mitsuba"])
def test_projector_lights_its_frustum_with_its_image(scene, kind):
    """At the pixel centres (spp 1): the lit patch is the frustum's, and on a floor facing the
    projector every lit point gets its cell's irradiance exactly (the 1/(z² cos θ) and the
    floor's cos θ cancel): radiance 0.8 · 2 · cell / 9."""
    img = _render(kind, scene, spp=1)
    # the pixel centres on the floor: the camera looks down from 4 (film left = world -x, up = -z)
    t = 4.0 * math.tan(math.radians(25.0))
    c = -(1.0 - 2.0 * (np.arange(W) + 0.5) / W) * t
    x, z = c[None, :], c[:, None]
    half_w = 3.0 * math.tan(math.radians(25.0))
    half_d = half_w * 3.0 / 5.0      # the image's aspect
    px = 2.0 * t / W                 # a pixel's width on the floor
    inside = (np.abs(x) < half_w - px) & (np.abs(z) < half_d - px)
    outside = (np.abs(x) > half_w + px) | (np.abs(z) > half_d + px)
    lit = img.sum(axis=2) > 0
    assert lit[inside].all() and not lit[outside].any() and inside.sum() > 200
    cell = img / (0.8 * 2.0 / 9.0)
    dist = np.abs(cell[:, :, None, :] - CELLS.reshape(1, 1, 15, 3)).max(axis=3).min(axis=2)
    u, v = 0.5 - x / (2 * half_w), 0.5 - z / (2 * half_d)
    clear = inside & (np.abs(u * 5 - np.round(u * 5)) > 0.05) & (np.abs(v * 3 - np.round(v * 3)) > 0.05)
    assert dist[clear].max() < 1e-4
    assert len({tuple(np.round(p, 3)) for p in cell[clear]}) == 15
    centre = np.abs(u - 0.5) + np.abs(v - 0.5) < 0.05
    assert np.abs(cell[centre] - CELLS[1, 2]).max() < 1e-4


def _cells_clear_of_edges(margin=0.1):
    """The pixels whose footprint on the floor (plus ``margin`` pixels) lies inside one cell
    of the projected image: their radiance is constant over the pixel, so exact at any spp."""
    t = 4.0 * math.tan(math.radians(25.0))
    c = -(1.0 - 2.0 * (np.arange(W) + 0.5) / W) * t
    half_w = 3.0 * math.tan(math.radians(25.0))
    reach = (0.5 + margin) * 2.0 * t / W

    def clear(v, half, n):   # within one of the n cells across [-half, half]
        edges = -half + 2.0 * half * np.arange(n + 1) / n
        return (np.abs(v) < half) & (np.abs(v[:, None] - edges[None, :]).min(axis=1) > reach)
    return clear(c, half_w * 3.0 / 5.0, 3)[:, None] & clear(c, half_w, 5)[None, :]


@pytest.mark.slow
def test_projector_matches_mitsuba_direct_and_the_core(scene):
    """Against Mitsuba's ``direct`` (bsdf_samples 0): exact where a pixel sees one cell of the
    image (a delta light on a flat floor: no noise there); over the whole image (the pixels
    across the cells' edges too) within 1.5x Mitsuba's own relMSE at 256 spp against Mitsuba
    at 1024 spp. The core equals the plugin (which calls Mitsuba's own emitter)."""
    clear = _cells_clear_of_edges()
    assert clear.sum() > 200
    theirs4 = mitsuba_direct(scene, 4, seed=2)
    for kind in ("core", "mitsuba"):
        ours = _render(kind, scene, 4)
        assert np.abs(ours[clear] - theirs4[clear]).max() <= 1e-5 * theirs4[clear].max(), kind
    assert_both_match_mitsuba_direct(scene, 256, _render, ref_factor=4)
