"""The eye buffer as a grid over the camera's film (eyegrid.py, lightbuffer.plan_eye): its
nearest quadric hit equals the BVH walk's bit for bit (t, row, part, found) on camera rays,
random directions all around the eye (behind it, beside the film), rays grazing every bound,
rays along the grid's cell borders and along the cone ``d·f = KAPPA`` that parts the film's
cells from the cell behind; from an eye outside the field of spheres and from one among
them, over spheres and over spheres with capped cylinders; and the frames equal the BVH
walk's. The film ranges of a sphere follow from its tangent lines (analytic cases)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tests.plugins.test_lightbuffer import _prepared, _scene

pytestmark = pytest.mark.mitsuba

#: (origin, target) of the cameras: outside the field of spheres, and among them (spheres on
#: every side, behind included)
CAMERAS = (("0,7,10", "0,0.5,0"), ("-1.5,1.5,1.5", "3,1,-2"))


def test_ranges_are_the_tangent_lines():
    """A sphere's range of x / z seen from the eye: its tangent lines' slopes (widened by the
    margin), unbounded on a side it reaches at 90 degrees, everything when it holds the eye,
    nothing when it lies behind."""
    from links1_mitsuba import eyegrid
    x = np.array([0.0, 3.0, 0.2, 0.0, 2.0])
    z = np.array([2.0, 0.5, 0.1, -3.0, 0.0])
    rad = np.array([1.0, 1.0, 0.5, 1.0, 0.5])
    lo, hi = eyegrid._ranges(x, z, rad, 0.0)
    assert lo[0] == pytest.approx(-math.tan(math.radians(30))) and hi[0] == pytest.approx(math.tan(math.radians(30)))
    a = math.atan2(3.0, 0.5) - math.asin(1.0 / math.hypot(3.0, 0.5))
    assert lo[1] == pytest.approx(math.tan(a)) and hi[1] == np.inf           # beyond 90 degrees
    assert lo[2] == -np.inf and hi[2] == np.inf                                # holds the eye
    assert lo[3] > hi[3]                                                       # behind
    assert lo[4] == pytest.approx(math.tan(math.pi / 2 - math.asin(0.25))) and hi[4] == np.inf
    lo_m, hi_m = eyegrid._ranges(x[:1], z[:1], rad[:1], 1e-3)
    assert lo_m[0] < lo[0] and hi_m[0] > hi[0]


def _rays(eb, P, rng):
    """Unit float32 directions from the eye: film samples, all around, grazing every bound,
    along cell borders and along the cone d·f = KAPPA."""
    R = np.array(eb.frame)
    nu, nv = eb.nu, eb.nv
    to_world = lambda u, v, w: (np.stack([u, v, w], axis=1) @ R)   # noqa: E731  (rows of R: r, u, f)
    m = 4000
    dirs = [rng.normal(size=(m, 3)),
            to_world(eb.u0 + rng.uniform(0, nu / eb.su, m), eb.v0 + rng.uniform(0, nv / eb.sv, m), np.ones(m))]
    specs = P.bvh.specs
    lo = np.array([s.bounds()[0] for s in specs])
    hi = np.array([s.bounds()[1] for s in specs])
    c, r = 0.5 * (lo + hi), 0.5 * np.linalg.norm(hi - lo, axis=1)
    eye = np.array(eb.pos)
    for k in range(len(specs)):                       # grazing the bounds, both sides
        to = c[k] - eye
        side = np.cross(to, rng.normal(size=(40, 3)))
        side /= np.linalg.norm(side, axis=1)[:, None]
        dirs.append(to + side * (r[k] * rng.uniform(0.3, 1.05, 40))[:, None])
    iu, iv = rng.integers(0, nu + 1, m), rng.integers(0, nv + 1, m)     # cell borders
    dirs.append(to_world(eb.u0 + iu / eb.su, eb.v0 + rng.uniform(0, nv / eb.sv, m), np.ones(m)))
    dirs.append(to_world(eb.u0 + rng.uniform(0, nu / eb.su, m), eb.v0 + iv / eb.sv, np.ones(m)))
    phi = rng.uniform(0, 2 * math.pi, m)                                 # the cone d·f = KAPPA
    kz = eb.kappa * (1.0 + rng.uniform(-1e-3, 1e-3, m))
    s = np.sqrt(1.0 - kz * kz)
    dirs.append(to_world(s * np.cos(phi), s * np.sin(phi), kz))
    d = np.concatenate(dirs)
    return (d / np.linalg.norm(d, axis=1)[:, None]).astype(np.float32)


def _cylinders(xml):
    """``xml`` with every third sphere a cylinder capped at z = ±0.3 (two clip planes: finite,
    under the BVH; a box far from a sphere)."""
    parts = xml.split('<string name="kind" value="sphere"/>')
    caps = ('<string name="kind" value="cylinder"/><vector name="clip_0" value="0,0,1"/>'
            '<float name="clip_0_offset" value="0.3"/><vector name="clip_1" value="0,0,-1"/>'
            '<float name="clip_1_offset" value="0.3"/><boolean name="capped" value="true"/>')
    out = parts[0]
    for i, p in enumerate(parts[1:]):
        if i % 3 == 1 and "clip_0" not in p.split("</shape>")[0]:
            out += caps + p
        else:
            out += '<string name="kind" value="sphere"/>' + p
    return out


@pytest.mark.slow
@pytest.mark.parametrize("camera", CAMERAS, ids=["outside", "inside"])
@pytest.mark.parametrize("shapes", ["spheres", "cylinders"])
def test_eye_grid_nearest_matches_bvh(variant, camera, shapes):
    import drjit as dr
    import mitsuba as mi
    from links1_mitsuba import tuning
    xml = _scene(120).replace('origin="0,7,10" target="0,0.5,0"', f'origin="{camera[0]}" target="{camera[1]}"')
    if shapes == "cylinders":
        xml = _cylinders(xml)
    scene, integ, P = _prepared(xml)
    eb = P.eye_buf
    assert eb is not None and eb.kind == "eye"
    d = _rays(eb, P, np.random.default_rng(4))
    n = len(d)
    o = mi.Point3f(*[mi.Float(np.full(n, np.float32(v))) for v in eb.pos])
    dd = mi.Vector3f(*[mi.Float(np.ascontiguousarray(d[:, i])) for i in range(3)])
    tmin, tmax, act = mi.Float(np.full(n, 1e-3, np.float32)), mi.Float(np.full(n, np.inf, np.float32)), \
        dr.full(mi.Bool, True, n)
    a = [np.asarray(x) for x in eb.nearest(o, dd, tmin, tmax, act, None)]
    b = [np.asarray(x) for x in P.bvh.nearest(o, dd, tmin, tmax, act, None)]
    assert 0.1 < b[3].mean() < 0.95                  # hits and misses
    for x, y, name in zip(a, b, ("t", "row", "part", "found")):
        if name in ("row", "part"):
            x, y = x[b[3]], y[b[3]]
        assert np.array_equal(x, y), f"{name}: {np.sum(x != y)} rays differ"
    img = integ.render_window(scene, spp=4)
    with tuning.tuned(eye_buffer=False):
        scene2, integ2, _ = _prepared(xml)
        assert np.array_equal(integ2.render_window(scene2, spp=4), img)


def _field(k):
    """k x k small spheres on a unit grid seen obliquely from above (the scene of the sphere
    benchmarks: most of a cube-map cell's cone runs along a row of spheres)."""
    from tests.scenes import perspective, scene, whitted
    xs = np.arange(k) - (k - 1) / 2.0
    shapes = "".join(f'<shape type="links1_quadric"><string name="kind" value="sphere"/><transform name="to_world">'
                     f'<scale value="0.3"/><translate x="{x}" y="0.3" z="{z}"/></transform></shape>'
                     for x in xs for z in xs)
    return scene(whitted(1), perspective(f"0,{0.95 * k + 1},{0.95 * k + 1}", "0,0,0", fov=50, width=64), shapes)


def test_eye_grid_lists_fewer_than_the_cube_map(variant):
    """Over the camera's own rays the grid's lists are shorter than those of the cube map around
    the eye (lightbuffer.build_point at its finest), counted as entries tested per ray."""
    import drjit as dr
    import mitsuba as mi
    from links1_mitsuba import lightbuffer
    scene, integ, P = _prepared(_field(24))
    eb = P.eye_buf
    cube = lightbuffer.build(P.bvh, ("point", np.array(eb.pos)), eb.margin, N=lightbuffer.GRID_MAX)
    rng = np.random.default_rng(5)
    m = 20000
    R = np.array(eb.frame)
    d = np.stack([eb.u0 + rng.uniform(0, eb.nu / eb.su, m), eb.v0 + rng.uniform(0, eb.nv / eb.sv, m),
                  np.ones(m)], axis=1) @ R
    d = (d / np.linalg.norm(d, axis=1)[:, None]).astype(np.float32)
    o = mi.Point3f(*[mi.Float(np.full(m, np.float32(v))) for v in eb.pos])
    dd = mi.Vector3f(*[mi.Float(np.ascontiguousarray(d[:, i])) for i in range(3)])
    counts = []
    for buf in (eb, cube):
        cost = dr.zeros(mi.UInt32, m)
        buf.nearest(o, dd, mi.Float(0.0), mi.Float(np.inf), dr.full(mi.Bool, True, m), cost)
        counts.append(float(np.mean(np.asarray(cost))))
    assert counts[0] < 0.5 * counts[1], counts


def test_degenerate_window_is_the_unit_window():
    """A camera whose film window cannot be made (non-finite or empty) gets the window
    [-1, 1]², whose lists are still complete: the same lists as asked for that window."""
    from links1_mitsuba import eyegrid
    rng = np.random.default_rng(3)
    c, rad = rng.uniform(-5, 5, (40, 3)), rng.uniform(0.1, 1.0, 40)
    R, eye = np.eye(3), np.zeros(3)
    want = eyegrid.lists(eye, R, (-1.0, 1.0, -1.0, 1.0), (16, 16), c, rad, 1e-4)
    for bad in ((np.nan, 1.0, -1.0, 1.0), (0.5, 0.5, -1.0, 1.0), (-np.inf, np.inf, -1.0, 1.0)):
        got = eyegrid.lists(eye, R, bad, (16, 16), c, rad, 1e-4)
        for x, y in zip(got[:3], want[:3]):
            assert np.array_equal(x, y)
        assert got[3][1:5] == want[3][1:5]


def test_coarser_cells_past_the_entry_budget(variant, monkeypatch):
    """Lists that would pass ``MAX_ENTRIES`` (bounds filling the film) are made over coarser
    cells, within the budget, and still give the BVH walk's hits."""
    import drjit as dr
    import mitsuba as mi
    from links1_mitsuba import eyegrid, lightbuffer
    scene, integ, P = _prepared(_scene(120))
    fine = P.eye_buf
    monkeypatch.setattr(eyegrid, "MAX_ENTRIES", 3000)
    eb = lightbuffer.plan_eye(P, scene)
    assert eb.nu < fine.nu and eb.entries < fine.entries
    assert eb.entries <= 3000 + P.bvh.n          # the film cells within the budget, BEHIND at most all
    d = _rays(eb, P, np.random.default_rng(6))
    n = len(d)
    o = mi.Point3f(*[mi.Float(np.full(n, np.float32(v))) for v in eb.pos])
    dd = mi.Vector3f(*[mi.Float(np.ascontiguousarray(d[:, i])) for i in range(3)])
    args = (o, dd, mi.Float(np.full(n, 1e-3, np.float32)), mi.Float(np.full(n, np.inf, np.float32)),
            dr.full(mi.Bool, True, n), None)
    a = [np.asarray(x) for x in eb.nearest(*args)]
    b = [np.asarray(x) for x in P.bvh.nearest(*args)]
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1][b[3]], b[1][b[3]])
