"""Frame time at 512x512, spp 1, warm (kernels compiled): the float64 core, links1_whitted on
llvm (full depth and depth 1), and Mitsuba's direct/path on scenes built only from Mitsuba
shapes. Not a test.

    .venv/bin/python compare/bench_plugins.py [--res 512] [--frames 7] [--skip-core] [--scenes a,b]
                                              [--scaling 10,100,1000,10000] [--scaling-only]
                                              [--before REV [--threads 1]]

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
    ap.add_argument("--scaling", default="10,100,1000,10000",
                    help="quadric counts of the scaling rows (compare.scaling.quadric_scene); '' for none")
    ap.add_argument("--scaling-only", action="store_true", help="only the scaling rows (merged into the files)")
    ap.add_argument("--before", default=None,
                    help="git revision of plugins/links1_mitsuba to compare with (before/after rows: "
                         "each scene in its own processes, interleaved, merged into the files)")
    ap.add_argument("--threads", type=int, default=1,
                    help="Dr.Jit threads of the before/after runs (1: steadier on a shared machine)")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    if args.before:
        return _before_after(args, argv)
    import mitsuba as mi
    import links1_mitsuba as lm
    rows = []
    out = os.path.join(ROOT, "compare", "results")
    scaling = _scaling(args, lm) if args.scaling else []
    if args.scaling_only:
        with open(os.path.join(out, "plugins.json")) as f:
            old = json.load(f)
        old["scaling"] = scaling
        old["meta"]["scaling_command"] = "python compare/bench_plugins.py " + " ".join(
            sys.argv[1:] if argv is None else argv)
        with open(os.path.join(out, "plugins.json"), "w") as f:
            json.dump(old, f, indent=2)
        _markdown(out, old["meta"], old["rows"], scaling, old.get("before_after"))
        return
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
        row["custom_shapes"] = len(r.integrator.info()["custom_shapes"])
        row["max_depth"] = r.integrator.max_depth
        r1 = lm.MitsubaRenderer(path, params={"res": args.res}, spp=1, max_depth=1)
        row["plugin_depth1_ms"] = timed(r1.render, args.frames)
        if not args.skip_core:
            from links1.scene.loader import load_scene
            from links1.tracing.render import render
            sc = load_scene(path, res=str(args.res))
            row["core_ms"] = timed(lambda: render(sc, spp=1), 1)
        if row["custom_shapes"] == 0:
            for integ in ("direct", "path"):
                try:
                    s2 = lm.load_file(path, links1_integrator="scene", res=str(args.res))
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
    os.makedirs(out, exist_ok=True)
    extra = {}
    if args.scenes and os.path.exists(os.path.join(out, "plugins.json")):
        # a partial run (--scenes) replaces those rows of the last full run and keeps the rest
        with open(os.path.join(out, "plugins.json")) as f:
            old = json.load(f)
        new_rows = {r_["scene"]: dict(r_, command=meta["command"]) for r_ in rows}
        rows = [dict(r_, **new_rows.pop(r_["scene"], {})) for r_ in old["rows"]] + list(new_rows.values())
        meta = dict(old["meta"], rerun_commands=old["meta"].get("rerun_commands", []) + [meta["command"]])
        scaling = scaling or old.get("scaling", [])
        extra = {k: v for k, v in old.items() if k not in ("meta", "rows", "scaling")}
    with open(os.path.join(out, "plugins.json"), "w") as f:
        json.dump({"meta": meta, "rows": rows, "scaling": scaling, **extra}, f, indent=2)
    _markdown(out, meta, rows, scaling, extra.get("before_after"))


_AB_CODE = r"""
import json, os, sys, time, warnings
import numpy as np
warnings.simplefilter("ignore")
import drjit as dr
dr.set_thread_count(int(sys.argv[4]))
from links1_mitsuba import MitsubaRenderer
r = MitsubaRenderer(sys.argv[1], params={"res": int(sys.argv[2])}, spp=1)
r.render(); r.render()
ts = []
for _ in range(int(sys.argv[3])):
    t0 = time.perf_counter(); r.render(); ts.append(time.perf_counter() - t0)
