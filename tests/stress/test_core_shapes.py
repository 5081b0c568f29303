"""Numerical stress cases of docs/numerics.md on the core's primitives (float64).

Property-based (hypothesis, derandomised, few examples); every case asserts that no output
is NaN/Inf where it must be finite, and hit/miss equal to a float64 analytic reference
outside a stated tangent band.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from links1.geometry.blob import MAX_MARCH, MAX_REFINE, Blob
from links1.geometry.shapes import Quadric, TriangleMesh
from links1.maths.transform import scale, translate

from .oracles import (blob_first_hit, blob_radius, cube_mesh, perpendicular, rays_with_impact,
                      sphere_t, unit)

SETTINGS = dict(max_examples=12, deadline=None, derandomize=True)
#: Relative tangent band of the float64 core: impact parameters within R·(1 ± BAND) may go
#: either way.
BAND = 1e-9

directions = st.tuples(*(st.floats(-1, 1, allow_nan=False) for _ in range(3))).filter(
    lambda v: sum(x * x for x in v) > 1e-2)


def _no_nan(*arrays):
    for a in arrays:
        assert not np.any(np.isnan(a)), "NaN in an output"


def _check_sphere(shape, centre, radius, d, dist, n=400, seed=0):
    rng = np.random.default_rng(seed)
    b = radius * rng.uniform(0.0, 1.5, n)
    o, dd = rays_with_impact(centre, np.repeat(np.atleast_2d(d), n, 0), b, np.full(n, dist))
    t, prim = shape.intersect(o, dd, np.zeros(n), np.full(n, np.inf))
    _no_nan(t)
    assert np.all(np.isfinite(t) == (prim >= 0))
    ref = sphere_t(b, np.full(n, dist), radius)
    clear = np.abs(b - radius) > BAND * radius
    assert np.array_equal(np.isfinite(t)[clear], np.isfinite(ref)[clear])
    hit = clear & np.isfinite(ref)
    return t[hit], ref[hit]


# ---------------------------------------------------------------- 6. camera distance
@settings(**SETTINGS)
@given(d=directions, logD=st.integers(2, 6), radius=st.sampled_from([1e-3, 1.0, 1e3]))
def test_sphere_hit_miss_at_every_camera_distance(d, logD, radius):
    dist = 10.0 ** logD * radius
    s = Quadric("sphere", translate([0.3, -0.2, 0.1]) @ scale(radius))
    t, ref = _check_sphere(s, np.array([0.3, -0.2, 0.1]), radius, unit(d), dist)
    # the hit lies on the sphere to float64 accuracy relative to the distance travelled
    assert np.all(np.abs(t - ref) <= 1e-12 * dist + 1e-9 * radius)


# ---------------------------------------------------------------- 2./grazing: tangent sweep
@pytest.mark.parametrize("k", range(1, 8))
@pytest.mark.parametrize("sgn", [-1.0, 1.0])
def test_sphere_tangent_sweep(k, sgn):
    b = np.array([1.0 + sgn * 10.0 ** -k])
    o, d = rays_with_impact([0, 0, 0], [[0, 0, 1]], b, np.array([50.0]))
    t, _ = Quadric("sphere").intersect(o, d, [0.0], [np.inf])
    _no_nan(t)
    assert np.isfinite(t[0]) == (sgn < 0)


# ---------------------------------------------------------------- 7. translated and scaled
@settings(**SETTINGS)
@given(d=directions, shift=st.sampled_from([0.0, 1e5, -1e5]), s=st.sampled_from([1e-4, 1.0, 1e4]))
def test_translated_and_scaled_sphere(d, shift, s):
    centre = np.array([shift, shift * 0.5, -shift])
    sh = Quadric("sphere", translate(centre) @ scale(s))
    t, ref = _check_sphere(sh, centre, s, unit(d), 20.0 * s)
    assert np.all(np.abs(t - ref) <= 1e-6 * ref)  # relative error <= 1e-6 (numerics 7)


# ---------------------------------------------------------------- 5. eye inside
@settings(**SETTINGS)
@given(d=directions, frac=st.floats(0.0, 0.99))
def test_eye_inside_sphere_finds_the_exit_back_facing(d, frac):
    d = unit(np.atleast_2d(d))
    o = frac * perpendicular(d)
    sh = Quadric("sphere")
    t, prim = sh.intersect(o, d, [0.0], [np.inf])
    exit_t = -np.sum(o * d) + math.sqrt(1.0 - frac * frac)  # o ⟂ d
    assert np.isfinite(t[0]) and abs(t[0] - exit_t) < 1e-12
    p, ng, ns = sh.surface(o, d, t, prim)
    _no_nan(p, ng, ns)
    assert np.dot(ng[0], d[0]) > 0  # outward normal along the ray: seen from behind


def test_eye_inside_cylinder_and_blob():
    cyl = Quadric("cylinder", clips=[([0, 0, 1], 2.0), ([0, 0, -1], 2.0)], capped=True)
    o, d = np.array([[0.2, 0.1, 0.0]]), unit([[1.0, 0.3, 0.2]])
    t, prim = cyl.intersect(o, d, [0.0], [np.inf])
    assert np.isfinite(t[0])
    _, ng, _ = cyl.surface(o, d, t, prim)
    assert np.dot(ng[0], d[0]) > 0
    blob = Blob([[0, 0, 0, 1.0, 1.0]], 0.5)
    t, prim = blob.intersect(o * 0, d, [0.0], [np.inf])
    assert abs(t[0] - blob_radius(1.0, 1.0, 0.5)) < 1e-12
    _, ng, _ = blob.surface(o * 0, d, t, prim)
    assert np.dot(ng[0], d[0]) > 0


# ---------------------------------------------------------------- 8. axis-parallel cylinder
@pytest.mark.parametrize("eps", [1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 0.0])
@pytest.mark.parametrize("rho", [0.0, 0.5, 0.999])
def test_cylinder_rays_nearly_along_the_axis(eps, rho):
    cyl = Quadric("cylinder", clips=[([0, 0, 1], 1e9), ([0, 0, -1], 1e9)])
    o = np.array([[rho, 0.0, 0.0]])
    d = np.array([[math.sin(eps), 0.0, math.cos(eps)]])
    t, prim = cyl.intersect(o, d, [0.0], [np.inf])
    _no_nan(t)
    if eps == 0.0:
        assert not np.isfinite(t[0])  # parallel inside an open shell: never meets the wall
    else:
        ref = (1.0 - rho) / math.sin(eps)  # t = ρ' / sin ε (ρ' = distance to the wall)
        assert abs(t[0] - ref) <= 1e-9 * ref
    outside = Quadric("cylinder", clips=[([0, 0, 1], 5.0), ([0, 0, -1], 5.0)], capped=True)
    t2, _ = outside.intersect(o + [[2.0, 0, -10]], np.array([[0, 0, 1.0]]), [0.0], [np.inf])
    assert not np.isfinite(t2[0])


# ---------------------------------------------------------------- 9. hemisphere / clip planes
@settings(**SETTINGS)
@given(x=st.floats(-0.95, 0.95), y=st.floats(-0.95, 0.95))
def test_hemisphere_seen_through_its_opening(x, y):
    if x * x + y * y >= 0.95:
        return
    hemi = Quadric("sphere", clips=[([0, 0, 1], 0.0)])  # keeps z <= 0: open at the top
    o = np.array([[x, y, 5.0]])
    d = np.array([[0.0, 0.0, -1.0]])
    t, prim = hemi.intersect(o, d, [0.0], [np.inf])
    ref = 5.0 + math.sqrt(1.0 - x * x - y * y)  # the inside (far) surface
    assert abs(t[0] - ref) < 1e-12
    _, ng, _ = hemi.surface(o, d, t, prim)
    assert ng[0, 2] < 0 and np.dot(ng[0], d[0]) > 0  # back-facing inside surface


def test_rays_in_the_clip_plane_are_deterministic():
    hemi = Quadric("sphere", clips=[([0, 0, 1], 0.0)])
    o = np.array([[-5.0, y, 0.0] for y in np.linspace(-1.2, 1.2, 25)])
    d = np.tile([[1.0, 0.0, 0.0]], (25, 1))
    t1, _ = hemi.intersect(o, d, np.zeros(25), np.full(25, np.inf))
    t2, _ = hemi.intersect(o[::-1], d, np.zeros(25), np.full(25, np.inf))
    _no_nan(t1)
    assert np.array_equal(t1, t2[::-1])


# ---------------------------------------------------------------- 1./2. single-centre blob
@pytest.mark.parametrize("q", [0.1, 0.5, 2.0 / 3.0, 0.9])
def test_single_centre_blob_depth(q):
    w, S = 1.3, 0.7
    T = q * w
    r = blob_radius(w, S, T)
    blob = Blob([[0.0, 0.0, 0.0, w, S]], T)
    n = 64
    rng = np.random.default_rng(1)
    d = unit(rng.normal(size=(n, 3)))
    b = r * rng.uniform(0, 0.999, n)
    o, d = rays_with_impact([0, 0, 0], d, b, np.full(n, 10.0))
    cost = np.zeros(n, dtype=np.int64)
    t, _ = blob.intersect(o, d, np.zeros(n), np.full(n, np.inf), cost)
    ref = sphere_t(b, np.full(n, 10.0), r)
    assert np.all(np.abs(t - ref) <= 4 * np.spacing(ref))  # a few float64 ulp
    assert np.all(cost <= MAX_MARCH + MAX_REFINE)


@pytest.mark.parametrize("k", range(1, 8))
@pytest.mark.parametrize("sgn", [-1.0, 1.0])
def test_blob_tangent_sweep(k, sgn):
    w, S, T = 1.0, 1.0, 0.5
    r = blob_radius(w, S, T)
    blob = Blob([[0.0, 0.0, 0.0, w, S]], T)
    b = np.array([r * (1.0 + sgn * 10.0 ** -k)])
    o, d = rays_with_impact([0, 0, 0], [[0, 1, 0]], b, np.array([10.0]))
    cost = np.zeros(1, dtype=np.int64)
    t, _ = blob.intersect(o, d, [0.0], [np.inf], cost)
    _no_nan(t)
    assert cost[0] <= MAX_MARCH + MAX_REFINE  # iteration count bounded
    if k <= 5:  # outside the tangent band |b/r − 1| < 1e-5, hit/miss must be right
        assert np.isfinite(t[0]) == (sgn < 0)
    if np.isfinite(t[0]):
        assert abs(t[0] - sphere_t(b, np.array([10.0]), r)[0]) < 1e-3


# ---------------------------------------------------------------- 3. pinch point
def test_pinch_point_normal_is_finite():
    centres = [[-1.5, 0, 0, 1.0, 1.0], [1.5, 0, 0, 1.0, 1.0]]
    blob = Blob(centres, 0.75)
    rng = np.random.default_rng(2)
    n = 200
    o = np.tile([[0.0, 0.0, -5.0]], (n, 1)) + np.c_[rng.normal(0, 0.05, (n, 2)), np.zeros(n)]
    o[0] = [0, 0, -5]
    d = np.tile([[0.0, 0.0, 1.0]], (n, 1))
    t, prim = blob.intersect(o, d, np.zeros(n), np.full(n, np.inf))
    hit = np.isfinite(t)
    p, ng, ns = blob.surface(o[hit], d[hit], t[hit], prim[hit])
    _no_nan(p, ng, ns)
    assert np.all(np.isfinite(ng)) and np.allclose(np.linalg.norm(ng, axis=1), 1.0)


# ---------------------------------------------------------------- 4. negative carving
def test_negative_carving():
    blob = Blob([[0, 0, 0, 1.0, 1.0], [0, 0, -1.2, -1.0, 0.5]], 0.5)
    t, _ = blob.intersect(np.array([[0, 0, -10.0]]), np.array([[0, 0, 1.0]]), [0.0], [np.inf])
    assert abs(t[0] - 9.50718) < 1e-5
    ref = blob_first_hit([[0, 0, -10.0]], [[0, 0, 1.0]],
                         [[0, 0, 0, 1.0, 1.0], [0, 0, -1.2, -1.0, 0.5]], 0.5, 12.0, step=1e-3)
    assert abs(t[0] - ref[0]) < 1e-9


def test_coincident_opposite_centres_never_hit():
    blob = Blob([[0, 0, 0, 1.0, 1.0], [0, 0, 0, -1.0, 1.0]], 0.5)
    rng = np.random.default_rng(3)
    n = 300
    o = rng.normal(size=(n, 3)) * 3
    d = unit(rng.normal(size=(n, 3)))
    t, _ = blob.intersect(o, d, np.zeros(n), np.full(n, np.inf))
    assert not np.any(np.isfinite(t))


# ---------------------------------------------------------------- 15. tiny S
@pytest.mark.parametrize("S", [1e-20, 1e-8, 1e8])
def test_tiny_and_huge_ranges_are_solved_in_normalised_units(S):
    blob = Blob([[0, 0, 0, 1.0, S]], 0.5)
    r = blob_radius(1.0, S, 0.5)
    o = np.array([[0.3 * r, 0.0, -10.0 * S]])
    t, _ = blob.intersect(o, np.array([[0, 0, 1.0]]), [0.0], [np.inf])
    ref = 10.0 * S - math.sqrt(r * r - (0.3 * r) ** 2)
    assert abs(t[0] - ref) <= 1e-12 * 10 * S


# ---------------------------------------------------------------- 11. closed mesh from inside
@settings(**SETTINGS)
@given(ox=st.floats(-0.9, 0.9), oy=st.floats(-0.9, 0.9), oz=st.floats(-0.9, 0.9),
       kind=st.sampled_from(["edge", "vertex", "random"]))
def test_closed_cube_from_inside_has_no_cracks(ox, oy, oz, kind):
    v, f = cube_mesh(1.0)
    mesh = TriangleMesh(v, f)
    o = np.array([[ox, oy, oz]])
    rng = np.random.default_rng(abs(hash((ox, oy, oz))) % 2 ** 32)
    if kind == "vertex":
        targets = v
    elif kind == "edge":  # midpoints and random points of all edges (incl. diagonals)
        e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        a = rng.uniform(0, 1, (e.shape[0], 1))
        targets = v[e[:, 0]] * a + v[e[:, 1]] * (1 - a)
    else:
        targets = rng.uniform(-1, 1, (64, 3))
        targets[np.arange(64), rng.integers(0, 3, 64)] = rng.choice([-1.0, 1.0], 64)
    d = unit(targets - o)
    n = d.shape[0]
    oo = np.repeat(o, n, 0)
    t, prim = mesh.intersect(oo, d, np.zeros(n), np.full(n, np.inf))
    assert np.all(np.isfinite(t)), "a ray from inside a closed mesh escaped through a crack"
    ref = np.linalg.norm(targets - o, axis=1)
    assert np.allclose(t, ref, rtol=1e-12, atol=1e-12)


# ---------------------------------------------------------------- 12. degenerate triangles
def test_triangle_plane_containing_the_eye_is_a_miss():
    mesh = TriangleMesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    o = np.array([[-1.0, 0.2, 0.0], [0.2, 0.2, 0.0], [5, 5, 0.0]])
    d = unit([[1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [-1.0, -1.0, 0.0]])
    t, prim = mesh.intersect(o, d, np.zeros(3), np.full(3, np.inf))
    _no_nan(t)
    assert not np.any(np.isfinite(t)) and np.all(prim == -1)


@settings(**SETTINGS)
@given(u=st.floats(0.01, 0.99), size=st.sampled_from([1e-4, 1e-2, 1.0]),
       aspect=st.sampled_from([1.0, 1e-3, 1e-6]))
def test_needle_and_tiny_triangles_far_away(u, size, aspect):
    c = np.array([0.0, 0.0, 1e3])
    v = c + size * np.array([[0, 0, 0], [1, 0, 0], [0.5, aspect, 0]])
    mesh = TriangleMesh(v, [[0, 1, 2]])
    target = v[0] + u * (v[1] - v[0]) + 0.5 * min(u, 1 - u) * (v[2] - v[0])
    d = unit(target[None])
    t, _ = mesh.intersect(np.zeros((1, 3)), d, [0.0], [np.inf])
    _no_nan(t)
    assert np.isfinite(t[0]) and abs(t[0] - np.linalg.norm(target)) < 1e-9 * 1e3
    miss = unit((target + [0, -size * 0.25 - 1e-9, 0])[None])  # below the base edge
    t2, _ = mesh.intersect(np.zeros((1, 3)), miss, [0.0], [np.inf])
    assert not np.isfinite(t2[0])


# ---------------------------------------------------------------- non-unit float32 directions
@settings(**SETTINGS)
@given(d=directions)
def test_float32_normalised_directions(d):
    d32 = np.asarray(d, dtype=np.float32)
    d32 = (d32 / np.linalg.norm(d32)).astype(np.float32)[None].astype(np.float64)
    norm = float(np.linalg.norm(d32))  # 1 ± a few 1e-8
    o = -1e4 * d32 / norm
    for sh, ref in ((Quadric("sphere"), 1e4 - 1.0),
                    (Blob([[0, 0, 0, 1.0, 1.0]], 0.5), 1e4 - blob_radius(1, 1, 0.5))):
        t, _ = sh.intersect(o, d32, [0.0], [np.inf])
        assert np.isfinite(t[0])
        assert abs(t[0] * norm - ref) < 1e-7 * 1e4  # the distance along the actual ray
