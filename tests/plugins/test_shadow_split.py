"""Shadow rays through Mitsuba's shapes: the occluders' box cull never drops a ray
that Embree finds blocked (grazing rays, rays along box faces and axes, origins on faces), and
the split transmittance (one any-hit query over the opaque shapes, one per transparent shape:
``shadow_plan.shadow_split``) is 3-3-3's product over the shapes a segment meets, checked against
float64 geometry (spheres, a plane) and against the nearest-first crossing walk it replaces."""
from __future__ import annotations

import numpy as np
import pytest

from tests.scenes import perspective, scene, whitted

from .conftest import use_variant, variant_marks

pytestmark = pytest.mark.mitsuba

# glass spheres (centre, radius, transmittance), the last two nested; an opaque wall x = 3.
SPHERES = [((0.0, 1.0, 0.0), 1.0, (0.9, 0.8, 0.7)), ((2.0, 1.2, 1.0), 0.6, (0.5, 0.6, 0.9)),
           ((-1.5, 0.8, 2.0), 0.9, (0.7, 0.7, 0.7)), ((-1.5, 0.8, 2.0), 0.4, (0.3, 0.9, 0.6))]
WALL_X = 3.0


def _xml(cube=True):
    glass = "".join(
        f'<shape type="sphere"><point name="center" value="{c[0]},{c[1]},{c[2]}"/>'
        f'<float name="radius" value="{r}"/><bsdf type="links1_phong"><rgb name="diffuse" value="0.1"/>'
        f'<rgb name="transmittance" value="{t[0]},{t[1]},{t[2]}"/><float name="ior" value="1"/></bsdf></shape>'
        for c, r, t in SPHERES)
    box = ('<shape type="cube"><transform name="to_world"><scale value="0.5"/><rotate y="1" angle="30"/>'
           '<translate x="0.5" y="0.5" z="-2.5"/></transform>'
           '<bsdf type="links1_phong"><rgb name="diffuse" value="0.5"/></bsdf></shape>') if cube else ""
    return scene(whitted(3), perspective("0,4,9", "0,0.8,0", fov=50, width=48, height=36, spp=None), f"""
  <emitter type="point"><point name="position" value="-2,5,3"/><rgb name="intensity" value="40"/></emitter>
  <emitter type="directional"><vector name="direction" value="0.5,-1,-0.3"/><rgb name="irradiance" value="0.6"/></emitter>
  <emitter type="constant"><rgb name="radiance" value="0.2"/></emitter>
  <shape type="rectangle"><transform name="to_world"><rotate x="1" angle="-90"/><scale value="6"/></transform>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.6"/></bsdf></shape>
  <shape type="rectangle"><transform name="to_world"><rotate y="1" angle="-90"/><scale value="6"/>
    <translate x="{WALL_X}"/></transform><bsdf type="links1_phong"><rgb name="diffuse" value="0.4"/></bsdf></shape>
  {box}{glass}""")


def _prepared(xml):
    import links1_mitsuba
    scene = links1_mitsuba.load_string(xml)
    integ = scene.integrator()
    return scene, integ, integ.prepare(scene)


def _arrays(o, d, smax):
    import mitsuba as mi
    return (mi.Point3f(*[mi.Float(np.ascontiguousarray(o[:, i], dtype=np.float32)) for i in range(3)]),
            mi.Vector3f(*[mi.Float(np.ascontiguousarray(d[:, i], dtype=np.float32)) for i in range(3)]),
            mi.Float(np.ascontiguousarray(smax, dtype=np.float32)))


