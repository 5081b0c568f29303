"""A light at a pinhole camera's eye (a headlight): the camera rays' hits send it no shadow ray
(``shadow_plan.eye_lights``, the core's ``links1.tracing.occluders.lights_at_eye``).

Why no pixel can change: the shadow ray of a camera ray's hit toward the eye runs back along
that camera ray, which met nothing before the hit. The camera rays start on the near plane, so
a shape nearer the eye than the near plane's corner is unseen yet casts a shadow: there the
rule is off, and so it is for a light a little off the eye, and after a links1 shape moves
there (the frozen launch recorded again)."""
from __future__ import annotations

import numpy as np
import pytest

from tests.scenes import integrator, perspective, scene, whitted

from .test_vs_mitsuba_integrators import DIFFUSE

pytestmark = pytest.mark.mitsuba

EYE = "0, 2.5, 6"
#: a floor, a Mitsuba sphere and a cube (the delta-light test scene's shapes, without its lights)
SHAPES = DIFFUSE[:DIFFUSE.index("<emitter")]


def body(light=EYE, near_ball=False, quadric="0.9, 0.6, 0.8"):
    """A floor, a Mitsuba sphere and cube, a links1 quadric sphere at ``quadric``, a point light
    at ``light``; ``near_ball``: a small sphere 0.5 from the eye toward the scene, before a
    near plane 1.5 away (unseen by the camera rays)."""
    ball = ('<shape type="sphere"><point name="center" x="0" y="2.3" z="5.5"/><float name="radius" value="0.15"/>'
            '<bsdf type="diffuse"/></shape>') if near_ball else ""
    return SHAPES + f"""
  <shape type="links1_quadric" id="q"><string name="kind" value="sphere"/>
    <transform name="to_world"><scale value="0.3"/><translate value="{quadric}"/></transform>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.7, 0.3, 0.2"/></bsdf></shape>
  {ball}""" + point_light(light)


def point_light(at):
    return f'\n  <emitter type="point"><point name="position" value="{at}"/><rgb name="intensity" value="40"/></emitter>'


def xml(b, near=None, method=None, spp=4):
    return scene(perspective(EYE, "0, 0.7, 0", fov=40, width=40, height=30, spp=spp, near=near),
                 method or whitted(1), b)


def render(text, variant, on=True):
    """(image, shadow rays traced) of links1_whitted with the rule on or off."""
    import mitsuba as mi
    from links1_mitsuba import load_string
    from links1_mitsuba.tuning import Tuning
    sc = load_string(text, variant=variant)
    sc.integrator().tuning = Tuning(eye_lights=on)
    img = np.array(mi.render(sc, seed=0))
    return img, sc.integrator().stats["shadow"]


def test_a_headlight_sends_no_shadow_ray_and_changes_no_pixel(variant):
    on, n_on = render(xml(body()), variant)
    off, n_off = render(xml(body()), variant, on=False)
    assert n_on == 0 and n_off > 2000          # every lit hit tested without the rule
    assert np.array_equal(on, off)
    assert on[..., :3].max() > 0.1


@pytest.mark.slow
def test_a_headlight_matches_mitsuba_direct(variant):
    """Against Mitsuba's ``direct`` on the Mitsuba shapes alone (many samples: its jitter)."""
    import mitsuba as mi
    from links1_mitsuba import load_string
    b = SHAPES + point_light(EYE)
    a = load_string(xml(b, spp=64), variant=variant)
    img = np.array(mi.render(a, seed=0), dtype=np.float64)[..., :3]
    assert a.integrator().stats["shadow"] == 0
    m = load_string(xml(b, method=integrator("direct"), spp=512), links1_integrator="scene", variant=variant)
    ref = np.array(mi.render(m, seed=0), dtype=np.float64)[..., :3]
    assert np.sum((img - ref) ** 2) / np.sum(ref ** 2) < 2e-3
    assert abs(img.mean() - ref.mean()) / ref.mean() < 5e-3