print(json.dumps({"ms": 1000 * float(np.median(ts)), "load": os.getloadavg()[0]}))
"""


def _before_after(args, argv):
    """Frame times of the plugin at revision ``--before`` and of the working tree, per scene in
    fresh processes, one after the other (same load), ``--threads`` Dr.Jit threads."""
    import subprocess
    import tarfile
    import tempfile
    import io
    out = os.path.join(ROOT, "compare", "results")
    paths = sorted(glob.glob(os.path.join(ROOT, "scenes", "*.xml")))
    if args.scenes:
        keep = {s if s.endswith(".xml") else s + ".xml" for s in args.scenes.split(",")}
        paths = [p for p in paths if os.path.basename(p) in keep]
    rows = []
    with tempfile.TemporaryDirectory() as d:
        blob = subprocess.run(["git", "-C", ROOT, "archive", args.before, "plugins/links1_mitsuba"],
                              check=True, capture_output=True).stdout
        tarfile.open(fileobj=io.BytesIO(blob)).extractall(d)
        for path in paths:
            row = {"scene": os.path.basename(path)}
            for tag, pp in (("before", os.path.join(d, "plugins")), ("after", None)):
                env = dict(os.environ)
                if pp:
                    env["PYTHONPATH"] = pp
                p = subprocess.run([sys.executable, "-c", _AB_CODE, path, str(args.res), str(args.frames),
                                    str(args.threads)], env=env, capture_output=True, text=True, cwd=d)
                row[tag] = json.loads(p.stdout.strip().splitlines()[-1]) if p.returncode == 0 else \
                    {"error": p.stderr.strip().splitlines()[-1][:200] if p.stderr.strip() else "failed"}
            rows.append(row)
            print(json.dumps(row), flush=True)
    with open(os.path.join(out, "plugins.json")) as f:
        res = json.load(f)
    res["before_after"] = {"before": args.before, "threads": args.threads, "frames": args.frames,
                           "command": "python compare/bench_plugins.py " + " ".join(
                               sys.argv[1:] if argv is None else argv), "rows": rows}
    with open(os.path.join(out, "plugins.json"), "w") as f:
        json.dump(res, f, indent=2)
    _markdown(out, res["meta"], res["rows"], res.get("scaling", []), res["before_after"])


def _scaling(args, lm):
    """Plugin frame time against the number of links1 quadrics."""
    import tempfile
    sys.path.insert(0, ROOT)
    from compare.scaling import quadric_scene
    res = []
    with tempfile.TemporaryDirectory() as d:
        for n in [int(v) for v in args.scaling.split(",") if v]:
            p = os.path.join(d, f"quadric-{n}.xml")
            with open(p, "w") as f:
                f.write(quadric_scene(n))
            t0 = time.perf_counter()
            r = lm.MitsubaRenderer(p, params={"res": args.res}, spp=1)
            r.render()
            first = time.perf_counter() - t0
            row = {"quadrics": n, "plugin_llvm_ms": timed(r.render, args.frames), "load_and_first_frame_s": first,
                   "rays_per_pixel": {"camera": 1.0, **r.integrator.stats["per_camera_ray"]},
                   "load_avg_before": load_avg()}
            res.append(row)
            print(json.dumps(row), flush=True)
    if res:
        base = res[0]["plugin_llvm_ms"]
        for row in res:
            row["ratio_to_smallest"] = row["plugin_llvm_ms"] / base
    return res


def _markdown(out, meta, rows, scaling, before_after=None):
    args_res, frames = meta["res"], meta["frames"]
    fmt = lambda v: "-" if v is None else f"{v:.1f}"  # noqa: E731
    lines = [f"# Plugin frame times ({args_res}x{args_res}, spp 1, warm, median of {frames})", "",
             f"Command: `{meta['command']}` ({meta['cpu_count']} cores shared with other work, {meta['variant']}, "
             f"Mitsuba {meta['mitsuba']}).",
             *([f"Rows rerun (marked *) with: " + "; ".join(f"`{c}`" for c in meta["rerun_commands"])]
               if meta.get("rerun_commands") else []),
             f"Target: <= {TARGET_MS:.0f} ms per frame; Mitsuba direct/path only on scenes without links1 analytic "
             "shapes (direct = depth 1: compare with the plugin's depth-1 column).", "",
             "| scene | depth | core ms | plugin ms | plugin kernels ms | plugin depth-1 ms | Mitsuba direct ms "
             "| Mitsuba path ms (depth+1) | rays/pixel (shadow, reflect, refract) | load |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r_ in rows:
        rp = r_["rays_per_pixel"]
        lines.append(f"| {r_['scene']}{' *' if 'command' in r_ else ''} | {r_['max_depth']} | {fmt(r_.get('core_ms'))} | {fmt(r_['plugin_llvm_ms'])} | "
                     f"{fmt(r_['plugin_kernel_ms'])} | {fmt(r_['plugin_depth1_ms'])} | "
                     f"{fmt(r_.get('mitsuba_direct_ms'))} | {fmt(r_.get('mitsuba_path_ms'))} | "
                     f"{rp['shadow']:.2f}, {rp['reflect']:.2f}, {rp['refract']:.2f} | "
                     f"{fmt(r_.get('load_avg_before'))} |")
    if scaling:
        lines += ["", f"## Scaling with the number of links1 quadrics (BVH; `compare.scaling.quadric_scene`, "
                  f"{args_res}x{args_res}, spp 1, direct light)", "",
                  "| quadrics | plugin ms | x of smallest | load + first frame s | shadow rays/pixel |",
                  "| --- | --- | --- | --- | --- |"]
        for r_ in scaling:
            lines.append(f"| {r_['quadrics']} | {r_['plugin_llvm_ms']:.1f} | {r_['ratio_to_smallest']:.2f} | "
                         f"{r_['load_and_first_frame_s']:.1f} | {r_['rays_per_pixel']['shadow']:.2f} |")
    if before_after:
        ba = before_after
        lines += ["", f"## Before / after (plugin at `{ba['before']}` vs this tree, {ba['threads']} Dr.Jit "
                  f"thread(s), median of {ba['frames']} frames, each in a fresh process, one after the other)", "",
                  f"Command: `{ba['command']}`. The tree's plugin stops ray-tree branches whose weight "
                  "falls to 1/255 (default `min_weight`, as the core); a revision without that option traced "
                  "every branch, so part of the speed-up on deep scenes is fewer rays.", "",
                  "| scene | before ms | after ms | speed-up | load |", "| --- | --- | --- | --- | --- |"]
        for r_ in ba["rows"]:
            b, a = r_["before"].get("ms"), r_["after"].get("ms")
            sp = f"{b / a:.1f}x" if (a and b) else "-"
            lines.append(f"| {r_['scene']} | {fmt(b)} | {fmt(a)} | {sp} | {fmt(r_['after'].get('load'))} |")
    with open(os.path.join(out, "plugins.md"), "w") as f:
        f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
