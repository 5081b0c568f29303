"""Mesh sources: OBJ/PLY readers, Mitsuba's rectangle and cube, bicubic Bézier patches (eq. 3.3)."""
from __future__ import annotations

import os

import numpy as np
import pytest

from links1.geometry import bezier, mesh_files, meshes

DATA = os.path.join(os.path.dirname(__file__), "data")


def face_normals(v, f):
    p = v[f]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


# -- Mitsuba's built-in meshes --------------------------------------------------------------

def test_rectangle_is_mitsubas():
    v, f, n = meshes.rectangle_mesh()
    assert v.shape == (4, 3) and f.shape == (2, 3)
    np.testing.assert_array_equal(v.min(0), [-1, -1, 0])
    np.testing.assert_array_equal(v.max(0), [1, 1, 0])
    np.testing.assert_allclose(face_normals(v, f), [[0, 0, 1]] * 2)
    np.testing.assert_array_equal(n, [[0, 0, 1]] * 4)


def test_cube_is_mitsubas_flat_outward():
    v, f, n = meshes.cube_mesh()
    assert v.shape == (24, 3) and f.shape == (12, 3)
    # Mitsuba 3.9.1's cube (mi.traverse of <shape type="cube"/>): first face and its triangles
    np.testing.assert_array_equal(v[:4], [[1, -1, -1], [1, -1, 1], [-1, -1, 1], [-1, -1, -1]])
    np.testing.assert_array_equal(f[:2], [[0, 1, 2], [3, 0, 2]])
    fn = face_normals(v, f)
    centroid = v[f].mean(axis=1)
    assert np.all(np.einsum("ij,ij->i", fn, centroid) > 0)  # outward winding
    np.testing.assert_allclose(fn, n[f[:, 0]])  # flat: vertex normals equal the face normal
    for k in range(3):  # each face's vertices lie on one face of [-1, 1]^3
        assert np.all(np.abs(v[f]).max(axis=(1, 2)) == 1)


# -- OBJ --------------------------------------------------------------------------------------

def test_obj_quad_with_normals_is_fanned():
    v, f, n = mesh_files.read_obj(os.path.join(DATA, "quad_poly.obj"))
    np.testing.assert_array_equal(v, [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    np.testing.assert_array_equal(f, [[0, 1, 2], [0, 2, 3]])
    np.testing.assert_array_equal(n, [[0, 0, 1]] * 4)


def test_obj_negative_indices_polygon_no_normals():
    v, f, n = mesh_files.read_obj(os.path.join(DATA, "pentagon.obj"))
    assert n is None
    assert v.shape == (5, 3) and np.all(v[:, 2] == 2)
    np.testing.assert_array_equal(f, [[0, 1, 2], [0, 2, 3], [0, 3, 4]])


def test_obj_round_trip(tmp_path):
    v, f, n = meshes.cube_mesh()
    p = str(tmp_path / "cube.obj")
    mesh_files.write_obj(p, v, f, n)
    v2, f2, n2 = mesh_files.read_obj(p)
    np.testing.assert_array_equal(v2[f2], v[f])
    np.testing.assert_array_equal(n2[f2], n[f])


@pytest.mark.parametrize("text,where", [("v 0 0 0\nv 1 0 0\nf 1 2 7\n", ":3:"),
                                        ("v 0 0 x\n", ":1:"),
                                        ("v 0 0 0\n", "no faces")])
def test_obj_errors_name_file_and_line(tmp_path, text, where):
    p = tmp_path / "bad.obj"
    p.write_text(text)
    with pytest.raises(ValueError) as e:
        mesh_files.read_obj(str(p))
    assert "bad.obj" in str(e.value) and where in str(e.value)


# -- PLY --------------------------------------------------------------------------------------

def test_ply_ascii_and_binary_agree():
    a = mesh_files.read_ply(os.path.join(DATA, "quad_ascii.ply"))
    b = mesh_files.read_ply(os.path.join(DATA, "quad_binary.ply"))
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(a[1], [[0, 1, 2], [0, 2, 3]])
    np.testing.assert_array_equal(a[2], [[0, 0, 1]] * 4)


@pytest.mark.parametrize("binary", [True, False])
def test_ply_round_trip(tmp_path, binary):
    v, f, n = meshes.cube_mesh()
    p = str(tmp_path / "cube.ply")
    mesh_files.write_ply(p, v, f, n, binary=binary)
    v2, f2, n2 = mesh_files.read_ply(p)
    np.testing.assert_array_equal(v2, v)
    np.testing.assert_array_equal(f2, f)
    np.testing.assert_array_equal(n2, n)


def test_ply_big_endian_mixed_polygons_and_extra_element(tmp_path):
    head = ("ply\nformat binary_big_endian 1.0\nelement vertex 5\nproperty double x\n"
            "property double y\nproperty double z\nelement face 2\n"
            "property list uchar uint vertex_indices\nproperty uchar flags\n"
            "element extra 1\nproperty list uchar float stuff\nend_header\n")
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0]], dtype=">f8")
    body = v.tobytes()
    body += bytes([4]) + np.array([0, 1, 2, 3], ">u4").tobytes() + bytes([7])
    body += bytes([3]) + np.array([1, 4, 2], ">u4").tobytes() + bytes([0])
    body += bytes([2]) + np.array([1.5, 2.5], ">f4").tobytes()
    p = tmp_path / "be.ply"
    p.write_bytes(head.encode() + body)
    v2, f2, n2 = mesh_files.read_ply(str(p))
    np.testing.assert_array_equal(v2, v.astype(np.float64))
    np.testing.assert_array_equal(f2, [[0, 1, 2], [0, 2, 3], [1, 4, 2]])
    assert n2 is None


