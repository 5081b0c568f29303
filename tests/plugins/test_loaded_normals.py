"""A mesh file without normals gives the same normals, and the same image, on every load.

Mitsuba computes such normals with float32 atomic scatter-adds over Dr.Jit's threads, so their
last bits change from load to load (a 50k-face mesh: 3 different results in 10 loads of
``mi.load_dict``); ``links1_mitsuba.load_file`` computes them again on one thread
(``loader._settle_normals``). The references: the normals of the same mesh in float64
(``links1.geometry.meshes.angle_weighted_normals``, Mitsuba's weighting), and Mitsuba's own
reading of a file that stores normals, which the loader must leave as it is. LLVM only (the
``llvm`` fixture): the order in question is that of Dr.Jit's LLVM thread pool, and one thread
is how the loader fixes it; a CUDA variant's atomics keep Mitsuba's order."""
from __future__ import annotations

import numpy as np
import pytest

from links1.geometry import mesh_files, meshes
from tests.scenes import perspective, scene, whitted

pytestmark = pytest.mark.mitsuba

LOADS = 6


def _bumpy(n=160):
    """A bumpy sphere open at its poles, ``n`` rings of ``n`` vertices (2 n (n - 1) faces, outward)."""
    t, p = np.meshgrid(np.linspace(0.05, np.pi - 0.05, n), np.linspace(0, 2 * np.pi, n, endpoint=False),
                       indexing="ij")
    r = 1 + 0.08 * np.sin(5 * t) * np.cos(7 * p)
    v = np.stack([r * np.sin(t) * np.cos(p), r * np.cos(t), r * np.sin(t) * np.sin(p)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n), indexing="ij")
    a, b = i * n + j, i * n + (j + 1) % n
    f = np.concatenate([np.stack([a, b, a + n], -1).reshape(-1, 3), np.stack([b, b + n, a + n], -1).reshape(-1, 3)])
    return v.astype(np.float32), f


def _xml(path):
    lamp = '<emitter type="point"><point name="position" x="2" y="3" z="4"/><rgb name="intensity" value="30"/></emitter>'
    return scene(perspective("0, 0.5, 4", "0, 0, 0", fov=35, width=24, spp=1), whitted(1),
                 f'<shape type="ply" id="bumpy"><string name="filename" value="{path}"/></shape>', lamp)


def _normals(mi, sc):
    (mesh,) = [s for s in sc.shapes() if s.id() == "bumpy"]
    return np.array(mi.traverse(mesh)["vertex_normals"], dtype=np.float32).reshape(-1, 3)


@pytest.mark.slow
def test_computed_normals_and_image_same_bits_every_load(tmp_path, llvm):
    """Six loads of a mesh file without normals: the same normals bit for bit, within 2e-5 of
    the float64 angle-weighted normals, and the same image. LLVM only: the load-to-load order is
    that of Dr.Jit's LLVM thread pool."""
    import mitsuba as mi
    import links1_mitsuba
    v, f = _bumpy()
    mesh_files.write_ply(str(tmp_path / "bumpy.ply"), v, f)
    (tmp_path / "s.xml").write_text(_xml(tmp_path / "bumpy.ply"))
    scenes = [links1_mitsuba.load_file(str(tmp_path / "s.xml")) for _ in range(LOADS)]
    normals = [_normals(mi, sc) for sc in scenes]
    for n in normals[1:]:
        np.testing.assert_array_equal(n, normals[0])
    ref = meshes.angle_weighted_normals(v.astype(np.float64), f)
    np.testing.assert_allclose(normals[0], ref, rtol=0, atol=2e-5)
    images = [np.array(mi.render(sc, spp=1, seed=3)) for sc in (scenes[0], scenes[-1])]
    assert np.any(images[0] > 0)
    np.testing.assert_array_equal(images[0], images[1])


def test_normals_a_file_stores_are_mitsubas(tmp_path, llvm):
    """A file that stores normals keeps Mitsuba's own reading of them. LLVM only: the loader's
    one-thread recompute, which must leave these alone, runs on LLVM variants alone."""
    import mitsuba as mi
    import links1_mitsuba
    v, f = _bumpy(24)
    n = meshes.angle_weighted_normals(v.astype(np.float64), f) * [1.0, -1.0, 1.0]   # not Mitsuba's own
    mesh_files.write_ply(str(tmp_path / "bumpy.ply"), v, f, n)
    (tmp_path / "s.xml").write_text(_xml(tmp_path / "bumpy.ply"))
    plain = mi.load_dict({"type": "ply", "filename": str(tmp_path / "bumpy.ply")})
    np.testing.assert_array_equal(_normals(mi, links1_mitsuba.load_file(str(tmp_path / "s.xml"))),
                                  np.array(mi.traverse(plain)["vertex_normals"]).reshape(-1, 3))
