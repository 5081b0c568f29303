"""Triangles (eq. 3.1-3.3), clipped quadrics (eq. 3.4-3.5) and the disk, against analytic
expectations (docs numerics stress cases 5, 6, 8, 9, 11, 12)."""
from __future__ import annotations


import numpy as np
import pytest

from links1.maths import transform as tf
from links1.geometry.shapes import Disk, Quadric, TriangleMesh

INF = np.inf


def rays(o, d):
    o = np.atleast_2d(np.asarray(o, dtype=np.float64))
    d = np.atleast_2d(np.asarray(d, dtype=np.float64))
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    o = np.broadcast_to(o, d.shape).copy() if o.shape[0] == 1 else o
    d = np.broadcast_to(d, o.shape).copy() if d.shape[0] == 1 else d
    n = o.shape[0]
    return o, d, np.zeros(n), np.full(n, INF)


def cube_mesh(half=1.0):
    v = np.array([[x, y, z] for x in (-half, half) for y in (-half, half) for z in (-half, half)])
    # Outward winding: (v1 - v0) x (v2 - v0) points out.
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    f = []
    for a, b, c, d in quads:
        f += [(a, b, c), (a, c, d)]
    return TriangleMesh(v, np.array(f))


def uv_sphere(nu=50, nv=51):
    th = np.linspace(0, np.pi, nv)[1:-1]
    ph = np.linspace(0, 2 * np.pi, nu, endpoint=False)
    T, P = np.meshgrid(th, ph, indexing="ij")
    ring = np.stack([np.sin(T) * np.cos(P), np.cos(T), np.sin(T) * np.sin(P)], -1).reshape(-1, 3)
    v = np.vstack([ring, [[0, 1, 0], [0, -1, 0]]])
    top, bot = len(v) - 2, len(v) - 1
    f = []
    for j in range(nu):
        f.append((top, (j + 1) % nu, j))
    for i in range(len(th) - 1):
        for j in range(nu):
            a, b = i * nu + j, i * nu + (j + 1) % nu
            c, d = a + nu, b + nu
            f += [(a, b, c), (b, d, c)]
    base = (len(th) - 1) * nu
    for j in range(nu):
        f.append((bot, base + j, base + (j + 1) % nu))
    return v, np.array(f)


# ---------------------------------------------------------------------------- triangles
def test_triangle_distance_and_barycentrics_analytic():
    v = np.array([[0.0, 0, 5], [2, 0, 5], [0, 2, 5]])
    m = TriangleMesh(v, [[0, 1, 2]])
    rng = np.random.default_rng(0)
    b = rng.dirichlet([1, 1, 1], size=500)
    target = b @ v
    o = rng.normal(size=(500, 3)) * 3 + np.array([0, 0, -4])
    d = target - o
    dist = np.linalg.norm(d, axis=1)
    o, d, tmin, tmax = rays(o, d)
    cost = np.zeros(500, dtype=np.int64)
    t, prim = m.intersect(o, d, tmin, tmax, cost)
    assert np.all(prim == 0)
    np.testing.assert_allclose(t, dist, rtol=1e-13)
    np.testing.assert_allclose(m.barycentrics(o, d, prim), b, atol=1e-12)
    p, ng, ns = m.surface(o, d, t, prim)
    np.testing.assert_allclose(p, target, atol=1e-12)
    # Mitsuba winding: (v1 - v0) x (v2 - v0) = +z; never flipped toward the ray.
    np.testing.assert_array_equal(ng, np.tile([0.0, 0.0, 1.0], (500, 1)))
    np.testing.assert_array_equal(ns, ng)
    assert np.all(cost == 1)


def test_triangle_miss_outside_and_behind():
    m = TriangleMesh([[0.0, 0, 5], [2, 0, 5], [0, 2, 5]], [[0, 1, 2]])
    o, d, tmin, tmax = rays([[1.5, 1.5, 0], [0.5, 0.5, 0], [0.5, 0.5, 0]], [[0, 0, 1], [0, 0, -1], [0, 0, 1]])
    tmax[2] = 4.9  # segment ends before the plane
    t, prim = m.intersect(o, d, tmin, tmax)
    assert np.all(np.isinf(t)) and np.all(prim == -1)


