"""Light buffers (lightbuffer.py): a shadow query through a light buffer gives the same
occlusion as the BVH walk (the same exact quadric test on a conservative candidate list), on
random shadow rays over many spheres, spheres that contain the light, rays that graze spheres
and rays along the borders of the buffer's cells; and the images match (bit for bit with opaque
shadows, to float32 rounding with transparent ones: the transmittances of 3-3-3 are multiplied
in another order)."""
from __future__ import annotations

import numpy as np
import pytest

from tests.scenes import perspective, scene, whitted

pytestmark = pytest.mark.mitsuba

LIGHT = (0.7, 2.2, 0.4)


def _scene(n, transparent=False, seed=11):
    rng = np.random.default_rng(seed)
    shapes = []
    for i in range(n):
        x, z = rng.uniform(-4, 4, 2)
        y = rng.uniform(0.0, 3.0)
        s = rng.uniform(0.15, 0.6)
        if i < 3:     # three spheres around the point light (nested: the light is inside all three)
            x, y, z, s = LIGHT[0] + 0.1 * i, LIGHT[1] - 0.05 * i, LIGHT[2], 0.6 + 0.3 * i
        # the spheres around the light let light through (all with the same t: a product of
        # equal factors has the same bits in any order); others are opaque or, in the transparent
        # scene, a third of them transparent with different t
        t = 0.6 if i < 3 else (0.2 + 0.1 * (i % 5) if transparent and i % 3 == 0 else 0.0)
        clip = ""
        if i % 5 == 4:  # a capped, clipped sphere now and then (its box is not a cube)
            clip = ('<vector name="clip_0" value="0,0,1"/><float name="clip_0_offset" value="0.3"/>'
                    '<boolean name="capped" value="true"/>')
        shapes.append(f'<shape type="links1_quadric"><string name="kind" value="sphere"/>{clip}'
                      f'<transform name="to_world"><rotate x="1" angle="{rng.uniform(0, 180):.3f}"/>'
                      f'<scale x="{s:.3f}" y="{s * rng.uniform(0.6, 1.4):.3f}" z="{s:.3f}"/>'
                      f'<translate x="{x:.3f}" y="{y:.3f}" z="{z:.3f}"/></transform>'
                      f'<bsdf type="links1_phong"><rgb name="diffuse" value="0.6, 0.5, 0.4"/>'
                      f'<rgb name="reflectance" value="{0.3 if i % 4 == 0 else 0}"/>'
                      f'<rgb name="transmittance" value="{t}"/><float name="ior" value="1"/></bsdf></shape>')
    return scene(whitted(2), perspective("0,7,10", "0,0.5,0", fov=55, width=64, height=48, spp=None), f"""
  <emitter type="point"><point name="position" value="{LIGHT[0]},{LIGHT[1]},{LIGHT[2]}"/>
    <rgb name="intensity" value="20"/></emitter>
  <emitter type="point"><point name="position" value="-3,6,5"/><rgb name="intensity" value="60"/></emitter>
  <emitter type="spot"><transform name="to_world"><lookat origin="4,5,-3" target="0,0,0"/></transform>
    <rgb name="intensity" value="40"/><float name="cutoff_angle" value="40"/></emitter>
  <emitter type="directional"><vector name="direction" value="-1,-2,-0.7"/><rgb name="irradiance" value="0.5"/></emitter>
  <shape type="rectangle"><transform name="to_world"><rotate x="1" angle="-90"/><scale value="8"/></transform>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.5"/></bsdf></shape>
  {''.join(shapes)}""")


def _prepared(xml):
    import links1_mitsuba
    scene = links1_mitsuba.load_string(xml)
    integ = scene.integrator()
    P = integ.prepare(scene)
    assert P.bvh is not None
    return scene, integ, P


