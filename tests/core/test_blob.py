"""The weight-function surface (eq. 3.6-3.9): oracles and stress cases of docs numerics
(1 single centre, 2 tangent sweep, 3 pinch point, 4 negative carving, 5 eye inside,
6/7 distance and scale, 15 tiny S)."""
from __future__ import annotations

import numpy as np
import pytest

from links1.maths import transform as tf
from links1.geometry.blob import MAX_MARCH, MAX_REFINE, Blob

INF = np.inf

#: The 8-centre blob of the numerics prototype (two negative centres).
EIGHT = np.array([[-1.1, 1.0, 0.0, 1.0, 0.9], [0.0, 1.3, 0.2, 1.0, 0.8],
                  [1.1, 1.0, 0.0, 1.0, 0.9], [0.3, 0.6, 0.9, 0.8, 0.7],
                  [-0.4, 2.0, -0.2, 0.9, 0.6], [0.5, 1.5, -0.6, 0.7, 0.5],
                  [0.2, 1.0, 0.3, -0.6, 0.4], [-0.6, 0.8, 0.5, -0.5, 0.5]])


def r_star(ratio, S=1.0):
    """Single-centre oracle: radius of the surface W = T for T/w = ratio."""
    return S * np.sqrt(3 * (1 - ratio)) if ratio > 2 / 3 else S * (3 - np.sqrt(6 * ratio))


def field(C, p):
    r = np.linalg.norm(p[:, None, :] - C[None, :, :3], axis=2)
    S = C[:, 4]
    P = np.where(r < S, 1 - r ** 2 / (3 * S ** 2), np.where(r < 3 * S, (r - 3 * S) ** 2 / (6 * S ** 2), 0))
    return (C[:, 3] * P).sum(1)


def grid_rays(n=64, z=-8.0):
    x, y = np.meshgrid(np.linspace(-3, 3, n), np.linspace(-1.5, 3.5, n))
    o = np.stack([x.ravel(), y.ravel(), np.full(n * n, z)], -1)
    d = np.tile([0.0, 0.0, 1.0], (n * n, 1))
    return o, d


@pytest.mark.parametrize("ratio", [0.1, 0.5, 2 / 3, 0.9])
@pytest.mark.parametrize("w,S", [(1.0, 1.0), (2.5, 0.7)])
def test_single_centre_oracle(ratio, w, S):
    c = np.array([0.3, -0.2, 0.5])
    b = Blob([[*c, w, S]], ratio * w)
    R = r_star(ratio, S)
    rng = np.random.default_rng(0)
    n = 200
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    perp = np.cross(dirs, rng.normal(size=(n, 3)))
    perp /= np.linalg.norm(perp, axis=1, keepdims=True)
    imp = R * rng.random(n) * 0.95
    o = c - 10 * dirs + imp[:, None] * perp
    cost = np.zeros(n, dtype=np.int64)
    t, prim = b.intersect(o, dirs, np.zeros(n), np.full(n, INF), cost)
    expect = 10 - np.sqrt(R * R - imp * imp)
    np.testing.assert_allclose(t, expect, rtol=1e-12)
    assert np.all(prim == 0)
    p, ng, ns = b.surface(o, dirs, t, prim)
    np.testing.assert_allclose(ng, (p - c) / R, atol=1e-9)
    assert cost.max() <= 16


def test_negative_carving():
    b = Blob([[0, 0, 0, 1, 1], [0, 0, -1.2, -1, 0.5]], 0.5)
    t, _ = b.intersect(np.array([[0, 0, -10.0]]), np.array([[0, 0, 1.0]]), [0.0], [INF])
    assert abs(t[0] - 9.50718) < 1e-5  # not 8.732, the uncarved sphere
    p = np.array([[0, 0, -10 + t[0]]])
    assert abs(field(b.centers, p)[0] - 0.5) < 1e-12


def test_coincident_opposite_centres_miss():
    b = Blob([[0, 0, 0, 1, 1], [0, 0, 0, -1, 1]], 0.5)
    o, d = grid_rays(16, z=-5.0)
    cost = np.zeros(len(o), dtype=np.int64)
    t, prim = b.intersect(o, d, 0.0, INF, cost)
    assert np.all(np.isinf(t)) and np.all(prim == -1)
    assert cost.max() <= 10  # W = 0 < T everywhere: steps of ~T/L