def test_shading_normal_interpolation_eq_3_3():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    nrm = np.array([[0.0, 0, 1], [1, 0, 1], [0, 1, 1]])
    m = TriangleMesh(v, [[0, 1, 2]], normals=nrm)
    b = np.array([0.2, 0.3, 0.5])
    o, d, tmin, tmax = rays(b @ v + [0, 0, 3], [0, 0, -1])
    t, prim = m.intersect(o, d, tmin, tmax)
    _, ng, ns = m.surface(o, d, t, prim)
    expect = b @ nrm
    expect /= np.linalg.norm(expect)
    np.testing.assert_allclose(ns[0], expect, atol=1e-14)
    np.testing.assert_allclose(ng[0], [0, 0, 1], atol=0)


def test_watertight_shared_edge_of_quad():
    # Two triangles sharing the diagonal v0-v2, at an awkward position and scale.
    v = np.array([[0.1, 0.2, 3.3], [1.7, 0.3, 3.1], [1.9, 1.6, 2.9], [0.2, 1.3, 3.4]])
    m = TriangleMesh(v, [[0, 1, 2], [0, 2, 3]])
    rng = np.random.default_rng(1)
    n = 20000
    s = rng.random(n)
    target = v[0] + s[:, None] * (v[2] - v[0])  # exactly (to rounding) on the shared edge
    o = rng.normal(size=(n, 3)) * 0.5 + [1.0, 0.8, -2.0]
    o, d, tmin, tmax = rays(o, target - o)
    t, prim = m.intersect(o, d, tmin, tmax)
    assert np.all(np.isfinite(t)), f"{np.sum(~np.isfinite(t))} rays leaked through the edge"
    assert set(np.unique(prim)) <= {0, 1}


def test_closed_mesh_from_inside_no_cracks_through_edges_and_vertices():
    v, f = uv_sphere(24, 25)
    m = TriangleMesh(v, f)
    assert m.closed
    rng = np.random.default_rng(2)
    # Aim at every vertex and at points on every edge from several inner origins.
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    s = rng.random(len(e))[:, None]
    targets = np.vstack([v, v[e[:, 0]] + s * (v[e[:, 1]] - v[e[:, 0]])])
    for origin in ([0, 0, 0], [0.3, -0.2, 0.1], [-0.5, 0.4, -0.3]):
        o, d, tmin, tmax = rays(np.tile(origin, (len(targets), 1)), targets - np.array(origin))
        t, _ = m.intersect(o, d, tmin, tmax)
        assert np.all(np.isfinite(t))


def test_plane_through_origin_is_a_miss_not_nan():
    m = TriangleMesh([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    # Origins in the triangle's plane; directions in the plane and out of it.
    o, d, tmin, tmax = rays([[0.2, 0.2, 0], [-1, 0.3, 0], [0.2, 0.2, 0], [0.3, 0.3, 0]],
                            [[1, 0, 0], [1, 0, 0], [0, 0, 1], [0.3, 0.4, -1]])
    with np.errstate(all="raise"):
        pass
    t, prim = m.intersect(o, d, tmin, tmax)
    assert not np.any(np.isnan(t))
    assert np.all(np.isinf(t)) and np.all(prim == -1)
    assert not np.any(m.any_hit(o, d, tmin, tmax))


def test_needle_and_tiny_triangles_far_away():
    # A needle 1e-9 wide and 1 long.
    m = TriangleMesh([[0.0, 0, 10], [1, 0, 10], [0.5, 1e-9, 10]], [[0, 1, 2]])
    o, d, tmin, tmax = rays([[0.5, 2.5e-10, 0], [0.5, 2e-9, 0], [0.5, -1e-12, 0]], [0, 0, 1])
    t, _ = m.intersect(o, d, tmin, tmax)
    assert t[0] == 10.0 and np.isinf(t[1]) and np.isinf(t[2])
    # A 1e-4-sized triangle at distance 1e3, hit at its centroid from an oblique origin.
    c = np.array([1e3, 2e2, -3e2])
    v = c + 1e-4 * np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0.3]])
    m = TriangleMesh(v, [[0, 1, 2]])
    target = v.mean(axis=0)
    o, d, tmin, tmax = rays([[0.0, 0, 0]], [target])
    t, _ = m.intersect(o, d, tmin, tmax)
    np.testing.assert_allclose(t[0], np.linalg.norm(target), rtol=1e-13)
    o2, d2, _, _ = rays([[0.0, 0, 0]], [target + [0, 1e-4, 0]])
    assert np.isinf(m.intersect(o2, d2, tmin, tmax)[0][0])


