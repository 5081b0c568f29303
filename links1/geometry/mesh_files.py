"""Triangle-mesh files: OBJ, PLY and Mitsuba ``serialized``, read (and OBJ / PLY written) as
the arrays of :mod:`links1.geometry.meshes` (its module doc); a bad file is a ``ValueError``
naming the file and line.

Mitsuba semantics kept here
---------------------------
* OBJ (``v``, ``vt``, ``vn``, ``f`` with ``v``, ``v/vt``, ``v//vn``, ``v/vt/vn`` and negative
  indices; other statements ignored): polygons are triangulated as fans ``(0, k, k+1)``; a
  vertex is one ``(position, texcoord, normal)`` triple; unreferenced positions are dropped.
* PLY: ``ascii``, ``binary_little_endian`` and ``binary_big_endian``; vertex ``x y z``,
  optional ``nx ny nz`` and texcoords ``u v`` (or ``texture_u texture_v``, or ``s t``); faces
  from the list ``vertex_indices`` (or ``vertex_index``), fans again.
* Mitsuba ``serialized`` (:func:`read_serialized`): header ``0x041C``, version 3 or 4, then a
  zlib stream: ``uint32`` flags (``0x1`` normals, ``0x2`` texcoords, ``0x8`` vertex colours,
  skipped; ``0x2000`` double precision, else single), the shape's name (version 4, NUL-terminated),
  ``uint64`` vertex and face counts, positions, [normals], [texcoords], [colours], ``uint32``
  faces. Several meshes are concatenated, each with its own header; ``shape_index`` k > 0 is found
  through the table at the end of the file (k-th ``uint64`` offset, ``uint32`` in version 3, then
  the ``uint32`` count). The ``0x10`` face-normals flag is not read (as Mitsuba 3.9.1).
* Texcoords (``uv=True``) come back as stored; Mitsuba's ``flip_tex_coords`` (``v -> 1 - v``,
  default on for OBJ, off for PLY) is the loader's business.
"""
from __future__ import annotations

import mmap
import os
import struct
import zlib

import numpy as np

from ..maths import transform as tf


def _fan(poly: list) -> list:
    return [(poly[0], poly[k], poly[k + 1]) for k in range(1, len(poly) - 1)]


# --------------------------------------------------------------------------------------------
# OBJ
# --------------------------------------------------------------------------------------------

