"""``shapegroup`` / ``instance`` in both renderers (flattened into copies) against Mitsuba.

An instance is its group's shapes mapped by the instance's ``to_world`` after their own: each
renderer's image of an instanced scene equals, bit for bit, its image of the same shapes
written out with the composed transformations (ids in file order included), and matches
Mitsuba's own ``direct`` integrator on the instanced scene (which Mitsuba renders through
real instances) within 2x Mitsuba's relMSE. links1_whitted once rendered instances as
nothing (a hit on a shape shared by instances had no row in its per-shape tables)."""
from __future__ import annotations

import numpy as np
import pytest

from links1.errors import SceneError
from links1_app.renderers import make_renderer

from .conftest import assert_matches_mitsuba_direct

W, H = 48, 36
HEAD = """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="45"/>
    <transform name="to_world"><lookat origin="0, 3, 9" target="0, 0.5, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="{W}"/><integer name="height" value="{H}"/>
      <rfilter type="box"/></film></sensor>
  <emitter type="point"><point name="position" x="3" y="6" z="5"/><rgb name="intensity" value="60"/></emitter>
  <shape type="rectangle"><transform name="to_world"><scale value="8"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf></shape>
""".format(W=W, H=H)
SPHERE = """<shape type="sphere"><transform name="to_world"><scale value="0.6"/>{outer}<translate y="0.6"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.8, 0.3, 0.2"/></bsdf></shape>"""
CUBE = """<shape type="cube"><transform name="to_world"><scale value="0.4"/><translate x="1.1" y="0.4"/>{outer}</transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.4, 0.8"/></bsdf></shape>"""
OUTERS = ['<rotate y="1" angle="30"/><translate x="-2"/>', '<scale value="1.3"/><translate x="1.5" z="-1"/>']

INSTANCED = HEAD + """  <shape type="shapegroup" id="g">
    """ + SPHERE.format(outer="").replace('<scale value="0.6"/><translate y="0.6"/>',
                                          '<scale value="0.6"/><translate y="0.6"/>') + """
    """ + CUBE.format(outer="") + """
  </shape>
""" + "".join(f'  <shape type="instance"><ref id="g"/><transform name="to_world">{o}</transform></shape>\n'
              for o in OUTERS) + "</scene>"
# the same shapes written out: a member's own transformation, then the instance's
FLAT = HEAD + "".join(
    SPHERE.format(outer="").replace('<translate y="0.6"/></transform>', f'<translate y="0.6"/>{o}</transform>')
    + CUBE.format(outer=o) for o in OUTERS) + "</scene>"


@pytest.fixture
def scenes(tmp_path):
    a, b = tmp_path / "instanced.xml", tmp_path / "flat.xml"
    a.write_text(INSTANCED)
    b.write_text(FLAT)
    return str(a), str(b)


@pytest.mark.slow
def test_instances_are_the_shapes_written_out(scenes, renderer_kind):
    kind = renderer_kind
    inst, flat = scenes
    a = make_renderer(kind, inst, spp=4, aovs=("depth", "id")).render()
    b = make_renderer(kind, flat, spp=4, aovs=("depth", "id")).render()
    assert np.array_equal(a, b)
    # both instances are seen: red (sphere) and blue (cube) pixels in each half of the image
    red = a[..., 0] > 1.5 * a[..., 2]
    blue = a[..., 2] > 1.5 * a[..., 0]
    for half in (slice(0, W // 2), slice(W // 2, W)):
        assert red[:, half].sum() > 10 and blue[:, half].sum() > 5


@pytest.mark.slow
@pytest.mark.mitsuba
def test_instancing_matches_mitsuba_direct(scenes, kind_with_mitsuba):
    kind = kind_with_mitsuba
    assert_matches_mitsuba_direct(kind, scenes[0])


@pytest.mark.parametrize("body,message", [
    ('<shape type="instance"/>', "exactly one shapegroup"),
    ('<shape type="shapegroup" id="g"><bsdf type="diffuse"/></shape>', "only shapes"),
    ('<shape type="shapegroup" id="h"><shape type="sphere"/></shape><shape type="shapegroup" id="g">'
     '<shape type="instance"><ref id="h"/></shape></shape><shape type="instance"><ref id="g"/></shape>',
     "nested instancing"),
    ('<shape type="shapegroup" id="g"><shape type="sphere"><emitter type="area"/></shape></shape>'
     '<shape type="instance"><ref id="g"/></shape>', "emitter"),
])
def test_bad_instancing_is_a_scene_error(tmp_path, body, message):
    from links1.scene import loader
    p = tmp_path / "bad.xml"
    p.write_text('<scene version="3.0.0">' + body + "</scene>")
    with pytest.raises(SceneError, match=message):
        loader.load_scene(str(p))