def test_closed_detection():
    assert cube_mesh().closed
    quad = TriangleMesh([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]])
    assert not quad.closed
    assert TriangleMesh(quad.vertices, quad.faces, closed=True).closed


def test_cube_normals_outward_and_exit_from_inside():
    m = cube_mesh()
    o, d, tmin, tmax = rays([[0.1, 0.2, -5], [0.1, 0.2, 0.3]], [[0, 0, 1], [0, 0, 1]])
    t, prim = m.intersect(o, d, tmin, tmax)
    np.testing.assert_allclose(t, [4.0, 0.7], rtol=1e-15)
    _, ng, _ = m.surface(o, d, t, prim)
    np.testing.assert_allclose(ng, [[0, 0, -1], [0, 0, 1]], atol=0)


@pytest.mark.parametrize("k,shift", [(1e-4, 0.0), (1e4, 0.0), (1.0, 1e5), (1e-4, 1e5)])
def test_mesh_translated_and_scaled(k, shift):
    base = cube_mesh()
    m = TriangleMesh(base.vertices * k + shift, base.faces)
    rng = np.random.default_rng(9)
    target = rng.uniform(-0.9, 0.9, size=(300, 3))
    target[:, 2] = -1.0  # points on the z = -1 face
    o = np.array([0.1, -0.2, -6.0]) + rng.normal(size=(300, 3)) * [1, 1, 0.1]
    dist = np.linalg.norm(target - o, axis=1)
    o2, d, tmin, tmax = rays(o * k + shift, target - o)
    t, prim = m.intersect(o2, d, tmin, tmax)
    np.testing.assert_allclose(t / k, dist, rtol=1e-6 if shift else 1e-12)
    _, ng, _ = m.surface(o2, d, t, prim)
    np.testing.assert_allclose(ng, np.tile([0, 0, -1.0], (300, 1)), atol=1e-9)


def test_mesh_validation():
    with pytest.raises(ValueError):
        TriangleMesh(np.zeros((0, 3)), [[0, 1, 2]])
    with pytest.raises(ValueError):
        TriangleMesh([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 3]])
    with pytest.raises(ValueError):
        TriangleMesh([[0.0, 0, 0], [1, 0, np.nan], [0, 1, 0]], [[0, 1, 2]])
    with pytest.raises(ValueError):
        TriangleMesh([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], normals=np.zeros((2, 3)))


def test_mesh_5000_triangles_bvh_culls():
    v, f = uv_sphere(50, 52)
    assert 4900 <= len(f) <= 5100
    m = TriangleMesh(v, f)
    n = 256
    x, y = np.meshgrid(np.linspace(-1.2, 1.2, n), np.linspace(-1.2, 1.2, n))
    o = np.stack([x.ravel(), y.ravel(), np.full(n * n, -5.0)], -1)
    d = np.tile([0, 0, 1.0], (n * n, 1))
    cost = np.zeros(n * n, dtype=np.int64)
    t, _ = m.intersect(o, d, np.zeros(n * n), np.full(n * n, INF), cost)
    r2 = x.ravel() ** 2 + y.ravel() ** 2
    # The tessellation lies inside the unit sphere: hits inside, misses outside.
    assert np.all(np.isinf(t[r2 > 1.0]))
    assert np.all(np.isfinite(t[r2 < 0.99]))
    assert cost.mean() < 20  # the hierarchy culls: a handful of leaves per ray (speed: compare/)


