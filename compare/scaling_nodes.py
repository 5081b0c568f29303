"""Speed-up and true efficiency against node count. A benchmark, not a test.

For each renderer, scene, resolution and node count, every strategy is run for real on
``links1 schedule``'s code path (same plans, backends and report), each node with **one
thread** (the paper's definition: N one-thread nodes against one node with one thread; the
plugin's Dr.Jit thread count is set to 1 in every node and in this process), repeated
``--repeat`` times. Next to every run, the one-process frame is measured on node 0 (its one
thread, warm, the other nodes idle): the whole frame as one launch. Per run:

* speed-up = one-process frame / makespan; **true efficiency** = frame / (nodes x makespan);
* the report's ``time_split``: the shares of nodes x makespan that went to
  work, launch overhead (derived from the cost model), slowdown (nodes slower than the
  reference), dispatch, transfer and waiting (measured). Where a target is missed, the largest
  share that is not work is named: that is what stops it.

Medians over the repeats, with the spread of the true efficiency (min-max) to say how noisy the
machine was. Node count 1 renders in-process (as ``links1 schedule --nodes 1`` does).

Targets: core at 512^2, spp 1, many and fig11: true efficiency >= 0.9 at 2 nodes
(>= 0.85 at 8, >= 0.7 at 16 on a 16-core machine); the plugin (one thread per node) >= 0.85 at
2 nodes.

Usage::

    .venv/bin/python -m compare.scaling_nodes [--nodes 1,2] [--scenes many,fig11]
        [--renderers core,mitsuba] [--res 512] [--big] [--repeat 3] [--strategies ...]
        [--reference-repeat 1] [--out scaling_nodes]

``--big`` adds 1024^2. Writes ``compare/results/OUT.{json,md,png}``. On the 16-core device
machine: ``--nodes 1,2,4,8,16 --renderers core`` (docs/partitioning.md says how).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from argparse import Namespace
from pathlib import Path

import numpy as np

from compare.simulator_check import machine

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "compare" / "results"
STRATEGIES = ("subscreen", "scanline", "grid", "dynamic/tile", "dynamic/scanline", "subscreen-balanced")
PARTS = ("work", "launch_overhead", "slowdown", "dispatch", "transfer", "waiting")
TARGETS = {("core", 2): 0.9, ("core", 8): 0.85, ("core", 16): 0.7, ("mitsuba", 2): 0.85}


def _args(renderer, scene, res, strategy, nodes, spp):
    part, _, unit = strategy.partition("/")
    return Namespace(scene=str(ROOT / "scenes" / f"{scene}.xml"), renderer=renderer, variant=None,
                     integrator="links1", spp=spp, width=None, height=None, max_depth=None, seed=0, aov=["cost"],
                     defines=[("res", str(res))], min_weight=None, light_samples=None, adaptive=None,
                     adaptive_depth=None, sensor=None, no_progress=True, partition=part, unit=unit or "tile",
                     tiles_per_node=16, chunk_factor=None, chunk_by="units", order=None, scheduler=None,
                     dask_local=None, checkpoint=None, cull=False, load_table=None,
                     workers=0 if nodes == 1 else nodes)


def one_thread(renderer):
    """This process renders with one thread (the one-node runs are in-process)."""
    from links1_app.partition.runtime import set_threads
    if renderer == "mitsuba":
        import drjit
        import mitsuba  # noqa: F401
        drjit.set_thread_count(1)
    set_threads(1, renderer)


def capacity(pool, spec, alone_s):
    """What this machine gives N one-thread processes at once, measured: every node renders the
    whole frame at the same time; N x (the frame alone on node 0) / (the slowest of them). N on a
    machine with N free cores; less where other work takes cores (this shared VM)."""
    from links1_app.partition.costmodel import frame_seconds
    futs = [pool.pools[k].submit(frame_seconds, spec) for k in range(pool.n)]
    together = [f.result(timeout=600) for f in futs]
    return pool.n * alone_s / max(together)


def run_point(renderer, scene, res, nodes, strategies, repeat, ref_repeat, spp):
    """Every strategy ``repeat`` times on ``nodes`` one-thread nodes -> raw rows."""
    from functools import partial

    from links1_app.partition import cli as pcli
    from links1_app.partition.executors import render_plan
    from links1_app.partition.local_pool import LocalPool
    from links1_app.partition.costmodel import frame_seconds
    from links1_app.partition.report import build_report
    from links1_app.partition.schedule import single_node_reference
    from links1.tracing.aovs import aov_channel
    rows, ref, cap = [], None, {}
    for k in range(repeat):
        for strategy in strategies:
            args = _args(renderer, scene, res, strategy, nodes, spp)
            spec, model, channels, plan, backend = pcli.prepare(args, nodes=nodes)
            if isinstance(backend, LocalPool):
                backend.threads = 1   # one thread per node, whatever the cores
            res_ = render_plan(plan, spec, backend, progress=False)
            if ref is None:  # the cost model's units launched alone, once per point
                ref = single_node_reference(backend, spec, ref_repeat)
            frame = backend.call(partial(frame_seconds, repeat=1), spec)   # node 0, right after the run
            if isinstance(backend, LocalPool) and cap.get(k) is None:
                cap[k] = capacity(backend, spec, frame)
            cc = aov_channel(channels, "cost")
            rep = build_report(res_, plan, model, cost_channel=cc, reference=ref,
                               meta={"spp": spec.kwargs.get("spp")}, chunk_factor=backend.chunk_factor,
                               chunk_by=backend.chunk_by, task_pixels=backend.task_pixels)
            ts = rep["time_split"]
            m = rep["makespan_s"]
            row = {"renderer": renderer, "scene": scene, "res": res, "nodes": nodes, "strategy": strategy,
                   "repeat": k, "makespan_s": m, "frame_s": frame, "speedup": frame / m,
                   "true_efficiency": frame / (nodes * m), "true_efficiency_reference": rep["true_efficiency"],
                   "busy_efficiency": rep["busy_efficiency"], "imbalance": rep["imbalance"],
                   "launches": rep["launches"], "scale": (rep.get("overheads") or {}).get("scale"),
                   "shares": ts["shares"], "root": ts["root"], "startup_s": ts["startup_s"],
                   "per_launch_s": (rep.get("cost_model") or {}).get("per_launch_s"),
                   "capacity": cap.get(k, 1.0 if nodes == 1 else None), "off_cpu": ts.get("off_cpu_share")}
            rows.append(row)
            print(f"{renderer:8s} {scene:6s} {res:5d} n={nodes:2d} #{k} {strategy:17s} makespan {m * 1e3:8.1f} ms "
                  f"frame {frame * 1e3:8.1f} ms  true eff {row['true_efficiency']:.3f}  "
                  + " ".join(f"{p} {ts['shares'][p]:.2f}" for p in PARTS), file=sys.stderr, flush=True)
    pcli.close_backends()
    return rows


def _median(v):
    v = [x for x in v if x is not None]
    return float(np.median(v)) if v else None


def at_run_speed(row) -> dict:
    """A run's shares with work and launch overhead at the speed of the frame measured right after
    it (``frame_s``) rather than the reference's (measured once per point, maybe in a slower or
    faster minute of this shared machine): both times f = frame_s / reference frame, the
    difference moved to slowdown, so that the work share is the true efficiency (less one
    launch constant) and the shares still add up to 1."""
    sh = dict(row["shares"])
    te, te_ref = row.get("true_efficiency"), row.get("true_efficiency_reference")
    if not te or not te_ref:
        return sh
    f = te / te_ref
    moved = (1.0 - f) * (sh["work"] + sh["launch_overhead"])
    sh["work"] *= f
    sh["launch_overhead"] *= f
    sh["slowdown"] += moved
    return sh


def summarise(raw):
    """Medians per (renderer, scene, res, strategy, nodes); shares at each run's own speed."""
    keys = sorted({(r["renderer"], r["scene"], r["res"], r["strategy"], r["nodes"]) for r in raw},
                  key=lambda t: (t[0], t[1], t[2], t[3], t[4]))
    table = []
    for key in keys:
        rs = [r for r in raw if (r["renderer"], r["scene"], r["res"], r["strategy"], r["nodes"]) == key]
        te = [r["true_efficiency"] for r in rs]
        med = {p: float(np.median([at_run_speed(r)[p] for r in rs])) for p in PARTS}
        target = TARGETS.get((key[0], key[4])) if key[2] == 512 else None
        te_m = float(np.median(te))
        stop = None
        if target is not None and te_m < target:
            stop = max((p for p in PARTS if p != "work"), key=lambda p: med[p])
        table.append({"renderer": key[0], "scene": key[1], "res": key[2], "strategy": key[3], "nodes": key[4],
                      "frame_s": float(np.median([r["frame_s"] for r in rs])),
                      "makespan_s": float(np.median([r["makespan_s"] for r in rs])),
                      "speedup": float(np.median([r["speedup"] for r in rs])),
                      "true_efficiency": te_m, "te_min": float(min(te)), "te_max": float(max(te)),
                      "makespan_spread": float(np.ptp([r["makespan_s"] for r in rs]) /
                                               np.median([r["makespan_s"] for r in rs])),
                      "imbalance": float(np.median([r["imbalance"] or 1.0 for r in rs])),
                      "launches": float(np.median([r["launches"] for r in rs])),
                      "shares": med, "target": target, "met": None if target is None else te_m >= target,
                      "stopped_by": stop, "repeats": len(rs),
                      "capacity": _median([r.get("capacity") for r in rs]),
                      "off_cpu": _median([r.get("off_cpu") for r in rs]),
                      "efficiency_of_capacity": _median([r["speedup"] / r["capacity"] for r in rs
                                                         if r.get("capacity")])})
    return table


