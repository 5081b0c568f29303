"""Analytic expectations for the core integrator: eq. (3.10)-(3.16), shadows, depth."""
from __future__ import annotations

import math

import numpy as np
import pytest

from links1.sensor.camera import Camera
from links1.tracing.integrator import WhittedIntegrator, refract
from links1.shading.lights import CylinderSpotLight, ParallelLight, PointLight
from links1.shading.materials import Diffuse, Phong
from links1.scene.scene import Scene
from links1.geometry.shapes import Quadric, TriangleMesh
from links1.maths.transform import scale, translate


def quad(z=0.0, half=10.0, material=None, normal_up=True, name="quad"):
    """A square in the plane z = const, normal +z (or -z)."""
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]]) if normal_up else np.array([[0, 2, 1], [0, 3, 2]])
    m = TriangleMesh(v, f, name=name)
    m.material = material if material is not None else Phong(diffuse=0.5)
    return m


def sphere(center, radius, material):
    s = Quadric("sphere", translate(center) @ scale(radius))
    s.material = material
    return s


def scene_of(shapes, lights, max_depth=5, background=(0, 0, 0)):
    return Scene(camera=Camera(), shapes=list(shapes), lights=list(lights), max_depth=max_depth,
                 background=np.asarray(background, float))


def trace(scene, o, d, **kw):
    o = np.atleast_2d(np.asarray(o, float))
    d = np.atleast_2d(np.asarray(d, float))
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    n = o.shape[0]
    integ = WhittedIntegrator(scene, **kw)
    cost = np.zeros(n, dtype=np.int64)
    L, hits, _ = integ.trace(o, d, np.zeros(n), np.full(n, np.inf), cost)
    return L, integ, cost


# ---------------------------------------------------------------- eq. (3.11)
@pytest.mark.parametrize("theta_deg", [0.0, 30.0, 60.0])
def test_phong_terms_at_a_known_point(theta_deg):
    """Viewer straight above the point; parallel light at θ from the normal.

    Expected (eq. 3.11): dic + drc E cos θ + src E cos^n φ, with φ = θ (the mirror direction
    of the light makes the angle θ with the vertical viewer direction).
    """
    th = math.radians(theta_deg)
    dic, drc, src, n, E = 0.05, 0.6, 0.3, 7.0, 1.7
    mat = Phong(ambient=dic, diffuse=drc, specular_=src, exponent=n, reflectance=0.0)
    light = ParallelLight(direction=[-math.sin(th), 0.0, -math.cos(th)], irradiance=E)
    sc = scene_of([quad(material=mat)], [light])
    L, _, _ = trace(sc, [0, 0, 5], [0, 0, -1])
    expected = dic + drc * E * math.cos(th) + src * E * math.cos(th) ** n
    np.testing.assert_allclose(L[0], expected, rtol=1e-12)


def test_phong_light_below_the_surface_gives_ambient_only():
    mat = Phong(ambient=0.1, diffuse=0.6, specular_=0.3)
    sc = scene_of([quad(material=mat)], [ParallelLight(direction=[0, 0.2, 1], irradiance=1.0)])
    L, _, _ = trace(sc, [0, 0, 5], [0, 0, -1])
    np.testing.assert_allclose(L[0], 0.1, rtol=0, atol=0)


def test_phong_is_two_sided():
    """The paper's surfaces are shaded from whichever side is seen."""
    mat = Phong(ambient=0.0, diffuse=0.5, specular_=0.0)
    sc = scene_of([quad(material=mat, normal_up=False)], [ParallelLight(direction=[0, 0, -1], irradiance=2.0)])
    L, _, _ = trace(sc, [0, 0, 5], [0, 0, -1])
    np.testing.assert_allclose(L[0], 1.0, rtol=1e-12)


