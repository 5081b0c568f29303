"""What learning whether a mesh file stores normals costs at load, against reading the file.

    python -m compare.mesh_normals_scan [--grid 708] [--repeats 5]

The loader asks :func:`links1.geometry.mesh_files.stores_normals` of every mesh file whose
shape Mitsuba gave normals (those it computed are computed again on one thread). Meshes of
``--grid``² vertices (708: 999,698 triangles) written to a temporary folder as OBJ (with
and without ``vn`` lines), binary PLY (with and without ``nx``) and one serialized file of
two meshes (with normals, without). Per file, each round, in one process and interleaved:

* ``stores_normals``: the answer as the loader gets it;
* ``whole file``: the file read whole and searched as one (OBJ: the ``vn`` line's regular
  expression over the bytes; serialized: the mesh's flags inflated from the bytes read);
* ``Mitsuba load``: ``mi.load_dict`` of the shape (``llvm_ad_rgb``): the load it is part of.

Wall times, medians of ``--repeats`` rounds; the answers are checked equal. Writes
``compare/results/mesh_normals_scan.{json,md}``.
"""
from __future__ import annotations

import argparse
import re
import struct
import tempfile
import time
import zlib
from pathlib import Path

import numpy as np

from compare.common import command_line, machine_info, machine_markdown, md_table, write_results


def grid_mesh(n: int):
    """A wavy ``n`` × ``n`` vertex grid: (vertices, triangles, normals)."""
    x, y = np.meshgrid(np.linspace(0.0, 1.0, n), np.linspace(0.0, 1.0, n))
    v = np.stack([x.ravel(), y.ravel(), 0.1 * np.sin(7.0 * x.ravel())], 1)
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, 1:].ravel(), i[1:, :-1].ravel()
    f = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return v, f, np.tile([0.0, 0.0, 1.0], (len(v), 1))


def write_obj_fast(path, v, f, n=None) -> None:
    """OBJ as :func:`links1.geometry.mesh_files.write_obj` lays it out (v, vn, then f lines)."""
    with open(path, "w") as fh:
        np.savetxt(fh, v, fmt="v %.9g %.9g %.9g")
        if n is not None:
            np.savetxt(fh, n, fmt="vn %.9g %.9g %.9g")
            np.savetxt(fh, np.repeat(f + 1, 2, axis=1), fmt="f %d//%d %d//%d %d//%d")
        else:
            np.savetxt(fh, f + 1, fmt="f %d %d %d")


def whole_file(path, kind, index) -> bool:
    """The answer from the file read whole (the search over all of its bytes)."""
    data = Path(path).read_bytes()
    if kind == "obj":
        return re.search(rb"(?m)^[ \t]*vn[ \t]", data) is not None
    if kind == "ply":
        head = data[:data.index(b"end_header")]
        return b"property float nx" in head or b"property double nx" in head
    start = 4
    if index:
        (count,) = struct.unpack_from("<I", data, len(data) - 4)
        (start,) = struct.unpack_from("<Q", data, len(data) - 4 - 8 * (count - index))
        start += 4
    return bool(struct.unpack("<I", zlib.decompressobj().decompress(data[start:], 4))[0] & 1)


def measure(grid: int, repeats: int) -> dict:
    import mitsuba as mi
    from links1.geometry import mesh_files
    from tests.core.test_serialized import write_serialized
    mi.set_variant("llvm_ad_rgb")
    v, f, n = grid_mesh(grid)
    rows = []
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        write_obj_fast(d / "normals.obj", v, f, n)
        write_obj_fast(d / "plain.obj", v, f)
        mesh_files.write_ply(str(d / "normals.ply"), v, f, n)
        mesh_files.write_ply(str(d / "plain.ply"), v, f)
        write_serialized(str(d / "two.serialized"), [dict(v=v, f=f, n=n), dict(v=v, f=f)], 4)
        cases = [("normals.obj", "obj", 0), ("plain.obj", "obj", 0), ("normals.ply", "ply", 0),
                 ("plain.ply", "ply", 0), ("two.serialized", "serialized", 0), ("two.serialized", "serialized", 1)]
        ways = {
            "stores_normals": lambda p, k, i: mesh_files.stores_normals(p, k, i),
            "whole file": whole_file,
            "Mitsuba load": lambda p, k, i: mi.load_dict({"type": k, "filename": p, **({"shape_index": i}
                                                          if k == "serialized" else {})}).has_vertex_normals(),
        }
        times = {(c, w): [] for c in cases for w in ways}
        answers = {}
        for r in range(repeats + 1):          # round 0: warm-up (the page cache, Mitsuba's plugins)
            for c in cases:
                p = str(d / c[0])
                for w, fn in ways.items():
                    t0 = time.perf_counter()
                    a = fn(p, c[1], c[2])
                    dt = time.perf_counter() - t0
                    if w != "Mitsuba load":
                        answers.setdefault(c, set()).add(bool(a))
                    if r:
                        times[(c, w)].append(dt)
        for c in cases:
            if len(answers[c]) != 1:
                raise RuntimeError(f"{c}: the ways disagree: {answers[c]}")
            ms = {w: float(np.median(times[(c, w)])) * 1e3 for w in ways}
            rows.append(dict(file=c[0], shape_index=c[2], bytes=(d / c[0]).stat().st_size,
                             stores_normals=answers[c].pop(), ms=ms,
                             ratio=ms["stores_normals"] / ms["whole file"]))
    return dict(grid=grid, faces=int(len(f)), vertices=int(len(v)), repeats=repeats, rows=rows)


def markdown(res, info, cmd) -> str:
    table = md_table(["file", "shape", "MB", "normals", "stores_normals ms", "whole file ms", "ratio",
                      "Mitsuba load ms"],
                     [[r["file"], r["shape_index"], f"{r['bytes'] / 1e6:.1f}", "yes" if r["stores_normals"] else "no",
                       f"{r['ms']['stores_normals']:.2f}", f"{r['ms']['whole file']:.1f}", f"{r['ratio']:.3f}",
                       f"{r['ms']['Mitsuba load']:.0f}"] for r in res["rows"]])
    return ("# Whether a mesh file stores normals: the loader's question\n\n" + machine_markdown(info, cmd)
            + f"\n{res['faces']:,} triangles, {res['vertices']:,} vertices; wall times, medians of "
            f"{res['repeats']} interleaved rounds (`compare/mesh_normals_scan.py`).\n\n" + table)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m compare.mesh_normals_scan", description=__doc__.split("\n\n")[0])
    ap.add_argument("--grid", type=int, default=708)
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args(argv)
    info, cmd = machine_info(), command_line()
    res = measure(a.grid, a.repeats)
    for r in res["rows"]:
        print(f"{r['file']:16s} {r['shape_index']} {r['ms']['stores_normals']:8.2f} ms  whole file "
              f"{r['ms']['whole file']:8.1f} ms  Mitsuba load {r['ms']['Mitsuba load']:8.0f} ms", flush=True)
    paths = write_results("mesh_normals_scan", dict(machine=info, command=cmd, args=vars(a), **res),
                          markdown(res, info, cmd))
    print("wrote", ", ".join(str(p) for p in paths))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