def plot(table, path):
    from links1_app.partition.plots import pyplot, save_figure
    plt = pyplot()
    groups = sorted({(r["renderer"], r["scene"], r["res"]) for r in table})
    fig, axes = plt.subplots(2, len(groups), figsize=(4.2 * len(groups), 7.5), squeeze=False)
    colours = {s: f"C{i}" for i, s in enumerate(STRATEGIES)}
    pcol = {"work": "#2ca02c", "launch_overhead": "#ff7f0e", "slowdown": "#d62728", "dispatch": "#9467bd",
            "transfer": "#1f77b4", "waiting": "#bdbdbd"}
    for j, g in enumerate(groups):
        ax = axes[0][j]
        rows = [r for r in table if (r["renderer"], r["scene"], r["res"]) == g]
        for s in STRATEGIES:
            rs = sorted((r for r in rows if r["strategy"] == s), key=lambda r: r["nodes"])
            if not rs:
                continue
            n = [r["nodes"] for r in rs]
            ax.errorbar(n, [r["true_efficiency"] for r in rs],
                        yerr=[[r["true_efficiency"] - r["te_min"] for r in rs],
                              [r["te_max"] - r["true_efficiency"] for r in rs]],
                        marker="o", capsize=3, color=colours[s], label=s)
        caps = sorted({(r["nodes"], r["capacity"]) for r in rows if r.get("capacity")})
        if caps:  # the best true efficiency this machine allowed at that moment (measured)
            cn = sorted({n for n, _ in caps})
            ax.plot(cn, [np.median([c for n2, c in caps if n2 == n]) / n for n in cn], "k--", linewidth=1,
                    label="machine capacity / nodes")
        for (rend, n), t in TARGETS.items():
            if rend == g[0] and g[2] == 512 and n <= max(r["nodes"] for r in rows):
                ax.plot([n], [t], marker="_", markersize=18, color="k")
        ax.axhline(1.0, color="k", linewidth=0.5, linestyle=":")
        ax.set_ylim(0, 1.1)
        ax.set_xscale("log", base=2)
        ax.set_xticks(sorted({r["nodes"] for r in rows}), [str(v) for v in sorted({r["nodes"] for r in rows})])
        ax.set_title(f"{g[0]} {g[1]} {g[2]}²: true efficiency\n(median, bars min-max; black: target)", fontsize=9)
        ax.set_xlabel("nodes (one thread each)")
        if j == 0:
            ax.set_ylabel("one-process frame / (nodes x makespan)")
            ax.legend(fontsize=7)
        ax = axes[1][j]
        top = max(r["nodes"] for r in rows)
        rs = [r for s in STRATEGIES for r in rows if r["strategy"] == s and r["nodes"] == top]
        bottom = np.zeros(len(rs))
        for p in PARTS:
            v = np.array([r["shares"][p] for r in rs])
            ax.bar(range(len(rs)), np.clip(v, 0, None), bottom=bottom, color=pcol[p], label=p)
            bottom += np.clip(v, 0, None)
        ax.set_xticks(range(len(rs)), [r["strategy"] for r in rs], rotation=30, fontsize=7)
        ax.set_title(f"where nodes x makespan went at {top} nodes (median shares)", fontsize=9)
        if j == 0:
            ax.legend(fontsize=6)
    fig.tight_layout()
    save_figure(fig, str(path))
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--nodes", default="1,2")
    ap.add_argument("--scenes", default="many,fig11")
    ap.add_argument("--renderers", default="core,mitsuba")
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--big", action="store_true", help="also 1024^2")
    ap.add_argument("--spp", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--reference-repeat", type=int, default=1)
    ap.add_argument("--strategies", default=",".join(STRATEGIES))
    ap.add_argument("--out", default="scaling_nodes")
    ap.add_argument("--resummarise", action="store_true",
                    help="re-read compare/results/OUT.json's raw runs and rewrite its table, md and plot")
    a = ap.parse_args(argv)
    if a.resummarise:
        data = json.loads((RESULTS / f"{a.out}.json").read_text())
        table = summarise(data["raw"])
        data["table"] = table
        (RESULTS / f"{a.out}.json").write_text(json.dumps(data, indent=1, default=float))
        plot(table, RESULTS / f"{a.out}.png")
        md = markdown(table, data["machine"], Namespace(**data["args"]))
        (RESULTS / f"{a.out}.md").write_text(md)
        print(md)
        return
    nodes_list = [int(v) for v in a.nodes.split(",")]
    strategies = [s for s in a.strategies.split(",") if s]
    info = machine()
    load0 = info.get("loadavg")
    t0 = time.time()
    raw = []
    for renderer in a.renderers.split(","):
        one_thread(renderer)
        for scene in a.scenes.split(","):
            for res in [a.res] + ([1024] if a.big else []):
                for n in nodes_list:
                    raw += run_point(renderer, scene, res, n, strategies, a.repeat, a.reference_repeat, a.spp)
    try:
        info["loadavg_end"] = os.getloadavg()
    except OSError:
        pass
    info["loadavg_start"] = load0
    info["minutes"] = round((time.time() - t0) / 60, 1)
    table = summarise(raw)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{a.out}.json").write_text(json.dumps({"machine": info, "args": vars(a), "table": table, "raw": raw},
                                                      indent=1, default=float))
    plot(table, RESULTS / f"{a.out}.png")
    md = markdown(table, info, a)
    (RESULTS / f"{a.out}.md").write_text(md)
    print(md)