def test_ply_truncated(tmp_path):
    data = open(os.path.join(DATA, "quad_binary.ply"), "rb").read()
    p = tmp_path / "trunc.ply"
    p.write_bytes(data[:-5])
    with pytest.raises(ValueError, match="trunc.ply.*truncated"):
        mesh_files.read_ply(str(p))


@pytest.mark.parametrize("kind", ["ply", "ply-ascii", "obj", "serialized-3", "serialized-4"])
def test_stores_normals_says_what_the_file_holds(tmp_path, kind):
    """``stores_normals`` (which mesh files Mitsuba computes normals for) against files written
    with and without normals, and the readers' own answer (normals or None)."""
    from tests.core.test_serialized import QUAD, TET, write_serialized
    v, f, n = meshes.cube_mesh()
    answers = []
    for with_normals in (True, False):
        p = str(tmp_path / f"{with_normals}.{kind[:3]}")
        if kind.startswith("ply"):
            mesh_files.write_ply(p, v, f, n if with_normals else None, binary=kind == "ply")
            read = mesh_files.read_ply(p)[2]
        elif kind == "obj":
            mesh_files.write_obj(p, v, f, n if with_normals else None)
            read = mesh_files.read_obj(p)[2]
        else:   # the file's first mesh has normals, its second none
            write_serialized(p, [TET, QUAD], int(kind[-1]))
            read = mesh_files.read_serialized(p, 0 if with_normals else 1)[2]
        index = 1 if kind.startswith("serialized") and not with_normals else 0
        answers.append((mesh_files.stores_normals(p, kind.split("-")[0], index), read is not None))
    assert answers == [(True, True), (False, False)]


def test_stores_normals_names_a_bad_file(tmp_path):
    p = tmp_path / "bad.ply"
    p.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n")
    with pytest.raises(ValueError, match="bad.ply.*end_header"):
        mesh_files.stores_normals(str(p), "ply")
    with pytest.raises(ValueError, match="missing.obj: cannot read"):
        mesh_files.stores_normals(str(tmp_path / "missing.obj"), "obj")


#: an OBJ has normals where a line is ``vn`` after blanks and before a blank (Mitsuba 3.9.1's reader)
_VN_LINE = rb"(?m)^[ \t]*vn[ \t]"