def _shadow_rays(P, L, rng, N):
    """float32 shadow rays toward the point light ``L``: (o, d, smax) as numpy, the kernel's
    way (d = (L - p) / |L - p| in float32), from random points, points on the spheres' bounds
    whose segment to the light grazes another sphere, and points along cell borders."""
    specs = P.bvh.specs
    lo = np.array([s.bounds()[0] for s in specs])
    hi = np.array([s.bounds()[1] for s in specs])
    c = 0.5 * (lo + hi)
    pts = [rng.uniform([-5, -0.1, -5], [5, 3.5, 5], (3000, 3))]
    # grazing: segments tangent to a sphere's bounding box corners and to the sphere's centre plane
    for k in range(len(specs)):
        for _ in range(6):
            corner = np.where(rng.random(3) < 0.5, lo[k], hi[k])
            t = rng.uniform(1.05, 3.0)
            pts.append((L + (corner - L) * t)[None])
            side = rng.normal(size=3)
            side -= side @ (c[k] - L) / np.sum((c[k] - L) ** 2) * (c[k] - L)
            side /= np.linalg.norm(side) + 1e-30
            rad = 0.5 * np.min(hi[k] - lo[k])      # about the quadric's surface
            edge = c[k] + side * rad * rng.uniform(0.97, 1.03)
            pts.append((L + (edge - L) * rng.uniform(1.02, 2.5))[None])
    # exactly grazing: through the silhouette of each ellipsoid as seen from the light (its
    # object-space tangent circle), a little inside or outside, then on beyond the tangent point
    for s in specs:
        m = np.asarray(s.to_world, dtype=np.float64)
        lo_ = np.linalg.inv(m) @ np.append(L, 1.0)
        q2 = float(lo_[:3] @ lo_[:3])
        if q2 <= 1.0:
            continue
        a1 = np.cross(lo_[:3], [0.3, 0.5, 0.8])
        a1 /= np.linalg.norm(a1)
        a2 = np.cross(lo_[:3], a1) / np.sqrt(q2)
        phi = rng.uniform(0, 2 * np.pi, 24)
        y = lo_[:3] / q2 + np.sqrt(1 - 1 / q2) * (np.cos(phi)[:, None] * a1 + np.sin(phi)[:, None] * a2)
        y *= (1.0 + rng.uniform(-1e-5, 1e-5, 24))[:, None]
        x = y @ m[:3, :3].T + m[:3, 3]
        pts.append(L + (x - L) * rng.uniform(1.02, 3.0, 24)[:, None])
        # through the ellipsoid's farthest points from its centre (the ends of its longest
        # axis, just inside), where a bounding sphere around the centre is tight
        v1 = np.linalg.svd(m[:3, :3])[2][0]
        tips = np.array([v1, -v1]) * (1 - 1e-4)
        for x in tips @ m[:3, :3].T + m[:3, 3]:
            pts.append(L + (x - L) * rng.uniform(1.0001, 3.0, 8)[:, None])
    # along the borders of cube-map cells (u or v on a border, the other random)
    for face in range(6):
        ax, sgn = face // 2, (-1.0 if face % 2 else 1.0)
        for _ in range(200):
            dvec = np.zeros(3)
            dvec[ax] = sgn
            b = -1.0 + 2.0 * rng.integers(0, N + 1) / N
            o = rng.uniform(-1, 1)
            dvec[(ax + 1) % 3], dvec[(ax + 2) % 3] = (b, o) if rng.random() < 0.5 else (o, b)
            pts.append((L + dvec / np.linalg.norm(dvec) * rng.uniform(0.2, 8.0))[None])
    p = np.concatenate(pts).astype(np.float32)
    to = np.float32(L) - p
    dist = np.sqrt(np.sum(to.astype(np.float32) ** 2, axis=1, dtype=np.float32))
    keep = dist > 1e-3
    p, to, dist = p[keep], to[keep], dist[keep]
    d = (to / dist[:, None]).astype(np.float32)
    return p, d, (dist * np.float32(1 - 2 ** -20)).astype(np.float32)


def _query(P, lb, p, d, smax):
    import drjit as dr
    import mitsuba as mi
    o = mi.Point3f(*[mi.Float(np.ascontiguousarray(p[:, i])) for i in range(3)])
    dd = mi.Vector3f(*[mi.Float(np.ascontiguousarray(d[:, i])) for i in range(3)])
    sm = mi.Float(smax)
    act = dr.full(mi.Bool, True, len(p))
    a = lb.transmittance(o, dd, sm, act, None)
    b = P.bvh.transmittance(o, dd, sm, act, None)
    return np.asarray(a), np.asarray(b)          # (3, n) each