def _segments(rng, lo, hi, n=4000):
    """Segments from random points toward random points, toward the boxes' faces and corners
    (grazing, exactly on a face plane), and along the axes (direction components exactly 0)."""
    o = rng.uniform(-5, 5, (n, 3))
    o[:, 1] = rng.uniform(0.01, 4, n)
    targets = [rng.uniform(-5, 5, (n, 3))]
    for a, b in zip(lo, hi):
        k = n // (2 * len(lo))
        t = rng.uniform(a, b, (k, 3))
        ax = rng.integers(0, 3, k)
        t[np.arange(k), ax] = np.where(rng.random(k) < 0.5, a[ax], b[ax])    # on a face
        targets.append(t)
        corners = np.array([[x, y, z] for x in (a[0], b[0]) for y in (a[1], b[1]) for z in (a[2], b[2])])
        targets.append(corners[rng.integers(0, 8, k)] * (1 + rng.uniform(-1e-6, 1e-6, (k, 3))))
    tg = np.concatenate(targets)
    o = o[rng.integers(0, n, len(tg))]
    d = tg - o
    # a fifth along the axes: two direction components exactly zero
    m = rng.random(len(d)) < 0.2
    ax = rng.integers(0, 3, len(d))
    keep = np.zeros_like(d)
    keep[np.arange(len(d)), ax] = d[np.arange(len(d)), ax]
    d = np.where(m[:, None], keep, d)
    dist = np.linalg.norm(d, axis=1)
    ok = dist > 1e-3
    o, d, dist = o[ok], d[ok] / dist[ok, None], dist[ok]
    smax = np.where(rng.random(len(d)) < 0.3, np.inf, dist * rng.uniform(0.5, 2.0, len(d)))
    return o.astype(np.float32), d.astype(np.float32), smax.astype(np.float32)


def test_box_cull_keeps_every_blocked_ray(variant):
    """For each Mitsuba shape alone (a sub-scene of it), every segment Embree finds blocked
    meets the shape's cull box; and the cull does drop the clear rays it should."""
    import drjit as dr
    import mitsuba as mi
    from links1_mitsuba import intersect
    from links1_mitsuba.shadow_plan import occluder_boxes
    scene, integ, P = _prepared(_xml())
    shapes = scene.shapes()
    lo = np.array([np.array(s.bbox().min, dtype=np.float64) for s in shapes])
    hi = np.array([np.array(s.bbox().max, dtype=np.float64) for s in shapes])
    n = len(shapes)
    boxes = occluder_boxes(np.ones(n, dtype=bool), lo, hi, np.zeros(n, dtype=bool))
    assert boxes is not None and len(boxes) == n
    o, d, smax = _segments(np.random.default_rng(3), lo, hi)
    O, D, S = _arrays(o, d, smax)
    culled = 0
    for k, s in enumerate(shapes):
        sub = mi.load_dict({"type": "scene", s.id(): s})
        blocked = np.asarray(sub.ray_test(mi.Ray3f(O, D, S, 0.0, mi.Color0f())))
        meets = np.asarray(intersect.meets_boxes(O, D, S, [boxes[k]], dr.full(mi.Int32, -1, len(o))))
        assert blocked.sum() > 50, f"shape {k}: too few blocked rays to test"
        missed = blocked & ~meets
        assert not missed.any(), f"shape {k} ({s}): {missed.sum()} blocked rays culled"
        culled += int(np.sum(~meets))
    assert culled > 0.5 * n * len(o)


def _sphere_hit(o, d, smax, c, r, margin=1e-4):
    """float64: does o + t d, 0 <= t <= smax, cross the sphere's surface (a segment inside it
    meets nothing); and which rays are too close to call."""
    oc = o - np.asarray(c)
    b = np.sum(oc * d, axis=1)
    cc = np.sum(oc * oc, axis=1) - r * r
    disc = b * b - cc
    sq = np.sqrt(np.maximum(disc, 0))
    t0, t1 = -b - sq, -b + sq
    hit = (disc > 0) & (((t0 >= 0) & (t0 <= smax)) | ((t1 >= 0) & (t1 <= smax)))
    unsure = (np.abs(disc) < margin) | (np.abs(cc) < margin) | (np.abs(t0 - smax) < margin) | \
        (np.abs(t1 - smax) < margin) | (np.abs(t1) < margin) | (np.abs(t0) < margin)
    return hit, unsure


@pytest.mark.parametrize("variant_name,split", [
    pytest.param(v, split, marks=variant_marks(v), id=f"{v}-{'split' if split else 'walk'}")
    for v, split in (("llvm_ad_rgb", True), ("llvm_ad_rgb", False), ("cuda_ad_rgb", False))])
