"""What the one-thread normals cost a ``params.update()`` that moves a mesh's vertices.

    python -m compare.normals_update [--rings 160] [--repeats 15] [--width 64]

The mesh is the bumpy sphere of ``tests/plugins/test_loaded_normals.py`` (``--rings`` 160:
50,880 faces, 25,600 vertices) in a PLY file without normals, loaded by
``links1_mitsuba.load_file`` with ``links1_whitted`` (``max_depth`` 1, a point light, a
``--width`` square film, box filter, spp 1). Each round, in one process and interleaved:

* ``update``: ``params["bumpy.vertex_positions"] = ...; params.update()`` (Mitsuba's own work,
  its multi-threaded recompute of the normals included);
* ``settle``: :func:`links1_mitsuba.normals.settle_moved` of the mesh after such an update
  (one-thread recompute, both buffers read back and compared);
* ``recompute``: :func:`links1_mitsuba.normals.recompute` alone; ``threads``: Dr.Jit's thread
  count set to 1 and back, nothing between;
* ``frame`` / ``frame_unsettled``: an update and the frame after it (``mi.render``, evaluated),
  with the plugin's settle and with it switched off (``tables.settle_moved`` replaced by a
  no-op for that frame).

Wall times (medians of ``--repeats`` rounds); the frames' normals are checked to be the
fresh load's bits with the settle. Writes ``compare/results/normals_update.{json,md}``.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from compare.common import command_line, machine_info, machine_markdown, md_table, write_results


def _timed(fn):
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def measure(rings: int, repeats: int, width: int) -> dict:
    import drjit as dr
    import mitsuba as mi
    import links1_mitsuba as lm
    from links1.geometry import mesh_files
    from links1_mitsuba import normals, tables
    from tests.plugins.test_loaded_normals import _bumpy, _moved, _normals, _xml
    lm.register("llvm_ad_rgb")
    v, f = _bumpy(rings)
    moved = _moved(v).ravel()       # (a new variable each update: the same one is no change)
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        mesh_files.write_ply(str(d / "bumpy.ply"), v, f)
        mesh_files.write_ply(str(d / "moved.ply"), _moved(v), f)
        for name in ("bumpy", "moved"):
            xml = _xml(d / f"{name}.ply").replace('width" value="24"', f'width" value="{width}"')
            xml = xml.replace('height" value="24"', f'height" value="{width}"')
            (d / f"{name}.xml").write_text(xml)
        scene = lm.load_file(str(d / "bumpy.xml"))
        fresh = _normals(mi, lm.load_file(str(d / "moved.xml")))
    (mesh,) = [s for s in scene.shapes() if s.id() == "bumpy"]
    params = mi.traverse(scene)
    settle = tables.settle_moved

    def update():
        params["bumpy.vertex_positions"] = mi.Float(moved)
        params.update()
        dr.sync_thread()

    def frame():
        update()
        img = mi.render(scene, spp=1, seed=0)
        dr.eval(img)
        dr.sync_thread()

    def unsettled():
        tables.settle_moved = lambda meshes: 0
        try:
            frame()
        finally:
            tables.settle_moved = settle

    def threads():
        n = dr.thread_count()
        dr.set_thread_count(1)
        dr.set_thread_count(n)

    frame()
    unsettled()
    times = {k: [] for k in ("update", "settle", "recompute", "threads", "frame", "frame_unsettled")}
    same = True
    for r in range(repeats):
        times["update"].append(_timed(update))
        times["settle"].append(_timed(lambda: normals.settle_moved([mesh])))
        times["recompute"].append(_timed(lambda: normals.recompute([mesh])))
        times["threads"].append(_timed(threads))
        order = (("frame", frame), ("frame_unsettled", unsettled))
        for k, fn in (order if r % 2 == 0 else order[::-1]):
            times[k].append(_timed(fn))
            if k == "frame":
                same &= bool(np.array_equal(_normals(mi, scene), fresh))
    med = {k: float(np.median(t)) * 1e3 for k, t in times.items()}
    return dict(faces=int(len(f)), vertices=int(len(v)), threads=int(dr.thread_count()), repeats=repeats,
                width=width, median_ms=med, all_ms={k: [x * 1e3 for x in t] for k, t in times.items()},
                frame_ratio=med["frame"] / med["frame_unsettled"], settled_normals_are_fresh_load=same)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rings", type=int, default=160)
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--width", type=int, default=64)
    a = ap.parse_args(argv)
    info, cmd = machine_info(), command_line()
    res = measure(a.rings, a.repeats, a.width)
    m = res["median_ms"]
    rows = [[k, m[k]] for k in ("update", "settle", "recompute", "threads", "frame", "frame_unsettled")]
    md = ("# The one-thread normals of a moved mesh\n\n" + machine_markdown(info, cmd)
          + f"\n{res['faces']} faces, {res['vertices']} vertices, Dr.Jit threads {res['threads']}, "
          f"{res['repeats']} rounds, film {a.width} px wide, spp 1; wall-time medians (ms):\n\n"
          + md_table(["what", "ms"], rows)
          + f"\nframe with the settle / without: {res['frame_ratio']:.3f}; settled normals equal a fresh "
          f"load's every frame: {res['settled_normals_are_fresh_load']}\n")
    write_results("normals_update", dict(machine=info, command=cmd, args=vars(a), **res), md)
    print(md)


if __name__ == "__main__":
    main()
