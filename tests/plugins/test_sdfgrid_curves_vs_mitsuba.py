"""Mitsuba's ``sdfgrid``, ``linearcurve`` and ``bsplinecurve`` in the core, against Mitsuba 3.9.1's own
intersection (``scene.ray_intersect``, llvm_ad_rgb: Embree for the curves, the sdfgrid's
voxel-cubic solver) and against the plugin's render, which traces them through Mitsuba.

The SDF grid: a bumpy sphere's distance on a 12³ grid (``.vol`` written here), scaled and
moved by ``to_world``. The curves: two round linear curves (3 and 4 control points, radii
0.1-0.4), rotated, scaled and moved (the radii stay as written); two cubic B-spline curves
of 5 control points each (Embree's round curve: a circle swept along the spline, open ends). Random rays from a sphere of
radius 4-5 toward the shapes: the same rays hit and miss in both (none of the rays grazes
within float32 rounding of a silhouette), at distances within float32 rounding of Mitsuba's
(SDF: Mitsuba's regula falsi stops at 1e-5; curves: Embree's float32 solvers), with the
same geometric and shading normals (both ``normals`` modes), segment index and ``uv``."""
from __future__ import annotations

import numpy as np
import pytest

from links1.geometry.curves import RoundBSplineCurves, RoundLinearCurves, read_curves
from links1.geometry.sdfgrid import SDFGrid, read_vol

from tests.scenes import integrator, lit_floor, perspective, scene

from .conftest import assert_both_match_mitsuba_direct

pytestmark = pytest.mark.mitsuba

CURVES = """-1.0 0.1 0.1 0.3
 0.2 0.9 0.2 0.2
 1.0 1.4 1.2 0.4

-1.0 -0.5 -0.2 0.1
-0.3 -1.0 0.3 0.25
 0.8 -0.6 -0.4 0.15
 1.2 0.2 -0.3 0.3
"""

BSPLINES = """-1.0 0.1 0.1 0.2
-0.3 1.2 1.0 0.3
 0.3 0.3 1.1 0.25
 1.0 1.4 1.2 0.2
 1.5 0.4 0.2 0.3

-1.0 -0.5 -0.2 0.1
-0.3 -1.0 0.3 0.25
 0.8 -0.6 -0.4 0.15
 1.2 0.2 -0.3 0.3
 0.9 0.6 -0.8 0.2
"""


def write_vol(path, grid):
    """Mitsuba's grid volume: 'VOL' 3, float32 encoding, x y z resolution, 1 channel, box."""
    nz, ny, nx = grid.shape
    head = b"VOL" + bytes([3]) + np.array([1, nx, ny, nz, 1], "<i4").tobytes() \
        + np.array([0, 0, 0, 1, 1, 1], "<f4").tobytes()
    path.write_bytes(head + grid.astype("<f4").tobytes())


def bumpy_sphere(n=12):
    z, y, x = np.meshgrid(*(np.linspace(0.0, 1.0, n),) * 3, indexing="ij")
    return np.sqrt((x - 0.5) ** 2 + (y - 0.45) ** 2 + (z - 0.55) ** 2) - 0.3 + 0.05 * np.sin(7 * x) * np.cos(5 * y)


@pytest.fixture
def files(tmp_path):
    write_vol(tmp_path / "sdf.vol", bumpy_sphere())
    (tmp_path / "curves.txt").write_text(CURVES)
    (tmp_path / "bsplines.txt").write_text(BSPLINES)
    return tmp_path


def _rays(center, spread, n=3000, radius=4.5, seed=1):
    rng = np.random.default_rng(seed)
    tgt = np.asarray(center) + rng.normal(size=(n, 3)) * spread
    o = rng.normal(size=(n, 3))
    o = o / np.linalg.norm(o, axis=1)[:, None] * radius
    d = tgt - o
    return o, d / np.linalg.norm(d, axis=1)[:, None]


def _mitsuba_hits(shape_dict, o, d):
    import mitsuba as mi
    scene = mi.load_dict({"type": "scene", "s": shape_dict})
    ray = mi.Ray3f(mi.Point3f(*o.T.astype(np.float32)), mi.Vector3f(*d.T.astype(np.float32)))
    si = scene.ray_intersect(ray)
    return (np.array(si.t, dtype=np.float64), np.array(si.n, dtype=np.float64).T,
            np.array(si.sh_frame.n, dtype=np.float64).T, np.array(si.uv, dtype=np.float64).T,
            np.array(si.prim_index, dtype=np.int64))


