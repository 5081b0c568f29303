"""The BVH over links1 quadrics (bvh.py) finds the same hits as testing every quadric."""
from __future__ import annotations

import numpy as np
import pytest

from tests.scenes import perspective, scene, whitted

pytestmark = pytest.mark.mitsuba


def _scene(n):
    rng = np.random.default_rng(3)
    shapes = []
    for i in range(n):
        x, z = rng.uniform(-3, 3, 2)
        s = rng.uniform(0.2, 0.6)
        kind = "sphere" if i % 3 else "cylinder"
        clip = ""
        if kind == "cylinder" or i % 4 == 1:
            clip = ('<vector name="clip_0" value="0,0,1"/><float name="clip_0_offset" value="0.5"/>'
                    '<vector name="clip_1" value="0,0,-1"/><float name="clip_1_offset" value="1"/>'
                    f'<boolean name="capped" value="{"true" if i % 2 else "false"}"/>')
        shapes.append(f'<shape type="links1_quadric"><string name="kind" value="{kind}"/>{clip}'
                      f'<transform name="to_world"><rotate x="1" angle="{rng.uniform(0, 180):.3f}"/>'
                      f'<scale x="{s:.3f}" y="{s * 1.3:.3f}" z="{s:.3f}"/>'
                      f'<translate x="{x:.3f}" y="{s:.3f}" z="{z:.3f}"/></transform>'
                      f'<bsdf type="links1_phong"><rgb name="diffuse" value="0.6"/>'
                      f'<rgb name="reflectance" value="{0.3 if i % 5 == 0 else 0}"/>'
                      f'<rgb name="transmittance" value="{0.5 if i % 7 == 0 else 0}"/></bsdf></shape>')
    camera = perspective("0,5,9", "0,0,0", fov=50, width=48, height=40, spp=None, rfilter=None)
    return scene(whitted(3), camera, f"""
  <emitter type="point"><point name="position" value="3,8,4"/><rgb name="intensity" value="80"/></emitter>
  <emitter type="directional"><vector name="direction" value="-1,-2,-1"/><rgb name="irradiance" value="0.5"/></emitter>
  <shape type="rectangle"><transform name="to_world"><rotate x="1" angle="-90"/><scale value="8"/></transform>
    <bsdf type="diffuse"/></shape>
  {''.join(shapes)}""")


@pytest.mark.slow
def test_bvh_matches_every_quadric(variant):
    import links1_mitsuba
    from links1_mitsuba import tuning
    xml = _scene(40)
    scene = links1_mitsuba.load_string(xml)
    a = scene.integrator().render_window(scene, aovs=("id",))
    assert scene.integrator().info()["tables"].bvh is not None
    scene2 = links1_mitsuba.load_string(xml)
    with tuning.tuned(bvh_min=10 ** 9):
        b = scene2.integrator().render_window(scene2, aovs=("id",))
    assert scene2.integrator().info()["tables"].bvh is None
    assert np.mean(a[..., 3] != b[..., 3]) <= 2e-3
    rel = float(np.sum((a[..., :3] - b[..., :3]) ** 2) / np.sum(b[..., :3] ** 2))
    assert rel <= 1e-5



@pytest.mark.slow
def test_bvh_tables_are_aligned_node_lines(llvm):
    """The walk's tables sit in 64-byte aligned memory (numpy-mapped tables made the same walk
    35-62 ms at random, compare/quadric_accel.py), and a node's line holds its children's boxes
    and its own ``first``/``count`` bit for bit.

    LLVM only: on llvm_ad_rgb the tables are Dr.Jit arrays mapped on host memory, whose
    alignment is what this checks; on cuda_ad_rgb they are copied to the device
    (test_bvh_matches_every_quadric runs the walk on both)."""
    import drjit as dr
    import mitsuba as mi

    import links1_mitsuba
    from links1_mitsuba.bvh import build, pack_nodes
    scene = links1_mitsuba.load_string(_scene(40))
    integ = scene.integrator()
    integ.render_window(scene, (0, 0, 8, 8))
    bvh = integ.info()["tables"].bvh
    for name in ("inv", "nm", "clips", "slot", "st", "line"):
        assert np.asarray(getattr(bvh, name)).__array_interface__["data"][0] % 64 == 0, name
    rng = np.random.default_rng(5)
    lo = rng.uniform(-5, 5, (13, 3))
    hi = lo + rng.uniform(0.1, 1, (13, 3))
    _, nlo, nhi, first, count = build(lo, hi)
    line = pack_nodes(nlo, nhi, first, count)
    assert line.shape == (len(first), 4, 4) and line.dtype == np.float32
    np.testing.assert_array_equal(line[:, 0, 3].view(np.uint32), first)
    np.testing.assert_array_equal(line[:, 1, 3].view(np.uint32), count)
    for k in np.flatnonzero(count == 0):
        for j, c in enumerate((first[k], first[k] + 1)):
            np.testing.assert_array_equal(line[k, 2 * j, :3], nlo[c].astype(np.float32))
            np.testing.assert_array_equal(line[k, 2 * j + 1, :3], nhi[c].astype(np.float32))
    # a packet gather returns first/count bit for bit (small integers are denormal floats)
    tab = np.asarray(bvh.line).reshape(-1, 4, 4)
    assert tab.shape[0] == bvh.nnodes
    k = mi.UInt32(np.arange(bvh.nnodes, dtype=np.uint32) * 4)
    for j in (0, 1):
        w = dr.reinterpret_array(mi.UInt32, dr.gather(mi.Array4f, bvh.line, k + j).w)
        np.testing.assert_array_equal(np.asarray(w), tab[:, j, 3].view(np.uint32))
