"""links1_whitted's prepared tables follow the scene (issue 14): keyed on the scene's objects
and parameters, not on ``id(scene)``; a scene changed with ``mi.traverse`` after a render, or
another scene given to the same integrator, renders as a scene loaded that way."""
from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.mitsuba

XML = """<scene version="3.0.0">
 <sensor type="perspective"><float name="fov" value="45"/>
  <transform name="to_world"><lookat origin="0, 3, 6" target="0, 0.5, 0" up="0, 1, 0"/></transform>
  <film type="hdrfilm"><integer name="width" value="24"/><integer name="height" value="24"/><rfilter type="box"/></film>
 </sensor>
 <integrator type="links1_whitted"/>
 <shape type="rectangle" id="floor"><transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/></transform>
  <bsdf type="diffuse"/></shape>
 <shape type="sphere" id="ball"><point name="center" x="BX" y="1" z="0"/><float name="radius" value="0.6"/>
  <bsdf type="links1_phong"><rgb name="ambient" value="0.05"/><rgb name="diffuse" value="0.6"/></bsdf></shape>
 <emitter type="point" id="lamp"><point name="position" x="LX" y="5" z="1"/><rgb name="intensity" value="20"/></emitter>
</scene>"""


def _scene(variant, lx=0.0, bx=0.0):
    from links1_mitsuba import load_string
    return load_string(XML.replace("LX", str(lx)).replace("BX", str(bx)), variant=variant)


def _render(scene, integrator=None):
    return (integrator or scene.integrator()).render_window(scene, None, spp=1)


def _move_lamp(mi, params):
    params["lamp.position"] = mi.Point3f(2.0, 5.0, 1.0)


def _move_ball(mi, params):
    params["ball.to_world"] = mi.ScalarTransform4f().translate([1.0, 1.0, 0.0]).scale(0.6)


@pytest.mark.parametrize("change, fresh", [(_move_lamp, {"lx": 2.0}), (_move_ball, {"bx": 1.0})],
                         ids=["light moved", "occluder moved"])
def test_params_update_after_a_render(variant, change, fresh):
    import mitsuba as mi
    s = _scene(variant)
    before = _render(s)
    params = mi.traverse(s)
    change(mi, params)
    params.update()
    after = _render(s)
    expected = _render(_scene(variant, **fresh))
    assert not np.array_equal(before, expected)  # the change shows
    np.testing.assert_allclose(after, expected, rtol=1e-5, atol=1e-6)


def test_another_scene_through_the_same_integrator(variant):
    a, b = _scene(variant), _scene(variant, lx=-2.0)
    integ = a.integrator()
    ra = _render(a, integ)
    rb = _render(b, integ)                     # a's integrator, b's scene
    assert not np.array_equal(ra, rb)
    np.testing.assert_array_equal(rb, _render(b))
    np.testing.assert_array_equal(_render(a, integ), ra)