@pytest.mark.slow
@pytest.mark.parametrize("normals", ["smooth", "analytic"])
def test_sdfgrid_hits_match_mitsuba(files, llvm, normals):
    """The core's sdfgrid hits, distances and normals against Mitsuba's ``ray_intersect``.
    LLVM only: a test of the core against a reference Mitsuba computes once."""
    import mitsuba as mi
    to_world = mi.ScalarTransform4f().translate([0.1, -0.2, 0.3]).scale([1.5, 1.2, 0.9])
    o, d = _rays([0.85, 0.34, 0.75], 0.5)
    tm, ngm, nsm, _, _ = _mitsuba_hits({"type": "sdfgrid", "filename": str(files / "sdf.vol"),
                                        "to_world": to_world, "normals": normals}, o, d)
    core = SDFGrid(read_vol(files / "sdf.vol"), np.array(to_world.matrix), normals=normals)
    t, prim = core.intersect(o, d, 0.0, np.inf)
    hit = np.isfinite(t)
    assert 500 < hit.sum() < 2500                     # both hits and misses are tested
    assert np.array_equal(hit, np.isfinite(tm))
    _, ng, ns = core.surface(o[hit], d[hit], t[hit], prim[hit])
    assert np.max(np.abs(t[hit] - tm[hit])) < 2e-5 * 4.5
    assert np.max(np.abs(ng - ngm[hit])) < 2e-5
    assert np.max(np.abs(ns - nsm[hit])) < 5e-5
    if normals == "smooth":                           # the smooth normals are not the gradient
        assert np.max(np.abs(ns - ng)) > 1e-2


@pytest.mark.slow
@pytest.mark.parametrize("plugin", ["linearcurve", "bsplinecurve"])
def test_curve_hits_match_mitsuba(files, llvm, plugin):
    """The core's curve hits, distances, normals, uv and segments against Mitsuba's
    ``ray_intersect``. LLVM only: a test of the core against a reference Mitsuba computes once."""
    import mitsuba as mi
    linear = plugin == "linearcurve"
    to_world = mi.ScalarTransform4f().translate([0.1, -0.2, 0.3]).rotate([1, 2, 3], 30).scale([1.2, 1.0, 0.9])
    o, d = _rays([0.0, 0.0, 0.0], 0.8 if linear else 0.6, n=4000 if linear else 2000, radius=5.0)
    name = files / ("curves.txt" if linear else "bsplines.txt")
    tm, ngm, _, uvm, pm = _mitsuba_hits({"type": plugin, "filename": str(name), "to_world": to_world}, o, d)
    m = np.array(to_world.matrix)
    placed = [np.concatenate([c[:, :3] @ m[:3, :3].T + m[:3, 3], c[:, 3:]], axis=1)
              for c in read_curves(name, 2 if linear else 4)]
    core = (RoundLinearCurves if linear else RoundBSplineCurves)(placed)
    t, prim = core.intersect(o, d, 0.0, np.inf)
    hit = np.isfinite(t)
    assert 150 < hit.sum() < 0.8 * t.size
    assert np.array_equal(hit, np.isfinite(tm))
    _, ng, ns = core.surface(o[hit], d[hit], t[hit], prim[hit])
    uv = core.uv(o[hit], d[hit], t[hit], prim[hit])
    assert np.array_equal(prim[hit], pm[hit])
    assert np.max(np.abs(t[hit] - tm[hit])) < 2e-5 * 5.0   # Embree's float32 solvers
    assert np.max(np.abs(ng - ngm[hit])) < 1e-3
    assert np.array_equal(ns, ng)
    assert np.max(np.abs(uv - uvm[hit])) < 1e-4
    if linear:   # the ends are spheres: some rays hit a curve's first control point's sphere
        assert np.any((uv[:, 1] == 0.0) | (uv[:, 1] == 2 / 5))


SCENE = scene(integrator("direct", bsdf_samples=0),
              perspective("0.4, 2.5, 4.5", "0.3, 0.3, 0", fov=45, width=48, height=40, spp=None), lit_floor(-1.2), """
  <shape type="sdfgrid"><string name="filename" value="{vol}"/><string name="normals" value="{normals}"/>
    <transform name="to_world"><scale value="1.8"/><translate x="0.4" y="-1.5" z="-0.6"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.4, 0.2"/></bsdf></shape>
  <shape type="linearcurve"><string name="filename" value="{curves}"/>
    <transform name="to_world"><rotate y="1" angle="20"/><translate x="-0.6" y="0.2" z="0.2"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.5, 0.8"/></bsdf></shape>
  <shape type="bsplinecurve"><string name="filename" value="{bsplines}"/>
    <transform name="to_world"><scale value="0.6"/><translate x="1.2" y="0.9" z="-0.4"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.8, 0.7, 0.2"/></bsdf></shape>""")


@pytest.mark.slow
@pytest.mark.parametrize("normals", ["smooth", "analytic"])
def test_render_matches_mitsuba_direct_and_plugin(files, llvm, normals):
    """A point-lit floor under the SDF grid and the curves (shadows of all on the floor, of
    the curves on the grid): both renderers within 1.5x the relMSE of Mitsuba's ``direct``
    (bsdf_samples 0) at the same spp against its 16x reference, and the core equal to the
    plugin (relMSE <= 1e-4). LLVM only: the shapes are Mitsuba's own (Embree on LLVM, OptiX on
    CUDA: the plugin adds nothing of its own to test on the GPU), against the core."""
    path = files / "scene.xml"
    path.write_text(SCENE.format(vol=files / "sdf.vol", curves=files / "curves.txt",
                                bsplines=files / "bsplines.txt", normals=normals))
    assert_both_match_mitsuba_direct(str(path), 4)
