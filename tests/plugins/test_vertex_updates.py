"""A Mitsuba mesh's vertices moved through ``params.update()`` between frames, with the frozen
launch on: each frame is that of a scene loaded afresh with the moved mesh (bit for bit: the
same kernels over the same vertex bits), also with the vertices attached (reverse and forward
mode), and the case that aborted the process (the launch's scene input handed freeze a freed
vertex buffer: the parameter watch's pin of an attached value was a view of the mesh's field,
so the freed indices were handed out again and the change went unseen)."""
from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.mitsuba

W, H, SPP = 16, 12, 2
KEY = "obj.vertex_positions"
CUBE = np.array([(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float32)
QUADS = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]


def _ply(path, verts):
    """An 8-vertex cube as a PLY file (float32 positions written exactly)."""
    tris = [t for a, b, c, d in QUADS for t in ((a, b, c), (a, c, d))]
    head = (f"ply\nformat ascii 1.0\nelement vertex {len(verts)}\nproperty float x\nproperty float y\n"
            f"property float z\nelement face {len(tris)}\nproperty list uchar int vertex_indices\nend_header\n")
    path.write_text(head + "".join(" ".join(repr(float(c)) for c in v) + "\n" for v in verts)
                    + "".join(f"3 {a} {b} {c}\n" for a, b, c in tris))
    return str(path)


def _verts(frame):
    """The cube's vertices at ``frame``: turned a little and moved (float32)."""
    a = 0.35 + 0.1 * frame
    rot = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    return (0.7 * CUBE @ rot.T + (0.15 * frame - 0.2, 0.05 * frame, 0)).astype(np.float32)


def _scene(mi, path, verts, integrator):
    t = mi.ScalarTransform4f()
    return mi.load_dict({
        "type": "scene", "integrator": integrator,
        "obj": {"type": "ply", "filename": _ply(path, verts), "face_normals": True,
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.6, 0.5, 0.4]}}},
        "light": {"type": "point", "position": [2, 4, 3], "intensity": {"type": "rgb", "value": [30, 30, 30]}},
        "sensor": {"type": "perspective", "fov": 30, "to_world": t.look_at(origin=[0, 0.5, 6], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": W, "height": H, "rfilter": {"type": "box"}}}})


WHITTED = {"type": "links1_whitted", "max_depth": 1}


def test_moved_vertices_render_as_a_fresh_load(variant, tmp_path):
    import mitsuba as mi
    sc = _scene(mi, tmp_path / "cube.ply", _verts(0), WHITTED)
    assert sc.integrator().use_freeze
    params = mi.traverse(sc)
    last = np.array(mi.render(sc, seed=0, spp=SPP))
    for frame in (1, 2, 3):
        params[KEY] = mi.Float(_verts(frame).ravel())
        params.update()
        img = np.array(mi.render(sc, seed=frame, spp=SPP))
        fresh = _scene(mi, tmp_path / f"cube{frame}.ply", _verts(frame), WHITTED)
        assert np.array_equal(img, np.array(mi.render(fresh, seed=frame, spp=SPP))), frame
        assert not np.array_equal(img, last)
        last = img
    assert sc.integrator().info()["recordings"] >= 1   # the frozen launch made the frames


def _reverse(mi, dr, sc, verts, seed, integrator=None):
    """The frame, d (red sum of the right half) / d vertices at ``verts`` (attached; reverse
    mode) and d frame / d x of every vertex (forward mode)."""
    params = mi.traverse(sc)
    out = []
    for mode in ("reverse", "forward"):
        v = mi.Float(verts.ravel())
        dr.enable_grad(v)
        params[KEY] = v
        params.update()
        img = mi.render(sc, params, integrator=integrator, seed=seed + 100, seed_grad=seed, spp=SPP)
        if mode == "forward":
            dr.set_grad(v, mi.Float((np.arange(verts.size) % 3 == 0).astype(np.float32)))
            dr.forward_to(img)
            return (*out, np.array(dr.grad(img)))
        weight = np.zeros((H, W, 3), dtype=np.float32)
        weight[:, W // 2:, 0] = 1
        dr.backward(dr.sum(img * mi.TensorXf(weight), axis=None))
        out = [np.array(img), np.array(dr.grad(v))]


@pytest.mark.parametrize("projective", [False, True], ids=["interior", "projective"])
def test_attached_vertices_moved_each_frame_as_a_fresh_load(variant, tmp_path, projective):
    """Reverse and forward mode as inverse rendering runs them (the vertices attached, moved each step,
    through the integrator the scene holds and through another one, as the crash was found):
    each step's frame and derivatives equal those of a fresh scene and integrator (the vertices
    attached likewise)."""
    import drjit as dr
    import mitsuba as mi
    if not variant.startswith(("llvm_ad", "cuda_ad")):
        pytest.skip("gradients need an AD variant")
    integ = dict(WHITTED, projective=projective)
    sc = _scene(mi, tmp_path / "cube.ply", _verts(0), integ)
    other = mi.load_dict(integ)
    for frame in (1, 2, 3):
        for which in (None, other):
            img, grad, dimg = _reverse(mi, dr, sc, _verts(frame), frame, which)
            fresh = _scene(mi, tmp_path / f"cube{frame}.ply", _verts(frame), integ)
            ref_img, ref_grad, ref_dimg = _reverse(mi, dr, fresh, _verts(frame), frame,
                                                   None if which is None else mi.load_dict(integ))
            assert np.array_equal(img, ref_img), frame
            assert np.array_equal(dimg, ref_dimg) and np.any(dimg != 0), frame
            # (vertex gradients are sums over the pixels that see a triangle, which the threads
            # of a reverse pass add in any order: equal to float32 rounding, not bit for bit)
            np.testing.assert_allclose(grad, ref_grad, rtol=1e-5, atol=1e-5 * np.abs(ref_grad).max())
            assert np.any(grad != 0)
            params = mi.traverse(sc)        # left detached, as an optimiser's step leaves them
            params[KEY] = mi.Float(_verts(frame).ravel())
            params.update()
    assert sc.integrator().info()["recordings"] >= 1 and other.info()["recordings"] >= 1


def test_the_watch_sees_an_attached_vertex_buffer_replaced(variant, tmp_path):
    """The parameter watch (made as ``prepare`` makes it, under ``suspend_grad``) holds the
    attached vertices it saw: after an optimiser-like step (detached, then attached anew) the
    new value cannot take their indices, and the change is seen."""
    import drjit as dr
    import mitsuba as mi
    from links1_mitsuba.paramwatch import ParamWatch
    if not variant.startswith(("llvm_ad", "cuda_ad")):
        pytest.skip("gradients need an AD variant")
    sc = _scene(mi, tmp_path / "cube.ply", _verts(0), WHITTED)
    params = mi.traverse(sc)
    for frame in (1, 2, 3, 4):
        v = mi.Float(_verts(frame).ravel())
        dr.enable_grad(v)
        params[KEY] = v
        params.update()
        del v
        with dr.suspend_grad():
            watch = ParamWatch(sc)
        assert watch.attached() and watch.unchanged(sc)
        params[KEY] = mi.Float(_verts(frame).ravel())
        params.update()
        assert not watch.unchanged(sc)
        v = mi.Float(_verts(frame).ravel())
        dr.enable_grad(v)
        params[KEY] = v
        params.update()
        del v
        assert not watch.unchanged(sc), frame
