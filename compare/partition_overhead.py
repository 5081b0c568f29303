"""Per-unit overhead of tiled rendering (issue 4 §2): a frame rendered as 64 units in one
process versus the same frame in one piece, for each renderer. Target: ratio <= 1.15.

Usage: ``.venv/bin/python -m compare.partition_overhead [--quick]``; writes
``compare/results/partition_overhead.{json,md}``. A benchmark, not a test: the machine is
shared and noisy, so each figure is the best of ``repeat`` runs measured in the same process.
"""
from __future__ import annotations

import argparse
import json
import platform
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "compare" / "results"


def run(cases, repeat):
    from links1.partition.experiment import measure_overhead
    from links1.partition.runtime import RendererSpec
    rows = []
    for kind, scene, res in cases:
        try:
            spec = RendererSpec.make(kind, str(ROOT / "scenes" / f"{scene}.xml"), params={"res": str(res)})
            r = measure_overhead(spec, n_units=64, repeat=repeat)
        except Exception as e:  # noqa: BLE001 - a renderer that cannot run here is reported, not fatal
            rows.append({"renderer": kind, "scene": scene, "res": res, "error": f"{type(e).__name__}: {e}"})
            continue
        rows.append({"renderer": kind, "scene": scene, "res": res, **r})
        print(f"{kind:8s} {scene:8s} {res:4d}  full {r['full_s'] * 1e3:8.1f} ms  64 units "
              f"{r['tiled_s'] * 1e3:8.1f} ms  ratio {r['ratio']:.2f}", file=sys.stderr)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    # 512 x 512 is the paper's frame; smaller frames show the fixed cost per unit.
    cases = [("core", "fig11", 128), ("core", "fig11", 256), ("core", "fig11", 512), ("core", "many", 512),
             ("mitsuba", "fig11", 256), ("mitsuba", "fig11", 512), ("mitsuba", "many", 512)]
    if args.quick:
        cases = [c for c in cases if c[2] <= 256]
    rows = run(cases, repeat=2 if args.quick else 3)
    meta = {"command": "python -m compare.partition_overhead" + (" --quick" if args.quick else ""),
            "machine": {"cpu": platform.processor() or platform.machine(), "python": platform.python_version(),
                        "cores": __import__("os").cpu_count()}, "target_ratio": 1.15}
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "partition_overhead.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=2))
    lines = ["# Tiled-render overhead: 64 units vs one frame (target <= 1.15)", "",
             f"Command: `{meta['command']}`; machine: {meta['machine']}", "",
             "| renderer | scene | res | full frame ms | 64 units ms | ratio |", "| --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['renderer']} | {r['scene']} | {r['res']} | – | – | {r['error']} |")
        else:
            lines.append(f"| {r['renderer']} | {r['scene']} | {r['res']} | {r['full_s'] * 1e3:.1f} | "
                         f"{r['tiled_s'] * 1e3:.1f} | {r['ratio']:.2f} |")
    (RESULTS / "partition_overhead.md").write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
