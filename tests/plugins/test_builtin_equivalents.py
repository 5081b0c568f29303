"""Validation b: links1 shapes against Mitsuba's built-ins through the same integrator."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tests.scenes import perspective, scene, whitted

pytestmark = pytest.mark.mitsuba

#: the camera, integrator, material "m", floor and lights every scene here shares
HEAD = perspective("0.3, 2.2, 6", "0, 0.8, 0", fov=35, width=48) + whitted(2) + """
  <bsdf type="links1_phong" id="m"><rgb name="ambient" value="0.05"/><rgb name="diffuse" value="0.7, 0.3, 0.2"/>
    <rgb name="specular" value="0.4"/><float name="exponent" value="30"/><rgb name="reflectance" value="0.3"/></bsdf>
  <shape type="rectangle"><transform name="to_world"><scale value="5"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="links1_phong"><rgb name="ambient" value="0.02"/><rgb name="diffuse" value="0.5"/></bsdf></shape>
  <emitter type="links1_point"><point name="position" x="2" y="5" z="3"/><rgb name="L1" value="0.8"/></emitter>
  <emitter type="directional"><vector name="direction" x="-0.3" y="-1" z="-0.2"/><rgb name="irradiance" value="0.3"/></emitter>
"""


def render(xml, variant):
    from links1_mitsuba import load_string
    sc = load_string(scene(HEAD, xml), variant=variant)
    return sc.integrator().render_window(sc, None, spp=1, aovs=("id",))


def off_silhouettes(a, b):
    """Pixels whose 3x3 neighbourhood sees the same shapes in both images."""
    ida, idb = a[..., 3], b[..., 3]
    same = ida == idb
    keep = same.copy()
    h, w = same.shape
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            sh = np.zeros_like(same)
            ys, xs = slice(max(dy, 0), h + min(dy, 0)), slice(max(dx, 0), w + min(dx, 0))
            yd, xd = slice(max(-dy, 0), h + min(-dy, 0)), slice(max(-dx, 0), w + min(-dx, 0))
            sh[yd, xd] = (ida[ys, xs] == ida[yd, xd]) & (idb[ys, xs] == idb[yd, xd]) & same[ys, xs]
            keep &= sh
    return keep


def check(a, b):
    keep = off_silhouettes(a, b)
    assert keep.mean() > 0.8
    assert (a[..., 3] >= 0).sum() > 100
    err = np.abs(a[..., :3] - b[..., :3])[keep].max()
    assert err <= 1e-4, f"max abs difference {err:.3g} off silhouettes"


@pytest.mark.slow
def test_quadric_sphere_vs_mitsuba_sphere(variant):
    a = render("""<shape type="links1_quadric"><string name="kind" value="sphere"/>
        <transform name="to_world"><scale value="0.9"/><translate x="0.2" y="1" z="0.1"/></transform>
        <ref id="m"/></shape>""", variant)
    b = render("""<shape type="sphere"><point name="center" x="0.2" y="1" z="0.1"/>
        <float name="radius" value="0.9"/><ref id="m"/></shape>""", variant)
    check(a, b)


@pytest.mark.slow
def test_clipped_cylinder_vs_mitsuba_cylinder(variant):
    a = render("""<shape type="links1_quadric"><string name="kind" value="cylinder"/>
        <vector name="clip_0" x="0" y="0" z="1"/><float name="clip_0_offset" value="1"/>
        <vector name="clip_1" x="0" y="0" z="-1"/><float name="clip_1_offset" value="0"/>
        <transform name="to_world"><scale x="0.6" y="0.6" z="1.5"/><rotate x="1" angle="-90"/>
        <translate x="0.1" y="0.2"/></transform><ref id="m"/></shape>""", variant)
    b = render("""<shape type="cylinder"><float name="radius" value="0.6"/>
        <point name="p0" x="0.1" y="0.2" z="0"/><point name="p1" x="0.1" y="1.7" z="0"/>
        <ref id="m"/></shape>""", variant)
    check(a, b)


@pytest.mark.slow
@pytest.mark.parametrize("ratio", [0.5, 0.9])
def test_single_centre_blob_vs_sphere(variant, ratio):
    w, S = 1.0, 0.6
    T = ratio * w
    r_star = S * math.sqrt(3 * (1 - T / w)) if T / w > 2 / 3 else S * (3 - math.sqrt(6 * T / w))
    a = render(f"""<shape type="links1_blob"><string name="centers" value="0.1 1.0 0.0 {w} {S}"/>
        <float name="threshold" value="{T}"/><ref id="m"/></shape>""", variant)
    b = render(f"""<shape type="sphere"><point name="center" x="0.1" y="1" z="0"/>
        <float name="radius" value="{r_star}"/><ref id="m"/></shape>""", variant)
    check(a, b)
