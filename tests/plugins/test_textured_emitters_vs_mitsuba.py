"""Textured area emitters in the core against Mitsuba's ``direct``: a ``bitmap`` or
``checkerboard`` radiance on a rectangle, a sphere and a disk, seen directly and lighting a
diffuse floor. The core evaluates the texture at the uv of the hit and of each light sample
(uniform by area); Mitsuba samples the texture instead, so the two agree only in the limit: at
64 spp the core's relMSE against a 1024-spp Mitsuba ``direct`` reference must be at most twice
Mitsuba's own at 64 spp, and the mean within 2 %."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from links1.imaging.image import write_exr

from tests.scenes import integrator, perspective, scene

pytestmark = pytest.mark.mitsuba

SCENE = scene(integrator("direct"), perspective("0, 2.5, 5", "0, 1.0, 0", fov=50, width=32, spp=4), """
  <shape type="rectangle"><transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.6, 0.5"/></bsdf></shape>
  {shape}<emitter type="area">{texture}</emitter></shape>""")

BITMAP = '<texture type="bitmap" name="radiance"><string name="filename" value="em.exr"/></texture>'
CHECKER = ('<texture type="checkerboard" name="radiance"><rgb name="color0" value="1, 0.3, 0.2"/>'
           '<rgb name="color1" value="0.2, 0.4, 1"/><transform name="to_uv"><scale x="3" y="2"/></transform></texture>')
SHAPES = {
    "rectangle": '<shape type="rectangle"><transform name="to_world"><scale x="1.2" y="0.8" z="1"/>'
                 '<rotate x="1" angle="25"/><translate value="0, 1.4, -0.8"/></transform>',
    "sphere": '<shape type="sphere"><point name="center" value="0.3, 1.5, -0.5"/><float name="radius" value="0.6"/>',
    "disk": '<shape type="disk"><transform name="to_world"><scale value="0.9"/><rotate x="1" angle="20"/>'
            '<translate value="0, 1.4, -0.8"/></transform>',
}
CASES = {"rectangle-bitmap": ("rectangle", BITMAP), "rectangle-checkerboard": ("rectangle", CHECKER),
         "sphere-bitmap": ("sphere", BITMAP), "disk-checkerboard": ("disk", CHECKER)}


def rel_mse(a, b):
    return float(np.sum((a - b) ** 2) / np.sum(b ** 2))


def assert_core_converges_to_direct(path: str) -> None:
    """The core at 64 spp against Mitsuba's ``direct`` on the scene file ``path``: mean within
    2 % of a 1024-spp reference, relMSE at most twice Mitsuba's own at 64 spp."""
    import mitsuba as mi
    from links1 import load_scene
    from links1.tracing.render import render
    sc = mi.load_file(path)
    ref = np.array(mi.render(sc, spp=1024, seed=1), dtype=np.float64)[..., :3]
    m64 = np.array(mi.render(sc, spp=64, seed=2), dtype=np.float64)[..., :3]
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # no stand-in (a "0.5 grey" texture) either
        core = render(load_scene(path), spp=64)[..., :3]
    assert abs(core.mean() / ref.mean() - 1.0) < 0.02, (core.mean(), ref.mean())
    assert rel_mse(core, ref) <= 2.0 * rel_mse(m64, ref), (rel_mse(core, ref), rel_mse(m64, ref))


@pytest.mark.slow
@pytest.mark.parametrize("case", CASES)
def test_core_vs_mitsuba_direct(case, tmp_path, llvm):
    """LLVM only: a test of the core, whose reference is Mitsuba's ``direct``."""
    img = np.zeros((4, 6, 3), dtype=np.float32)   # smooth, bright, > 1: an emitter's bitmap
    img[..., 0] = np.linspace(0.5, 6.0, 6)[None, :]
    img[..., 1] = np.linspace(4.0, 1.0, 4)[:, None]
    img[..., 2] = 2.0
    write_exr(tmp_path / "em.exr", img)
    shape, texture = CASES[case]
    p = tmp_path / "scene.xml"
    p.write_text(SCENE.format(shape=SHAPES[shape], texture=texture))
    assert_core_converges_to_direct(str(p))