def test_split_transmittance_is_the_product_over_the_shapes_met(variant_name, split):
    """T of straight segments = 0 behind the wall, else the product of the transmittances of
    the glass spheres met (each once, nested ones too), from float64 geometry; the same with
    the crossing walk (split=False), which the split replaces. The split is LLVM only
    (shadow_plan.shadow_split: OptiX traces a kernel's rays through one pipeline, so cuda_ad_rgb
    makes no sub-scenes and walks the crossings): the walk runs on both variants."""
    import drjit as dr
    import mitsuba as mi
    from links1_mitsuba import intersect, shadow_plan, tuning
    use_variant(variant_name)
    scene, integ, P = _prepared(_xml(cube=False))
    if variant_name.startswith("llvm"):
        assert (P.shadow_split is not None) and len(P.shadow_split["trans"]) == len(SPHERES)
    else:
        assert P.shadow_split is None
    rng = np.random.default_rng(5)
    n = 6000
    o = rng.uniform([-4, 0.05, -3], [2.9, 3, 4], (n, 3))
    aim = np.array([c for c, _, _ in SPHERES])[rng.integers(0, len(SPHERES), n)] + rng.normal(0, 0.8, (n, 3))
    aim[n // 4:n // 3, 0] = 4.0                      # through the wall
    d = aim - o
    d /= np.linalg.norm(d, axis=1)[:, None]
    smax = np.where(rng.random(n) < 0.5, np.inf, rng.uniform(0.5, 8, n))
    o, d, smax = o.astype(np.float32), d.astype(np.float32), smax.astype(np.float32)
    O, D, S = _arrays(o, d, smax)
    cost = dr.zeros(mi.UInt32, n)
    T = intersect.shadow_mitsuba(P, scene, O, D, S, dr.full(mi.Bool, True, n), mi.Color3f(1.0), cost,
                                 tuning.Tuning(split=split))
    T = np.asarray(T).T                               # (n, 3)
    o64, d64, s64 = o.astype(np.float64), d.astype(np.float64), smax.astype(np.float64)
    want = np.ones((n, 3))
    unsure = np.zeros(n, dtype=bool)
    for c, r, t in SPHERES:
        hit, u = _sphere_hit(o64, d64, s64, c, r)
        want[hit] *= t
        unsure |= u
    opaque = np.zeros(n, dtype=bool)
    for axis, at, d_sign in ((0, WALL_X, 1), (1, 0.0, -1)):       # the wall x = 3, the floor y = 0
        with np.errstate(divide="ignore", invalid="ignore"):
            tp = (at - o64[:, axis]) / d64[:, axis]
        q = o64 + tp[:, None] * d64
        others = [k for k in range(3) if k != axis]
        inside = np.all(np.abs(q[:, others]) <= 6.0, axis=1)
        opaque |= (d_sign * d64[:, axis] > 0) & (tp <= s64) & inside
        unsure |= (np.abs(tp - s64) < 1e-4) | (np.abs(np.max(np.abs(q[:, others]), axis=1) - 6.0) < 1e-4)
    want[opaque] = 0.0
    sure = ~unsure
    assert sure.mean() > 0.95 and 0.1 < opaque[sure].mean() < 0.9
    assert (want[sure, 0] < 1).mean() > 0.3          # plenty of rays cross glass
    np.testing.assert_allclose(T[sure], want[sure], rtol=1e-6, atol=0)
    assert shadow_plan.SPLIT_MAX >= len(SPHERES)


@pytest.mark.slow
def test_split_image_matches_the_walk_and_the_core(llvm):
    """The images with and without the split agree but for a few pixels, where the split is
    the one nearer the core's float64 render.

    LLVM only: the split exists on LLVM only (shadow_plan.shadow_split: OptiX traces a kernel's rays
    through one pipeline, so CUDA walks the crossings, which
    test_split_transmittance_is_the_product_over_the_shapes_met checks there)."""
    from links1_app.renderers import make_renderer
    from links1_mitsuba import tuning
    import tempfile
    import os
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "glass.xml")
        with open(path, "w") as f:
            f.write(_xml())
        imgs = {}
        for split in (True, False):
            with tuning.tuned(split=split):
                imgs[split] = np.asarray(make_renderer("mitsuba", path, spp=2).render())
        core = np.asarray(make_renderer("core", path, spp=2).render())
    differ = np.abs(imgs[True] - imgs[False]).max(axis=2) > 1e-5
    assert differ.mean() < 0.01
    err = {k: np.abs(v - core).max(axis=2) for k, v in imgs.items()}
    assert np.mean(err[True] > 1e-3) <= np.mean(err[False] > 1e-3)
    assert np.mean(err[True] > 1e-3) < 0.01