@pytest.mark.parametrize("text", [
    b"", b"vn 0 0 1", b"v 0 0 0\nvn 0 0 1\n", b"v 0 0 0\r\n \t vn\t0 0 1\r\n", b"# normals: vn 0 0 1\nv 0 0 0\n",
    b"usemtl vn \nv nan inf 0\nf 1 1 1\n", b"vnx 0 0 1\nvn\n", b"o v vn\nv 0 0 0\n  vn 1 0 0", b"xvn 0 0 1\n",
    b"v 0 0 0\n" * 3 + b"vn", b"v 1 2 3\nvt 0 0\nf 1/1 1/1 1/1\n"])
def test_stores_normals_of_an_obj_is_its_first_vn_line(tmp_path, text):
    """The OBJ scan (a file mapped, its "n" bytes found and their lines checked) against the
    line rule as a regular expression over the whole file."""
    import re
    p = tmp_path / "m.obj"
    p.write_bytes(text)
    assert mesh_files.stores_normals(str(p), "obj") == (re.search(_VN_LINE, text) is not None)


def test_stores_normals_reads_a_ply_header_and_a_serialized_mesh_flags_alone(tmp_path):
    """The answer needs a PLY's header and a serialized mesh's flags word only: files whose data
    after that is cut off (the readers: truncated) still answer."""
    from tests.core.test_serialized import QUAD, TET, write_serialized
    v, f, n = meshes.cube_mesh()
    ply = tmp_path / "cut.ply"
    mesh_files.write_ply(str(ply), v, f, n)
    data = ply.read_bytes()
    ply.write_bytes(data[:data.index(b"end_header\n") + 11 + 5])
    with pytest.raises(ValueError, match="truncated"):
        mesh_files.read_ply(str(ply))
    assert mesh_files.stores_normals(str(ply), "ply")
    for k, shape in enumerate((TET, QUAD)):
        whole = tmp_path / f"{k}.serialized"
        write_serialized(str(whole), [shape])
        cut = tmp_path / f"cut{k}.serialized"
        cut.write_bytes(whole.read_bytes()[:4 + 16])     # the format header and the stream's first bytes
        with pytest.raises(ValueError, match="truncated"):
            mesh_files.read_serialized(str(cut))
        assert mesh_files.stores_normals(str(cut), "serialized") == (mesh_files.read_serialized(str(whole))[2]
                                                                     is not None) == (k == 0)


# -- normals, transforms ---------------------------------------------------------------------

def test_angle_weighted_normals_of_shared_cube_corners():
    v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    cv, cf, _ = meshes.cube_mesh()
    idx = [int(np.nonzero(np.all(v == p, axis=1))[0][0]) for p in cv]
    f = np.array(idx)[cf]
    n = meshes.angle_weighted_normals(v, f)
    np.testing.assert_allclose(n, v / np.sqrt(3.0), atol=1e-12)


def test_transform_mesh_uses_inverse_transpose():
    m = np.diag([2.0, 1.0, 1.0, 1.0])
    m[:3, 1] += [1.0, 0, 0]  # shear x += y
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    n = np.array([[0.0, 1.0, 0.0]] * 3)  # normal of the plane z... use plane y=0's normal
    v2, n2 = meshes.transform_mesh(m, v, n)
    # the plane y = 0 maps to itself: its normal must stay +y
    np.testing.assert_allclose(n2, [[0, 1, 0]] * 3, atol=1e-15)
    np.testing.assert_allclose(v2[2], [1, 1, 0])


def test_flip_reverses_winding_and_normals():
    v, f, n = meshes.rectangle_mesh()
    f2, n2 = meshes.flip(f, n)
    np.testing.assert_allclose(face_normals(v, f2), [[0, 0, -1]] * 2)
    np.testing.assert_array_equal(n2, -n)


# -- bicubic Bézier patches (eq. 3.3) ---------------------------------------------------------

