"""Mitsuba's ``ellipsoids`` and ``ellipsoidsmesh`` in the core, against Mitsuba 3.9.1's own
intersection (``scene.ray_intersect``, llvm_ad_rgb: the ellipsoids' closed-form test with back
faces culled; the mesh's triangles in Embree, culled from behind by its filter) and against the
plugin's render, which traces them through Mitsuba.

Six ellipsoids of random centres, semi-axes and rotations in a PLY file, placed by a rotating,
non-uniformly scaling ``to_world`` (Mitsuba's rule: the centres by the whole map, the semi-axes
by its mean stretch). Random rays from a sphere of radius 5 toward them, and rays from the
centre of one (inside: culled): the same rays hit and miss in both, at distances within
Mitsuba's float32 errors, with the same normals, ellipsoid index and (mesh) uv."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from links1.geometry import ellipsoids as ell

from tests.scenes import integrator, lit_floor, perspective, scene

from .conftest import assert_both_match_mitsuba_direct

pytestmark = pytest.mark.mitsuba


@pytest.fixture
def ply(tmp_path):
    rng = np.random.default_rng(0)
    q = rng.normal(size=(6, 4))
    ell.write_ellipsoids(tmp_path / "e.ply", rng.uniform(-1, 1, (6, 3)), rng.uniform(0.1, 0.3, (6, 3)),
                         q / np.linalg.norm(q, axis=1)[:, None])
    return tmp_path / "e.ply"


def _rays(n=3000, radius=5.0, seed=1):
    rng = np.random.default_rng(seed)
    tgt = rng.normal(size=(n, 3)) * 0.8
    o = rng.normal(size=(n, 3))
    o = o / np.linalg.norm(o, axis=1)[:, None] * radius
    d = tgt - o
    return o, d / np.linalg.norm(d, axis=1)[:, None]


@pytest.mark.parametrize("plugin, shell, mirror", [
    ("ellipsoids", None, False), ("ellipsoidsmesh", "ico_sphere", False), ("ellipsoidsmesh", "uv_sphere", False),
    ("ellipsoidsmesh", "box", False), ("ellipsoids", None, True), ("ellipsoidsmesh", "ico_sphere", True)])
def test_hits_match_mitsuba(ply, llvm, plugin, shell, mirror):
    """The core's hits, distances, normals, ellipsoid index and uv against Mitsuba's
    ``ray_intersect``. A mirroring ``to_world`` makes Mitsuba's semi-axes negative: the same
    ellipsoids, but the mesh's shells turned inside out (seen from inside, culled from outside).
    LLVM only: a test of the core against a reference Mitsuba computes once."""
    import mitsuba as mi
    to_world = mi.ScalarTransform4f().translate([0.1, 0.2, -0.1]).rotate([1, 2, 3], 25).scale(
        [-1.3 if mirror else 1.3, 1.1, 0.9])
    extent = 1.5
    spec = {"type": plugin, "filename": str(ply), "to_world": to_world, "extent": extent}
    if shell is not None:
        spec["shell"] = shell
    centers, rot, scales, _ = ell.read_ellipsoids(ply, np.array(to_world.matrix))
    if plugin == "ellipsoids":
        core = ell.Ellipsoids(centers, rot, scales * extent)
    else:
        core = ell.EllipsoidsMesh(centers, rot, scales * extent, ell.shell(shell))
    o, d = _rays()
    rng = np.random.default_rng(2)
    inner = rng.normal(size=(200, 3))
    o = np.concatenate([o, np.repeat(centers[:1], 200, 0)])
    d = np.concatenate([d, inner / np.linalg.norm(inner, axis=1)[:, None]])
    sc = mi.load_dict({"type": "scene", "s": spec})
    si = sc.ray_intersect(mi.Ray3f(mi.Point3f(*o.T.astype(np.float32)), mi.Vector3f(*d.T.astype(np.float32))))
    tm = np.array(si.t, dtype=np.float64)
    t, prim = core.intersect(o, d, 0.0, np.inf)
    hit = np.isfinite(t)
    assert 600 < hit[:3000].sum() < 2400                  # both hits and misses from outside
    assert np.array_equal(hit, np.isfinite(tm))
    if mirror and plugin == "ellipsoidsmesh":
        assert hit[3000:].all()                           # an inside-out shell is seen from inside
    else:
        assert hit[3000:].sum() < 100                     # most rays from inside see nothing
    _, ng, ns = core.surface(o[hit], d[hit], t[hit], prim[hit])
    uv = core.uv(o[hit], d[hit], t[hit], prim[hit])
    which = prim[hit] if plugin == "ellipsoids" else prim[hit] // core.faces_per_ellipsoid
    assert np.array_equal(which, np.array(si.prim_index, dtype=np.int64)[hit])
    # Mitsuba's float32 arithmetic; the ellipsoids' quadratic is solved from a point of the ray
    # that is not its closest approach (``dot(-o, d) / |d|`` for a non-unit d), whose
    # ``|p|² - 1`` cancels: a float32 emulation of it strays by up to 3e-4 at distance 5
    tol = 1e-4 if plugin == "ellipsoids" else 2e-5
    assert np.max(np.abs(t[hit] - tm[hit])) < tol * 5.0
    assert np.max(np.abs(ng - np.array(si.n, dtype=np.float64).T[hit])) < 1e-3
    assert np.array_equal(ng, ns)
    assert np.max(np.abs(uv - np.array(si.uv, dtype=np.float64).T[hit])) < 1e-4
    assert np.all(np.einsum("ij,ij->i", ng, d[hit]) < 0)   # entries only


SCENE = scene(integrator("direct", bsdf_samples=0),
              perspective("0.4, 2.0, 4.5", "0, 0, 0", fov=40, width=48, height=40, spp=None), lit_floor(-0.8), """
  <shape type="ellipsoids"><string name="filename" value="{ply}"/><float name="extent" value="1.2"/>
    <transform name="to_world"><rotate y="1" angle="30"/><scale x="1.2" y="1" z="0.9"/><translate y="0.2"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.3, 0.2"/></bsdf></shape>
  <shape type="ellipsoidsmesh"><string name="filename" value="{ply}"/><float name="extent" value="1.2"/>
    <transform name="to_world"><scale value="0.8"/><translate x="0.3" y="-0.3" z="1.4"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.5, 0.8"/></bsdf></shape>""")