def test_a_shape_before_the_near_plane_keeps_the_shadow_rays(variant):
    with_ball, n = render(xml(body(near_ball=True), near=1.5), variant)
    without, _ = render(xml(body(), near=1.5), variant)
    assert n > 2000
    # the ball is unseen (before the near plane) but shadows the middle of the view
    assert np.count_nonzero(with_ball[..., :3].sum(-1) < 0.5 * without[..., :3].sum(-1)) > 20


def test_a_light_off_the_eye_is_tested(variant):
    _, n = render(xml(body(light="0, 2.5, 6.001")), variant)
    assert n > 2000


def test_a_links1_shape_moved_before_the_eye_takes_the_rule_away(variant):
    """A geometry update that brings the quadric within the near plane's reach: the launch is
    recorded again (the rule is a literal of its kernel) and renders that scene's shadows."""
    import mitsuba as mi
    from links1_mitsuba import load_string
    text = xml(body(), near=1.5)
    sc = load_string(text, variant=variant)
    first = np.array(mi.render(sc, seed=0))
    assert sc.integrator().stats["shadow"] == 0
    params = mi.traverse(sc)
    key = "links1_whitted.q.to_world"
    params[key] = mi.Transform4f().translate(mi.Vector3f(0.0, 2.3, 5.5)) @ mi.Transform4f().scale(0.15)
    params.update()
    moved = np.array(mi.render(sc, seed=0))
    assert sc.integrator().stats["shadow"] > 2000
    fresh, _ = render(xml(body(quadric="0, 2.3, 5.5").replace('<scale value="0.3"/>', '<scale value="0.15"/>'),
                          near=1.5), variant)
    assert np.array_equal(moved, fresh)
    assert np.count_nonzero(moved[..., :3].sum(-1) < 0.5 * first[..., :3].sum(-1)) > 20


def test_a_headlight_over_mitsuba_instances(variant):
    """Plain ``mi.load_string`` of a scene with a shapegroup drawn twice (Mitsuba's own
    instances, not written out): the members are bounded by their instances' boxes."""
    import mitsuba as mi
    import links1_mitsuba
    from links1_mitsuba.tuning import Tuning
    links1_mitsuba.register(variant)
    floor, objects = SHAPES.split("<shape", 2)[1:]       # the floor; the sphere and the cube
    group = ('<shape type="shapegroup" id="g"><shape' + objects + "</shape>\n"
             + "".join(f'<shape type="instance"><ref id="g"/><transform name="to_world">'
                       f'<translate x="{x}"/></transform></shape>' for x in (-1.2, 1.2)))
    text = xml("<shape" + floor + group + point_light(EYE), near=1.5)
    frames = []
    for on in (True, False):
        sc = mi.load_string(text)
        sc.integrator().tuning = Tuning(eye_lights=on)
        frames.append((np.array(mi.render(sc, seed=0)), sc.integrator().stats["shadow"]))
    assert any(s.class_name() == "Instance" for s in sc.shapes())
    (on, n_on), (off, n_off) = frames
    assert n_on == 0 and n_off > 2000
    assert np.array_equal(on, off)


@pytest.mark.parametrize("sensor", ["thinlens", "orthographic"])
def test_no_headlight_rule_without_a_pinhole(variant, sensor):
    """A thin lens's rays start across its aperture and an orthographic camera's across its
    film: a light at the sensor's origin is not where they come from, so its shadow rays are
    tested (and the image is the rule-free one)."""
    lens = ('<float name="aperture_radius" value="0.05"/><float name="focus_distance" value="6"/>'
            if sensor == "thinlens" else "")
    text = xml(body()).replace('<sensor type="perspective">', f'<sensor type="{sensor}">{lens}')
    if sensor == "orthographic":
        text = text.replace('<float name="fov" value="40"/>', "")
    assert f'type="{sensor}"' in text
    img, n = render(text, variant)
    off, _ = render(text, variant, on=False)
    assert n > 2000
    assert np.array_equal(img, off)
