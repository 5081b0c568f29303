"""Is the schedule simulator right? Simulated vs measured makespan per strategy and node count.
A benchmark, not a test.

For each renderer, node count and repeat: the real runs of every strategy (``links1
schedule``'s code path: the same backends, plans, reference and report), then

* **self**: the simulator replaying a run's own strategy and node count with the costs
  fitted in that run (cost model from units launched alone; per-launch, per-unit, speed
  scale, transfer and dispatch fitted on the run's launches and tasks): the report's
  ``simulator_check``. It checks the work split between units and nodes and the hand-out
  (batched static tasks, guided chunks with two in flight), not the overheads' size, which
  are fitted on that run.
* **cross**: the simulator, with the costs fitted on the ``dynamic/tile`` run of the same
  repeat and node count, predicting every other strategy (what ``--simulate`` does for
  strategies it did not run).

Medians over the repeats (this machine is shared: each repeat measures every strategy
back to back). Node count 1 renders in-process, as ``links1 schedule --nodes 1`` does.

Usage: ``.venv/bin/python -m compare.simulator_check [--repeat 3] [--nodes 1,2]
[--renderers core,mitsuba] [--core-res 128] [--mitsuba-res 256] [--out NAME]``; writes
``compare/results/NAME.{json,md}`` (default ``simulator_check``).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from argparse import Namespace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "compare" / "results"
STRATEGIES = ("subscreen", "scanline", "grid", "dynamic/tile", "dynamic/scanline")


def _args(renderer, res, strategy, nodes):
    part, _, unit = strategy.partition("/")
    return Namespace(scene=str(ROOT / "scenes" / "many.xml"), renderer=renderer, variant=None, integrator="links1",
                     spp=None, width=None, height=None, max_depth=None, seed=0, aov=["cost"],
                     defines=[("res", str(res))], min_weight=None, light_samples=None, adaptive=None,
                     adaptive_depth=None, sensor=None, no_progress=True, partition=part, unit=unit or "tile",
                     tiles_per_node=16, chunk_factor=None, chunk_by="units", order=None, scheduler=None,
                     dask_local=None, checkpoint=None, cull=False, load_table=None,
                     workers=0 if nodes == 1 else nodes)


def one_repeat(renderer, res, nodes, ref_repeat):
    """Every strategy once on ``nodes`` nodes; the reference once -> {strategy: report + work map}."""
    from links1_app.partition import cli as pcli
    from links1_app.partition.executors import render_plan
    from links1_app.partition.report import build_report
    from links1_app.partition.schedule import single_node_reference
    from links1_app.partition.simulator import check_simulator, work_map
    from links1.tracing.aovs import aov_channel
    out, ref = {}, None
    for strategy in STRATEGIES:
        args = _args(renderer, res, strategy, nodes)
        spec, model, channels, plan, backend = pcli.prepare(args, nodes=nodes)
        res_ = render_plan(plan, spec, backend, progress=False)
        if ref is None:  # one reference per repeat (strategy-independent: units launched alone)
            ref = single_node_reference(backend, spec, ref_repeat)
        cc = aov_channel(channels, "cost")
        rep = build_report(res_, plan, model, cost_channel=cc, reference=ref,
                           meta={"spp": spec.kwargs.get("spp")}, chunk_factor=backend.chunk_factor,
                           chunk_by=backend.chunk_by, task_pixels=backend.task_pixels)
        tests = res_.image[..., cc]
        rep["simulator_check"] = check_simulator(rep, tests, model)
        out[strategy] = {"report": rep, "work": work_map(rep, tests), "model": model}
    return out


def cross(results, nodes, source="dynamic/tile"):
    """The costs fitted on ``source``'s run predicting every strategy at ``nodes``."""
    from links1_app.partition.simulator import simulate
    src = results[source]
    rows = simulate(src["work"], src["model"], [nodes], strategies=STRATEGIES, overheads=src["report"]["overheads"],
                    full_frame_s=src["report"]["full_frame_s"])
    return {r["strategy"]: r["makespan_s"] for r in rows}


