"""Hierarchical bounding boxes (paper 3-2-4): equal to brute force, deterministic, and the
shadow transmittance product of 3-3-3 (once per shape)."""
from __future__ import annotations

import numpy as np
import pytest

from links1.maths import transform as tf
from links1.geometry.accel import Accel
from links1.geometry.bvh import BVH
from links1.geometry.blob import Blob
from links1.geometry.shapes import Disk, Quadric, Shape, TriangleMesh

INF = np.inf


def random_rays(rng, n, spread=6.0):
    o = rng.normal(size=(n, 3)) * spread
    target = rng.normal(size=(n, 3)) * 2
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return o, d


def random_scene(rng, k=30):
    shapes = []
    for i in range(k):
        kind = i % 4
        c = rng.normal(size=3) * 3
        if kind == 0:
            M = tf.translate(c) @ tf.rotate(rng.normal(size=3), rng.random() * 180) @ tf.scale(rng.random(3) * 0.8 + 0.2)
            shapes.append(Quadric("sphere", M, name=f"s{i}"))
        elif kind == 1:
            v = c + rng.normal(size=(12, 3)) * 0.6
            f = rng.integers(0, 12, size=(10, 3))
            shapes.append(TriangleMesh(v, f, name=f"m{i}"))
        elif kind == 2:
            M = tf.translate(c) @ tf.rotate(rng.normal(size=3), rng.random() * 180) @ tf.scale(0.7)
            clips = [(np.array([0.0, 0, 1]), 1.0), (np.array([0.0, 0, -1]), 1.0)]
            shapes.append(Quadric("cylinder", M, clips=clips, capped=bool(rng.random() < 0.5)))
        else:
            M = tf.translate(c) @ tf.rotate(rng.normal(size=3), rng.random() * 180) @ tf.scale(0.9)
            shapes.append(Disk(M, name=f"d{i}"))
    shapes.append(Blob([[0, 0, 0, 1, 0.8], [0.6, 0.2, 0, 0.8, 0.6]], 0.5, to_world=tf.translate([1, -1, 0.5])))
    return shapes


def brute_force(shapes, o, d, tmin, tmax):
    n = o.shape[0]
    best_t = np.full(n, INF)
    best_s = np.full(n, -1)
    best_p = np.full(n, -1)
    for j, s in enumerate(shapes):
        t, p = s.intersect(o, d, tmin, tmax)
        win = t < best_t  # strict: the lower index keeps an exact tie
        best_t[win], best_s[win], best_p[win] = t[win], j, p[win]
    return best_t, best_s, best_p


def test_scene_accel_equals_brute_force():
    rng = np.random.default_rng(0)
    shapes = random_scene(rng)
    acc = Accel(shapes)
    o, d = random_rays(rng, 4000)
    tmin = np.zeros(len(o))
    tmax = np.where(rng.random(len(o)) < 0.2, rng.random(len(o)) * 8, INF)
    cost = np.zeros(len(o), dtype=np.int64)
    t, s, p = acc.intersect(o, d, tmin, tmax, cost)
    tb, sb, pb = brute_force(shapes, o, d, tmin, tmax)
    np.testing.assert_array_equal(t, tb)
    np.testing.assert_array_equal(s, sb)
    np.testing.assert_array_equal(p, pb)
    assert np.isfinite(t).sum() > 500
    assert not np.any(np.isnan(t))
    assert cost.sum() > 0


@pytest.mark.slow
def test_mesh_bvh_equals_single_leaf_brute_force():
    rng = np.random.default_rng(1)
    k = 1500
    v = rng.normal(size=(k, 3)) * 2
    # Small triangles scattered in space: vertex i plus two nearby offsets.
    v2 = np.vstack([v, v + rng.normal(size=v.shape) * 0.3, v + rng.normal(size=v.shape) * 0.3])
    faces = np.stack([np.arange(k), np.arange(k) + k, np.arange(k) + 2 * k], 1)
    mesh = TriangleMesh(v2, faces)
    brute = TriangleMesh(v2, faces, max_leaf=10 ** 9)  # one leaf: every triangle tested
    assert len(brute.bvh) == 1 and len(mesh.bvh) > 100
    n = 2000
    o, d = random_rays(rng, n)
    tmin, tmax = np.zeros(n), np.full(n, INF)
    c1 = np.zeros(n, dtype=np.int64)
    t1, p1 = mesh.intersect(o, d, tmin, tmax, c1)
    t2, p2 = brute.intersect(o, d, tmin, tmax)
    np.testing.assert_array_equal(t1, t2)
    np.testing.assert_array_equal(p1, p2)
    np.testing.assert_array_equal(mesh.any_hit(o, d, tmin, tmax), np.isfinite(t2))
    assert np.isfinite(t1).sum() > 200
    assert c1.mean() < 200  # far fewer than the 1500 of brute force


