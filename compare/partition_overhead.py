"""What partitioning costs and gains. A benchmark, not a test.

Table 1, per-launch overhead (one process, the renderer's own threads): the full frame vs
the same frame as 64 and as 256 tiles each in its own launch (the paper's one-unit-at-a-time
hand-out) vs the 64 tiles in two batches (two nodes' static batches, one after the other).
Targets: 64 own launches <= 1.15 x the frame, 256 <= 1.3 x, batched <= 1.05 x.

Table 2, ``links1 schedule --nodes 2`` at 512², spp 1, Mitsuba renderer: true efficiency
= full frame on one node / (2 x makespan) (target >= 0.85: dynamic on many, subscreen on
fig11).

Table 3, end to end (``--full``): ``links1 render`` wall time of a heavy frame (1024², spp 16)
with ``--workers 2`` and ``--dask-local 2`` vs the in-process render of the whole frame as
one unit (target <= 1.1 x), and the render part alone (makespan vs full frame).

The machine is shared (other engineers' test runs): every figure is the median of
``repeat`` runs and every target is a ratio measured in the same run.

Usage: ``.venv/bin/python -m compare.partition_overhead [--quick] [--full]``; writes
``compare/results/partition_overhead.{json,md}`` (``--quick``: ``partition_overhead_quick.{json,md}``).
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "compare" / "results"
LINKS1 = [sys.executable, "-m", "links1_app.cli"]


def overhead_rows(cases, repeat):
    from links1_app.partition.costmodel import measure_overhead
    from links1_app.partition.runtime import RendererSpec
    rows = []
    for kind, scene, res in cases:
        spec = RendererSpec.make(kind, str(ROOT / "scenes" / f"{scene}.xml"), params={"res": str(res)})
        try:
            a = measure_overhead(spec, n_units=64, repeat=repeat)
            b = measure_overhead(spec, n_units=256, repeat=repeat, batched=False)
        except Exception as e:  # noqa: BLE001 - a renderer that cannot run here is reported, not fatal
            rows.append({"renderer": kind, "scene": scene, "res": res, "error": f"{type(e).__name__}: {e}"})
            continue
        row = {"renderer": kind, "scene": scene, "res": res, "full_s": a["full_s"], "units64_s": a["tiled_s"],
               "ratio64": a["ratio"], "units256_s": b["tiled_s"], "ratio256": b["tiled_s"] / a["full_s"],
               "batched_s": a.get("batched_s"), "batched_ratio": a.get("batched_ratio"),
               "per_launch_ms": 1e3 * a["per_launch_overhead_s"]}
        rows.append(row)
        print(f"{kind:8s} {scene:14s} {res:4d} full {row['full_s'] * 1e3:7.1f} ms  64 {row['ratio64']:.2f}x  "
              f"256 {row['ratio256']:.2f}x  batched {row['batched_ratio']:.2f}x  launch {row['per_launch_ms']:.2f} ms",
              file=sys.stderr, flush=True)
    return rows


def schedule_rows(cases, repeat):
    rows = []
    for scene, strategy in cases:
        effs = []
        for _ in range(repeat):
            with tempfile.TemporaryDirectory() as d:
                rep = Path(d) / "r.json"
                p = subprocess.run(LINKS1 + ["schedule", str(ROOT / "scenes" / f"{scene}.xml"), "--renderer", "mitsuba",
                                            "-D", "res=512", "--nodes", "2", "--partition", strategy, "--no-progress",
                                            "--report", str(rep)], capture_output=True, text=True, timeout=600,
                                   cwd=ROOT)
                if p.returncode != 0:
                    rows.append({"scene": scene, "strategy": strategy, "error": p.stderr.strip()[-300:]})
                    break
                r = json.loads(rep.read_text())
                effs.append({k: r[k] for k in ("makespan_s", "full_frame_s", "true_efficiency", "parallel_efficiency",
                                               "imbalance", "launches")})
        if effs:
            med = {k: float(np.median([e[k] for e in effs])) for k in effs[0]}
            rows.append({"scene": scene, "strategy": strategy, "runs": len(effs), **med})
            print(f"schedule {scene} {strategy}: true efficiency {med['true_efficiency']:.3f} (makespan "
                  f"{med['makespan_s'] * 1e3:.1f} ms, one node {med['full_frame_s'] * 1e3:.1f} ms)", file=sys.stderr,
                  flush=True)
    return rows


def _wall(args):
    t = time.perf_counter()
    p = subprocess.run(LINKS1 + args, capture_output=True, text=True, timeout=900, cwd=ROOT)
    if p.returncode != 0:
        raise RuntimeError(p.stderr.strip()[-300:])
    return time.perf_counter() - t


def end_to_end_rows(scenes, res, spp, repeat):
    rows = []
    for scene in scenes:
        with tempfile.TemporaryDirectory() as d:
            base = ["render", str(ROOT / "scenes" / f"{scene}.xml"), "--renderer", "mitsuba", "-D", f"res={res}",
                    "--spp", str(spp), "--no-progress", "-o", os.path.join(d, "o.exr")]
            variants = {"in-process, one unit": ["--workers", "auto"], "--workers 2": ["--workers", "2"],
                        "--dask-local 2": ["--dask-local", "2"]}
            times = {k: [] for k in variants}
            try:
                for _ in range(repeat):
                    for k, extra in variants.items():
                        times[k].append(_wall(base + extra))
            except Exception as e:  # noqa: BLE001
                rows.append({"scene": scene, "error": str(e)})
                continue
        med = {k: float(np.median(v)) for k, v in times.items()}
        ref = med["in-process, one unit"]
        rows.append({"scene": scene, "res": res, "spp": spp, "wall_s": med,
                     "ratio": {k: v / ref for k, v in med.items()}})
        print(f"end to end {scene}: " + ", ".join(f"{k} {v:.2f} s ({v / ref:.2f}x)" for k, v in med.items()),
              file=sys.stderr, flush=True)
    return rows


def machine():
    info = {"cores": os.cpu_count(), "python": sys.version.split()[0]}
    try:
        model = re.search(r"model name\s*:\s*(.*)", Path("/proc/cpuinfo").read_text())
        info["cpu"] = model.group(1) if model else ""
        info["load_avg_at_start"] = os.getloadavg()
    except OSError:
        pass
    return info


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="256² only, fewer repeats")
    ap.add_argument("--full", action="store_true", help="also the end-to-end table (1024², spp 16)")
    ap.add_argument("--repeat", type=int, default=None)
    args = ap.parse_args(argv)
    repeat = args.repeat or (2 if args.quick else 3)
    res_list = (256,) if args.quick else (256, 512)
    cases = [("mitsuba", s, r) for r in res_list for s in ("fig11", "many", "mitsuba_glass")]
    cases += [("core", s, 256) for s in ("fig11", "many")]
    meta = {"command": "python -m compare.partition_overhead" + (" --quick" if args.quick else "")
            + (" --full" if args.full else "") + (f" --repeat {args.repeat}" if args.repeat else ""),
            "machine": machine(), "repeat": repeat,
            "note": "2 shared cores, loaded by other engineers' test runs: medians, same-run ratios"}
    out = {"meta": meta, "overhead": overhead_rows(cases, repeat)}
    out["schedule"] = schedule_rows([("many", "dynamic"), ("fig11", "subscreen")], repeat)
    if args.full:
        out["end_to_end"] = end_to_end_rows(("fig11", "many"), 1024, 16, max(1, repeat - 1))
    meta["load_avg_at_end"] = os.getloadavg()
    RESULTS.mkdir(parents=True, exist_ok=True)
    stem = "partition_overhead_quick" if args.quick and not args.full else "partition_overhead"  # keep --full's
    (RESULTS / f"{stem}.json").write_text(json.dumps(out, indent=2))
    (RESULTS / f"{stem}.md").write_text(markdown(out) + "\n")
    return 0


def markdown(out):
    m = out["meta"]
    lines = ["# Partitioning overhead and gain", "",
             f"Command: `{m['command']}`; machine: {m['machine']}; load average at the end {m.get('load_avg_at_end')}.",
             f"{m['note']} (median of {m['repeat']}).", "",
             "## Per-launch overhead, one process (targets: 64 units <= 1.15, 256 units <= 1.3, batched <= 1.05)",
             "", "| renderer | scene | res | full frame ms | 64 launches / frame | 256 launches / frame | "
             "64 units in 2 batches / frame | per launch ms |", "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in out["overhead"]:
        if "error" in r:
            lines.append(f"| {r['renderer']} | {r['scene']} | {r['res']} | – | – | – | – | {r['error']} |")
            continue
        b = "–" if r["batched_ratio"] is None else f"{r['batched_ratio']:.2f}"
        lines.append(f"| {r['renderer']} | {r['scene']} | {r['res']} | {r['full_s'] * 1e3:.1f} | {r['ratio64']:.2f} | "
                     f"{r['ratio256']:.2f} | {b} | {r['per_launch_ms']:.2f} |")
    lines += ["", "## `links1 schedule --nodes 2`, 512², spp 1, Mitsuba renderer (target: true efficiency >= 0.85)", "",
              "| scene | strategy | makespan ms | one node, full frame ms | true efficiency | busy efficiency | "
              "imbalance | launches |", "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in out["schedule"]:
        if "error" in r:
            lines.append(f"| {r['scene']} | {r['strategy']} | {r['error']} | | | | | |")
            continue
        lines.append(f"| {r['scene']} | {r['strategy']} | {r['makespan_s'] * 1e3:.1f} | {r['full_frame_s'] * 1e3:.1f} | "
                     f"{r['true_efficiency']:.3f} | {r['parallel_efficiency']:.3f} | {r['imbalance']:.3f} | "
                     f"{r['launches']:.0f} |")
    if out.get("end_to_end"):
        lines += ["", "## End to end, `links1 render` wall time, 1024², spp 16, Mitsuba renderer (target <= 1.1)", "",
                  "| scene | in-process, one unit s | --workers 2 s (ratio) | --dask-local 2 s (ratio) |",
                  "| --- | --- | --- | --- |"]
        for r in out["end_to_end"]:
            if "error" in r:
                lines.append(f"| {r['scene']} | {r['error']} | | |")
                continue
            w, q = r["wall_s"], r["ratio"]
            lines.append(f"| {r['scene']} | {w['in-process, one unit']:.2f} | {w['--workers 2']:.2f} "
                         f"({q['--workers 2']:.2f}) | {w['--dask-local 2']:.2f} ({q['--dask-local 2']:.2f}) |")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