@pytest.mark.slow
@pytest.mark.parametrize("transparent", [False, True])
def test_light_buffer_query_matches_bvh(variant, transparent):
    from links1_mitsuba import lightbuffer
    scene, integ, P = _prepared(_scene(120, transparent))
    rng = np.random.default_rng(7)
    L = np.array(LIGHT)
    margin = P.lbuf[0].margin if P.lbuf[0] is not None else 1e-3
    for N in (8, 33):
        lb = lightbuffer.build(P.bvh, ("point", L), margin, N=N)
        p, d, smax = _shadow_rays(P, L, rng, N)
        a, b = _query(P, lb, p, d, smax)
        assert 0.05 < np.mean(np.max(b, axis=0) == 0) < 0.95     # opaque hits and lit rays
        if transparent:
            np.testing.assert_allclose(a, b, rtol=3e-6, atol=0)
            assert np.array_equal(a == 0, b == 0)
        else:
            assert np.array_equal(a, b), f"N={N}: {np.sum(np.any(a != b, axis=0))} rays differ"
    # directional: parallel rays from random points and grazing points
    w = np.array([1.0, 2.0, 0.7])
    w /= np.linalg.norm(w)
    lb = lightbuffer.build(P.bvh, ("dir", w), margin, N=40)
    p = rng.uniform([-6, -0.1, -6], [6, 3.5, 6], (20000, 3)).astype(np.float32)
    d = np.broadcast_to(w.astype(np.float32), p.shape).copy()
    a, b = _query(P, lb, p, d, np.full(len(p), np.inf, dtype=np.float32))
    assert 0.05 < np.mean(np.max(b, axis=0) == 0) < 0.95
    if transparent:
        np.testing.assert_allclose(a, b, rtol=3e-6, atol=0)
    else:
        assert np.array_equal(a, b)


@pytest.mark.slow
@pytest.mark.parametrize("transparent", [False, True])
def test_light_buffer_images_match(variant, transparent):
    from links1_mitsuba import tuning
    xml = _scene(120, transparent)
    scene, integ, P = _prepared(xml)
    kinds = [None if lb is None else lb.kind for lb in P.lbuf]
    assert kinds.count("point") >= 2 and "dir" in kinds     # both point lights, the spot, the sun
    a = integ.render_window(scene, spp=2)
    with tuning.tuned(light_buffer=False):
        scene2, integ2, P2 = _prepared(xml)
        assert all(lb is None for lb in P2.lbuf)
        b = integ2.render_window(scene2, spp=2)
    if transparent:
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)
    else:
        assert np.array_equal(a, b)


def test_light_buffer_tables(variant):
    """CSR lists in 64-byte aligned tables; a light inside a bound lists it in every cell.
    (The alignment is checked on llvm_ad_rgb, where the tables map host memory; cuda_ad_rgb
    copies them to the device.)"""
    scene, integ, P = _prepared(_scene(40))
    lb = P.lbuf[0]
    assert lb is not None and lb.kind == "point"
    if variant.startswith("llvm"):
        for t in (lb.off, lb.ent):
            assert np.asarray(t).__array_interface__["data"][0] % 64 == 0
    off = np.asarray(lb.off)
    ent = np.asarray(lb.ent).reshape(-1, 2)
    rows = ent[:, 0].view(np.uint32)
    assert off[0] == 0 and np.all(np.diff(off) >= 0) and off[-1] == lb.entries
    around = {i for i, s in enumerate(P.bvh.specs) if np.linalg.norm(
        0.5 * (s.bounds()[0] + s.bounds()[1]) - np.array(LIGHT)) < 0.5}
    assert around
    for cell in range(len(off) - 1):
        lst = rows[off[cell]:off[cell + 1]]
        assert around <= set(lst.tolist())
        assert np.all(np.diff(ent[off[cell]:off[cell + 1], 1]) >= 0)     # nearest to the light first