def read_obj(path: str, uv: bool = False):
    """Read a Wavefront OBJ file → ``(vertices, faces, normals or None)`` (see module doc),
    and ``texcoords (V, 2) or None`` fourth with ``uv=True`` (0 where a corner has no ``vt``)."""
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            lines = fh.read().splitlines()
    except OSError as exc:
        raise ValueError(f"{path}: cannot read: {exc.strerror}") from None
    pos: list = []
    nrm: list = []
    tex: list = []
    key_index: dict = {}
    keys: list = []
    faces: list = []
    any_normal = False
    all_normal = True

    def num(tok, ln):
        try:
            x = float(tok)
        except ValueError:
            raise ValueError(f"{path}:{ln}: cannot parse '{tok}' as a number") from None
        if not np.isfinite(x):
            raise ValueError(f"{path}:{ln}: non-finite number '{tok}'")
        return x

    def index(tok, count, ln, what):
        try:
            i = int(tok)
        except ValueError:
            raise ValueError(f"{path}:{ln}: bad {what} index '{tok}'") from None
        j = i - 1 if i > 0 else count + i
        if i == 0 or not 0 <= j < count:
            raise ValueError(f"{path}:{ln}: {what} index {i} out of range (1..{count})")
        return j

    for ln, line in enumerate(lines, 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        toks = line.split()
        kw = toks[0]
        if kw == "v":
            if len(toks) < 4:
                raise ValueError(f"{path}:{ln}: 'v' needs 3 coordinates")
            pos.append([num(t, ln) for t in toks[1:4]])
        elif kw == "vn":
            if len(toks) < 4:
                raise ValueError(f"{path}:{ln}: 'vn' needs 3 coordinates")
            nrm.append([num(t, ln) for t in toks[1:4]])
        elif kw == "vt":
            if len(toks) < 3:
                raise ValueError(f"{path}:{ln}: 'vt' needs 2 coordinates")
            tex.append([num(t, ln) for t in toks[1:3]])
        elif kw == "f":
            if len(toks) < 4:
                raise ValueError(f"{path}:{ln}: a face needs at least 3 vertices")
            poly = []
            for t in toks[1:]:
                parts = t.split("/")
                vi = index(parts[0], len(pos), ln, "vertex")
                ti = ni = -1
                if len(parts) >= 2 and parts[1]:
                    ti = index(parts[1], len(tex), ln, "texcoord")
                if len(parts) >= 3 and parts[2]:
                    ni = index(parts[2], len(nrm), ln, "normal")
                    any_normal = True
                else:
                    all_normal = False
                key = (vi, ti, ni)
                k = key_index.get(key)
                if k is None:
                    k = key_index[key] = len(keys)
                    keys.append(key)
                poly.append(k)
            faces.extend(_fan(poly))
    if not faces:
        raise ValueError(f"{path}: no faces")
    keys_a = np.array(keys, dtype=np.int64)
    vertices = np.array(pos, dtype=np.float64)[keys_a[:, 0]]
    faces_a = np.array(faces, dtype=np.int64)
    normals = None
    if any_normal and all_normal:
        normals = tf.normalize(np.array(nrm, dtype=np.float64)[keys_a[:, 2]])
    if not uv:
        return vertices, faces_a, normals
    texcoords = None
    if np.any(keys_a[:, 1] >= 0):
        t = np.vstack([np.array(tex, dtype=np.float64).reshape(-1, 2), np.zeros((1, 2))])
        texcoords = t[keys_a[:, 1]]  # index -1: the zero row
    return vertices, faces_a, normals, texcoords


def write_obj(path: str, vertices, faces, normals=None) -> None:
    """Write a triangle mesh as OBJ (used by tests and tools)."""
    with open(path, "w") as fh:
        for p in vertices:
            fh.write("v %.17g %.17g %.17g\n" % tuple(p))
        if normals is not None:
            for n in normals:
                fh.write("vn %.17g %.17g %.17g\n" % tuple(n))
        for f in np.asarray(faces) + 1:
            if normals is None:
                fh.write("f %d %d %d\n" % tuple(f))
            else:
                fh.write("f %d//%d %d//%d %d//%d\n" % (f[0], f[0], f[1], f[1], f[2], f[2]))


# --------------------------------------------------------------------------------------------
# PLY
# --------------------------------------------------------------------------------------------

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


def _ply_header(data: bytes, path: str):
    if not data.startswith(b"ply"):
        raise ValueError(f"{path}:1: not a PLY file (missing 'ply' magic)")
    end = data.find(b"end_header")
    if end < 0:
        raise ValueError(f"{path}: truncated PLY header (no 'end_header')")
    nl = data.find(b"\n", end)
    body_start = len(data) if nl < 0 else nl + 1
    header = data[:end].decode("ascii", errors="replace").splitlines()
    fmt = None
    elements: list = []  # [name, count, [(prop, dtype) | (prop, ('list', count_dt, item_dt))], line]
    for ln, line in enumerate(header, 1):
        toks = line.split()
        if not toks or toks[0] in ("ply", "comment", "obj_info"):
            continue
        if toks[0] == "format":
            if len(toks) < 2 or toks[1] not in ("ascii", "binary_little_endian", "binary_big_endian"):
                raise ValueError(f"{path}:{ln}: unsupported PLY format '{' '.join(toks[1:])}'")
            fmt = toks[1]
        elif toks[0] == "element":
            try:
                elements.append([toks[1], int(toks[2]), [], ln])
            except (IndexError, ValueError):
                raise ValueError(f"{path}:{ln}: bad element line '{line}'") from None
        elif toks[0] == "property":
            if not elements:
                raise ValueError(f"{path}:{ln}: property before any element")
            try:
                if toks[1] == "list":
                    prop = (toks[4], ("list", _PLY_TYPES[toks[2]], _PLY_TYPES[toks[3]]))
                else:
                    prop = (toks[2], _PLY_TYPES[toks[1]])
            except (IndexError, KeyError):
                raise ValueError(f"{path}:{ln}: bad property line '{line}'") from None
            elements[-1][2].append(prop)
        else:
            raise ValueError(f"{path}:{ln}: unknown PLY header line '{line}'")
    if fmt is None:
        raise ValueError(f"{path}: PLY header has no 'format' line")
    return fmt, elements, body_start


def ply_file(path: str):
    """The bytes of the PLY file ``path`` and its header: ``(data, format, elements, offset of
    the body)`` (:func:`read_ply`, Mitsuba's ellipsoids); ValueError naming the file when it
    cannot be read or its header is bad."""
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        raise ValueError(f"{path}: cannot read: {exc.strerror}") from None
    return (data,) + _ply_header(data, path)


def _read_binary_element(buf: bytes, off: int, count: int, props, endian: str, path: str, name: str):
    """Read ``count`` records → (dict prop -> array or list of arrays, new offset)."""
    has_list = any(isinstance(t, tuple) for _, t in props)
    if not has_list:
        dt = np.dtype([(p, endian + t) for p, t in props])
        n = dt.itemsize * count
        if off + n > len(buf):
            raise ValueError(f"{path}: truncated PLY data in element '{name}'")
        rec = np.frombuffer(buf, dtype=dt, count=count, offset=off)
        return {p: rec[p] for p, _ in props}, off + n
    # fast path: every list has the same length as in the first record
    if count > 0:
        fields, probe, ok, lens = [], off, True, {}
        for p, t in props:
            if isinstance(t, tuple):
                cdt = np.dtype(endian + t[1])
                if probe + cdt.itemsize > len(buf):
                    ok = False
                    break
                k = lens[p] = int(np.frombuffer(buf, cdt, 1, probe)[0])
                if k < 1:
                    ok = False
                    break
                fields += [(p + "#n", endian + t[1]), (p, endian + t[2], (k,))]
                probe += cdt.itemsize + k * np.dtype(t[2]).itemsize
            else:
                fields.append((p, endian + t))
                probe += np.dtype(t).itemsize
        if ok:
            dt = np.dtype(fields)
            if off + dt.itemsize * count <= len(buf):
                rec = np.frombuffer(buf, dtype=dt, count=count, offset=off)
                if all(np.all(rec[p + "#n"] == k) for p, k in lens.items()):
                    out = {p: np.array(rec[p]) for p, _ in props}
                    return out, off + dt.itemsize * count
    out: dict = {p: [] for p, _ in props}
    for _ in range(count):
        for p, t in props:
            if isinstance(t, tuple):
                cdt, idt = np.dtype(endian + t[1]), np.dtype(endian + t[2])
                if off + cdt.itemsize > len(buf):
                    raise ValueError(f"{path}: truncated PLY data in element '{name}'")
                k = int(np.frombuffer(buf, cdt, 1, off)[0])
                off += cdt.itemsize
                if off + k * idt.itemsize > len(buf):
                    raise ValueError(f"{path}: truncated PLY data in element '{name}'")
                out[p].append(np.frombuffer(buf, idt, k, off))
                off += k * idt.itemsize
            else:
                dt = np.dtype(endian + t)
                if off + dt.itemsize > len(buf):
                    raise ValueError(f"{path}: truncated PLY data in element '{name}'")
                out[p].append(np.frombuffer(buf, dt, 1, off)[0])
                off += dt.itemsize
    return out, off


#: PLY vertex properties read as geometry (the others become mesh attributes).
_PLY_GEOMETRY = {"x", "y", "z", "nx", "ny", "nz", "u", "v", "texture_u", "texture_v", "s", "t"}


def _ply_attributes(element: dict, prefix: str, skip) -> dict:
    """Mitsuba's mesh attributes of a PLY element: properties ``name_0, name_1, ...`` become
    ``prefix + name`` with one column each (a lone property ``name``: one column)."""
    groups: dict = {}
    for prop, values in element.items():
        if prop in skip or not isinstance(values, np.ndarray):
            continue
        base, _, idx = prop.rpartition("_")
        key = base if (base and idx.isdigit()) else prop
        groups.setdefault(key, []).append((int(idx) if (base and idx.isdigit()) else 0, values))
    return {prefix + k: np.stack([np.asarray(v, dtype=np.float64) for _, v in sorted(cols, key=lambda c: c[0])],
                                 axis=1) for k, cols in groups.items()}


def read_ply(path: str, uv: bool = False, attributes: bool = False):
    """Read a PLY mesh → ``(vertices, faces, normals or None)`` (see module doc), and
    ``texcoords (V, 2) or None`` with ``uv=True``, then with ``attributes=True`` Mitsuba's mesh
    attributes ``{"vertex_<name>": (V, k), "face_<name>": (F, k)}`` (face rows per triangle
    after polygons are fanned)."""
    data, fmt, elements, off = ply_file(path)
    values: dict = {}
    if fmt == "ascii":
        toks = data[off:].split()
        pos = 0
        for name, count, props, ln in elements:
            has_list = any(isinstance(t, tuple) for _, t in props)
            try:
                if not has_list:
                    k = len(props)
                    if pos + k * count > len(toks):
                        raise ValueError(f"{path}: truncated PLY data in element '{name}'")
                    arr = np.array(toks[pos:pos + k * count], dtype=np.float64).reshape(count, k)
                    pos += k * count
                    values[name] = {p: arr[:, i] for i, (p, _) in enumerate(props)}
                else:
                    out: dict = {p: [] for p, _ in props}
                    for _ in range(count):
                        for p, t in props:
                            if isinstance(t, tuple):
                                k = int(toks[pos])
                                out[p].append(np.array(toks[pos + 1:pos + 1 + k], dtype=np.float64))
                                if len(out[p][-1]) != k:
                                    raise IndexError
                                pos += 1 + k
                            else:
                                out[p].append(float(toks[pos]))
                                pos += 1
                    values[name] = out
            except (IndexError, ValueError) as exc:
                if isinstance(exc, ValueError) and str(exc).startswith(path):
                    raise
                raise ValueError(f"{path}: truncated or malformed PLY data in element '{name}' "
                                 f"(declared at header line {ln})") from None
    else:
        endian = "<" if fmt == "binary_little_endian" else ">"
        for name, count, props, ln in elements:
            values[name], off = _read_binary_element(data, off, count, props, endian, path, name)
    vert = values.get("vertex")
    if vert is None or not all(k in vert for k in "xyz"):
        raise ValueError(f"{path}: PLY file has no vertex element with x, y, z")
    vertices = np.stack([np.asarray(vert[k], dtype=np.float64) for k in "xyz"], axis=1)
    if not np.all(np.isfinite(vertices)):
        raise ValueError(f"{path}: non-finite vertex coordinates")
    normals = None
    if all(k in vert for k in ("nx", "ny", "nz")):
        normals = tf.normalize(np.stack([np.asarray(vert[k], dtype=np.float64)
                                         for k in ("nx", "ny", "nz")], axis=1))
    texcoords = None
    for a, b in (("u", "v"), ("texture_u", "texture_v"), ("s", "t")):
        if a in vert and b in vert:
            texcoords = np.stack([np.asarray(vert[a], dtype=np.float64),
                                  np.asarray(vert[b], dtype=np.float64)], axis=1)
            break
    extra = (texcoords,) if uv else ()
    vattrs = _ply_attributes(vert, "vertex_", _PLY_GEOMETRY) if attributes else {}
    face = values.get("face")
    if face is None:
        raise ValueError(f"{path}: PLY file has no face element")
    lists = face.get("vertex_indices", face.get("vertex_index"))
    if lists is None:
        raise ValueError(f"{path}: PLY face element has no 'vertex_indices' list")
    nv = len(vertices)
    if isinstance(lists, np.ndarray) and lists.ndim == 2 and lists.shape[1] >= 3:
        poly = lists.astype(np.int64)  # every face has the same number of corners: vectorised fan
        if poly.min() < 0 or poly.max() >= nv:
            raise ValueError(f"{path}: a face indexes a vertex out of range (0..{nv - 1})")
        k = poly.shape[1]
        tri_a = np.stack([np.stack([poly[:, 0], poly[:, j], poly[:, j + 1]], 1)
                          for j in range(1, k - 1)], 1).reshape(-1, 3)
        if attributes:
            fattrs = {k_: np.repeat(a, k - 2, axis=0)
                      for k_, a in _ply_attributes(face, "face_", {"vertex_indices", "vertex_index"}).items()}
            extra = extra + ({**vattrs, **fattrs},)
        return (vertices, tri_a, normals) + extra
    tri: list = []
    per_face = []   # triangles of each face (face attributes repeat over them)
    for i, poly in enumerate(lists):
        poly = [int(x) for x in np.asarray(poly)]
        if len(poly) < 3:
            raise ValueError(f"{path}: face {i} has fewer than 3 vertices")
        if min(poly) < 0 or max(poly) >= nv:
            raise ValueError(f"{path}: face {i} indexes a vertex out of range (0..{nv - 1})")
        tri.extend(_fan(poly))
        per_face.append(len(poly) - 2)
    if not tri:
        raise ValueError(f"{path}: no faces")
    if attributes:
        face_arrays = {p_: np.asarray(v_, dtype=np.float64) for p_, v_ in face.items()
                       if p_ not in ("vertex_indices", "vertex_index")}
        fattrs = {k_: np.repeat(a, per_face, axis=0)
                  for k_, a in _ply_attributes(face_arrays, "face_", set()).items()}
        extra = extra + ({**vattrs, **fattrs},)
    return (vertices, np.array(tri, dtype=np.int64), normals) + extra


def write_ply(path: str, vertices, faces, normals=None, binary: bool = True) -> None:
    """Write a triangle mesh as PLY (``binary_little_endian`` or ``ascii``)."""
    v = np.asarray(vertices, dtype=np.float32)
    f = np.asarray(faces, dtype=np.int32)
    props = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals is not None else [])
    cols = v if normals is None else np.hstack([v, np.asarray(normals, dtype=np.float32)])
    head = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0",
            f"element vertex {len(v)}"] + [f"property float {p}" for p in props] + \
           [f"element face {len(f)}", "property list uchar int vertex_indices", "end_header"]
    with open(path, "wb") as fh:
        fh.write(("\n".join(head) + "\n").encode("ascii"))
        if binary:
            fh.write(cols.astype("<f4").tobytes())
            rec = np.zeros(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
            rec["n"], rec["i"] = 3, f
            fh.write(rec.tobytes())
        else:
            for row in cols:
                fh.write((" ".join("%.9g" % x for x in row) + "\n").encode())
            for row in f:
                fh.write(("3 %d %d %d\n" % tuple(row)).encode())


# --------------------------------------------------------------------------------------------
# Mitsuba serialized
# --------------------------------------------------------------------------------------------

SERIALIZED_MAGIC = 0x041C
#: flags of a serialized mesh (Mitsuba's ``TriMeshFlags``)
SERIALIZED_NORMALS, SERIALIZED_TEXCOORDS, SERIALIZED_COLORS = 0x1, 0x2, 0x8
SERIALIZED_FACE_NORMALS, SERIALIZED_SINGLE, SERIALIZED_DOUBLE = 0x10, 0x1000, 0x2000


def _serialized_start(read_at, size: int, path: str, k: int):
    """``(format version, offset of mesh k's zlib stream)`` of a serialized file of ``size``
    bytes, ``read_at(offset, n)`` its bytes there (the format header, and for k > 0 the
    end-of-file table's entry and the mesh's header: nothing else is read)."""
    if size < 4:
        raise ValueError(f"{path}: too short for a serialized mesh ({size} bytes)")
    magic, version = struct.unpack("<HH", read_at(0, 4))
    if magic != SERIALIZED_MAGIC:
        raise ValueError(f"{path}: not a Mitsuba serialized mesh (header 0x{magic:04X}, "
                         f"expected 0x{SERIALIZED_MAGIC:04X})")
    if version not in (3, 4):
        raise ValueError(f"{path}: serialized format version {version} is not supported (3 or 4)")
    if k < 0:
        raise ValueError(f"{path}: shape_index must be >= 0, got {k}")
    start = 4
    if k > 0:
        (count,) = struct.unpack("<I", read_at(size - 4, 4))
        if k >= count:
            raise ValueError(f"{path}: shape_index {k} is out of range (the file holds {count} "
                             f"mesh{'es' if count != 1 else ''}: 0..{count - 1})")
        width = 8 if version == 4 else 4
        at = size - 4 - width * (count - k)
        if at < 4:
            raise ValueError(f"{path}: the end-of-file table of {count} meshes does not fit in the file")
        (start,) = struct.unpack("<Q" if width == 8 else "<I", read_at(at, width))
        if start + 4 > at or struct.unpack("<H", read_at(start, 2))[0] != SERIALIZED_MAGIC:
            raise ValueError(f"{path}: the end-of-file table gives mesh {k} a bad offset {start}")
        start += 4
    return version, start


def read_serialized(path: str, shape_index: int = 0):
    """Read mesh ``shape_index`` of a Mitsuba ``.serialized`` file (format in the module doc) →
    ``(vertices, faces, normals or None, texcoords or None)``."""
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        raise ValueError(f"{path}: cannot read: {exc.strerror}") from None
    k = int(shape_index)
    version, start = _serialized_start(lambda at, n: data[at:at + n], len(data), path, k)
    stream = zlib.decompressobj()
    try:
        body = stream.decompress(data[start:])
    except zlib.error as exc:
        raise ValueError(f"{path}: mesh {k}: corrupt compressed data ({exc})") from None
    if not stream.eof:
        raise ValueError(f"{path}: mesh {k}: truncated compressed data")

    pos = 0

    def take(n_bytes, what):
        nonlocal pos
        if pos + n_bytes > len(body):
            raise ValueError(f"{path}: mesh {k}: truncated data in its {what}")
        chunk = body[pos:pos + n_bytes]
        pos += n_bytes
        return chunk

    (flags,) = struct.unpack("<I", take(4, "flags"))
    if version == 4:
        end = body.find(b"\0", pos)
        if end < 0:
            raise ValueError(f"{path}: mesh {k}: truncated data in its name")
        pos = end + 1
    n_vertices, n_faces = struct.unpack("<QQ", take(16, "counts"))
    real = np.dtype("<f8" if flags & SERIALIZED_DOUBLE else "<f4")

    def array(cols, what):
        return np.frombuffer(take(n_vertices * cols * real.itemsize, what), real).reshape(-1, cols).astype(np.float64)

    vertices = array(3, "vertex positions")
    normals = array(3, "vertex normals") if flags & SERIALIZED_NORMALS else None
    texcoords = array(2, "texcoords") if flags & SERIALIZED_TEXCOORDS else None
    if flags & SERIALIZED_COLORS:
        array(3, "vertex colours")   # skipped, as Mitsuba does
    faces = np.frombuffer(take(n_faces * 12, "faces"), "<u4").reshape(-1, 3).astype(np.int64)
    if not np.all(np.isfinite(vertices)):
        raise ValueError(f"{path}: mesh {k}: non-finite vertex positions")
    if faces.size and faces.max() >= n_vertices:
        raise ValueError(f"{path}: mesh {k}: a face indexes vertex {int(faces.max())}, out of "
                         f"range (0..{n_vertices - 1})")
    if normals is not None:
        normals = tf.normalize(normals)
    return vertices, faces, normals, texcoords


def stores_normals(path: str, kind: str, shape_index: int = 0) -> bool:
    """Whether the mesh file ``path`` of ``kind`` ``'ply'``, ``'obj'`` or ``'serialized'``
    stores vertex normals, as Mitsuba 3.9.1's readers decide (a PLY vertex element with ``nx``,
    an OBJ ``vn`` line, a serialized mesh's normals flag), reading no more of it than that
    takes: a PLY's header; an OBJ up to its first ``vn`` line (the whole file where it has
    none); a serialized file's format header, table entry and the first compressed bytes of the
    mesh (its flags). ValueError naming the file when it cannot be read."""
    if kind not in ("ply", "obj", "serialized"):
        raise ValueError(f"{path}: unknown mesh file kind {kind!r} (ply, obj, serialized)")
    try:
        with open(path, "rb") as fh:
            if kind == "ply":
                head = b""
                while b"end_header" not in head:
                    chunk = fh.read(1 << 16)
                    if not chunk:
                        break
                    head += chunk
                _, elements, _ = _ply_header(head, path)
                return any(e[0] == "vertex" and any(q[0] == "nx" for q in e[2]) for e in elements)
            if kind == "obj":
                return _obj_has_vn(fh)
            return _serialized_flags(fh, path, int(shape_index)) & SERIALIZED_NORMALS != 0
    except OSError as exc:
        raise ValueError(f"{path}: cannot read: {exc.strerror}") from None


def _obj_has_vn(fh) -> bool:
    """Whether an OBJ file (binary handle) has a ``vn`` line (``^[ \\t]*vn[ \\t]``), up to the
    first: the file mapped, its "n" bytes found (``find`` of one byte runs at memory speed, "vn"
    would not: a "v" starts most lines) and the line checked around each."""
    if os.fstat(fh.fileno()).st_size == 0:
        return False
    with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as m:
        at = m.find(b"n", 1)
        while at >= 0:
            if m[at - 1] == 0x76 and m[at + 1:at + 2] in (b" ", b"\t"):   # "vn" then a blank
                first = at - 1
                while first > 0 and m[first - 1] in (0x20, 0x09):
                    first -= 1
                if first == 0 or m[first - 1] == 0x0A:                       # at a line's start
                    return True
            at = m.find(b"n", at + 1)
    return False


def _serialized_flags(fh, path: str, k: int) -> int:
    """Mesh ``k``'s flags word of a serialized file (binary handle): the first four bytes of
    its zlib stream, inflated from as few compressed bytes as that takes."""
    def read_at(at, n):
        fh.seek(at)
        return fh.read(n)
    _, start = _serialized_start(read_at, os.fstat(fh.fileno()).st_size, path, k)
    fh.seek(start)
    data = b""
    while True:
        chunk = fh.read(1 << 12)
        data += chunk
        try:
            head = zlib.decompressobj().decompress(data, 4)
        except zlib.error as exc:
            raise ValueError(f"{path}: mesh {k}: corrupt compressed data ({exc})") from None
        if len(head) >= 4:
            return struct.unpack("<I", head)[0]
        if not chunk:
            raise ValueError(f"{path}: mesh {k}: truncated data in its flags")
