"""The corpus reference ``whitted_reference`` (tests/corpus/whitted_reference.py) against
Mitsuba's own integrators where the light paths coincide:

* no delta lobe in the scene: Whitted's paths are direct light, Mitsuba's ``direct``
  (emitter and BSDF sampling, MIS) at any depth;
* the camera sees only mirror / glass (or nothing), so every diffuse vertex comes after a
  delta chain: Mitsuba's ``path`` at a ``max_depth`` that leaves no room for a second
  non-delta vertex before a light computes Whitted's paths (one diffuse vertex, direct light),
  and so does the reference at the same ``max_depth``.

Each is judged by relMSE against the Mitsuba integrator at 32x the spp: the reference's must be
within 1.5x of that integrator's own error at equal spp (both are then noise around one image).
A renderer that recursed through diffuse lobes fails the first (interreflection on the
floor), one that stopped at mirrors fails the second (black reflections).
"""
from __future__ import annotations

import numpy as np
import pytest

from links1.imaging.diff import relmse

from .conftest import use_variant

pytestmark = pytest.mark.mitsuba

RES, SPP, REF_FACTOR = 24, 32, 32


@pytest.fixture
def mi():
    use_variant("llvm_ad_rgb")   # the reference is variant-independent Mitsuba code
    import mitsuba as mi
    from tests.corpus.whitted_reference import register
    register()
    return mi


def _scene(mi, objects: dict, origin, target, fov=35):
    T = mi.ScalarTransform4f
    return mi.load_dict({
        "type": "scene",
        "sensor": {"type": "perspective", "fov": fov,
                   "to_world": T().look_at(origin=origin, target=target, up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": RES, "height": RES, "rfilter": {"type": "box"}}},
        **objects})


def _lights(mi, kind):
    T = mi.ScalarTransform4f
    if kind == "point":
        return {"light": {"type": "point", "position": [1, 3, -2], "intensity": 20}}
    if kind == "area":
        return {"light": {"type": "rectangle", "to_world": T().translate([0, 3.5, -2]).rotate([1, 0, 0], 90),
                          "emitter": {"type": "area", "radiance": 4}}}
    return {"light": {"type": "constant", "radiance": 0.5}}


def _agrees(mi, scene, theirs: dict, ours: dict):
    ref = np.array(mi.render(scene, integrator=mi.load_dict(theirs), spp=SPP * REF_FACTOR, seed=1))
    mitsuba = np.array(mi.render(scene, integrator=mi.load_dict(theirs), spp=SPP, seed=2))
    whitted = np.array(mi.render(scene, integrator=mi.load_dict(ours), spp=SPP, seed=2))
    assert ref.mean() > 1e-3, "the scene is black: nothing to compare"
    e_theirs, e_ours = relmse(mitsuba, ref), relmse(whitted, ref)
    assert e_ours <= 1.5 * e_theirs, f"relMSE {e_ours:.3g} vs {theirs['type']}'s own {e_theirs:.3g}"


@pytest.mark.slow
@pytest.mark.parametrize("light", ["point", "area", "constant"])
def test_equals_direct_without_delta_lobes(mi, light):
    """Diffuse walls and a rough conductor and rough plastic (glossy: MIS matters) under a
    point, area or constant light: the reference at its default depth equals ``direct``."""
    T = mi.ScalarTransform4f
    objects = {
        "floor": {"type": "rectangle", "to_world": T().rotate([1, 0, 0], -90).scale(4),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.7, 0.6, 0.5]}}},
        "wall": {"type": "rectangle", "to_world": T().translate([0, 2, -3]).scale(4),
                 "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.2, 0.6, 0.3]}}},
        "metal": {"type": "sphere", "center": [-0.8, 0.7, -1], "radius": 0.7,
                  "bsdf": {"type": "roughconductor", "alpha": 0.15}},
        "plastic": {"type": "sphere", "center": [0.9, 0.6, -0.5], "radius": 0.6,
                    "bsdf": {"type": "roughplastic", "alpha": 0.2}},
        **_lights(mi, light)}
    scene = _scene(mi, objects, origin=[0, 2, 5], target=[0, 0.7, -1])
    _agrees(mi, scene, {"type": "direct"}, {"type": "whitted_reference"})


@pytest.mark.slow
@pytest.mark.parametrize("light", ["point", "area", "constant"])
def test_equals_path_through_a_mirror(mi, light):
    """The camera sees a mirror sphere and the black beyond it; diffuse walls behind the
    camera (seen only in the mirror) and a point, area or constant light. ``path`` and the
    reference at ``max_depth`` 3 (mirror, wall, light)."""
    T = mi.ScalarTransform4f
    objects = {
        "mirror": {"type": "sphere", "center": [0, 0, -4], "radius": 1.2, "bsdf": {"type": "conductor"}},
        "floor": {"type": "rectangle", "to_world": T().translate([0, -1.5, 1]).rotate([1, 0, 0], -90).scale(4),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.8, 0.3, 0.2]}}},
        "back": {"type": "rectangle", "to_world": T().translate([0, 0, 3]).rotate([0, 1, 0], 180).scale(6),
                 "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.2, 0.4, 0.8]}}},
        **_lights(mi, light)}
    scene = _scene(mi, objects, origin=[0, 0, 0], target=[0, 0, -4], fov=30)
    _agrees(mi, scene, {"type": "path", "max_depth": 3, "rr_depth": 100},
            {"type": "whitted_reference", "max_depth": 3})


@pytest.mark.slow
def test_equals_path_through_glass(mi):
    """A glass sphere hides a small diffuse sphere from the camera, which sees it refracted
    (camera, glass in, glass out, diffuse, point light: ``max_depth`` 4); the diffuse sphere is
    the scene's only non-delta surface and convex, so ``path`` finds no second diffuse vertex."""
    objects = {
        "glass": {"type": "sphere", "center": [0, 0, -4], "radius": 1, "bsdf": {"type": "dielectric"}},
        "ball": {"type": "sphere", "center": [0, 0, -6.5], "radius": 0.4,
                 "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.9, 0.5, 0.1]}}},
        "light": {"type": "point", "position": [0, 2, -5], "intensity": 10}}
    scene = _scene(mi, objects, origin=[0, 0, 0], target=[0, 0, -4], fov=20)
    _agrees(mi, scene, {"type": "path", "max_depth": 4, "rr_depth": 100},
            {"type": "whitted_reference", "max_depth": 4})


@pytest.mark.slow
def test_max_depth_one_sees_emitters_only(mi):
    """``max_depth`` 1 counts as Mitsuba's: emission seen directly, no lighting of surfaces."""
    objects = {"floor": {"type": "rectangle", "bsdf": {"type": "diffuse"}},
               **_lights(mi, "constant")}
    scene = _scene(mi, objects, origin=[0, 0, 3], target=[0, 0, 0], fov=60)
    img = np.array(mi.render(scene, integrator=mi.load_dict({"type": "whitted_reference", "max_depth": 1}), spp=4))
    assert img[RES // 2, RES // 2].max() == 0 and img[0, 0].min() == pytest.approx(0.5)