def test_pinch_point_normal_is_finite():
    b = Blob([[-1.5, 0, 0, 1, 1], [1.5, 0, 0, 1, 1]], 0.75)
    o = np.array([[0.0, 0, -10], [1e-9, 0, -10], [0, 1e-7, -10]])
    d = np.tile([0, 0, 1.0], (3, 1))
    t, prim = b.intersect(o, d, np.zeros(3), np.full(3, INF))
    p, ng, _ = b.surface(o, d, t, prim)
    assert np.all(np.isfinite(p)) and np.all(np.isfinite(ng))
    np.testing.assert_allclose(np.linalg.norm(ng, axis=1), 1.0, rtol=1e-12)
    # Exactly at the pinch point the gradient vanishes: the fallback is -d.
    p0, ng0, _ = b.surface(o[:1], d[:1], np.array([10.0]), np.array([0]))
    np.testing.assert_array_equal(ng0, [[0, 0, -1.0]])


def test_eye_inside_gives_exit_hit_backfacing():
    b = Blob([[0, 0, 0, 1, 1]], 0.5)
    o = np.array([[0.0, 0, 0], [0.2, 0.1, 0.0]])
    d = np.array([[0, 0, 1.0], [1.0, 0, 0]])
    t, prim = b.intersect(o, d, np.zeros(2), np.full(2, INF))
    R = r_star(0.5)
    np.testing.assert_allclose(t, [R, np.sqrt(R * R - 0.01) - 0.2], rtol=1e-12)
    _, ng, _ = b.surface(o, d, t, prim)
    assert np.all((ng * d).sum(1) > 0)  # outward normal along the ray: back-facing


@pytest.mark.slow
def test_exact_solver_matches_dense_reference_and_is_cheap():
    b = Blob(EIGHT, 0.5)
    o, d = grid_rays(48)
    n = len(o)
    cost = np.zeros(n, dtype=np.int64)
    t, _ = b.intersect(o, d, np.zeros(n), np.full(n, INF), cost)
    crossing = cost > 0
    mean_evals = cost[crossing].mean()
    assert mean_evals <= 16, mean_evals  # numerics: ~12.7 for the prototype
    assert cost.max() <= MAX_MARCH + MAX_REFINE
    # Dense reference: first sign change on a fine grid, refined by bisection.
    ts = np.linspace(0, 16, 8001)
    rng = np.random.default_rng(5)
    for i in rng.choice(n, 300, replace=False):
        v = field(EIGHT, o[i] + ts[:, None] * d[i]) - 0.5
        k = np.nonzero(v > 0)[0]
        if k.size == 0:
            assert np.isinf(t[i])
            continue
        a, c = ts[k[0] - 1], ts[k[0]]
        for _ in range(60):
            m = 0.5 * (a + c)
            if field(EIGHT, (o[i] + m * d[i])[None])[0] > 0.5:
                c = m
            else:
                a = m
        assert abs(t[i] - c) < 1e-12


def test_paper_solver_loose_and_error_decreasing_with_samples():
    ref = Blob(EIGHT, 0.5)
    o, d = grid_rays(40)
    n = len(o)
    t_ref, _ = ref.intersect(o, d, np.zeros(n), np.full(n, INF))
    errs, evals = [], []
    for samples in (4, 8, 16, 32):
        b = Blob(EIGHT, 0.5, solver="paper", samples=samples)
        cost = np.zeros(n, dtype=np.int64)
        t, _ = b.intersect(o, d, np.zeros(n), np.full(n, INF), cost)
        assert not np.any(np.isnan(t))
        both = np.isfinite(t) & np.isfinite(t_ref)
        disagree = np.sum(np.isfinite(t) != np.isfinite(t_ref))
        t, t_ref_b = np.where(both, t, 0.0), np.where(both, t_ref, 0.0)
        errs.append(np.abs(t - t_ref_b)[both].max() + disagree)
        evals.append(cost[cost > 0].mean())
        if samples >= 8:
            assert disagree <= n // 100
            assert np.abs(t - t_ref_b)[both].max() < 0.05
    assert all(e1 > e2 for e1, e2 in zip(errs, errs[1:])), errs
    assert all(c1 < c2 for c1, c2 in zip(evals, evals[1:])), evals
    assert errs[-1] < 2e-3


