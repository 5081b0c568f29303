"""links1_whitted's frame with the nearest hit's record made in the kernel (``tables.MeshRecord``,
``intersect.mesh_surface``: meshes, rectangles, spheres, disks), each way of picking a lane's
kind (``intersect.DISPATCH``), its meshes' vertices read from the per-face table
(``MeshRecord.packets``) or from the meshes' buffers (way ``buffers``), against the same frame
with Mitsuba's record (``scene.ray_intersect``: Embree's hit and the shapes' surface call).

    python -m compare.mesh_record [--only teapot cbox_point delta_bsdfs] [--spp 1 16] [--repeats 9]
                                  [--ways if select switch buffers mitsuba]

Per case (``compare.ray_floor``'s scenes, 512 px wide, ``--filter``), one scene object; the
frames of the ``ways`` alternate (the record or the dispatch switched and the frozen launches
recorded again at each switch, outside the timing), ``repeats`` rounds after one warm-up of
each: wall time and process CPU time (every thread) of ``mi.render`` (a ``dr.eval`` of its
output), medians, and per way the median of its ratios to the first way's frame of the same
round. Every frame must be the first way's bits (checked). Writes
``compare/results/<--out>.{json,md}`` (``mesh_record``; the ways' comparison of the dispatch:
``mesh_record_dispatch``).
"""
from __future__ import annotations

import argparse

import numpy as np

from compare.common import command_line, machine_info, machine_markdown, timed_render, write_results

WAYS = ("if", "select", "switch", "buffers", "mitsuba")


def measure(cid, spp, repeats, variant, ways=("if", "mitsuba"), filt="box"):
    import drjit as dr
    import mitsuba as mi
    from compare.ray_floor import load_case

    from links1_mitsuba import intersect

    scene, _, _, _ = load_case(cid, filt, 512, variant)
    engine = scene.integrator().engine
    dr.eval(mi.render(scene, spp=spp, seed=0))
    base = engine.tables.last.base or engine.tables.last
    rec, dispatch = base.mesh_record, intersect.DISPATCH
    packets = None if rec is None else rec.packets
    if rec is None:
        raise RuntimeError(f"{cid}: no record made in the kernel (a shape it does not make, or instances)")

    def frame(way):
        base.mesh_record = None if way == "mitsuba" else rec
        intersect.DISPATCH = dispatch if way in ("mitsuba", "buffers") else way
        rec.packets = None if way == "buffers" else packets
        engine.launches.forget()
        dr.eval(mi.render(scene, spp=spp, seed=0))      # (recorded: not timed)
        return timed_render(scene, spp)

    wall, cpu = ({w: [] for w in ways} for _ in range(2))
    same = {w: True for w in ways}
    try:
        for k in range(repeats + 1):
            first = None
            for w in ways:
                tw, tc, img = frame(w)
                first = img if first is None else first
                same[w] &= bool(np.array_equal(img, first))
                if k:
                    wall[w].append(tw)
                    cpu[w].append(tc)
    finally:
        base.mesh_record, intersect.DISPATCH, rec.packets = rec, dispatch, packets
        engine.launches.forget()
    out = dict(id=cid, spp=spp, kinds=sorted(rec.kinds), ways={})
    for w in ways:
        rw = [a / b for a, b in zip(wall[w], wall[ways[0]])]
        rc = [a / b for a, b in zip(cpu[w], cpu[ways[0]])]
        out["ways"][w] = dict(wall_ms=float(np.median(wall[w])), cpu_ms=float(np.median(cpu[w])),
                              wall_ratio=float(np.median(rw)), cpu_ratio=float(np.median(rc)),
                              cpu_ratios=rc, same=same[w])
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="compare.mesh_record", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", nargs="*", default=["teapot", "cbox_point", "delta_bsdfs"])
    ap.add_argument("--spp", type=int, nargs="+", default=[1, 16])
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--ways", nargs="+", default=["if", "mitsuba"], choices=WAYS)
    ap.add_argument("--filter", default="box")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--out", default="mesh_record", help="name of the result files in compare/results")
    a = ap.parse_args(argv)
    info, cmd = machine_info(), command_line()
    rows = []
    for cid in a.only:
        for spp in a.spp:
            r = measure(cid, spp, a.repeats, a.variant, tuple(a.ways), a.filter)
            rows.append(r)
            print(f"{cid:12s} spp {spp:3d}: " + ", ".join(
                f"{w} {v['cpu_ms']:.1f} ms CPU ({v['cpu_ratio']:.3f}, wall {v['wall_ratio']:.3f}) same={v['same']}"
                for w, v in r["ways"].items()), flush=True)
    first = a.ways[0]
    md = ["# links1_whitted's frame: the kernel's surface record, its dispatch, against Mitsuba's record\n",
          machine_markdown(info, cmd),
          f"\n`mi.render` (512 px wide, {a.filter} filter), the frames of each way alternated, {a.repeats} rounds, "
          "medians of process CPU time (every thread) and wall time; ratio: the median of each round's ratio to the "
          f"`{first}` frame (CPU; wall in brackets); ways: `if`/`select`/`switch` the kernel's record "
          "(`intersect.DISPATCH`), `buffers` the kernel's record with the meshes' vertices gathered from their buffers "
          "instead of the per-face table, `mitsuba` Mitsuba's record; same: every frame equals the first way's bit for bit "
          "(`compare/mesh_record.py`).\n",
          "| scene | spp | kinds | way | CPU ms | wall ms | ratio | same |", "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    names = {0: "mesh", 1: "rectangle", 2: "sphere", 3: "disk"}
    for r in rows:
        for w, v in r["ways"].items():
            md.append(f"| `{r['id']}` | {r['spp']} | {' '.join(names[k] for k in r['kinds'])} | {w} | {v['cpu_ms']:.1f} | "
                      f"{v['wall_ms']:.1f} | **{v['cpu_ratio']:.3f}** ({v['wall_ratio']:.3f}) | {v['same']} |")
    paths = write_results(a.out, dict(machine=info, command=cmd, cases=rows), "\n".join(md) + "\n")
    print("wrote " + ", ".join(str(p) for p in paths))
    return 0 if all(v["same"] for r in rows for v in r["ways"].values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
