"""Frame time at 512x512, spp 1, warm (kernels compiled): the float64 core, links1_whitted on
llvm (full depth and depth 1), and Mitsuba's direct/path on scenes built only from Mitsuba
shapes. Not a test.

    .venv/bin/python compare/bench_plugins.py [--res 512] [--frames 7] [--skip-core] [--scenes a,b]

Writes compare/results/plugins.json and compare/results/plugins.md. Every time is the median
of ``--frames`` warm frames of one process; the plugin's kernel time (sum of the Dr.Jit kernels'
execution times of one frame, from ``dr.kernel_history``) is given next to its wall time,
because the 2-core machine is shared and wall times vary with the other load.
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
TARGET_MS = 1000.0 / 30.0


def timed(fn, frames):
    fn()  # warm: compile kernels
    fn()
    ts = []
    for _ in range(frames):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return 1000 * float(np.median(ts))


def kernel_ms(fn):
    import drjit as dr
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()
    fn()
    hist = dr.kernel_history()
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    return sum(float(k.get("execution_time", 0.0)) for k in hist), len(hist)


def load_avg():
    try:
        return os.getloadavg()[0]
    except OSError:  # pragma: no cover
        return None


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--frames", type=int, default=7)
    ap.add_argument("--skip-core", action="store_true")
    ap.add_argument("--scenes", default=None, help="comma-separated scene names (default: all)")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    import mitsuba as mi
    import links1_mitsuba as lm
    rows = []
    paths = sorted(glob.glob(os.path.join(ROOT, "scenes", "*.xml")))
    if args.scenes:
        keep = {s if s.endswith(".xml") else s + ".xml" for s in args.scenes.split(",")}
        paths = [p for p in paths if os.path.basename(p) in keep]
    for path in paths:
        name = os.path.basename(path)
        row = {"scene": name, "load_avg_before": load_avg()}
        r = lm.MitsubaRenderer(path, params={"res": args.res}, spp=1)
        row["plugin_llvm_ms"] = timed(r.render, args.frames)
        row["plugin_kernel_ms"], row["plugin_kernels"] = kernel_ms(r.render)
        st = r.integrator.stats
        row["rays_per_pixel"] = {"camera": 1.0, **st["per_camera_ray"]}
        row["custom_shapes"] = len(r.integrator.custom)
        row["max_depth"] = r.integrator.max_depth
        r1 = lm.MitsubaRenderer(path, params={"res": args.res}, spp=1, max_depth=1)
        row["plugin_depth1_ms"] = timed(r1.render, args.frames)
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
    meta = {"command": "python compare/bench_plugins.py " + " ".join(sys.argv[1:] if argv is None else argv),
            "res": args.res, "spp": 1, "frames": args.frames, "variant": mi.variant(),
            "cpu_count": os.cpu_count(), "machine": platform.machine(), "python": platform.python_version(),
            "mitsuba": mi.__version__, "target_ms": TARGET_MS}
    out = os.path.join(ROOT, "compare", "results")
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, "plugins.json"), "w") as f:
        json.dump({"meta": meta, "rows": rows}, f, indent=2)
    fmt = lambda v: "-" if v is None else f"{v:.1f}"  # noqa: E731
    lines = [f"# Plugin frame times ({args.res}x{args.res}, spp 1, warm, median of {args.frames})", "",
             f"Command: `{meta['command']}` ({meta['cpu_count']} cores shared with other work, {meta['variant']}, "
             f"Mitsuba {meta['mitsuba']}).",
             f"Target: <= {TARGET_MS:.0f} ms per frame; Mitsuba direct/path only on scenes without links1 analytic "
             "shapes (direct = depth 1: compare with the plugin's depth-1 column).", "",
             "| scene | depth | core ms | plugin ms | plugin kernels ms | plugin depth-1 ms | Mitsuba direct ms "
             "| Mitsuba path ms (depth+1) | rays/pixel (shadow, reflect, refract) | load |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r_ in rows:
        rp = r_["rays_per_pixel"]
        lines.append(f"| {r_['scene']} | {r_['max_depth']} | {fmt(r_.get('core_ms'))} | {fmt(r_['plugin_llvm_ms'])} | "
                     f"{fmt(r_['plugin_kernel_ms'])} | {fmt(r_['plugin_depth1_ms'])} | "
                     f"{fmt(r_.get('mitsuba_direct_ms'))} | {fmt(r_.get('mitsuba_path_ms'))} | "
                     f"{rp['shadow']:.2f}, {rp['reflect']:.2f}, {rp['refract']:.2f} | "
                     f"{fmt(r_.get('load_avg_before'))} |")
    with open(os.path.join(out, "plugins.md"), "w") as f:
        f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
