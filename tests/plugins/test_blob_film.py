"""Camera rays of a many-centre blob take their candidate centres from a list per cell of the
camera's film (``BlobSpec.film_lists``, ``lightbuffer.plan_eye``), shadow rays toward a
directional light from a grid across it (``BlobSpec.dir_lists``, ``lightbuffer.plan``), instead
of the hierarchy's walk: the same per-ray test over a conservative superset in the same order,
so the same lists, hits and images bit for bit."""
from __future__ import annotations

import numpy as np
import pytest

from links1_mitsuba import eyegrid

pytestmark = pytest.mark.mitsuba

SIZE = (40, 30)
FOV = 50.0


def _spin(angle, axis):
    a = np.radians(angle)
    c, s = np.cos(a), np.sin(a)
    i, j = [(1, 2), (0, 2), (0, 1)][axis]
    m = np.eye(4)
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def _camera(eye, target):
    """Camera-to-world matrix of a pinhole at ``eye`` looking at ``target`` (Mitsuba's lookat)."""
    f = np.asarray(target, float) - eye
    f /= np.linalg.norm(f)
    left = np.cross([0.0, 1.0, 0.0], f)
    left /= np.linalg.norm(left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, np.cross(f, left), f, eye
    return m


def _cases():
    rng = np.random.default_rng(3)
    n = 150
    cloud = np.c_[rng.uniform(-4, 4, (n, 3)) * [1, 0.3, 1], rng.choice([1.0, -0.4], n), rng.uniform(0.3, 0.8, n)]
    row = np.c_[np.arange(90) * 0.4 - 18, np.zeros((90, 2)), np.ones(90), np.full(90, 0.6)]   # > LIST_CAP on a line
    moved = _spin(30, 1) @ np.diag([1.5, 0.7, 1.0, 1.0])
    moved[:3, 3] = [0.5, -0.2, 1.0]
    return [("cloud above", cloud, None, [0.0, 6.0, 7.0], [0.0, 0.0, 0.0]),
            ("cloud, eye among the centres", cloud, None, [0.3, 0.2, 0.1], [3.0, -1.0, 2.0]),
            ("cloud transformed", cloud, moved, [1.0, 5.0, -6.0], [0.0, 0.0, 0.0]),
            ("row along the view", row, None, [-25.0, 0.0, 0.01], [0.0, 0.0, 0.0])]


@pytest.mark.parametrize("case", _cases(), ids=lambda c: c[0])
def test_film_lists_give_the_walks_lists(variant, case):
    """Over the film, beyond its border and behind the eye: the film cell's list gives each ray
    the walk's list, count and overflow, and the same nearest hit bit for bit."""
    import drjit as dr
    import mitsuba as mi
    from links1_mitsuba.blob import BlobSpec
    _, centres, to_world, eye, target = case
    spec = BlobSpec(0, "b", centres, 0.5, to_world=to_world)
    assert spec.uses_lists()
    eye = np.asarray(eye, float)
    cam = _camera(eye, target)
    R = eyegrid.camera_frame(cam)
    film = spec.film_lists(eye, R, eyegrid.film_window(cam, FOV, SIZE, R), SIZE, 1e-4, 1e-4)
    rng = np.random.default_rng(7)
    tn = np.tan(np.radians(FOV / 2))
    k = 6000
    sx, sy = rng.uniform(-1.3, 1.3, k) * tn, rng.uniform(-1.3, 1.3, k) * tn * SIZE[1] / SIZE[0]
    d = np.c_[sx, sy, np.ones(k)] @ cam[:3, :3].T
    d[:500] = rng.normal(size=(500, 3))          # any direction, some behind the eye
    d /= np.linalg.norm(d, axis=1)[:, None]
    O = mi.Vector3f(np.tile(eye[:, None], k).astype(np.float32))
    D = mi.Vector3f(d.T.astype(np.float32))
    ovf = _same_lists(spec, O, D, film, k)
    if case[0].startswith("row"):
        assert ovf.any()                 # some lines cross more than the list holds
    act = dr.ones(mi.Bool, k)
    t0, _ = spec.intersect(O, D, 0.0, np.inf, act)
    t1, _ = spec.intersect(O, D, 0.0, np.inf, act, film=film)
    t0, t1 = np.array(t0), np.array(t1)
    assert np.isfinite(t0).any() and np.array_equal(t0.view(np.uint32), t1.view(np.uint32))


def _same_lists(spec, O, D, grid, k):
    """The walk's and ``grid``'s lists of the rays ``O + t D``: equal (count, overflow, entries)."""
    import drjit as dr
    import mitsuba as mi
    act = dr.ones(mi.Bool, k)
    u, v, _ = spec._unit_ray(O, D)
    walk, lists = spec._line_candidates(u, v, act), spec._film_candidates(u, v, grid, O, D, act)
    cnt = np.array(walk[1])
    assert cnt.max() > 0 and np.array_equal(cnt, np.array(lists[1]))
    assert np.array_equal(np.array(walk[2]), np.array(lists[2]))
    for j in range(int(cnt.max())):
        a, b = (np.array(dr.select(j < x[1], x[0].read(j), 0)) for x in (walk, lists))
        assert np.array_equal(a, b), j
    return np.array(walk[2])


@pytest.mark.parametrize("case", _cases(), ids=lambda c: c[0])
def test_light_grid_lists_give_the_walks_lists(variant, case):
    """A directional light's grid (``dir_lists``): the shadow rays from points all over the scene
    (and far beyond the grid, and a non-finite one) get the walk's lists, and the same any-hit
    result bit for bit."""
    import drjit as dr
    import mitsuba as mi
    from links1_mitsuba.blob import BlobSpec
    _, centres, to_world, _, _ = case
    spec = BlobSpec(0, "b", centres, 0.5, to_world=to_world)
    w = np.array([0.4, 1.0, -0.3]) if not case[0].startswith("row") else np.array([1.0, 1e-3, 0.0])
    w /= np.linalg.norm(w)
    lo, hi = spec.bounds()
    ext = float(np.abs(np.r_[lo, hi]).max()) + 2.0
    grid = spec.dir_lists(w, ext, 1e-4 * (1.0 + ext))
    rng = np.random.default_rng(5)
    k = 6000
    o = rng.uniform(lo - 2.0, hi + 2.0, (k, 3))
    o[:300] *= 50.0
    o[300] = np.inf
    O = mi.Vector3f(o.T.astype(np.float32))
    D = mi.Vector3f(np.tile(w[:, None], k).astype(np.float32))
    ovf = _same_lists(spec, O, D, grid, k)
    if case[0].startswith("row"):
        assert ovf.any()
    act = dr.ones(mi.Bool, k)
    t0, _ = spec.intersect(O, D, 0.0, 100.0, act, any_hit=True)
    t1, _ = spec.intersect(O, D, 0.0, 100.0, act, any_hit=True, film=grid)
    t0, t1 = np.array(t0), np.array(t1)
    assert np.isfinite(t0).any() and np.array_equal(t0.view(np.uint32), t1.view(np.uint32))


def test_blob_frame_with_film_lists_is_bit_identical(variant, tmp_path):
    """A many-centre blob's frame (its camera rays over the film lists, its shadow rays over the
    light's grid) equals the frame whose rays walk the hierarchy (``eye_buffer=False``,
    ``light_buffer=False``) bit for bit."""
    import mitsuba as mi
    import links1_mitsuba
    from links1_mitsuba import tuning
    from compare.blob_mesh import scene_xml
    p = tmp_path / "blob.xml"
    p.write_text(scene_xml(40))
    sc = links1_mitsuba.load_file(str(p), res=48)
    P = sc.integrator().prepare(sc)
    assert P.bvh is None and 0 in P.eye_buf.blobs     # a blob alone: the film lists only
    assert 0 in P.lbuf[0].blobs                       # and the directional light's grid
    a = np.array(mi.render(sc, spp=2))
    with tuning.tuned(eye_buffer=False, light_buffer=False):
        b = np.array(mi.render(links1_mitsuba.load_file(str(p), res=48), spp=2))
    assert a.mean() > 0 and np.array_equal(a.view(np.uint32), b.view(np.uint32))


def test_camera_move_and_new_centres_replan_the_film_lists(variant, tmp_path):
    """After ``params.update()`` of the camera and then of the blob's centres the film lists
    are planned again (new objects) and each frame is that of a fresh load given the same
    values, bit for bit."""
    import drjit as dr
    import mitsuba as mi
    import links1_mitsuba
    from compare.blob_mesh import scene_xml
    from tests.plugins.test_param_update_kernels import collect_earlier_scenes, sensor_key
    p = tmp_path / "blob.xml"
    p.write_text(scene_xml(40))

    def values(params, scene, m, shift):
        params[sensor_key(params, scene, "to_world")] = m
        if shift:
            key = next(k for k in params.keys() if k.endswith("centers"))
            c = np.array(params[key]).reshape(3, -1)
            c[0] += 0.25
            params[key] = mi.Point3f(c)
        params.update()

    collect_earlier_scenes()
    scene = links1_mitsuba.load_file(str(p), res=40)
    integ = scene.integrator()
    mi.render(scene, spp=2)
    params = mi.traverse(scene)
    k = sensor_key(params, scene, "to_world")
    m = mi.Transform4f().translate(mi.Vector3f(0.4, -0.3, 0.2)) @ mi.Transform4f(params[k])
    for shift in (False, True):
        old = integ.info()["tables"].eye_buf
        values(params, scene, m, shift)
        got = np.array(mi.render(scene, spp=2))
        V = integ.info()["tables"]
        assert V.eye_buf is not old and V.eye_buf.blobs
        fresh = links1_mitsuba.load_file(str(p), res=40)
        fp = mi.traverse(fresh)
        values(fp, fresh, m, shift)
        assert np.array_equal(got, np.array(mi.render(fresh, spp=2))), shift
        del fresh, fp
        dr.sync_thread()
