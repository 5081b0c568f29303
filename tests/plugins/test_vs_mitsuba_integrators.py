"""Validations c and d: links1_whitted against Mitsuba's own integrators.

Mitsuba picks one emitter per shading point at random and jitters pixel samples, so its
images are compared at many samples (links1_whitted at 64 strata) with tolerances that
cover that noise; the means must agree to a fraction of a percent.

c. Delta lights + diffuse surfaces: Whitted max_depth 1 equals Mitsuba's ``direct`` (and
   ``path`` with max_depth 2). Mirror / glass objects over one diffuse plane lit by point
   lights: Whitted max_depth k equals ``path`` max_depth k + 1 on those light paths.
d. Mitsuba's ``path`` with links1_point emitters and links1_phong surfaces (no ambient)
   equals links1_whitted (links1_phong samples only its delta lobes).
"""
from __future__ import annotations

import numpy as np
import pytest

from tests.scenes import integrator, perspective, scene, whitted as whitted_integrator

pytestmark = pytest.mark.mitsuba

RES = 32


def scene_xml(body, method, spp=1):
    return scene(perspective("0, 2.5, 6", "0, 0.7, 0", fov=40, width=RES, spp=spp), method, body)


def whitted(body, variant, max_depth, spp=1):
    from links1_mitsuba import load_string
    sc = load_string(scene_xml(body, whitted_integrator(max_depth)), variant=variant)
    return sc.integrator().render_window(sc, None, spp=spp)


def mitsuba(body, variant, kind, max_depth, spp):
    from links1_mitsuba import load_string
    import mitsuba as mi
    sc = load_string(scene_xml(body, integrator(kind, max_depth=max_depth) if kind == "path" else
                               integrator(kind), spp=spp),
                     links1_integrator="scene", variant=variant)
    return np.array(mi.render(sc, spp=spp), dtype=np.float64)[..., :3]


def rel_mse(a, b):
    return float(np.sum((a - b) ** 2) / max(np.sum(b ** 2), 1e-30))


DIFFUSE = """
  <shape type="rectangle"><transform name="to_world"><scale value="5"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.5, 0.4"/></bsdf></shape>
  <shape type="sphere"><point name="center" x="-0.6" y="0.8" z="0"/><float name="radius" value="0.8"/>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.5, 0.8"/></bsdf></shape>
  <shape type="cube"><transform name="to_world"><scale value="0.4"/><rotate y="1" angle="30"/>
    <translate x="1" y="0.4" z="0.5"/></transform><bsdf type="diffuse"/></shape>
  <emitter type="point"><point name="position" x="2" y="4" z="3"/><rgb name="intensity" value="20"/></emitter>
  <emitter type="directional"><vector name="direction" x="-0.4" y="-1" z="-0.3"/><rgb name="irradiance" value="0.8"/></emitter>
  <emitter type="spot"><transform name="to_world"><lookat origin="-2, 4, 2" target="0, 0, 0"/></transform>
    <rgb name="intensity" value="30"/><float name="cutoff_angle" value="25"/></emitter>
"""


@pytest.mark.slow
def test_delta_lights_diffuse_vs_direct(variant):
    """Direct light only: whitted (max_depth 1) vs Mitsuba direct, noise-free with delta lights."""
    a = whitted(DIFFUSE, variant, 1, spp=64)
    b = mitsuba(DIFFUSE, variant, "direct", 2, spp=512)
    # same pixel areas (strata vs independent samples): edge pixels carry the noise
    assert rel_mse(a, b) < 2e-3
    assert abs(a.mean() - b.mean()) / b.mean() < 5e-3


@pytest.mark.slow
def test_delta_lights_diffuse_vs_path_depth2(variant):
    a = whitted(DIFFUSE, variant, 1, spp=64)
    b = mitsuba(DIFFUSE, variant, "path", 2, spp=512)
    assert rel_mse(a, b) < 2e-3
    assert abs(a.mean() - b.mean()) / b.mean() < 5e-3