def test_bvh_structure_covers_items():
    rng = np.random.default_rng(2)
    lo = rng.normal(size=(500, 3))
    hi = lo + rng.random((500, 3))
    b = BVH(lo, hi, max_leaf=4)
    assert sorted(b.order.tolist()) == list(range(500))
    leaves = np.nonzero(b.count)[0]
    assert b.count[leaves].max() <= 4 and b.count.sum() == 500
    for nid in leaves:
        items = b.order[b.start[nid]: b.start[nid] + b.count[nid]]
        assert np.all(np.diff(items) > 0)  # sorted inside a leaf (tie-break by index)
        assert np.all(lo[items] >= b.node_lo[nid]) and np.all(hi[items] <= b.node_hi[nid])


def test_sah_split_separates_clusters_and_covers_items():
    """The one builder's SAH rule (the plugin's trees): two far clusters of
    boxes of unequal size (30 and 170) are cut apart at the root (a median cut would mix
    them: 100 and 100), every item sits in one leaf inside its node's box, and
    children are allocated as consecutive pairs (the plugin's flat layout relies on it)."""
    rng = np.random.default_rng(5)
    a = rng.normal(size=(30, 3)) * 0.1
    b = rng.normal(size=(170, 3)) * 0.1 + [10.0, 0, 0]
    lo = np.vstack([a, b])
    hi = lo + 0.05
    t = BVH(lo, hi, max_leaf=1, split="sah")
    assert sorted(t.order.tolist()) == list(range(200)) and t.count.sum() == 200
    inner = np.nonzero(t.count == 0)[0]
    assert np.all(t.right[inner] == t.left[inner] + 1)
    left = t.left[0]
    left_items = set()
    stack = [left]
    while stack:
        k = stack.pop()
        if t.count[k]:
            left_items |= set(t.order[t.start[k]:t.start[k] + t.count[k]].tolist())
        else:
            stack += [t.left[k], t.right[k]]
    assert left_items in (set(range(30)), set(range(30, 200)))
    for k in np.nonzero(t.count)[0]:
        items = t.order[t.start[k]:t.start[k] + t.count[k]]
        assert np.all(lo[items] >= t.node_lo[k]) and np.all(hi[items] <= t.node_hi[k])
    with pytest.raises(ValueError, match="split"):
        BVH(lo, hi, split="middle")


def test_exact_ties_lower_index_wins():
    s0 = Quadric("sphere", tf.translate([0, 0, 0]))
    s1 = Quadric("sphere", tf.translate([0, 0, 0]))
    o = np.tile([0.0, 0, -5], (3, 1))
    d = np.tile([0.0, 0, 1], (3, 1))
    for shapes, expect in (([s0, s1], 0), ([s1, s0], 0)):
        t, s, _ = Accel(shapes).intersect(o, d, 0.0, INF)
        assert np.all(s == expect) and np.all(t == 4.0)
    # Coincident triangles inside one mesh: the lower face index wins.
    v = np.array([[-1.0, -1, 0], [1, -1, 0], [0, 1, 0]])
    m = TriangleMesh(np.vstack([v, v]), [[3, 4, 5], [0, 1, 2]])
    t, p = m.intersect(o, d, 0.0, INF)
    assert np.all(p == 0) and np.all(t == 5.0)


def test_results_independent_of_batch():
    rng = np.random.default_rng(3)
    shapes = random_scene(rng, 20)
    acc = Accel(shapes)
    o, d = random_rays(rng, 3000)
    n = len(o)
    c_full = np.zeros(n, dtype=np.int64)
    full = acc.intersect(o, d, np.zeros(n), np.full(n, INF), c_full)
    sel = rng.choice(n, 700, replace=False)
    c_sub = np.zeros(sel.size, dtype=np.int64)
    sub = acc.intersect(o[sel], d[sel], np.zeros(sel.size), np.full(sel.size, INF), c_sub)
    for a, b in zip(sub, full):
        np.testing.assert_array_equal(a, b[sel])
    np.testing.assert_array_equal(c_sub, c_full[sel])


