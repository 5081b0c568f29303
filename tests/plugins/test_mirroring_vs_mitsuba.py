"""Which side of a surface is its front, in the core as in Mitsuba 3.9.1's ``direct``:
``flip_normals`` on a rectangle area light (how Blender exports lights), and a mirroring
``to_world`` (negative determinant) on a rectangle light and on mesh floors. Mitsuba transforms
given normals by the inverse transpose (so they keep their side while the winding turns) and
its BSDFs and emitters follow those normals; normals it computes itself come from the placed,
turned winding (a floor wound to face down and mirrored, without normals, faces up and is lit).

At 64 spp the core's relMSE against a 1024-spp Mitsuba ``direct`` reference must be at most
twice Mitsuba's own at 64 spp, and the means agree within 2 %."""
from __future__ import annotations

import pytest

from tests.plugins.test_textured_emitters_vs_mitsuba import assert_core_converges_to_direct

from tests.scenes import integrator, perspective, scene

pytestmark = pytest.mark.mitsuba

SCENE = scene(integrator("direct"), perspective("0, 4, 4.5", "0, 0.3, 0", fov=45, width=32, spp=4), """
  <shape type="sphere"><point name="center" value="0.6, 0.5, 0.4"/><float name="radius" value="0.5"/>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.3, 0.5, 0.8"/></bsdf></shape>
  {floor}
  {light}""")

FLOOR = ('<shape type="rectangle"><transform name="to_world"><scale value="3"/><rotate x="1" angle="-90"/></transform>'
         '<bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.6, 0.5"/></bsdf></shape>')
#: a floor quad: with a +y normal in the file (wound to face +y), and without one (wound to face -y)
QUAD_OBJ = "v -1 0 -1\nv -1 0 1\nv 1 0 1\nv 1 0 -1\n"
MESH_FLOOR = ('<shape type="obj"><string name="filename" value="{obj}"/><transform name="to_world">'
              '<scale x="-3" y="1" z="3"/></transform>'
              '<bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.6, 0.5"/></bsdf></shape>')
LIGHT = ('<shape type="rectangle"><transform name="to_world"><scale x="{sx}" y="0.5" z="1"/>'
         '<rotate x="1" angle="{angle}"/><translate value="-0.4, 2, -0.6"/></transform>{flip}'
         '<emitter type="area"><rgb name="radiance" value="12"/></emitter></shape>')
DOWN = LIGHT.format(sx=0.5, angle=90, flip="")
CASES = {
    # +z turned up, then flipped: it lights the floor
    "flip_normals-light": (FLOOR, LIGHT.format(sx=0.5, angle=-90, flip='<boolean name="flip_normals" value="true"/>')),
    # mirrored in x: its normal (inverse transpose of +z) still points down
    "mirrored-light": (FLOOR, LIGHT.format(sx=-0.5, angle=90, flip="")),
    "mirrored-floor-given-normals": (MESH_FLOOR.format(obj="n.obj"), DOWN),
    "mirrored-floor-computed-normals": (MESH_FLOOR.format(obj="plain.obj"), DOWN),
}


@pytest.mark.slow
@pytest.mark.parametrize("case", CASES)
def test_core_vs_mitsuba_direct(case, tmp_path, llvm):
    """LLVM only: a test of the core, whose reference is Mitsuba's ``direct``."""
    (tmp_path / "plain.obj").write_text(QUAD_OBJ + "f 4 3 2 1\n")
    (tmp_path / "n.obj").write_text(QUAD_OBJ + "vn 0 1 0\nf 1//1 2//1 3//1 4//1\n")
    floor, light = CASES[case]
    p = tmp_path / "scene.xml"
    p.write_text(SCENE.format(floor=floor, light=light))
    assert_core_converges_to_direct(str(p))
