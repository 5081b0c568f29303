"""Mitsuba ``diffuse`` BSDFs of one reflectance value (``rgb`` or a float, alone or in a
``twosided``) are evaluated in links1_whitted's kernel from a per-slot table
(``tables._lambert_tables``, ``raytree.Hit._lambert``) instead of through the BSDF call.

The reference is Mitsuba's own ``SmoothDiffuse::eval`` (and ``twosided``'s): the same scene
rendered with that table switched off (every BSDF called) is the same image bit for bit; a
kernel whose slots are all such BSDFs calls no BSDF (no ``BSDF::eval`` in its code), one with
a textured diffuse still does. A ``params.update()`` of such a reflectance updates the table in
place (no rebuild, the frozen launch replayed with the new table as its input) and renders
what a new integrator renders of the changed scene."""
from __future__ import annotations

import numpy as np
import pytest

from tests.scenes import perspective, scene

pytestmark = pytest.mark.mitsuba

LAMP = '<emitter type="point" id="lamp"><point name="position" x="1" y="5" z="2"/><rgb name="intensity" value="20"/></emitter>'
FLOOR = ('<shape type="rectangle" id="floor"><transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/>'
         '</transform>{bsdf}</shape>')
# a cube seen from outside, a one-sided rectangle seen from its back (black through diffuse,
# lit through twosided), a sphere with the default BSDF (none given)
BOX = ('<shape type="cube" id="box"><transform name="to_world"><translate x="-0.8" y="0.5" z="0"/><scale value="0.5"/>'
       '</transform>{bsdf}</shape>')
CARD = ('<shape type="rectangle" id="card"><transform name="to_world"><scale value="0.6"/><rotate y="1" angle="180"/>'
        '<rotate x="1" angle="-20"/><translate x="0.8" y="0.7" z="0.5"/></transform>{bsdf}</shape>')
BALL = '<shape type="sphere"><point name="center" x="0" y="0.4" z="1.4"/><float name="radius" value="0.4"/></shape>'

RGB = '<bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.4, 0.3"/></bsdf>'
FLOAT = '<bsdf type="diffuse"><float name="reflectance" value="0.3"/></bsdf>'
TWO = '<bsdf type="twosided"><bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.7, 0.4"/></bsdf></bsdf>'
ONE = '<bsdf type="diffuse"><rgb name="reflectance" value="0.7"/></bsdf>'
TEXTURED = ('<bsdf type="diffuse"><texture type="checkerboard" name="reflectance"><rgb name="color0" value="0.2"/>'
            '<rgb name="color1" value="0.8"/></texture></bsdf>')
PHONG = '<bsdf type="links1_phong"><rgb name="diffuse" value="0.5"/></bsdf>'


def xml(floor, box, card):
    return scene(perspective("0, 3, 6", "0, 0.5, 0", fov=45, width=24, height=20, spp=2),
                 '<integrator type="links1_whitted"/>', LAMP,
                 FLOOR.format(bsdf=floor), BOX.format(bsdf=box), CARD.format(bsdf=card), BALL)


def render(text, table=True):
    """(image, the code of the kernels the frame compiled, the tables) of scene ``text``, with
    the diffuse table or (``table`` False) every BSDF called."""
    import drjit as dr
    import mitsuba as mi

    import links1_mitsuba as lm
    from links1_mitsuba import tables as T
    orig = T._uniform_diffuse
    if not table:
        T._uniform_diffuse = lambda b: None
    try:
        s = lm.load_string(text)
        with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
            dr.kernel_history()
            img = np.array(mi.render(s, seed=3))
            dr.sync_thread()
            code = "".join(k["ir"].getvalue() for k in dr.kernel_history() if "ir" in k)
    finally:
        T._uniform_diffuse = orig
    return img, code, s.integrator().engine.tables.last


@pytest.mark.parametrize("floor, box, card, all_lam", [
    (RGB, FLOAT, TWO, True),
    (RGB, TEXTURED, ONE, False),
    (PHONG, FLOAT, TWO, True),
], ids=["rgb float twosided", "with a texture", "with links1_phong"])
def test_diffuse_table_renders_mitsubas_eval(variant, floor, box, card, all_lam):
    fast, code_fast, tab = render(xml(floor, box, card))
    called, code_called, tab_called = render(xml(floor, box, card), table=False)
    assert tab.any_lam and tab.all_lam == all_lam and not tab_called.any_lam
    assert tab.any_lam_two == (card == TWO)
    assert np.count_nonzero(fast) > fast.size // 2    # lit, and the card's back too where twosided
    np.testing.assert_array_equal(fast, called)
    assert "Call: BSDF::eval()" in code_called
    assert ("Call: BSDF::eval()" in code_fast) == (not all_lam)


@pytest.mark.slow
def test_reflectance_update_goes_into_the_table(variant):
    """Four updates: after the first (dr.freeze may record a launch twice, the second time with
    the values that changed made opaque) the others replay the recording, reading the table: at
    most one more recording in all (freeze records again once where its inputs' layout changes,
    seen in some orders of the suite's tests), never one an update."""
    import mitsuba as mi

    import links1_mitsuba as lm
    s = lm.load_string(xml(RGB, FLOAT, TWO))
    integ = s.integrator()
    before = np.array(mi.render(s, seed=3))
    params = mi.traverse(s)
    recs = []
    for box, card in ((0.9, (0.8, 0.1, 0.1)), (0.2, (0.1, 0.9, 0.3)), (0.5, (0.3, 0.3, 0.8)), (0.7, (0.6, 0.2, 0.4))):
        recs.append(integ.info()["recordings"])
        params["box.bsdf.reflectance.value"] = mi.Float(box)
        params["card.bsdf.brdf_0.reflectance.value"] = mi.Color3f(*card)
        params.update()
        after = np.array(mi.render(s, seed=3))
        mi.render(s, seed=3)
        expected = np.array(mi.render(s, seed=3, integrator=mi.load_dict({"type": "links1_whitted"})))
        assert not np.array_equal(before, expected)
        np.testing.assert_array_equal(after, expected)
        before = after
    recs.append(integ.info()["recordings"])
    assert (integ.info()["scene_builds"], integ.info()["value_updates"]) == (1, 4)
    assert recs[1] <= 2 and recs[-1] <= recs[1] + 1, recs    # the later updates: replayed, the table their input