def test_paper_solver_single_centre():
    o = np.array([[0, 0, -10.0], [0.3, 0.2, -10]])
    d = np.tile([0, 0, 1.0], (2, 1))
    R = r_star(0.5)
    expect = 10 - np.sqrt(R * R - np.array([0.0, 0.13]))
    for samples, tol in ((8, 0.05), (16, 0.05), (32, 1e-4), (128, 1e-5)):
        b = Blob([[0, 0, 0, 1, 1]], 0.5, solver="paper", samples=samples)
        t, _ = b.intersect(o, d, 0.0, INF)
        np.testing.assert_allclose(t, expect, atol=tol)


def test_tangent_sweep_bounded_and_correct_outside_band():
    R = r_star(0.5)
    b = Blob([[0, 0, 0, 1, 1]], 0.5)
    k = np.arange(1, 8)
    imp = np.concatenate([R * (1 - 10.0 ** -k), R * (1 + 10.0 ** -k)])
    n = imp.size
    o = np.stack([imp, np.zeros(n), np.full(n, -10.0)], -1)
    d = np.tile([0, 0, 1.0], (n, 1))
    cost = np.zeros(n, dtype=np.int64)
    t, _ = b.intersect(o, d, np.zeros(n), np.full(n, INF), cost)
    assert not np.any(np.isnan(t))
    assert cost.max() <= MAX_MARCH + MAX_REFINE
    inside, outside = np.isfinite(t[:7]), np.isfinite(t[7:])
    assert np.all(inside[:5])       # 1e-1 .. 1e-5 below the tangent: hits
    assert not np.any(outside)      # above the tangent: never a hit
    hit = np.isfinite(t)
    np.testing.assert_allclose(t[hit], 10 - np.sqrt(R * R - imp[hit] ** 2), atol=1e-6)


@pytest.mark.parametrize("D", [1e2, 1e4, 1e6])
def test_far_camera(D):
    b = Blob([[1.0, 2.0, 3.0, 1, 1]], 0.5)
    R = r_star(0.5)
    imp = np.array([0.0, 0.5, 1.2, R * 0.999, R * 1.001, 2.0])
    o = np.stack([1 + imp, np.full(imp.size, 2.0), np.full(imp.size, 3 - D)], -1)
    d = np.tile([0, 0, 1.0], (imp.size, 1))
    t, _ = b.intersect(o, d, 0.0, INF)
    assert np.array_equal(np.isfinite(t), imp < R)
    hit = imp < R
    np.testing.assert_allclose(t[hit], D - np.sqrt(R * R - imp[hit] ** 2), rtol=1e-14, atol=4e-16 * D)


def test_to_world_distances_in_world_units():
    M = tf.translate([1e5, -3, 2]) @ tf.rotate([0, 1, 1], 30) @ tf.scale([2.0, 1.0, 0.5])
    b = Blob(EIGHT, 0.5, to_world=M)
    rng = np.random.default_rng(7)
    n = 400
    target = tf.apply_point(M, EIGHT[rng.integers(0, 8, n), :3])
    o = target + rng.normal(size=(n, 3)) * 10
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t, prim = b.intersect(o, d, 0.0, INF)
    hit = np.isfinite(t)
    assert hit.mean() > 0.9
    p, ng, _ = b.surface(o[hit], d[hit], t[hit], prim[hit])
    A = np.linalg.inv(M[:3, :3])
    y = (p - M[:3, 3]) @ A.T
    np.testing.assert_allclose(field(EIGHT, y), 0.5, atol=1e-9)
    lo, hi = b.bounds()
    assert np.all(p >= lo) and np.all(p <= hi)
    # The normal is -grad W in object space, transformed as a normal.
    eps = 1e-6
    g = np.stack([(field(EIGHT, y + eps * e) - field(EIGHT, y - eps * e)) / (2 * eps) for e in np.eye(3)], -1)
    n_ref = -g @ A
    n_ref /= np.linalg.norm(n_ref, axis=1, keepdims=True)
    np.testing.assert_allclose(ng, n_ref, atol=1e-6)