MIRROR_GLASS = """
  <shape type="rectangle"><transform name="to_world"><scale value="5"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.6, 0.5"/></bsdf></shape>
  <shape type="sphere"><point name="center" x="-0.9" y="1.2" z="0"/><float name="radius" value="0.7"/>
    <bsdf type="conductor"/></shape>
  <shape type="sphere"><point name="center" x="0.9" y="1.2" z="0.3"/><float name="radius" value="0.7"/>
    <bsdf type="dielectric"/></shape>
  <emitter type="point"><point name="position" x="1" y="5" z="3"/><rgb name="intensity" value="25"/></emitter>
  <emitter type="point"><point name="position" x="-3" y="4" z="1"/><rgb name="intensity" value="10"/></emitter>
"""


@pytest.mark.slow
def test_mirror_glass_over_plane_vs_path(variant):
    """Whitted depth 3 vs path depth 4: the same eye-specular-diffuse-light paths. Path also
    carries plane -> glass reflection -> plane paths (a few % of the glass's Fresnel
    reflectance of indirect light), hence the tolerance."""
    a = whitted(MIRROR_GLASS, variant, 3, spp=64)
    b = mitsuba(MIRROR_GLASS, variant, "path", 4, spp=512)
    assert rel_mse(a, b) < 1e-2
    assert abs(a.mean() - b.mean()) / b.mean() < 3e-2


@pytest.mark.slow
def test_mirror_only_vs_path_exact_paths(variant):
    """Mirror sphere over a plane: whitted depth 2 vs path depth 3 (no other light paths)."""
    body = MIRROR_GLASS.replace('<bsdf type="dielectric"/>', '<bsdf type="conductor"/>')
    a = whitted(body, variant, 2, spp=64)
    b = mitsuba(body, variant, "path", 3, spp=512)
    assert rel_mse(a, b) < 5e-3
    assert abs(a.mean() - b.mean()) / b.mean() < 1e-2


PHONG = """
  <shape type="rectangle"><transform name="to_world"><scale value="5"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.6, 0.5, 0.4"/><rgb name="specular" value="0.2"/></bsdf></shape>
  <shape type="sphere"><point name="center" x="-0.6" y="1" z="0"/><float name="radius" value="0.9"/>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.2, 0.3, 0.6"/><rgb name="specular" value="0.5"/>
      <float name="exponent" value="40"/><rgb name="reflectance" value="0.4"/></bsdf></shape>
  <emitter type="links1_point"><point name="position" x="2" y="5" z="3"/><vector name="direction" x="-0.3" y="-1" z="-0.5"/>
    <rgb name="L1" value="0.4"/><rgb name="L2" value="0.5"/></emitter>
  <emitter type="links1_point"><point name="position" x="-3" y="3" z="2"/><rgb name="L1" value="3"/>
    <string name="falloff" value="inverse_square"/></emitter>
"""


@pytest.mark.slow
def test_path_with_links1_plugins_vs_whitted(variant):
    """Mitsuba's path uses links1_point and links1_phong as real plugins (validation d)."""
    a = whitted(PHONG, variant, 3, spp=64)
    b = mitsuba(PHONG, variant, "path", 4, spp=512)
    assert b.mean() > 0.05
    assert rel_mse(a, b) < 2e-3
    assert abs(a.mean() - b.mean()) / b.mean() < 5e-3


def test_mi_render_on_loaded_scene(variant):
    """mi.render(scene) works on a scene from the loader (links1_whitted inside)."""
    import mitsuba as mi
    from links1_mitsuba import load_string
    sc = load_string(scene_xml(PHONG, "", spp=1), variant=variant)
    img = np.array(mi.render(sc), dtype=np.float64)
    ref = sc.integrator().render_window(sc, None, spp=1)
    assert img.shape == (RES, RES, 3)
    assert np.allclose(img, ref, atol=1e-6)