# ---------------------------------------------------------------- eq. (3.10)
@pytest.mark.parametrize("angle_deg", [0.0, 45.0, 89.0, 120.0, 180.0])
def test_cosine_lobe_point_light(angle_deg):
    """L_s = L1 + L2 cos θ inside ±90°, L1 outside (eq. 3.10); falloff none."""
    L1, L2 = np.array([0.2, 0.3, 0.4]), np.array([1.0, 0.5, 0.25])
    a = math.radians(angle_deg)
    light = PointLight(position=[0, 0, 0], direction=[math.sin(a), 0, math.cos(a)], L1=L1, L2=L2)
    wi, dist, L = light.illuminate(np.array([[0.0, 0.0, 3.0]]))
    expected = L1 + L2 * max(math.cos(a), 0.0)
    np.testing.assert_allclose(L[0], expected, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(dist, [3.0])
    np.testing.assert_allclose(wi[0], [0, 0, -1])


def test_point_light_inverse_square_falloff_matches_mitsuba_units():
    """Mitsuba diffuse under Mitsuba's point light: radiance ρ/π · I / h² at the foot point."""
    rho, I, h = 0.7, 5.0, 2.5
    sc = scene_of([quad(material=Diffuse(reflectance=rho))],
                  [PointLight(position=[0, 0, h], L1=I, falloff="inverse_square")])
    L, _, _ = trace(sc, [0, 0, 9], [0, 0, -1])
    np.testing.assert_allclose(L[0], rho / math.pi * I / h ** 2, rtol=1e-12)


def test_mitsuba_diffuse_is_black_from_behind():
    sc = scene_of([quad(material=Diffuse(reflectance=0.7), normal_up=False)],
                  [PointLight(position=[0, 0, 2], L1=5.0, falloff="inverse_square")])
    L, _, _ = trace(sc, [0, 0, 9], [0, 0, -1])
    np.testing.assert_array_equal(L[0], 0.0)


# ---------------------------------------------------------------- cylinder spotlight
def test_cylinder_spotlight_edge_and_base_plane():
    R = 1.5
    spot = CylinderSpotLight(origin=[0, 0, 4], direction=[0, 0, -1], radius=R, intensity=[1, 2, 3])
    p = np.array([[R * (1 - 1e-9), 0, 0], [R * (1 + 1e-9), 0, 0], [0, R * 0.999, 3.9], [0, 0, 4.1]])
    wi, dist, L = spot.illuminate(p)
    np.testing.assert_array_equal(L[0], [1, 2, 3])
    np.testing.assert_array_equal(L[1], [0, 0, 0])
    np.testing.assert_array_equal(L[2], [1, 2, 3])
    np.testing.assert_array_equal(L[3], [0, 0, 0])  # behind the base plane: unlit
    np.testing.assert_allclose(dist[:3], [4.0, 0.0, 0.1])  # shadow rays end at the base plane
    np.testing.assert_array_equal(wi[0], [0, 0, 1])


def test_spotlight_shadow_ray_ends_at_the_base_plane():
    """An opaque object *behind* the spotlight's base disc casts no shadow."""
    floor = quad(material=Phong(diffuse=0.5, specular_=0.0))
    blocker = quad(z=6.0, half=3.0, material=Phong(diffuse=0.5), name="behind")
    spot = CylinderSpotLight(origin=[0, 0, 4], direction=[0, 0, -1], radius=2.0, intensity=1.0)
    sc = scene_of([floor, blocker], [spot])
    L, _, _ = trace(sc, [0.5, 0, 3], [0, 0, -1])
    np.testing.assert_allclose(L[0], 0.5, rtol=1e-12)


# ---------------------------------------------------------------- shadows, 3-3-3
def test_transparent_shadows_multiply_t1_t2():
    t1, t2 = np.array([0.9, 0.3, 0.3]), np.array([0.3, 0.4, 0.9])
    floor = quad(material=Phong(diffuse=1.0, specular_=0.0))
    pane1 = quad(z=1.0, half=2.0, material=Phong(diffuse=0.0, transmittance=t1), name="p1")
    pane2 = quad(z=2.0, half=2.0, material=Phong(diffuse=0.0, transmittance=t2), name="p2")
    sc = scene_of([floor, pane1, pane2], [ParallelLight(direction=[0, 0, -1], irradiance=1.0)], max_depth=1)
    # look at the floor from the side so the camera ray does not cross the panes
    L, _, _ = trace(sc, [[0.5, 0.0, 0.5], [5.0, 0.0, 0.5]], [[0, 0, -1], [0, 0, -1]])
    np.testing.assert_allclose(L[0], t1 * t2, rtol=1e-12)
    np.testing.assert_allclose(L[1], 1.0, rtol=1e-12)  # outside the panes' shadow


def test_closed_transparent_object_scales_the_light_once():
    t = np.array([0.5, 0.6, 0.7])
    floor = quad(material=Phong(diffuse=1.0, specular_=0.0))
    ball = sphere([0, 0, 2], 0.5, Phong(diffuse=0.0, transmittance=t, ior=1.0))
    sc = scene_of([floor, ball], [PointLight(position=[0, 0, 6], L1=1.0)], max_depth=1)
    L, _, _ = trace(sc, [0.0, 0.2, 0.5], [0, 0, -1])
    # shadow ray from (0, 0.2, 0) to the light crosses the ball's surface twice
    np.testing.assert_allclose(L[0], t * math.cos(math.atan2(0.2, 6.0)), rtol=1e-12)


def test_opaque_occluder_blocks():
    floor = quad(material=Phong(diffuse=1.0, specular_=0.0))
    ball = sphere([0, 0, 2], 0.5, Phong(diffuse=0.3))
    sc = scene_of([floor, ball], [PointLight(position=[0, 0, 6], L1=1.0)], max_depth=1)
    L, _, _ = trace(sc, [0.0, 0.1, 0.5], [0, 0, -1])
    np.testing.assert_array_equal(L[0], 0.0)


# ---------------------------------------------------------------- eq. (3.12)-(3.16)
def test_mirror_reflection_weight_and_direction():
    """Camera ray at 45° onto a mirror floor sees a lit wall: I = r · I(wall)."""
    r = 0.8
    mirror = quad(material=Phong(diffuse=0.0, specular_=0.0, reflectance=r))
    wall_v = np.array([[5, -10, -10], [5, 10, -10], [5, 10, 10], [5, -10, 10]], float)
    wall = TriangleMesh(wall_v, np.array([[0, 1, 2], [0, 2, 3]]), name="wall")
    wall.material = Phong(ambient=0.25, diffuse=0.0, specular_=0.0)
    sc = scene_of([mirror, wall], [])
    L, integ, _ = trace(sc, [-1, 0, 1], [1, 0, -1])
    np.testing.assert_allclose(L[0], r * 0.25, rtol=1e-12)
    assert integ.stats.rays["reflect"] == 1
    assert integ.stats.rays["refract"] == 0


@pytest.mark.parametrize("theta_deg", [0.0, 20.0, 41.0, 60.0, 89.0])
def test_refract_obeys_snell(theta_deg):
    eta = 1.0 / 1.5
    th = math.radians(theta_deg)
    d = np.array([[math.sin(th), 0.0, -math.cos(th)]])
    n = np.array([[0.0, 0.0, 1.0]])
    dt, tir = refract(d, n, np.array([eta]))
    assert not tir[0]
    sin_t = math.hypot(dt[0, 0], dt[0, 1])
    np.testing.assert_allclose(sin_t, eta * math.sin(th), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(dt[0]), 1.0, rtol=1e-14)
    assert dt[0, 2] < 0


@pytest.mark.parametrize("theta_deg,expect_tir", [(41.0, False), (41.9, True), (70.0, True)])
def test_total_internal_reflection_from_inside_glass(theta_deg, expect_tir):
    """Critical angle for η = 1.5 is asin(1/1.5) = 41.81°."""
    th = math.radians(theta_deg)
    d = np.array([[math.sin(th), 0.0, -math.cos(th)]])
    _, tir = refract(d, np.array([[0.0, 0.0, 1.0]]), np.array([1.5]))
    assert bool(tir[0]) is expect_tir


def test_slab_shifts_the_ray_laterally_by_snell():
    """A ray through a glass slab (η = 1.5, thickness h) at 45° leaves parallel, shifted by
    h sin(θ − θt)/cos θt; a cylinder spotlight edge on the floor behind reveals the shift."""
    h, ior = 1.0, 1.5
    glass = Phong(ambient=0.0, diffuse=0.0, specular_=0.0, reflectance=0.0, transmittance=1.0, ior=ior)
    top = quad(z=2.0, half=50.0, material=glass, name="top")
    bottom = quad(z=2.0 - h, half=50.0, material=glass, name="bottom", normal_up=False)
    floor = quad(z=0.0, half=50.0, material=Phong(diffuse=1.0, specular_=0.0), name="floor")
    edge = 3.0  # lit where x <= edge (a huge cylinder whose boundary is the plane x = edge near y = 0)
    big = 1e4
    spot = CylinderSpotLight(origin=[edge - big, 0, 10], direction=[0, 0, -1], radius=big, intensity=1.0)
    th = math.radians(45.0)
    th_t = math.asin(math.sin(th) / ior)
    # straight-line landing x of a ray from (x0, 0, 3) at 45°: x0 + 3; through the slab it
    # falls short by the lateral offset along x: h (tan θ − tan θt)
    short = h * (math.tan(th) - math.tan(th_t))
    xs = np.array([edge - 3.0 + short - 1e-3, edge - 3.0 + short + 1e-3])
    o = np.stack([xs, np.zeros(2), np.full(2, 3.0)], axis=1)
    d = np.tile([math.sin(th), 0.0, -math.cos(th)], (2, 1))
    sc = scene_of([top, bottom, floor], [spot], max_depth=4)
    L, integ, _ = trace(sc, o, d)
    assert L[0, 0] > 0.0 and L[1, 0] == 0.0
    assert integ.stats.rays["refract"] == 4  # into and out of the slab, for both rays


def test_max_depth_bounds_the_ray_tree():
    """Two facing mirrors: max_depth D spawns D − 1 mirror rays per camera ray."""
    m = Phong(ambient=0.1, diffuse=0.0, specular_=0.0, reflectance=0.5)
    a = quad(z=0.0, material=m, name="a")
    b = quad(z=1.0, material=m, name="b", normal_up=False)
    for depth in (1, 2, 5):
        sc = scene_of([a, b], [], max_depth=depth)
        L, integ, _ = trace(sc, [0, 0, 0.5], [0, 0, -1])
        assert integ.stats.rays["reflect"] == depth - 1
        expected = sum(0.1 * 0.5 ** k for k in range(depth))
        np.testing.assert_allclose(L[0], expected, rtol=1e-12)


def test_background_and_escaping_rays():
    sc = scene_of([], [], background=(0.1, 0.2, 0.3))
    L, _, cost = trace(sc, [0, 0, 0], [0, 0, 1])
    np.testing.assert_array_equal(L[0], [0.1, 0.2, 0.3])
    assert cost[0] == 0


def test_min_weight_prunes_the_tree_within_its_bound():
    m = Phong(ambient=0.1, diffuse=0.0, specular_=0.0, reflectance=0.5)
    a = quad(z=0.0, material=m, name="a")
    b = quad(z=1.0, material=m, name="b", normal_up=False)
    sc = scene_of([a, b], [], max_depth=20)
    full, integ_full, _ = trace(sc, [0, 0, 0.5], [0, 0, -1], min_weight=0.0)
    pruned, integ, _ = trace(sc, [0, 0, 0.5], [0, 0, -1], min_weight=1 / 255)
    assert integ.stats.rays["reflect"] < integ_full.stats.rays["reflect"]
    # the dropped tail is bounded by the weight threshold times the largest radiance (0.1 / (1 - 0.5))
    assert 0 <= full[0, 0] - pruned[0, 0] <= (1 / 255) * 0.2