def test_render_matches_mitsuba_direct_and_plugin(ply, llvm):
    """A point-lit floor under both kinds of ellipsoids (their shadows on the floor and on each
    other): both renderers within 1.5x the relMSE of Mitsuba's ``direct`` (bsdf_samples 0) at
    the same spp against its 16x reference, and the core equal to the plugin (relMSE <= 1e-4).
    LLVM only: the shapes are Mitsuba's own (the plugin adds nothing of its own to test on the
    GPU), against the core."""
    path = ply.parent / "scene.xml"
    path.write_text(SCENE.format(ply=ply))
    assert_both_match_mitsuba_direct(str(path), 4)


def test_nested_shell_matches_mitsuba(ply, llvm):
    """An ``ellipsoidsmesh`` whose shell is a nested, turned and stretched ``cube`` (Mitsuba
    takes the nested mesh's placed vertices): the scene file loaded by the core and by Mitsuba
    gives the same hits, at distances within float32 rounding. LLVM only: a test of the core
    against a reference Mitsuba computes once."""
    import mitsuba as mi

    from links1 import load_scene
    path = ply.parent / "shell.xml"
    path.write_text(scene(f'<shape type="ellipsoidsmesh"><string name="filename" value="{ply}"/>'
                          '<shape type="cube" name="shell"><transform name="to_world"><rotate z="1" angle="30"/>'
                          '<scale x="1.5" y="1" z="0.8"/></transform></shape></shape>'))
    o, d = _rays()
    si = mi.load_file(str(path)).ray_intersect(
        mi.Ray3f(mi.Point3f(*o.T.astype(np.float32)), mi.Vector3f(*d.T.astype(np.float32))))
    tm = np.array(si.t, dtype=np.float64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")          # no sensor: Mitsuba's default camera
        core = load_scene(str(path)).shapes[0]
    assert core.faces_per_ellipsoid == 12
    t, _ = core.intersect(o, d, 0.0, np.inf)
    hit = np.isfinite(t)
    assert 600 < hit.sum() < 2800 and np.array_equal(hit, np.isfinite(tm))
    assert np.max(np.abs(t[hit] - tm[hit])) < 2e-5 * 5.0