def test_shadow_transmittance_once_per_closed_object():
    a = Quadric("sphere", tf.translate([0, 0, 0]))
    b = Quadric("sphere", tf.translate([0, 0, 4]))
    wall = TriangleMesh([[-5.0, -5, 8], [5, -5, 8], [0, 5, 8]], [[0, 1, 2]])
    shadow_t = np.array([[0.5, 0.6, 0.7], [0.5, 0.5, 0.5], [0.0, 0.0, 0.0]])
    acc = Accel([a, b, wall])
    o = np.array([[0.0, 0, -5], [0.0, 0, -5], [0.0, 0, -5], [3.0, 0, -5], [0.0, 0, 3.5]])
    d = np.tile([0.0, 0, 1], (5, 1))
    tmax = np.array([7.0, 11.0, 20.0, 20.0, 3.0])
    cost = np.zeros(5, dtype=np.int64)
    T = acc.shadow_transmittance(o, d, tmax, shadow_t, cost)
    expect = np.array([
        [0.5, 0.6, 0.7],             # through sphere a (two crossings, counted once)
        [0.25, 0.3, 0.35],           # through a and b
        [0.0, 0.0, 0.0],             # and the opaque wall
        [1.0, 1.0, 1.0],             # x = 3: beside both spheres and the wall
        [0.5, 0.5, 0.5],             # starts inside b: leaves it once
    ])
    np.testing.assert_array_equal(T, expect)
    assert np.all(cost > 0)


def test_any_hit_per_shape():
    a = Quadric("sphere", tf.translate([0, 0, 0]))
    b = Quadric("sphere", tf.translate([0, 3, 0]))
    acc = Accel([a, b])
    o = np.array([[0.0, 0, -5], [0.0, 3, -5], [0.0, 1.5, -5]])
    d = np.tile([0.0, 0, 1], (3, 1))
    got = dict(acc.any_hit_per_shape(o, d, np.zeros(3), np.full(3, INF)))
    np.testing.assert_array_equal(got[0], [True, False, False])
    np.testing.assert_array_equal(got[1], [False, True, False])
    got = dict(acc.any_hit_per_shape(o, d, np.zeros(3), np.full(3, 2.0)))
    assert all(not h.any() for h in got.values())


class _Plane(Shape):
    """An unbounded plane z = 0 (to test the always-tested list)."""

    def bounds(self):
        return np.full(3, -INF), np.full(3, INF)

    def intersect(self, o, d, tmin, tmax, cost=None):
        if cost is not None:
            cost += 1
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -o[:, 2] / d[:, 2]
        ok = np.isfinite(t) & (t > tmin) & (t < tmax)
        return np.where(ok, t, INF), np.where(ok, 0, -1)


def test_unbounded_shapes_and_empty_scene():
    acc = Accel([Quadric("sphere", tf.translate([0, 0, 3])), _Plane()])
    assert acc.unbounded == [1]
    o = np.array([[0.0, 0, 10], [5.0, 0, 10], [5.0, 0, 10]])
    d = np.array([[0.0, 0, -1], [0.0, 0, -1], [0.0, 0, 1]])
    t, s, _ = acc.intersect(o, d, 0.0, INF)
    np.testing.assert_array_equal(t, [6.0, 10.0, INF])
    np.testing.assert_array_equal(s, [0, 1, -1])
    t, s, p = Accel([]).intersect(o, d, 0.0, INF)
    assert np.all(np.isinf(t)) and np.all(s == -1) and np.all(p == -1)
    T = Accel([]).shadow_transmittance(o, d, np.full(3, 5.0), np.zeros((0, 3)))
    np.testing.assert_array_equal(T, np.ones((3, 3)))


def test_axis_aligned_rays_and_flat_boxes():
    # A flat quad in z = 0 and rays with zero direction components, some lying in the
    # quad's plane (slab test with 0 * inf must not produce NaN or false misses).
    quad = TriangleMesh([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]])
    acc = Accel([quad, Quadric("sphere", tf.translate([5, 5, 5]))])
    o = np.array([[0.5, 0.5, 3], [0.5, 0.5, -3], [0.0, 0.5, 3], [1.0, 1.0, 3], [-1, 0.5, 0]])
    d = np.array([[0.0, 0, -1], [0, 0, 1], [0, 0, -1], [0, 0, -1], [1, 0, 0]])
    t, s, _ = acc.intersect(o, d, 0.0, INF)
    np.testing.assert_array_equal(t[:4], [3.0, 3.0, 3.0, 3.0])
    assert np.isinf(t[4]) and s[4] == -1  # a ray in the quad's plane: a miss


