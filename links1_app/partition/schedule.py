"""``links1 schedule``: a root/node screen-partitioning experiment on real nodes.

One run (or a sweep of strategies x node counts x unit sizes) rendered as ``links1 render``
would render it (:mod:`.cli`'s set-up), then its report (:mod:`.report`, with the cost model of
:mod:`.costmodel`), the simulator's replay of it (:mod:`.simulator`) and the plots
(:mod:`.plots`). docs/partitioning.md, "Reading the report".
"""
from __future__ import annotations

import argparse
import copy
import os
import sys
import warnings
from functools import partial

from links1.errors import UsageError
from links1.partition.strategies import STRATEGIES as KNOWN, UNITS
from links1.tracing.aovs import aov_channel

from ..cli_options import add_progress_arguments, add_render_arguments, progress_choice
from ..renderers import require_mitsuba
from .checkpoint import atomic_write_bytes, atomic_write_json
from .cli import close_backends, cull_map, partition_options, positive, prepare
from .costmodel import measure_overhead
from .executors import render_plan
from .plots import plot_report, plot_simulation, plot_sweep
from .report import build_report, efficiency_text, share_text
from .simulator import check_simulator, format_table, simulate, work_map


def _nodes_list(text):
    try:
        v = [int(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"--simulate expects a list like 1,4,16,64, got {text!r}") from None
    if not v or min(v) < 1:
        raise argparse.ArgumentTypeError(f"--simulate node counts must be >= 1, got {text!r}")
    return v


SCHEDULE_EXAMPLES = """examples:
  links1 schedule scenes/many.xml --renderer core --nodes 2 --partition dynamic --report r.json --plot r.png
  links1 schedule scenes/many.xml --renderer core --nodes 2 --partition subscreen --tiles-per-node 64 \\
      --report s.json --simulate 1,4,16,64,256,1024 --sim-plot sim.png
  links1 schedule scenes/fig11.xml --nodes 4 --dask-local 4 --partition scanline --report d.json
"""


def add_cli(subparsers) -> None:
    """Add ``links1 schedule`` to the main parser's subcommands."""
    p = subparsers.add_parser("schedule", help="run a root/node screen-partitioning experiment",
                              epilog=SCHEDULE_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter,
                              description="Render a scene on N nodes with a partitioning strategy and report per "
                              "unit predicted load (eq. 4.1), measured seconds and ray-primitive tests, per node busy "
                              "time, makespan, imbalance, parallel efficiency; optionally simulate more nodes.")
    add_render_arguments(p)
    p.add_argument("--nodes", type=positive("--nodes"), default=None,
                   help="node count (local worker processes); required unless --sweep")
    partition_options(p, nodes_option=True)
    p.add_argument("--report", required=True, metavar="OUT.json", help="write the report here (JSON, atomic)")
    p.add_argument("--plot", default=None, metavar="OUT.png", help="Gantt chart per node + predicted-vs-measured")
    p.add_argument("--simulate", type=_nodes_list, default=None, metavar="1,4,16,...",
                   help="replay the measured cost map at these node counts")
    p.add_argument("--sim-plot", default=None, metavar="OUT.png", help="simulation plot (default: next to --plot)")
    p.add_argument("--launch-overhead", type=float, default=None, metavar="S",
                   help="simulated seconds per launch (default: the cost model's constant, fitted on units "
                        "launched alone in this run)")
    p.add_argument("--unit-overhead", type=float, default=None, metavar="S",
                   help="simulated seconds per further unit in a launch (default: fitted on this run's launches)")
    p.add_argument("--object-cost", type=float, default=0.0, metavar="S",
                   help="simulated seconds per object sent to a node (default 0: local and Dask nodes load the "
                        "whole scene before the clock starts; set it to model 4-4 shipping)")
    p.add_argument("--reference-repeat", type=positive("--reference-repeat"), default=3, metavar="N",
                   help="the single-process reference (full frame, 64 one-unit launches, 2 batches): "
                        "medians of N rounds after one warm-up (default 3)")
    g = p.add_argument_group("sweep: strategies x node counts x unit sizes in one command")
    g.add_argument("--sweep", action="store_true",
                   help="run every strategy of --sweep-strategies at every node count of --sweep-nodes and tiles per "
                        "node of --sweep-tiles; --report gets one tidy table (JSON, and CSV next to it), --plot the "
                        "makespan, imbalance and true efficiency against node count: measured points, simulated curves")
    g.add_argument("--sweep-strategies", default="subscreen,scanline,grid,dynamic/tile,dynamic/scanline",
                   metavar="S,S", help="strategies (dynamic/tile, dynamic/scanline name the unit); default all five")
    g.add_argument("--sweep-nodes", type=_nodes_list, default=[1, 2], metavar="1,2",
                   help="node counts run for real (default 1,2)")
    g.add_argument("--sweep-tiles", type=_nodes_list, default=[16], metavar="4,16",
                   help="tiles per node (the unit size of subscreen, grid and dynamic tiles; default 16)")
    g.add_argument("--sweep-simulate", type=_nodes_list, default=[1, 2, 4, 8, 16, 32, 64], metavar="1,2,...",
                   help="node counts of the simulated curves (default 1,2,4,...,64)")
    add_progress_arguments(p)
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    p.set_defaults(func=run_cli)


def run_cli(args) -> int:
    """``links1 schedule``: a real run, its report, optional plots and simulation."""
    if args.renderer == "mitsuba":
        require_mitsuba(args.variant)
    if args.plot or args.sim_plot:  # matplotlib is an extra: say so before rendering, not after
        try:   # lazy: matplotlib is optional (links1[plot]); plots.py imports it when it draws
            import matplotlib  # noqa: F401, PLC0415
        except ImportError:
            opt = "--plot" if args.plot else "--sim-plot"
            raise UsageError(f"{opt} needs matplotlib, which is not installed; "
                             "pip install 'links1[plot]'") from None
    aovs = tuple(args.aov or ())
    if "cost" not in aovs:
        args.aov = aovs + ("cost",)  # the per-pixel ray-primitive tests: the measured cost map
    if args.sweep:
        return run_sweep(args)
    if args.nodes is None:
        raise UsageError("schedule needs --nodes N (or --sweep)")
    report, model, tests, plan = _one_run(args, args.nodes, close=True)
    if args.simulate:
        wm = work_map(report, tests) if tests is not None else None
        if wm is None:
            warnings.warn("no cost model (no units launched alone with the cost AOV): nothing to simulate")
        else:
            ov = dict(report["overheads"])
            if args.launch_overhead is not None:
                ov["per_launch_s"] = args.launch_overhead
            if args.unit_overhead is not None:
                ov["per_unit_s"] = args.unit_overhead
            rows = simulate(wm, model, args.simulate, tiles_per_node=args.tiles_per_node, overheads=ov,
                            object_cost=args.object_cost, full_frame_s=report.get("full_frame_s"),
                            in_process_one=not (args.scheduler or args.dask_local))
            report["simulation"] = {"overheads": ov, "object_cost_s": args.object_cost,
                                    "source": "simulated: the work map (cost_model on exact ray tests) replayed "
                                              "as the backends hand out work, with the overheads above",
                                    "rows": rows}
            print(format_table(rows))
            sim_plot = args.sim_plot or (os.path.splitext(args.plot)[0] + "-simulate.png" if args.plot else None)
            if sim_plot:
                plot_simulation(rows, sim_plot)
    atomic_write_json(args.report, report)
    if args.plot:
        plot_report(report, args.plot)
    print(summary_line(report, plan.strategy) + f"; wrote {args.report}", file=sys.stderr)
    return 0


def _one_run(args, nodes, *, close, reference=None):
    """One real run of ``args`` on ``nodes`` nodes -> (report, model, ray tests map, plan)."""
    args.workers = 0 if nodes == 1 and not (args.scheduler or args.dask_local) else nodes
    spec, model, channels, plan, backend = prepare(args, nodes=nodes)
    cull = cull_map(plan, model, spec) if args.cull else None
    res = render_plan(plan, spec, backend, progress=progress_choice(args), cull=cull)
    if reference is None:
        reference = single_node_reference(backend, spec, args.reference_repeat)
    if close:
        backend.close()
    cost_channel = aov_channel(channels, "cost")
    report = build_report(res, plan, model, cost_channel=cost_channel, reference=reference,
                          meta={"scene": os.path.abspath(args.scene), "renderer": args.renderer,
                                "cull": bool(args.cull), "spp": spec.kwargs.get("spp"),
                                "chunk_factor": getattr(backend, "chunk_factor", None),
                                "chunk_by": getattr(backend, "chunk_by", None)},
                          chunk_factor=getattr(backend, "chunk_factor", None),
                          chunk_by=getattr(backend, "chunk_by", None),
                          task_pixels=getattr(backend, "task_pixels", None))
    tests = res.image[..., cost_channel] if cost_channel is not None else None
    if tests is not None:
        report["simulator_check"] = check_simulator(report, tests, model)
    return report, model, tests, plan


SWEEP_FIELDS = ("kind", "strategy", "tiles_per_node", "nodes", "makespan_s", "imbalance", "busy_efficiency",
                "true_efficiency", "launches", "units", "full_frame_s", "scale", "simulated_s")


def run_sweep(args) -> int:
    """``links1 schedule --sweep``: strategies x node counts x tiles per node, measured and simulated."""
    names = [v.strip() for v in args.sweep_strategies.split(",") if v.strip()]
    for name in names:
        part, _, unit = name.partition("/")
        if part not in KNOWN or (unit and (part != "dynamic" or unit not in UNITS)):
            raise UsageError(f"--sweep-strategies: unknown strategy {name!r}; choose from subscreen, scanline, grid, "
                             "dynamic/tile, dynamic/scanline, subscreen-balanced")
    rows, refs, runs = [], {}, {}
    for tpn in args.sweep_tiles:
        for n in args.sweep_nodes:
            for name in names:
                part, _, unit = name.partition("/")
                a = copy.copy(args)
                a.partition, a.unit, a.tiles_per_node = part, unit or "tile", tpn
                rep, model, tests, _ = _one_run(a, n, close=False, reference=refs.get(n))
                refs.setdefault(n, rep["reference"])   # one reference per node count
                chk = rep.get("simulator_check") or {}
                rows.append({"kind": "measured", "strategy": name, "tiles_per_node": tpn, "nodes": rep["nodes"],
                             "makespan_s": rep["makespan_s"], "imbalance": rep["imbalance"],
                             "busy_efficiency": rep["busy_efficiency"], "true_efficiency": rep["true_efficiency"],
                             "launches": rep["launches"], "units": len(rep["units"]),
                             "full_frame_s": rep["full_frame_s"], "scale": (rep.get("overheads") or {}).get("scale"),
                             "simulated_s": chk.get("simulated_s")})
                runs[(name, tpn, n)] = (rep, model, tests)
                print(f"links1: sweep {name} tiles/node {tpn} on {n} nodes: makespan {rep['makespan_s']:.4f} s "
                      f"(measured), simulated {chk.get('simulated_s') or float('nan'):.4f} s, true efficiency "
                      f"{efficiency_text(rep['true_efficiency'], rep.get('true_efficiency_spread'))}",
                      file=sys.stderr)
        close_backends()
    # simulated curves: each strategy and unit size from its run on the most nodes measured
    top = max(args.sweep_nodes)
    for tpn in args.sweep_tiles:
        for name in names:
            rep, model, tests = runs[(name, tpn, top)]
            wm = work_map(rep, tests) if tests is not None else None
            if wm is None:
                continue
            for r in simulate(wm, model, args.sweep_simulate, strategies=(name,), tiles_per_node=tpn,
                              overheads=rep["overheads"], full_frame_s=rep["full_frame_s"],
                              in_process_one=not (args.scheduler or args.dask_local)):
                rows.append({"kind": "simulated", "strategy": name, "tiles_per_node": tpn, "nodes": r["nodes"],
                             "makespan_s": r["makespan_s"], "imbalance": r["imbalance"],
                             "busy_efficiency": r["efficiency"], "true_efficiency": r["true_efficiency"],
                             "launches": r["launches"], "units": r["units"], "full_frame_s": rep["full_frame_s"],
                             "scale": rep["overheads"]["scale"], "simulated_s": r["makespan_s"]})
    out = {"scene": os.path.abspath(args.scene), "renderer": args.renderer, "film": list(runs[next(iter(runs))][0]
                                                                                          ["film"]),
           "measured_nodes": args.sweep_nodes, "simulated_nodes": args.sweep_simulate,
           "sources": {"kind=measured": "a real run (makespan: root clock; true efficiency: one-process frame / "
                                        "(nodes x makespan)); simulated_s: the simulator replaying that run",
                       "kind=simulated": "the simulator with the costs fitted on the run of the same strategy and "
                                         f"unit size on {top} nodes"},
           "rows": rows}
    atomic_write_json(args.report, out)
    csv = os.path.splitext(args.report)[0] + ".csv"
    lines = [",".join(SWEEP_FIELDS)] + [",".join("" if r.get(k) is None else str(r[k]) for k in SWEEP_FIELDS)
                                        for r in rows]
    atomic_write_bytes(csv, ("\n".join(lines) + "\n").encode())
    if args.plot:
        plot_sweep(out, args.plot)
    print(f"links1: sweep of {len(names)} strategies x {len(args.sweep_nodes)} node counts x "
          f"{len(args.sweep_tiles)} unit sizes: {sum(r['kind'] == 'measured' for r in rows)} runs measured, "
          f"{sum(r['kind'] == 'simulated' for r in rows)} points simulated; wrote {args.report} and {csv}"
          + (f" and {args.plot}" if args.plot else ""), file=sys.stderr)
    return 0


def single_node_reference(backend, spec, repeat=3):
    """The same renderer on one node (its threads, warm): full frame, 64 one-unit launches, the
    64 units in 2 batches, measured in the same run after the partitioned render."""
    try:
        return backend.call(partial(measure_overhead, repeat=repeat), spec)
    except Exception as e:  # noqa: BLE001 - e.g. a cluster whose renderer this machine lacks
        warnings.warn(f"no single-process reference here ({type(e).__name__}: {e}); true efficiency not reported")
        return None


def summary_line(report, strategy) -> str:
    """One line, every figure named with its source (docs/partitioning.md, "Reading the report")."""
    def f(v, nd=3):
        return "n/a" if v is None else f"{v:.{nd}f}"
    pl = (report.get("reference") or {}).get("per_launch_overhead_s")
    rc = report["rank_correlation"]
    us = report.get("unit_seconds") or {}
    cm = report.get("cost_model") or {}
    chk = report.get("simulator_check")
    sim = "" if not chk else (f"; simulator on this run: {f(chk['simulated_s'], 4)} s simulated vs "
                              f"{f(chk['measured_s'], 4)} s measured ({chk['error'] * 100:+.1f} %)")
    return (f"links1: schedule {strategy} on {report['nodes']} nodes: "
            f"TRUE EFFICIENCY {efficiency_text(report.get('true_efficiency'), report.get('true_efficiency_spread'))}"
            f" (one-process frame {f(report.get('full_frame_s'))} s"
            f" / ({report['nodes']} x makespan {f(report['makespan_s'])} s), measured); "
            f"busy efficiency {f(report['parallel_efficiency'])} (node busy / (nodes x makespan): counts overhead "
            f"as busy), imbalance {f(report['imbalance'])} (measured busy), "
            f"{report.get('launches')} launches, per-launch overhead "
            f"{f(None if pl is None else pl * 1e3, 2)} ms (measured); "
            f"unit seconds: {us.get('measured', 0)} measured (launched alone), {us.get('derived', 0)} derived "
            f"(cost model fitted on {cm.get('fitted_on_units', 0)} units launched alone); "
            f"rank correlation of predicted load (eq. 4.1) with measured seconds "
            f"{f(rc.get('predicted_vs_measured_seconds'))} (n={rc.get('n_measured')}), with exact ray tests "
            f"{f(rc.get('predicted_vs_ray_tests'))} (n={rc.get('n_units')})" + sim + split_phrase(report))


def split_phrase(report) -> str:
    """Where the makespan went (the report's ``time_split``), as shares of nodes x makespan."""
    ts = report.get("time_split")
    if not ts:
        return ""
    sh = ts["shares"]
    su = [v for v in (ts.get("startup_s") or {}).values() if v is not None]
    return ("; nodes x makespan went to " + ", ".join(share_text(k, v) for k, v in sh.items())
            + " (work, launch overhead: derived; the rest measured)"
            + (f", start-up before the clock {max(su):.2f} s (measured)" if su else ""))