def _f(v):
    return "" if v is None else f"{v:.2f}"


def _nondefault(a) -> str:
    """The options of the run besides those the title names, where not their defaults."""
    return "".join(f" --{k.replace('_', '-')} {v}" for k, v, default in
                   (("spp", a.spp, 1), ("strategies", a.strategies, ",".join(STRATEGIES)), ("out", a.out, "scaling_nodes"))
                   if v != default)


def markdown(table, info, a) -> str:
    lines = [f"# Speed-up and true efficiency against node count (`python -m compare.scaling_nodes --nodes {a.nodes} "
             f"--scenes {a.scenes} --renderers {a.renderers} --res {a.res}{' --big' if a.big else ''} --repeat "
             f"{a.repeat}{_nondefault(a)}`)", "",
             f"Machine: {info.get('cpu', '?')}, {info.get('cores')} cores, {info.get('platform')}; git {info.get('git')}; "
             f"load average at start {info.get('loadavg_start')}, at end {info.get('loadavg_end')}; "
             f"{info.get('minutes')} min.", "",
             "Every node renders with one thread; node count 1 renders in-process. *frame*: the one-process frame "
             "(the whole frame as one launch on node 0, one thread, measured right after each run). *true eff*: "
             "frame / (nodes x makespan), median over the repeats, [min-max]. *spread*: (max - min) / median of the "
             "makespans. The shares split nodes x makespan (the report's `time_split`, medians): work and launch "
             "overhead derived from the cost model, rescaled to the speed of the frame measured right after the run "
             "(so work is the true efficiency less one launch constant), slowdown = measured launches - both (nodes "
             "slower than one node alone: contention, drift), dispatch, transfer, waiting measured. *stopped by*: "
             "where a target is missed, the largest share that is not work. *capacity*: the speed-up this "
             "machine gave N one-thread processes at that moment, measured (every node rendering the whole frame "
             "at once: N x frame alone / the slowest; N with N free cores); *of capacity*: speed-up / capacity, "
             "the partitioning's efficiency on the cores it got. *off-CPU*: the part of nodes x makespan the nodes spent "
             "inside launches without a core (launch wall time - the node's CPU time, measured in the node; "
             "inside slowdown): contention, not work that fails to scale.", "",
             "| renderer | scene | res | strategy | nodes | frame ms | makespan ms | speed-up | true eff [min-max] "
             "| spread | launches | work | launch ovh | slowdown | dispatch | transfer | waiting | target | stopped by "
             "| capacity | of capacity | off-CPU |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- "
             "| --- | --- | --- | --- | --- |"]
    for r in table:
        sh = r["shares"]
        tgt = "" if r["target"] is None else f"{r['target']:.2f} {'met' if r['met'] else 'missed'}"
        lines.append(f"| {r['renderer']} | {r['scene']} | {r['res']} | {r['strategy']} | {r['nodes']} | "
                     f"{r['frame_s'] * 1e3:.0f} | {r['makespan_s'] * 1e3:.0f} | {r['speedup']:.2f}x | "
                     f"{r['true_efficiency']:.2f} [{r['te_min']:.2f}-{r['te_max']:.2f}] | "
                     f"{r['makespan_spread'] * 100:.0f} % | {r['launches']:.0f} | "
                     + " | ".join(f"{sh[p]:.2f}" for p in PARTS) + f" | {tgt} | {r['stopped_by'] or ''} | "
                     f"{_f(r['capacity'])} | {_f(r['efficiency_of_capacity'])} | {_f(r.get('off_cpu'))} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