def test_cells_are_conservative():
    """Every direction that meets a bound (the tangent cone's rim included, and directions
    snapped onto cell borders) falls in a cell that lists it; a bound holding the light is in
    every cell. Pure numpy (lightbuffer.build_point)."""
    from links1_mitsuba import lightbuffer as lb
    rng = np.random.default_rng(4)
    L = np.array([0.3, 1.0, -0.2])
    c = rng.uniform(-4, 4, (150, 3))
    r = rng.uniform(0.05, 0.7, 150)
    c[0], r[0] = L + 0.1, 0.5                      # holds the light
    for N in (8, 21):
        off, ob, _ = lb.build_point(L, c, r, N)
        lists = [set(ob[off[k]:off[k + 1]].tolist()) for k in range(6 * N * N)]
        assert all(0 in s for s in lists)
        for k in range(1, 150):
            ax = (c[k] - L) / np.linalg.norm(c[k] - L)
            sin_a = min(r[k] / np.linalg.norm(c[k] - L), 1.0)
            e1 = np.cross(ax, [0.3, 0.5, 0.8]); e1 /= np.linalg.norm(e1)
            e2 = np.cross(ax, e1)
            phi = rng.uniform(0, 2 * np.pi, 64)
            s = sin_a * np.sqrt(rng.uniform(0, 1, 64))
            s[:16] = sin_a                                               # on the rim
            dirs = ax * np.sqrt(1 - s ** 2)[:, None] + (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2) * s[:, None]
            # snap a quarter of them onto the nearest cell border of their face
            a = np.abs(dirs)
            m = np.argmax(a, axis=1)
            for i in range(48, 64):
                o = (m[i] + 1) % 3
                u = dirs[i, o] / a[i, m[i]]
                dirs[i, o] = np.round((u + 1) * N / 2) * 2 / N - 1
                dirs[i, o] *= a[i, m[i]]
            dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
            dirs = dirs[dirs @ ax >= np.sqrt(1 - sin_a ** 2) - 1e-12]     # snapped ones still in the cone
            for cell in lb.cube_cell(dirs.astype(np.float32), N):
                assert k in lists[cell], (N, k)


def test_bounding_spheres_hold_the_quadrics(variant):
    """Every point of every quadric (its ellipsoid, the longest axis's ends included; a clipped
    or capped one lies inside its ellipsoid and its box) is inside its light-buffer sphere."""
    from links1_mitsuba import lightbuffer
    scene, integ, P = _prepared(_scene(60))
    c, r = lightbuffer.quadric_spheres(P.bvh.specs, 0.0)
    rng = np.random.default_rng(2)
    u = rng.normal(size=(400, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    for k, s in enumerate(P.bvh.specs):
        m = np.asarray(s.to_world, dtype=np.float64)
        v1 = np.linalg.svd(m[:3, :3])[2][0]
        pts = np.concatenate([u, [v1, -v1]]) @ m[:3, :3].T + m[:3, 3]
        lo, hi = s.bounds()
        pts = pts[np.all((pts >= lo - 1e-12) & (pts <= hi + 1e-12), axis=1)]   # within its box
        assert np.all(np.linalg.norm(pts - c[k], axis=1) <= r[k] * (1 + 1e-9)), k


@pytest.mark.slow
def test_sampled_mean_list_estimates_the_built_buffer(variant):
    """The pre-build estimate that skips hopeless buffers (plan) is within 15 % of
    the mean list length of the buffer built for the same point."""
    from links1_mitsuba import lightbuffer
    scene, integ, P = _prepared(_scene(120))
    margin = 1e-3
    c, r = lightbuffer.quadric_spheres(P.bvh.specs, margin)
    for pos in (np.array(LIGHT), np.array([-3.0, 6.0, 5.0]), np.array([0.0, 7.0, 10.0])):
        for N in (16, 64):
            built = lightbuffer.build(P.bvh, ("point", pos), margin, N=N).mean_list
            est = lightbuffer.sampled_mean_list(pos, c, r, N)
            assert built > 1.0 and abs(est / built - 1.0) < 0.15, (pos, N, est, built)