@pytest.mark.parametrize("S", [1e-20, 1e20])
def test_extreme_scales_in_normalised_units(S):
    b = Blob([[0, 0, 0, 1, S]], 0.5)
    R = r_star(0.5, S)
    o = np.array([[0, 0, -10 * S], [0.5 * R, 0, -10 * S], [2 * R, 0, -10 * S]])
    d = np.tile([0, 0, 1.0], (3, 1))
    t, _ = b.intersect(o, d, 0.0, INF)
    np.testing.assert_allclose(t[:2], [10 * S - R, 10 * S - R * np.sqrt(0.75)], rtol=1e-12)
    assert np.isinf(t[2])


def test_tiny_range_ratio_rejected():
    with pytest.raises(ValueError, match="float64"):
        Blob([[0, 0, 0, 1, 1.0], [1, 0, 0, 1, 1e-120]], 0.5)


@pytest.mark.parametrize("centers,T,kw,msg", [
    ([[0, 0, 0, 1, 0.0]], 0.5, {}, "S must be > 0"),
    ([[0, 0, 0, 1, -1.0]], 0.5, {}, "S must be > 0"),
    ([[0, 0, np.nan, 1, 1.0]], 0.5, {}, "finite"),
    ([[0, 0, 0, 1, np.inf]], 0.5, {}, "finite"),
    (np.zeros((0, 5)), 0.5, {}, "non-empty"),
    ([[0, 0, 0, 1]], 0.5, {}, r"\(K, 5\)"),
    ([[0, 0, 0, -1, 1.0]], 0.5, {}, "w > 0"),
    ([[0, 0, 0, 1, 1.0]], 0.0, {}, "threshold"),
    ([[0, 0, 0, 1, 1.0]], np.nan, {}, "threshold"),
    ([[0, 0, 0, 1, 1.0]], 0.5, {"solver": "newton"}, "solver"),
    ([[0, 0, 0, 1, 1.0]], 0.5, {"samples": 2}, "samples"),
    ([[0, 0, 0, 1, 1.0]], 0.5, {"to_world": np.zeros((4, 4))}, "singular"),
])
def test_validation(centers, T, kw, msg):
    with pytest.raises(ValueError, match=msg):
        Blob(centers, T, **kw)


def test_batch_independent_bits():
    b = Blob(EIGHT, 0.5)
    o, d = grid_rays(32)
    n = len(o)
    c_full = np.zeros(n, dtype=np.int64)
    t_full, _ = b.intersect(o, d, np.zeros(n), np.full(n, INF), c_full)
    sel = np.arange(100, 900, 7)
    c_sub = np.zeros(sel.size, dtype=np.int64)
    t_sub, _ = b.intersect(o[sel], d[sel], np.zeros(sel.size), np.full(sel.size, INF), c_sub)
    np.testing.assert_array_equal(t_sub, t_full[sel])
    np.testing.assert_array_equal(c_sub, c_full[sel])


def test_segment_limits_and_any_hit():
    b = Blob([[0, 0, 0, 1, 1]], 0.5)
    R = r_star(0.5)
    o = np.tile([0, 0, -10.0], (3, 1))
    d = np.tile([0, 0, 1.0], (3, 1))
    tmax = np.array([INF, 10 - R - 1e-9, INF])
    tmin = np.array([0.0, 0.0, 10 - R + 1e-9])  # starts inside: the exit
    t, _ = b.intersect(o, d, tmin, tmax)
    np.testing.assert_allclose(t, [10 - R, INF, 10 + R], rtol=1e-13)
    np.testing.assert_array_equal(b.any_hit(o, d, tmin, tmax), [True, False, True])


def _many_centres(k=400, seed=3):
    rng = np.random.default_rng(seed)
    m = int(np.ceil(np.sqrt(k)))
    ij = np.array([(i, j) for i in range(m) for j in range(m)][:k], dtype=np.float64) - (m - 1) / 2
    w = np.where(rng.uniform(size=k) < 0.15, -0.5, 1.0)
    return np.c_[ij[:, 0], rng.uniform(-0.2, 0.2, k), ij[:, 1], w, rng.uniform(0.4, 0.7, k)], m