def machine():
    info = {"platform": platform.platform(), "cores": os.cpu_count()}
    try:
        info["cpu"] = next(ln.split(":", 1)[1].strip() for ln in open("/proc/cpuinfo") if ln.startswith("model name"))
    except (OSError, StopIteration):
        pass
    try:
        info["loadavg"] = os.getloadavg()
    except OSError:
        pass
    try:
        info["git"] = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                                     text=True).stdout.strip()
    except OSError:
        pass
    return info


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--nodes", default="1,2")
    ap.add_argument("--renderers", default="core,mitsuba")
    ap.add_argument("--core-res", type=int, default=128)
    ap.add_argument("--mitsuba-res", type=int, default=256)
    ap.add_argument("--reference-repeat", type=int, default=1)
    ap.add_argument("--out", default="simulator_check")
    a = ap.parse_args(argv)
    nodes_list = [int(v) for v in a.nodes.split(",")]
    info = machine()
    load0 = info.get("loadavg")
    raw, table = [], []
    t_start = time.time()
    for renderer in a.renderers.split(","):
        res = a.core_res if renderer == "core" else a.mitsuba_res
        for n in nodes_list:
            per = {s: {"measured": [], "self": [], "cross": [], "spread": [], "own": []} for s in STRATEGIES}
            for k in range(a.repeat):
                results = one_repeat(renderer, res, n, a.reference_repeat)
                cr = cross(results, n)
                for s in STRATEGIES:
                    rep = results[s]["report"]
                    m, sc = rep["makespan_s"], rep["simulator_check"]
                    per[s]["measured"].append(m)
                    per[s]["self"].append(sc["simulated_s"])
                    per[s]["cross"].append(cr[s])
                    per[s]["spread"].append(sc.get("node_speed_spread") or 1.0)
                    per[s]["own"].append(sc["simulated_node_speeds_s"])
                    raw.append({"renderer": renderer, "res": res, "nodes": n, "repeat": k, "strategy": s,
                                "measured_s": m, "self_s": sc["simulated_s"], "cross_s": cr[s],
                                "own_speeds_s": sc["simulated_node_speeds_s"],
                                "true_efficiency": rep["true_efficiency"], "busy_efficiency": rep["busy_efficiency"],
                                "launches": rep["launches"], "overheads": rep["overheads"],
                                "cost_model": rep["cost_model"], "full_frame_s": rep["full_frame_s"]})
                    print(f"{renderer:8s} {res:4d} n={n} #{k} {s:17s} measured {m * 1e3:8.1f} ms  self "
                          f"{sc['simulated_s'] * 1e3:8.1f} ({(sc['simulated_s'] / m - 1) * 100:+6.1f} %)  cross "
                          f"{cr[s] * 1e3:8.1f} ({(cr[s] / m - 1) * 100:+6.1f} %)", file=sys.stderr, flush=True)
                from links1_app.partition import cli as pcli
                pcli.close_backends()
            for s in STRATEGIES:
                m = float(np.median(per[s]["measured"]))
                errs_self = [x / y - 1 for x, y in zip(per[s]["self"], per[s]["measured"])]
                errs_cross = [x / y - 1 for x, y in zip(per[s]["cross"], per[s]["measured"])]
                errs_own = [x / y - 1 for x, y in zip(per[s]["own"], per[s]["measured"])]
                table.append({"renderer": renderer, "res": res, "nodes": n, "strategy": s, "measured_s": m,
                              "self_s": float(np.median(per[s]["self"])),
                              "self_err": float(np.median(errs_self)),
                              "self_err_max": float(max(errs_self, key=abs)),
                              "own_err": float(np.median(errs_own)),
                              "cross_s": float(np.median(per[s]["cross"])),
                              "cross_err": float(np.median(errs_cross)),
                              "cross_err_max": float(max(errs_cross, key=abs)),
                              "measured_spread": float(np.ptp(per[s]["measured"]) / m) if m > 0 else None,
                              "node_speed_spread": float(np.median(per[s]["spread"]))})
    try:
        info["loadavg_end"] = os.getloadavg()
    except OSError:
        pass
    info["loadavg_start"] = load0
    info["minutes"] = round((time.time() - t_start) / 60, 1)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{a.out}.json").write_text(json.dumps({"machine": info, "args": vars(a), "table": table,
                                                       "raw": raw}, indent=1, default=float))
    lines = [f"# Simulator check: simulated vs measured makespan (many.xml, `python -m compare.simulator_check "
             f"--repeat {a.repeat} --nodes {a.nodes} --renderers {a.renderers}`)", "",
             f"Machine: {info.get('cpu', '?')}, {info.get('cores')} cores, {info.get('platform')}; git "
             f"{info.get('git')}; load average at start {load0}, at end {info.get('loadavg_end')}; "
             f"{info['minutes']} min.", "",
             "Medians over the repeats. *self*: the run's own strategy and node count replayed with the costs fitted "
             "in that run. *cross*: every strategy predicted from the `dynamic/tile` run of the same repeat. "
             "*own speeds*: self, with each node at its own measured speed (what is left is the hand-out, transfer "
             "and assembly model). *max*: the worst repeat. *spread*: (max - min) / median of the measured makespans. *node speeds*: "
             "the slowest node's launch time over the cost model's / the fastest node's (median; 1 = the nodes "
             "ran at one speed, which is what the replay assumes).", "",
             "| renderer | res | nodes | strategy | measured ms | self ms | self err | self max | own speeds err | cross ms "
             "| cross err "
             "| cross max | spread | node speeds |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in table:
        lines.append(f"| {r['renderer']} | {r['res']} | {r['nodes']} | {r['strategy']} | {r['measured_s'] * 1e3:.1f} | "
                     f"{r['self_s'] * 1e3:.1f} | {r['self_err'] * 100:+.1f} % | {r['self_err_max'] * 100:+.1f} % | "
                     f"{r['own_err'] * 100:+.1f} % | "
                     f"{r['cross_s'] * 1e3:.1f} | {r['cross_err'] * 100:+.1f} % | {r['cross_err_max'] * 100:+.1f} % | "
                     f"{r['measured_spread'] * 100:.0f} % | {r['node_speed_spread']:.2f} |")
    within = sum(abs(r["self_err"]) <= 0.10 for r in table)
    within_c = sum(abs(r["cross_err"]) <= 0.10 for r in table)
    within_o = sum(abs(r["own_err"]) <= 0.10 for r in table)
    lines += ["", f"Within 10 % (median): self {within} of {len(table)}, own speeds {within_o} of {len(table)}, "
                  f"cross {within_c} of {len(table)}."]
    (RESULTS / f"{a.out}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