# ---------------------------------------------------------------------------- quadrics
def test_sphere_distance_and_normal():
    s = Quadric("sphere", tf.translate([1, 2, 3]) @ tf.scale(2.0))
    rng = np.random.default_rng(3)
    n = 1000
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    o = np.array([1, 2, 3]) - 10 * dirs  # 10 from the centre, aimed at it (off-axis below)
    perp = np.cross(dirs, rng.normal(size=(n, 3)))
    perp /= np.linalg.norm(perp, axis=1, keepdims=True)
    b = rng.random(n) * 1.9
    o = o + b[:, None] * perp
    o, d, tmin, tmax = rays(o, dirs)
    cost = np.zeros(n, dtype=np.int64)
    t, prim = s.intersect(o, d, tmin, tmax, cost)
    np.testing.assert_allclose(t, 10 - np.sqrt(4 - b * b), rtol=1e-13)
    p, ng, ns = s.surface(o, d, t, prim)
    np.testing.assert_allclose(ng, (p - [1, 2, 3]) / 2, atol=1e-13)
    assert np.all(cost == 1) and np.all(prim == 0)
    assert s.closed


def test_ellipsoid_distance_normal_and_bounds():
    M = tf.translate([0.5, -1, 2]) @ tf.rotate([1, 2, 3], 37) @ tf.scale([3.0, 1.0, 0.5])
    s = Quadric("sphere", M)
    rng = np.random.default_rng(4)
    n = 2000
    o = rng.normal(size=(n, 3)) * 8
    target = M[:3, 3] + rng.normal(size=(n, 3))
    o, d, tmin, tmax = rays(o, target - o)
    t, prim = s.intersect(o, d, tmin, tmax)
    # Analytic: solve |A(o + t d - m)|^2 = 1 in object space by the textbook formula.
    A = np.linalg.inv(M[:3, :3])
    u = (o - M[:3, 3]) @ A.T
    v = d @ A.T
    a, b, c = (v * v).sum(1), (u * v).sum(1), (u * u).sum(1) - 1
    disc = b * b - a * c
    hit = disc > 1e-9
    t_ref = (-b - np.sqrt(np.maximum(disc, 0))) / a
    t_ref = np.where(t_ref > 0, t_ref, (-b + np.sqrt(np.maximum(disc, 0))) / a)
    assert np.array_equal(np.isfinite(t[hit | (disc < -1e-9)]), hit[hit | (disc < -1e-9)])
    np.testing.assert_allclose(t[hit], t_ref[hit], rtol=1e-10)
    p, ng, _ = s.surface(o[hit], d[hit], t[hit], prim[hit])
    y = (p - M[:3, 3]) @ A.T
    expect = y @ A
    expect /= np.linalg.norm(expect, axis=1, keepdims=True)
    np.testing.assert_allclose(ng, expect, atol=1e-12)
    lo, hi = s.bounds()
    assert np.all(p >= lo - 1e-12) and np.all(p <= hi + 1e-12)
    # The box is tight: extreme points of the ellipsoid touch it.
    L = M[:3, :3]
    for i in range(3):
        w = L[i] / np.linalg.norm(L[i])
        assert np.isclose((L @ w)[i] + M[i, 3], hi[i], rtol=1e-14)


def test_eye_inside_sphere_gets_exit_hit_backfacing():
    s = Quadric("sphere", np.eye(4))
    o, d, tmin, tmax = rays([[0.2, 0.1, 0.0]], [[0, 0, 1]])
    t, prim = s.intersect(o, d, tmin, tmax)
    np.testing.assert_allclose(t, [np.sqrt(1 - 0.05)], rtol=1e-15)
    _, ng, _ = s.surface(o, d, t, prim)
    assert np.dot(ng[0], -d[0]) < 0  # back-facing: the integrator sees the inside


def test_hemisphere_seen_through_its_opening():
    clips = [(np.array([0.0, 1, 0]), 0.0)]  # keep y <= 0: a bowl open at the top
    bowl = Quadric("sphere", np.eye(4), clips=clips)
    assert not bowl.closed
    xs = np.array([0.0, 0.5, 0.9])
    o, d, tmin, tmax = rays(np.stack([xs, np.full(3, 10.0), np.zeros(3)], -1), [[0, -1, 0]])
    t, prim = bowl.intersect(o, d, tmin, tmax)
    np.testing.assert_allclose(t, 10 + np.sqrt(1 - xs ** 2), rtol=1e-14)  # far root
    p, ng, _ = bowl.surface(o, d, t, prim)
    np.testing.assert_allclose(ng, p, atol=1e-14)  # outward: away from the viewer
    assert np.all((ng * -d).sum(1) < 0)
    # From below it is the outside of the bowl (near root).
    o2, d2, _, _ = rays(np.stack([xs, np.full(3, -10.0), np.zeros(3)], -1), [[0, 1, 0]])
    t2, _ = bowl.intersect(o2, d2, tmin, tmax)
    np.testing.assert_allclose(t2, 10 - np.sqrt(1 - xs ** 2), rtol=1e-14)
    # Capped: the flat lid (plane normal +y) is hit first from above.
    lid = Quadric("sphere", np.eye(4), clips=clips, capped=True)
    assert lid.closed
    t3, prim3 = lid.intersect(o, d, tmin, tmax)
    np.testing.assert_allclose(t3, [10, 10, 10], rtol=0)
    assert np.all(prim3 == 1)
    _, ng3, _ = lid.surface(o, d, t3, prim3)
    np.testing.assert_array_equal(ng3, np.tile([0.0, 1, 0], (3, 1)))