@pytest.mark.parametrize("solver", ["exact", "paper"])
def test_field_sums_only_met_centres(solver):
    """Each evaluation sums over the centres whose 3S sphere the ray crosses only: the
    field there equals the dense field over all centres, the per-ray candidate count
    stays bounded however many centres there are, and a sub-batch gives the same bits."""
    C, m = _many_centres()
    b = Blob(C, 0.5, solver=solver)
    rng = np.random.default_rng(0)
    n = 600
    eye = np.array([0.0, m + 1.0, m + 1.0])
    tgt = np.c_[rng.uniform(-m / 2, m / 2, n), rng.uniform(-0.3, 0.3, n), rng.uniform(-m / 2, m / 2, n)]
    d = tgt - eye
    d /= np.linalg.norm(d, axis=1)[:, None]
    o = np.broadcast_to(eye, (n, 3)).copy()
    # Candidate lists: sorted by centre index, exactly the crossed centres.
    o2, dn, lam, ts = b._to_local(o, d)
    tau, h2 = b._ray_centres(o2, dn)
    crossed = h2 < 9 * b._S ** 2
    assert b._centre_bvh is not None
    rr, cc, tv, hv = b._crossed_pairs(o2, dn)   # found with the hierarchy: the dense set, same bits
    r0, c0 = np.nonzero(crossed)
    assert np.array_equal(rr, r0) and np.array_equal(cc, c0)
    assert np.array_equal(tv, tau[r0, c0]) and np.array_equal(hv, h2[r0, c0])
    cand, idx, valid, _, _ = b._candidates(n, rr, cc, tv, hv)
    assert idx.shape[1] < C.shape[0] // 8
    assert np.array_equal(valid.sum(1), crossed.sum(1))
    assert np.all(np.diff(idx, axis=1) >= 0) and np.all(idx[~valid] == C.shape[0])
    assert np.all(np.diff(np.where(valid, idx, 10 ** 6 + np.arange(idx.shape[1])), axis=1) > 0)
    # The compacted field equals the dense one along the rays.
    t = tau[np.arange(n), np.argmax(crossed, axis=1)]
    W, _ = b._field(t, cand)
    p = (o2 + t[:, None] * dn) * b._s0
    assert np.allclose(W, field(C, p), rtol=1e-12, atol=1e-12)
    # Hits agree with the dense field; sub-batches give the same bits and costs.
    cost = np.zeros(n, dtype=np.int64)
    th, _ = b.intersect(o, d, 0.0, INF, cost)
    hit = np.isfinite(th)
    assert hit.sum() > n // 3
    if solver == "exact":
        assert np.allclose(field(C, o[hit] + th[hit, None] * d[hit]), 0.5, atol=1e-9)
    sub = np.arange(1, n, 5)
    cs = np.zeros(sub.size, dtype=np.int64)
    ts_, _ = b.intersect(o[sub], d[sub], 0.0, INF, cs)
    assert np.array_equal(ts_, th[sub]) and np.array_equal(cs, cost[sub])
    # Without the hierarchy (every centre tested per ray): the same bits and costs.
    dense = Blob(C, 0.5, solver=solver)
    dense._centre_bvh = None
    cd = np.zeros(n, dtype=np.int64)
    td, _ = dense.intersect(o, d, 0.0, INF, cd)
    assert np.array_equal(td, th) and np.array_equal(cd, cost)


def test_surface_normals_from_met_centres_equal_dense():
    """With the hierarchy, the normal sums over the centres the ray crosses only: the same
    bits as the sum over every centre."""
    C, m = _many_centres(300, seed=4)
    b = Blob(C, 0.5)
    dense = Blob(C, 0.5)
    dense._centre_bvh = None
    assert b._centre_bvh is not None
    rng = np.random.default_rng(2)
    n = 500
    eye = np.array([0.0, m + 1.0, m + 1.0])
    d = np.c_[rng.uniform(-m / 2, m / 2, n), rng.uniform(-0.3, 0.3, n), rng.uniform(-m / 2, m / 2, n)] - eye
    d /= np.linalg.norm(d, axis=1)[:, None]
    o = np.broadcast_to(eye, (n, 3)).copy()
    t, prim = b.intersect(o, d, 0.0, INF)
    h = np.isfinite(t)
    assert h.sum() > n // 3
    p1, ng1, ns1 = b.surface(o[h], d[h], t[h], prim[h])
    p2, ng2, ns2 = dense.surface(o[h], d[h], t[h], prim[h])
    assert np.array_equal(p1, p2) and np.array_equal(ng1, ng2) and np.array_equal(ns1, ns2)
