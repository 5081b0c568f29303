"""Area emitters against Lambert's closed form: the irradiance a uniformly
emitting polygon gives a point is E = L/2 Σ_edges Θ_i (γ_i · n) (Lambert 1760; Arvo 1995),
Θ_i the angle the edge subtends at the point and γ_i the unit normal of the plane through the
point and the edge. A diffuse floor of albedo ρ then leaves ρ E / π.

The luminaire is a downward quad plus a triangle facing up (lighting nothing below it): one
non-convex mesh, so it is an occluder of its own light. Floor points that see the quad
obliquely were shadowed by the quad itself (their shadow rays, started from the offset
origin along the unoffset direction, met its plane before the sampled point), up to 25×
too dark (found against Mitsuba's ``direct``)."""
from __future__ import annotations

import numpy as np
import pytest

from links1 import load_scene
from links1.tracing.render import render

from tests.scenes import integrator, perspective, scene

from . import oracle

QUAD = np.array([[-0.5, 3, -0.5], [0.5, 3, -0.5], [0.5, 3, 0.5], [-0.5, 3, 0.5]])  # normal -y
L, RHO, RES = 5.0, 0.5, 24

SCENE = scene(integrator("direct"), perspective("0, 2, 9", "0, 0, -1", fov=50, width="{res}", spp=None), """
  <shape type="rectangle"><transform name="to_world"><scale value="10"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="{rho}"/></bsdf></shape>
  <shape type="obj"><string name="filename" value="lum.obj"/>
    <emitter type="area"><rgb name="radiance" value="{L}"/></emitter></shape>""")


def lambert_irradiance(p, n, poly):
    """Irradiance at points p (N,3) with normals n (N,3) from a polygon of unit radiance
    whose front faces them."""
    e = np.zeros(len(p))
    for a, b in zip(poly, np.roll(poly, -1, axis=0)):
        ra, rb = a - p, b - p
        ra /= np.linalg.norm(ra, axis=1, keepdims=True)
        rb /= np.linalg.norm(rb, axis=1, keepdims=True)
        theta = np.arccos(np.clip(np.einsum("ij,ij->i", ra, rb), -1, 1))
        g = np.cross(ra, rb)
        g /= np.linalg.norm(g, axis=1, keepdims=True)
        e += theta * np.einsum("ij,ij->i", g, n)
    return np.abs(e) / 2


@pytest.fixture(scope="module")
def scene_path(tmp_path_factory):
    d = tmp_path_factory.mktemp("lambert")
    with open(d / "lum.obj", "w") as fh:
        fh.write("".join(f"v {x} {y} {z}\n" for x, y, z in QUAD))
        fh.write("v 3 3.5 -3\nv 4 3.5 -3\nv 3 3.5 -2\n")  # facing +y: lights nothing below
        fh.write("f 1 2 3\nf 1 3 4\nf 5 7 6\n")
    p = d / "scene.xml"
    p.write_text(SCENE.format(res=RES, rho=RHO, L=L))
    return str(p)


def test_floor_under_a_non_convex_luminaire_matches_lambert(scene_path):
    sc = oracle.Scene(scene_path, {})
    d = sc.camera_rays(1)
    t = -sc.eye[1] / d[:, 1]
    p = sc.eye + t[:, None] * d
    on_floor = (t > 0) & (np.abs(p[:, 0]) < 10) & (np.abs(p[:, 2]) < 10)
    # the quad and the triangle hide no floor pixel from this eye (below the luminaire's height)
    expect = RHO / np.pi * L * lambert_irradiance(p, np.tile([0.0, 1.0, 0.0], (len(p), 1)), QUAD)
    img = render(load_scene(scene_path), spp=1, light_samples=256)[..., 0].reshape(-1)
    rel = np.abs(img - expect) / expect
    oblique = on_floor & (np.abs(p[:, 0]) + np.abs(p[:, 2]) > 4)   # the points that were too dark
    assert on_floor.sum() > 300 and oblique.sum() > 50
    # 256 stratified light samples on a quad: a few per cent at most
    assert np.percentile(rel[on_floor], 95) < 0.03 and rel[on_floor].max() < 0.08, \
        (np.percentile(rel[on_floor], 95), rel[on_floor].max())
    assert abs(img[oblique].sum() / expect[oblique].sum() - 1) < 0.01