def test_rays_in_a_clip_plane_are_deterministic():
    bowl = Quadric("sphere", np.eye(4), clips=[(np.array([0.0, 1, 0]), 0.0)])
    o, d, tmin, tmax = rays([[-5, 0, 0.3], [-5, 0, 0.3]], [[1, 0, 0], [1, 0, 0]])
    t1, _ = bowl.intersect(o, d, tmin, tmax)
    t2, _ = bowl.intersect(o[::-1], d[::-1], tmin, tmax)
    assert not np.any(np.isnan(t1))
    np.testing.assert_array_equal(t1, t2)
    np.testing.assert_allclose(t1, 5 - np.sqrt(1 - 0.09), rtol=1e-14)  # n.y <= h keeps y = 0


def _capped_cylinder(zlo=-1.0, zhi=1.0, M=None, capped=True):
    clips = [(np.array([0.0, 0, 1]), zhi), (np.array([0.0, 0, -1]), -zlo)]
    return Quadric("cylinder", np.eye(4) if M is None else M, clips=clips, capped=capped)


def test_capped_cylinder_cap_hit_and_normal():
    M = tf.translate([1, 2, 3]) @ tf.rotate([1, 0, 0], 90) @ tf.scale([0.5, 0.5, 2.0])
    cyl = _capped_cylinder(M=M)
    assert cyl.closed
    # Object z axis maps to world -y... (rotate x by 90: z -> -y); caps at y = 2 -/+ 2.
    axis = M[:3, :3] @ [0, 0, 1.0]
    axis /= np.linalg.norm(axis)
    o, d, tmin, tmax = rays(M[:3, 3] + 10 * axis + [0.1, 0, 0.1], -axis)
    t, prim = cyl.intersect(o, d, tmin, tmax)
    np.testing.assert_allclose(t, [8.0], rtol=1e-14)
    assert prim[0] == 1  # the cap of clip plane 0 (z <= 1)
    _, ng, _ = cyl.surface(o, d, t, prim)
    np.testing.assert_allclose(ng[0], axis, atol=1e-15)
    # A side hit: from +x, the wall of radius 0.5.
    o, d, tmin, tmax = rays(M[:3, 3] + [10, 0, 0], [-1, 0, 0])
    t, prim = cyl.intersect(o, d, tmin, tmax)
    np.testing.assert_allclose(t, [9.5], rtol=1e-14)
    _, ng, _ = cyl.surface(o, d, t, prim)
    np.testing.assert_allclose(ng[0], [1, 0, 0], atol=1e-15)
    lo, hi = cyl.bounds()
    np.testing.assert_allclose(lo, [0.5, 0, 2.5], atol=1e-14)
    np.testing.assert_allclose(hi, [1.5, 4, 3.5], atol=1e-14)


def test_ray_parallel_to_cylinder_axis_inside_and_outside():
    capped, open_ = _capped_cylinder(), _capped_cylinder(capped=False)
    o, d, tmin, tmax = rays([[0.5, 0, -10], [0.5, 0, 0], [2, 0, -10], [1.0, 0, -10]],
                            [[0, 0, 1], [0, 0, 1], [0, 0, 1], [0, 0, 1]])
    t, prim = capped.intersect(o, d, tmin, tmax)
    assert t[0] == 9.0 and prim[0] == 2  # the z >= -1 cap, entering
    assert t[1] == 1.0 and prim[1] == 1  # from inside: the z <= 1 cap, leaving
    assert np.isinf(t[2])  # outside: a = 0, c > 0: miss
    assert not np.any(np.isnan(t))
    _, ng, _ = capped.surface(o[:2], d[:2], t[:2], prim[:2])
    np.testing.assert_array_equal(ng, [[0, 0, -1.0], [0, 0, 1.0]])
    t, prim = open_.intersect(o, d, tmin, tmax)
    assert np.all(np.isinf(t[:3]))  # an open tube is never crossed by an axis-parallel ray


