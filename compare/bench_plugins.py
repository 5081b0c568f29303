"""Frame time at 512x512, spp 1, warm (kernels compiled): core, links1_whitted on llvm, and
Mitsuba's direct/path on scenes built only from Mitsuba shapes. Not a test.

    .venv/bin/python compare/bench_plugins.py [--res 512] [--frames 5] [--skip-core]

Writes compare/results/plugins.json and compare/results/plugins.md.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import platform
import sys
import time
import warnings

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def timed(fn, frames):
    fn()  # warm: compile kernels
    ts = []
    for _ in range(frames):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return 1000 * float(np.median(ts))


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--skip-core", action="store_true")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    import mitsuba as mi
    import links1_mitsuba as lm
    rows = []
    for path in sorted(glob.glob(os.path.join(ROOT, "scenes", "*.xml"))):
        name = os.path.basename(path)
        row = {"scene": name}
        r = lm.MitsubaRenderer(path, params={"res": args.res}, spp=1)
        row["plugin_llvm_ms"] = timed(r.render, args.frames)
        row["custom_shapes"] = len(r.integrator.custom)
        row["max_depth"] = r.integrator.max_depth
        if not args.skip_core:
            from links1.loader import load_scene
            from links1.render import render
            sc = load_scene(path, res=str(args.res))
            row["core_ms"] = timed(lambda: render(sc, spp=1), 1)
        if row["custom_shapes"] == 0:
            for integ in ("direct", "path"):
                try:
                    s2 = lm.load_file(path, integrator="scene", res=str(args.res))
                    xml_depth = row["max_depth"] + 1
                    d = {"type": integ} if integ == "direct" else {"type": "path", "max_depth": xml_depth}
                    it = mi.load_dict(d)
                    row[f"mitsuba_{integ}_ms"] = timed(lambda: mi.render(s2, integrator=it, spp=1), args.frames)
                except Exception as exc:  # e.g. links1 BSDFs inside Mitsuba's integrators
                    row[f"mitsuba_{integ}_ms"] = None
                    row[f"mitsuba_{integ}_error"] = str(exc)[:200]
        rows.append(row)
        print(json.dumps(row), flush=True)
    meta = {"command": "python compare/bench_plugins.py " + " ".join(argv or sys.argv[1:]),
            "res": args.res, "spp": 1, "frames": args.frames, "variant": mi.variant(),
            "cpu_count": os.cpu_count(), "machine": platform.machine(), "python": platform.python_version(),
            "mitsuba": mi.__version__}
    out = os.path.join(ROOT, "compare", "results")
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, "plugins.json"), "w") as f:
        json.dump({"meta": meta, "rows": rows}, f, indent=2)
    fmt = lambda v: "-" if v is None else f"{v:.1f}"
    lines = [f"# Plugin frame times ({args.res}x{args.res}, spp 1, warm, median of {args.frames})", "",
             f"Command: `{meta['command']}` ({meta['cpu_count']} cores, {meta['variant']}, Mitsuba {meta['mitsuba']}).",
             "Target: <= 33 ms per frame; Mitsuba direct/path only on scenes without links1 analytic shapes.", "",
             "| scene | core ms | plugin llvm ms | Mitsuba direct ms | Mitsuba path ms (depth+1) |",
             "| --- | --- | --- | --- | --- |"]
    for r_ in rows:
        lines.append(f"| {r_['scene']} | {fmt(r_.get('core_ms'))} | {fmt(r_['plugin_llvm_ms'])} | "
                     f"{fmt(r_.get('mitsuba_direct_ms'))} | {fmt(r_.get('mitsuba_path_ms'))} |")
    with open(os.path.join(out, "plugins.md"), "w") as f:
        f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