def _quadric_zoo(rng, k=40):
    shapes = []
    for i in range(k):
        M = (tf.translate(rng.normal(size=3) * 3) @ tf.rotate(rng.normal(size=3), rng.random() * 180)
             @ tf.scale(rng.random(3) * 0.8 + 0.2))
        kind = ("sphere", "cylinder")[i % 2]
        clips = [(rng.normal(size=3), rng.normal() * 0.5) for _ in range(i % 3)]
        if kind == "cylinder":
            clips += [(np.array([0.0, 0, 1]), 1.0), (np.array([0.0, 0, -1]), 1.0)]
        shapes.append(Quadric(kind, M, clips=clips, capped=bool(i % 4 == 1)))
    return shapes


def test_quadric_pairs_equal_each_quadric_bitwise():
    """The vectorised (ray, quadric) intersector gives each Quadric's own bits."""
    from links1.geometry.accel import _QuadricSet
    rng = np.random.default_rng(5)
    quads = _quadric_zoo(rng)
    qs = _QuadricSet(quads)
    o, d = random_rays(rng, 4000)
    qi = rng.integers(0, len(quads), o.shape[0])
    d = np.array([q.m for q in quads])[qi] + rng.normal(size=o.shape) * 0.5 - o  # aim at them
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    tmin = np.where(rng.random(o.shape[0]) < 0.3, 0.5, 0.0)
    tmax = np.where(rng.random(o.shape[0]) < 0.3, 4.0, INF)
    t, p = qs.hits(qi, o, d, tmin, tmax)
    for j, q in enumerate(quads):
        s = qi == j
        tj, pj = q.intersect(o[s], d[s], tmin[s], tmax[s])
        assert np.array_equal(t[s], tj) and np.array_equal(p[s], pj)
    assert np.isfinite(t).sum() > 1000 and (p > 0).sum() > 50  # quadric and cap hits


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lockstep_and_packet_traversals_same_bits(seed):
    """Both traversals (and "auto", which picks by rays per leaf) give the same nearest
    hits, costs, shadow products and any-hit sets, and a sub-batch the same bits."""
    rng = np.random.default_rng(seed)
    shapes = random_scene(rng, k=40) + _quadric_zoo(rng, 30)
    shapes.append(shapes[0])  # exact ties: the lower index wins
    n = 2500
    o, d = random_rays(rng, n)
    tmin = np.where(rng.random(n) < 0.2, 0.5, 0.0)
    tmax = np.where(rng.random(n) < 0.3, 5.0, INF)
    st = rng.random((len(shapes), 3))
    st[rng.random(len(shapes)) < 0.3] = 0.0
    st[rng.random(len(shapes)) < 0.2] = 1.0
    out = {}
    for mode in ("packet", "lockstep", "auto"):
        acc = Accel(shapes, traversal=mode)
        c1, c2, c3 = (np.zeros(n, dtype=np.int64) for _ in range(3))
        hit = acc.intersect(o, d, tmin, tmax, c1)
        T = acc.shadow_transmittance(o, d, np.full(n, 4.0), st, c2)
        anyh = [(j, h.copy()) for j, h in acc.any_hit_per_shape(o, d, tmin, tmax, c3)]
        sub = np.arange(1, n, 3)
        cs = np.zeros(sub.size, dtype=np.int64)
        hs = acc.intersect(o[sub], d[sub], tmin[sub], tmax[sub], cs)
        assert all(np.array_equal(a[sub], b) for a, b in zip(hit, hs)) and np.array_equal(cs, c1[sub])
        out[mode] = (hit, c1, T, c2, anyh, c3)
    bt, bs, bp = brute_force(shapes, o, d, tmin, tmax)
    assert np.array_equal(out["packet"][0][0], bt) and np.array_equal(out["packet"][0][1], bs)
    ref = out["packet"]
    for mode in ("lockstep", "auto"):
        got = out[mode]
        assert all(np.array_equal(a, b) for a, b in zip(ref[0], got[0]))
        assert np.array_equal(ref[1], got[1]) and np.array_equal(ref[2], got[2]) and np.array_equal(ref[3], got[3])
        assert [j for j, _ in ref[4]] == [j for j, _ in got[4]]
        assert all(np.array_equal(a, b) for (_, a), (_, b) in zip(ref[4], got[4]))
        assert np.array_equal(ref[5], got[5])