def test_near_axis_rays_hit_wall_at_rho_over_sin():
    cyl = _capped_cylinder(-1e9, 1e9)
    eps = 10.0 ** -np.arange(2, 7)
    o, d, tmin, tmax = rays(np.zeros((eps.size, 3)), np.stack([np.sin(eps), 0 * eps, np.cos(eps)], -1))
    d = np.stack([np.sin(eps), 0 * eps, np.cos(eps)], -1)  # exactly unit
    t, prim = cyl.intersect(o, d, tmin, tmax)
    np.testing.assert_allclose(t, 1 / np.sin(eps), rtol=1e-12)
    assert np.all(prim == 0)
    # Exactly parallel from the axis: the far cap.
    t, prim = cyl.intersect(np.zeros((1, 3)), np.array([[0, 0, 1.0]]), [0.0], [INF])
    assert t[0] == 1e9 and prim[0] == 1


@pytest.mark.parametrize("D", [1e2, 1e3, 1e4, 1e5, 1e6])
def test_far_camera_hit_miss_agrees_with_analytic(D):
    s = Quadric("sphere", tf.translate([0.3, -0.2, 0.1]))
    rng = np.random.default_rng(int(D))
    n = 4000
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    perp = np.cross(dirs, rng.normal(size=(n, 3)))
    perp /= np.linalg.norm(perp, axis=1, keepdims=True)
    b = rng.random(n) * 2
    b = b[np.abs(b - 1) > 1e-6]  # outside the tangent band
    dirs, perp = dirs[: b.size], perp[: b.size]
    c = np.array([0.3, -0.2, 0.1])
    o = c - D * dirs + b[:, None] * perp
    t, _ = s.intersect(o, dirs, np.zeros(b.size), np.full(b.size, INF))
    assert np.array_equal(np.isfinite(t), b < 1)
    hit = b < 1
    p = o[hit] + t[hit, None] * dirs[hit]
    np.testing.assert_allclose(np.linalg.norm(p - c, axis=1), 1.0, atol=1e-15 * D * 4)
    np.testing.assert_allclose(t[hit], D - np.sqrt(1 - b[hit] ** 2), rtol=1e-14, atol=1e-15 * D * 4)


def test_quadric_validation():
    with pytest.raises(ValueError, match="singular"):
        Quadric("sphere", tf.scale([1, 0, 1]))
    with pytest.raises(ValueError, match="non-finite"):
        Quadric("sphere", np.full((4, 4), np.nan))
    with pytest.raises(ValueError, match="infinite cylinder"):
        Quadric("cylinder", np.eye(4))
    with pytest.raises(ValueError, match="infinite cylinder"):
        Quadric("cylinder", np.eye(4), clips=[(np.array([0.0, 0, 1]), 1.0)])
    with pytest.raises(ValueError, match="kind"):
        Quadric("cone", np.eye(4))


def test_scene_translated_and_scaled_relative_error():
    base = Quadric("sphere", np.eye(4), clips=[(np.array([0.0, 1, 0]), 0.5)], capped=True)
    o, d, tmin, tmax = rays([[0.3, 5, 0.1], [-5, -0.2, 0.1]], [[0, -1, 0], [1, 0, 0]])
    t0, p0 = base.intersect(o, d, tmin, tmax)
    for k in (1e-4, 1e4):
        for shift in (0.0, 1e5):
            M = tf.translate([shift, shift, 0]) @ tf.scale(k)
            s = Quadric("sphere", M, clips=base.clips, capped=True)
            t, p = s.intersect(o * k + [shift, shift, 0], d, tmin, tmax)
            assert np.array_equal(p, p0)
            tol = 1e-6 if shift else 1e-12
            np.testing.assert_allclose(t / k, t0, rtol=tol)


