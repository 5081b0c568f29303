"""links1_whitted's frame with the nearest hit's record made in the kernel on triangle meshes
(``tables.MeshRecord``, ``intersect.mesh_surface``) against the same frame with Mitsuba's
record (``scene.ray_intersect``: Embree's hit and the shapes' surface call).

    python -m compare.mesh_record [--only teapot cbox_point] [--spp 1 16] [--repeats 9]

Per case (``compare.ray_floor``'s scenes with a box filter, 512 px wide), one scene object; the
two frames alternate (the record taken from the tables and the frozen launches recorded again
at each switch, outside the timing), ``repeats`` pairs after one warm-up of each: wall time of
``mi.render`` (a ``dr.eval`` of its output), medians, and the median of the pairs' ratios. Both
frames must be the same bits (checked). Writes ``compare/results/mesh_record.{json,md}``.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from compare.common import command_line, machine_info, machine_markdown, write_results


def measure(cid, spp, repeats, variant):
    import drjit as dr
    import mitsuba as mi
    from compare.ray_floor import load_case

    scene, _, _, _ = load_case(cid, "box", 512, variant)
    engine = scene.integrator().engine
    dr.eval(mi.render(scene, spp=spp, seed=0))
    base = engine.tables.last.base or engine.tables.last
    rec = base.mesh_record
    if rec is None:
        raise RuntimeError(f"{cid}: no mesh record (a shape other than a triangle mesh, or instances)")

    def frame(own):
        base.mesh_record = rec if own else None
        engine.launches.forget()
        img = mi.render(scene, spp=spp, seed=0)       # (recorded: not timed)
        dr.eval(img)
        t0 = time.perf_counter()
        img = mi.render(scene, spp=spp, seed=0)
        dr.eval(img)
        dr.sync_thread()
        return (time.perf_counter() - t0) * 1e3, np.array(img)

    try:
        ms = {True: [], False: []}
        imgs = {}
        for k in range(repeats + 1):
            for own in (True, False):
                t, imgs[own] = frame(own)
                if k:
                    ms[own].append(t)
    finally:
        base.mesh_record = rec
        engine.launches.forget()
    ratios = [a / b for a, b in zip(ms[True], ms[False])]
    return dict(id=cid, spp=spp, own_ms=float(np.median(ms[True])), mitsuba_ms=float(np.median(ms[False])),
                ratio=float(np.median(ratios)), ratios=ratios, same=bool(np.array_equal(imgs[True], imgs[False])))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="compare.mesh_record", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", nargs="*", default=["teapot", "cbox_point"])
    ap.add_argument("--spp", type=int, nargs="+", default=[1, 16])
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    a = ap.parse_args(argv)
    info, cmd = machine_info(), command_line()
    rows = []
    for cid in a.only:
        for spp in a.spp:
            r = measure(cid, spp, a.repeats, a.variant)
            rows.append(r)
            print(f"{cid:12s} spp {spp:3d}: kernel's record {r['own_ms']:7.1f} ms, Mitsuba's {r['mitsuba_ms']:7.1f} ms, "
                  f"ratio {r['ratio']:.3f} ({min(r['ratios']):.2f}-{max(r['ratios']):.2f}) same={r['same']}", flush=True)
    md = ["# links1_whitted's frame: the kernel's mesh record against Mitsuba's\n", machine_markdown(info, cmd),
          f"\nWall time of `mi.render` (512 px wide, box filter), the two frames alternated, {a.repeats} pairs, "
          "medians; ratio: median of the pairs' ratios (range in brackets); same: the frames equal bit for bit "
          "(`compare/mesh_record.py`).\n",
          "| scene | spp | kernel's record ms | Mitsuba's record ms | ratio | same |", "| --- | --- | --- | --- | --- | --- |"]
    md += [f"| `{r['id']}` | {r['spp']} | {r['own_ms']:.1f} | {r['mitsuba_ms']:.1f} | **{r['ratio']:.2f}** "
           f"({min(r['ratios']):.2f}–{max(r['ratios']):.2f}) | {r['same']} |" for r in rows]
    paths = write_results("mesh_record", dict(machine=info, command=cmd, cases=rows), "\n".join(md) + "\n")
    print("wrote " + ", ".join(str(p) for p in paths))
    return 0 if all(r["same"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