def test_flat_patch_reproduces_plane_and_normals():
    patches = bezier.read_patches(os.path.join(DATA, "flat.patch"))
    assert patches.shape == (1, 4, 4, 3)
    v, f, n = bezier.tessellate_patches(patches, subdivisions=4)
    assert v.shape == (25, 3) and f.shape == (32, 3)
    t = np.linspace(0, 1, 5)
    uu, vv = np.meshgrid(t, t, indexing="ij")
    np.testing.assert_allclose(v, np.stack([2 * uu.ravel(), 2 * vv.ravel(), 0 * uu.ravel()], 1),
                               atol=1e-15)
    np.testing.assert_allclose(n, [[0, 0, 1]] * 25, atol=1e-15)
    np.testing.assert_allclose(face_normals(v, f), [[0, 0, 1]] * 32, atol=1e-15)


def test_patch_on_hyperbolic_paraboloid():
    # z = x y over [0,1]^2 is bilinear, so its cubic Bezier control points are
    # P[i][j] = (i/3, j/3, (i/3)(j/3)) (degree elevation)
    ctrl = np.array([[[i / 3, j / 3, (i / 3) * (j / 3)] for j in range(4)] for i in range(4)])
    v, f, n = bezier.tessellate_patches(ctrl[None], subdivisions=6)
    np.testing.assert_allclose(v[:, 2], v[:, 0] * v[:, 1], atol=1e-15)
    expect = np.stack([-v[:, 1], -v[:, 0], np.ones(len(v))], 1)
    expect /= np.linalg.norm(expect, axis=1, keepdims=True)
    np.testing.assert_allclose(n, expect, atol=1e-14)
    # triangles are wound like S_u x S_v: their normals agree with the vertex normals
    assert np.all(np.einsum("ij,ij->i", face_normals(v, f), n[f].mean(axis=1)) > 0.99)


def test_bezier_eval_derivatives_match_finite_differences():
    rng = np.random.default_rng(3)
    ctrl = rng.normal(size=(4, 4, 3))
    u, v, h = np.array([0.3]), np.array([0.7]), 1e-6
    p, pu, pv = bezier.bezier_eval(ctrl, u, v)
    np.testing.assert_allclose(pu, (bezier.bezier_eval(ctrl, u + h, v)[0]
                                    - bezier.bezier_eval(ctrl, u - h, v)[0]) / (2 * h), atol=1e-7)
    np.testing.assert_allclose(pv, (bezier.bezier_eval(ctrl, u, v + h)[0]
                                    - bezier.bezier_eval(ctrl, u, v - h)[0]) / (2 * h), atol=1e-7)


def test_collapsed_patch_edge_gets_a_finite_normal():
    # a patch whose whole u = 0 edge collapses to one point (like a teapot lid's top)
    # and whose u-tangent is horizontal there (z control values 1, 1, 0.5, 0)
    z = [1.0, 1.0, 0.5, 0.0]
    ctrl = np.array([[[i / 3 * np.cos(j * np.pi / 6), i / 3 * np.sin(j * np.pi / 6), z[i]]
                      for j in range(4)] for i in range(4)])
    v, f, n = bezier.tessellate_patches(ctrl[None], subdivisions=4)
    assert np.all(np.isfinite(n))
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)
    assert np.all(n[:5, 2] > 0.99)  # at the apex the dome's normal is +z


def test_inline_control_points_and_errors():
    text = " ".join(["0 0 0"] * 16)
    assert bezier.parse_patches(text, with_count=False).shape == (1, 4, 4, 3)
    with pytest.raises(ValueError, match="48 numbers"):
        bezier.parse_patches("1 2 3", "inline", with_count=False)
    with pytest.raises(ValueError, match="2 patch"):
        bezier.parse_patches("2 " + text, "file.patch")
    with pytest.raises(ValueError, match="file.patch:1"):
        bezier.parse_patches("1 x", "file.patch")
    with pytest.raises(ValueError, match="subdivisions"):
        bezier.tessellate_patches(np.zeros((1, 4, 4, 3)), 0)