# ---------------------------------------------------------------------------- disk
def test_disk_hit_normal_and_coplanar_miss():
    M = tf.translate([0, 0, 2]) @ tf.rotate([0, 1, 0], 90) @ tf.scale(2.0)
    dk = Disk(M)
    n = tf.apply_normal(M, np.array([0.0, 0, 1]))
    n /= np.linalg.norm(n)
    o, d, tmin, tmax = rays([[5, 0.5, 2.5], [5, 0.0, 4.5], [0, 0.5, 2.5]],
                            [[-1, 0, 0], [-1, 0, 0], [0, 1, 0]])
    t, prim = dk.intersect(o, d, tmin, tmax)
    assert t[0] == 5.0 and np.isinf(t[1]) and np.isinf(t[2])
    assert list(prim) == [0, -1, -1]
    _, ng, _ = dk.surface(o[:1], d[:1], t[:1], prim[:1])
    np.testing.assert_allclose(ng[0], n, atol=1e-15)
    lo, hi = dk.bounds()
    np.testing.assert_allclose(lo, [0, -2, 0], atol=1e-14)
    np.testing.assert_allclose(hi, [0, 2, 4], atol=1e-14)
    assert not dk.closed


def test_quadric_bounds_hold_the_surface_and_are_the_tighter_rule():
    """One bounds rule for both renderers: every point of a clipped sphere or
    cylinder lies in ``quadric_bounds``; an unclipped rotated ellipsoid gets its exact box
    (``m ± |L rows|``), a sphere cut at z <= 0.25 the object box's top at 0.25 (the rule the
    plugin had), an obliquely clipped cylinder a finite box."""
    from links1.geometry.quadrics import quadric_bounds
    rng = np.random.default_rng(7)
    for trial in range(40):
        kind = "sphere" if trial % 2 == 0 else "cylinder"
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        M = np.eye(4)
        M[:3, :3] = q @ np.diag(rng.uniform(0.3, 2.0, 3))
        M[:3, 3] = rng.normal(size=3)
        clips = [((0.0, 0.0, 1.0), float(rng.uniform(0.2, 1.5))), ((0.0, 0.0, -1.0), float(rng.uniform(0.2, 1.5)))]
        if trial % 3 == 0:
            clips.append((tuple(rng.normal(size=3)), float(rng.uniform(0.0, 0.8))))
        lo, hi = quadric_bounds(kind, M, clips)
        assert np.all(np.isfinite(lo)) and np.all(lo <= hi)
        # surface points: the unit sphere, or the unit cylinder between z = -2 and 2
        u = rng.normal(size=(20000, 3))
        if kind == "sphere":
            y = u / np.linalg.norm(u, axis=1, keepdims=True)
        else:
            a = np.arctan2(u[:, 1], u[:, 0])
            y = np.stack([np.cos(a), np.sin(a), rng.uniform(-2, 2, len(a))], axis=1)
        keep = np.all([y @ np.asarray(n) <= h for n, h in clips], axis=0)
        x = y[keep] @ M[:3, :3].T + M[:3, 3]
        tol = 1e-12 * (1 + np.abs(x))
        assert np.all(x >= lo - tol) and np.all(x <= hi + tol)
    # exact box of an unclipped rotated ellipsoid
    M = np.eye(4)
    M[:3, :3] = np.array([[1.0, 0.5, 0.0], [0.0, 1.0, 0.3], [0.2, 0.0, 2.0]])
    lo, hi = quadric_bounds("sphere", M, [])
    ext = np.sqrt((M[:3, :3] ** 2).sum(axis=1))
    assert np.allclose(lo, -ext) and np.allclose(hi, ext)
    # a cut sphere: the axis-aligned clip sets the top
    lo, hi = quadric_bounds("sphere", np.eye(4), [((0.0, 0.0, 1.0), 0.25)])
    assert np.allclose(lo, [-1, -1, -1]) and np.allclose(hi, [1, 1, 0.25])
    # an unbounded cylinder
    lo, hi = quadric_bounds("cylinder", np.eye(4), [((0.0, 0.0, 1.0), 1.0)])
    assert np.all(np.isinf(lo)) and np.all(np.isinf(hi))