def test_accel_rejects_unknown_traversal():
    with pytest.raises(ValueError, match="traversal"):
        Accel([Quadric("sphere", tf.scale(1.0))], traversal="bfs")


def test_surface_batched_equals_each_shape_bitwise():
    """Accel.surface: the shapes' own surface() bits, quadrics (caps included) batched."""
    rng = np.random.default_rng(7)
    shapes = random_scene(rng, k=40) + _quadric_zoo(rng, 40)
    acc = Accel(shapes)
    o, d = random_rays(rng, 4000)
    t, s, p = acc.intersect(o, d, 0.0, INF)
    assert (s >= 0).sum() > 500 and (p > 0).sum() > 5
    P, NG, NS = acc.surface(o, d, t, s, p)
    for j in np.unique(s[s >= 0]):
        m = s == j
        pj, ngj, nsj = shapes[j].surface(o[m], d[m], t[m], p[m])
        assert np.array_equal(P[m], pj) and np.array_equal(NG[m], ngj) and np.array_equal(NS[m], nsj)
    assert np.all(P[s < 0] == 0) and np.all(NG[s < 0] == 0)


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:overflow encountered")
@pytest.mark.parametrize("mode", ["packet", "lockstep"])
def test_scalar_walk_same_bits_as_numpy_walk(monkeypatch, mode):
    """The Python-scalar walk of a few rays (``SCALAR_RAYS``) visits the same
    leaves in the same order as the numpy walk: the same nearest hits, costs (which count
    the culled visits), shadow products and any-hit sets, with every batch walked in
    scalars or none; also for rays with zero direction components (huge reciprocals whose
    slab products overflow) and subnormal ones (infinite reciprocals: numpy walk)."""
    import links1.geometry.bvh as bvh_mod
    rng = np.random.default_rng(11)
    shapes = random_scene(rng, k=40) + _quadric_zoo(rng, 30)
    shapes.append(shapes[0])
    n = 600
    o, d = random_rays(rng, n)
    d[:60, rng.integers(0, 3)] = 0.0                   # axis-parallel components
    d[60:70, 0] = 1e-310                               # subnormal: 1/d is inf
    d[70:80] = [0.0, 0.0, -1.0]
    o[70:80, 2] = 6.0
    o[75:80, 0] = shapes[0].bounds()[0][0]             # origins on a box plane
    tmin = np.where(rng.random(n) < 0.2, 0.5, 0.0)
    tmax = np.where(rng.random(n) < 0.3, 5.0, INF)
    st = rng.random((len(shapes), 3))
    st[rng.random(len(shapes)) < 0.3] = 0.0
    out = {}
    for k in (0, n):                                   # never / always the scalar walk
        monkeypatch.setattr(bvh_mod, "SCALAR_RAYS", k)
        acc = Accel(shapes, traversal=mode)
        c1, c2, c3 = (np.zeros(n, dtype=np.int64) for _ in range(3))
        hit = acc.intersect(o, d, tmin, tmax, c1)
        T = acc.shadow_transmittance(o, d, np.full(n, 4.0), st, c2)
        anyh = [(j, h.copy()) for j, h in acc.any_hit_per_shape(o, d, tmin, tmax, c3)]
        one = [acc.intersect(o[i:i + 1], d[i:i + 1], tmin[i:i + 1], tmax[i:i + 1]) for i in range(0, n, 7)]
        out[k] = (hit, c1, T, c2, anyh, c3, one)
    a, b = out[0], out[n]
    assert all(np.array_equal(x, y) for x, y in zip(a[0], b[0]))
    assert np.isfinite(a[0][0]).sum() > 100 and a[1].sum() > n     # hits and culled costs
    assert np.array_equal(a[1], b[1]) and np.array_equal(a[2], b[2]) and np.array_equal(a[3], b[3])
    assert [j for j, _ in a[4]] == [j for j, _ in b[4]]
    assert all(np.array_equal(x, y) for (_, x), (_, y) in zip(a[4], b[4]))
    assert np.array_equal(a[5], b[5])
    for x1, y1 in zip(a[6], b[6]):
        assert all(np.array_equal(x, y) for x, y in zip(x1, y1))
    # a one-ray batch gives the full batch's bits
    for r, (t, s, p) in zip(range(0, n, 7), b[6]):
        assert t[0] == a[0][0][r] or (np.isnan(t[0]) and np.isnan(a[0][0][r]))
        assert s[0] == a[0][1][r] and p[0] == a[0][2][r]
