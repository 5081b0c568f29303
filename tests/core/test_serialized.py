"""Mitsuba ``serialized`` meshes in the core: the reader (links1.geometry.mesh_files.read_serialized)
on files written by :func:`write_serialized` below (the format as Mitsuba's
``src/shapes/serialized.cpp`` documents and reads it), and the loader's ``serialized`` shape.
What Mitsuba itself loads from the same files: tests/plugins/test_serialized_vs_mitsuba.py."""
from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest

from links1 import load_scene
from links1.errors import SceneError
from links1.geometry import mesh_files


def write_serialized(path, shapes, version=4) -> None:
    """Write ``shapes`` (dicts: ``v`` (V, 3), ``f`` (F, 3), optional ``n``, ``uv``, ``colors``,
    ``name``, ``double``) as one ``.serialized`` file: per mesh a header and a zlib stream, then
    the end-of-file table of offsets (uint64; uint32 in version 3) and the count."""
    out, offsets = b"", []
    for s in shapes:
        dt = "<f8" if s.get("double") else "<f4"
        flags = 0x2000 if s.get("double") else 0x1000
        body = b""
        for key, bit in (("n", 0x1), ("uv", 0x2), ("colors", 0x8)):
            if s.get(key) is not None:
                flags |= bit
                body += np.asarray(s[key], dtype=dt).tobytes()
        flags |= s.get("extra_flags", 0)
        head = struct.pack("<I", flags)
        if version == 4:
            head += s.get("name", "mesh").encode() + b"\0"
        v, f = np.asarray(s["v"]), np.asarray(s["f"])
        head += struct.pack("<QQ", len(v), len(f)) + np.asarray(v, dtype=dt).tobytes()
        offsets.append(len(out))
        out += struct.pack("<HH", 0x041C, version) + zlib.compress(
            head + body + np.asarray(f, dtype="<u4").tobytes())
    out += b"".join(struct.pack("<Q" if version == 4 else "<I", o) for o in offsets)
    out += struct.pack("<I", len(shapes))
    with open(path, "wb") as fh:
        fh.write(out)


#: a tetrahedron-like open mesh with normals, texcoords and colours; a single quad
TET = dict(v=[[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.3, 1.0]], f=[[0, 2, 1], [0, 1, 3], [1, 2, 3]],
           n=[[0, 0, -1], [0.6, 0, 0.8], [0, 0.6, 0.8], [0, 0, 1]],
           uv=[[0, 0], [1, 0], [0, 1], [0.25, 0.75]], colors=[[1, 0, 0]] * 4, name="tet")
QUAD = dict(v=[[-1, -1, 2], [1, -1, 2], [1, 1, 2], [-1, 1, 2]], f=[[0, 1, 2], [2, 3, 0]], name="quad")


@pytest.mark.parametrize("version", [3, 4])
@pytest.mark.parametrize("double", [False, True])
def test_every_mesh_of_a_file_reads_back(tmp_path, version, double):
    p = str(tmp_path / "m.serialized")
    write_serialized(p, [dict(TET, double=double), dict(QUAD, double=double)], version)
    v, f, n, uv = mesh_files.read_serialized(p, 0)
    np.testing.assert_array_equal(v, np.asarray(TET["v"], dtype="f8" if double else "f4"))
    np.testing.assert_array_equal(f, TET["f"])
    np.testing.assert_allclose(n, TET["n"], rtol=1e-7)  # unit already, up to float32
    np.testing.assert_array_equal(uv, TET["uv"])
    v, f, n, uv = mesh_files.read_serialized(p, 1)
    np.testing.assert_array_equal(v, QUAD["v"])
    np.testing.assert_array_equal(f, QUAD["f"])
    assert n is None and uv is None


@pytest.mark.parametrize("damage,message", [
    (lambda b: b"\x1d\x04" + b[2:], "not a Mitsuba serialized mesh (header 0x041D"),
    (lambda b: b[:2] + b"\x05\x00" + b[4:], "version 5 is not supported"),
    (lambda b: b[:30], "truncated compressed data"),
    (lambda b: b[:4] + b"garbage" + b[11:], "corrupt compressed data"),
])
def test_bad_files_are_named(tmp_path, damage, message):
    p = tmp_path / "bad.serialized"
    write_serialized(str(p), [TET])
    p.write_bytes(damage(p.read_bytes()))
    with pytest.raises(ValueError, match="bad.serialized") as e:
        mesh_files.read_serialized(str(p))
    assert message in str(e.value)


def test_out_of_range_index_and_face(tmp_path):
    p = str(tmp_path / "m.serialized")
    write_serialized(p, [TET, QUAD])
    with pytest.raises(ValueError, match=r"shape_index 2 is out of range \(the file holds 2 meshes: 0..1\)"):
        mesh_files.read_serialized(p, 2)
    write_serialized(p, [dict(QUAD, f=[[0, 1, 4]])])
    with pytest.raises(ValueError, match=r"indexes vertex 4, out of range \(0..3\)"):
        mesh_files.read_serialized(p, 0)


SCENE = """<scene version="3.0.0">
  <shape type="serialized"><string name="filename" value="m.serialized"/>{extra}</shape>
</scene>"""


def _load(tmp_path, extra=""):
    (tmp_path / "s.xml").write_text(SCENE.format(extra=extra))
    with pytest.warns(Warning):   # no sensor
        return load_scene(str(tmp_path / "s.xml"))


def test_loader_places_the_chosen_mesh(tmp_path):
    write_serialized(str(tmp_path / "m.serialized"), [TET, QUAD])
    s = _load(tmp_path, '<integer name="shape_index" value="1"/>'
                        '<transform name="to_world"><translate value="0, 0, 3"/></transform>')
    (mesh,) = s.shapes
    np.testing.assert_array_equal(mesh.vertices, np.asarray(QUAD["v"]) + [0, 0, 3])
    # no normals in the file: Mitsuba's angle-weighted vertex normals (flat quad: its normal)
    np.testing.assert_allclose(mesh.normals, [[0, 0, 1]] * 4)


def test_loader_error_names_the_element(tmp_path):
    write_serialized(str(tmp_path / "m.serialized"), [TET])
    (tmp_path / "s.xml").write_text(SCENE.format(extra='<integer name="shape_index" value="3"/>'))
    with pytest.raises(SceneError, match=r"s\.xml:2.*shape_index 3 is out of range"):
        load_scene(str(tmp_path / "s.xml"))


def test_a_file_without_a_table_is_refused_for_a_later_mesh(tmp_path):
    p = tmp_path / "m.serialized"
    write_serialized(str(p), [QUAD])
    p.write_bytes(p.read_bytes()[:-12] + struct.pack("<I", 1000))   # table gone, count 1000
    with pytest.raises(ValueError, match="end-of-file table of 1000 meshes does not fit"):
        mesh_files.read_serialized(str(p), 5)
