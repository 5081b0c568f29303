"""Mitsuba's ``spot`` with a ``texture``: a projector, in both renderers.

The texture scales the intensity at ``uv = 1/2 + (x, y) / (2 z tan(cutoff))`` of the direction
to the lit point in the light's frame (Mitsuba's ``direction_to_uv``). A checkerboard
projected straight down onto a diffuse floor: both renderers match Mitsuba's own ``direct``
within 2x its relMSE, and the pattern is there (the floor under a dark square is dark, as
the checkerboard's colours say, where the untextured spot lights it evenly)."""
from __future__ import annotations

import numpy as np
import pytest

from links1_app.renderers import make_renderer

from tests.scenes import perspective, scene

from .conftest import assert_matches_mitsuba_direct

pytestmark = pytest.mark.mitsuba

W = H = 40
SCENE = scene(perspective("0, 4, 0.01", "0, 0, 0", up="0, 0, -1", fov=50, width=W, height=H, spp=None), """
  <emitter type="spot"><rgb name="intensity" value="20"/><float name="cutoff_angle" value="30"/>
    <float name="beam_width" value="29"/>
    {texture}
    <transform name="to_world"><lookat origin="0, 3, 0" target="0, 0, 0" up="0, 0, 1"/></transform></emitter>
  <shape type="rectangle"><transform name="to_world"><scale value="5"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.8"/></bsdf></shape>""")
CHECKER = """<texture name="texture" type="checkerboard"><rgb name="color0" value="1"/>
      <rgb name="color1" value="0.1"/><transform name="to_uv"><scale value="4"/></transform></texture>"""


@pytest.fixture
def scenes(tmp_path):
    a, b = tmp_path / "projector.xml", tmp_path / "plain.xml"
    a.write_text(SCENE.format(W=W, H=H, texture=CHECKER))
    b.write_text(SCENE.format(W=W, H=H, texture=""))
    return str(a), str(b)


@pytest.mark.slow
def test_projector_matches_mitsuba_direct(scenes, kind_with_mitsuba):
    kind = kind_with_mitsuba
    projector, plain = scenes
    assert_matches_mitsuba_direct(kind, projector)
    # the pattern: inside the beam the ratio to the untextured spot is the checkerboard's 1 or 0.1
    even = np.asarray(make_renderer(kind, plain, spp=1, max_depth=1).render())[..., 0]
    lit = even > 0.5 * even.max()
    ratio = np.asarray(make_renderer(kind, projector, spp=1, max_depth=1).render())[..., 0][lit] / even[lit]
    assert lit.sum() > 100
    near = lambda v: np.abs(ratio - v) < 0.05  # noqa: E731 - away from the squares' edges (bilinear: none)
    assert near(1.0).sum() > 0.25 * lit.sum() and near(0.1).sum() > 0.25 * lit.sum()
    assert (near(1.0) | near(0.1)).mean() > 0.8
