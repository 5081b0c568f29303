"""A diffuse ``bsplinecurve`` under a constant environment, both renderers against Mitsuba's
``direct`` (emitter and BSDF sampling, one each): the BSDF samples leave the curve in its
shading frame, whose tangent Mitsuba takes from the curve's ``dp_du`` (around the tube), so
the core and the plugin draw the same directions only where the core's frame is Mitsuba's:
both within 1.5x the relMSE of Mitsuba's ``direct`` at the same spp against its 16x reference,
and the core equal to the plugin (relMSE <= 1e-4; with ``coordinate_system(n)``'s tangent it
is 9e-4)."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from links1_app.renderers import make_renderer
from tests.scenes import integrator, perspective, scene

from .conftest import assert_both_match_mitsuba_direct

pytestmark = pytest.mark.mitsuba

#: A planar zigzag of radius 0.1 (its own numbers; the corpus' documentation curve is alike),
#: stretched by ``to_world`` so that its radius stays below its radius of curvature (Embree's
#: premise: as written, its turns fold onto themselves and Embree misses hits there).
ZIGZAG = """-1.2 0 -0.9 0.1
-0.7 0 0.9 0.1
-0.4 0 -0.9 0.1
-0.1 0 0.9 0.1
 0.2 0 -0.9 0.1
 0.6 0 0.9 0.1
 1.2 0 -0.9 0.1
"""


def _render(kind, path, spp):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return np.asarray(make_renderer(kind, path, spp=spp, max_depth=1).render(), dtype=np.float64)[..., :3]


@pytest.mark.slow
def test_curve_under_an_environment_matches_mitsuba_direct_and_plugin(tmp_path, llvm):
    """LLVM only: the curve is Mitsuba's own shape (Embree on LLVM, OptiX on CUDA), the test is
    of the core's shading frame against it."""
    (tmp_path / "zigzag.txt").write_text(ZIGZAG)
    path = tmp_path / "scene.xml"
    path.write_text(scene(
        integrator("direct"),
        perspective("0, -4.5, 3.2", "0, 0, 0.8", fov=50, width=40, height=30, spp=None, up="0, 0, 1"),
        '<emitter type="constant"><rgb name="radiance" value="1.0"/></emitter>',
        '<shape type="rectangle"><transform name="to_world"><scale value="3"/></transform>'
        '<bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf></shape>',
        f'<shape type="bsplinecurve"><string name="filename" value="{tmp_path / "zigzag.txt"}"/>'
        '<transform name="to_world"><matrix value="2 2 0 0 -0.7 0.7 0 0 0 0 1 1 0 0 0 1"/></transform>'
        '<bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.25, 0.7"/></bsdf></shape>'))
    assert_both_match_mitsuba_direct(str(path), 4, _render)
