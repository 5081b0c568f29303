"""The schedule report of one real run (``links1 schedule``) and where its makespan went.

Every figure says where it comes from (``sources`` in the report): **measured** (a clock
around real work), **exact** (a count), **derived** (a model fitted in the same run applied to
exact counts) or **simulated**.

Report (``links1 schedule ... --report OUT.json``) keys
------------------------------------------------------
scene, renderer, strategy, unit, order, tiles_per_node, backend, film [w, h], nodes, spp
units[]            per unit: index, window [x0, y0, w, h] (row 0 at the top), node, pixels,
                   predicted_load (eq. 4.1), ray_tests (exact: the cost AOV's ray-primitive
                   tests), camera_rays (exact: pixels x spp), seconds + seconds_source:
                   ``measured`` when the unit was launched alone (its launch's own clock), else
                   ``derived`` = cost_model(pixels, ray_tests): the seconds it would take launched
                   alone; work_s (derived: cost_model without its per-launch constant); launch
                   (id), launch_seconds (measured), launch_units, task; start/stop (seconds from
                   the first launch's start: the launch's span, node clocks)
nodes_busy[]       per node: node, busy_s (measured: the sum of its launches), units, launches
makespan_s         measured, root clock, first dispatch to last result (scene loading excluded)
full_frame_s       measured: the same renderer and options rendering the whole frame as one
                   launch on one node, in the same run (median of --reference-repeat)
true_efficiency    the headline: full_frame_s / (nodes * makespan_s) (1 = perfect speed-up)
parallel_efficiency  busy efficiency: sum(busy) / (nodes * makespan_s); blind to per-launch
                   overhead (it counts as busy); also under busy_efficiency
imbalance          max(busy) / mean(busy) over the nodes (measured busy)
launches           kernel launches in the run; per node in nodes_busy[]
reference          measure_overhead(): full frame, 64 one-unit launches, 2 batches,
                   per_launch_overhead_s, and alone_units[] (each tile launched alone: window,
                   pixels, ray_tests, seconds measured, median over the rounds)
cost_model         fitted on units launched alone (the reference's tiles and full frame and the
                   run's units launched alone): seconds = per_launch_s + per_pixel_s * pixels
                   + per_test_s * ray_tests (relative least squares, coefficients >= 0)
overheads          fitted on this run: per_launch_s, per_unit_s, scale (work in a batched launch
                   / the alone model's), transfer_s + transfer_per_pixel_s (a task's result from
                   its last launch's end to the root), dispatch_s (root sends -> node starts)
rank_correlation   Spearman, named: predicted_vs_measured_seconds (units launched alone, n in
                   n_measured), predicted_vs_ray_tests (the run's units, exact cost),
                   ray_tests_vs_measured_seconds
simulator_check    the simulator replaying this run's own strategy and node count with the
                   fitted costs: simulated_s, measured_s, error
time_split         where the makespan went: per node work_s, launch_overhead_s (derived
                   from the cost model), slowdown_s (measured launches - both), dispatch_s,
                   transfer_s, waiting_s (measured), adding up to makespan_s, and startup_s
                   (before the clock); root: dispatch_s, assembly_s, rendering_s (in-process),
                   waiting_s (adding up), planning_s, root_load_s (before the clock); totals,
                   shares (each part summed over nodes / (nodes x makespan)), segments (the
                   Gantt chart's intervals, seconds from the first dispatch), sources
sources            figure -> measured | exact | derived | simulated, in words
load_table, data_per_node[], faults
simulation         (with --simulate) overheads used and rows {strategy, nodes, units, launches,
                   makespan_s, imbalance, efficiency (busy), true_efficiency, objects...}
"""
from __future__ import annotations

import numpy as np

from links1.partition.strategies import unit_loads

from .costmodel import fit_cost_model, fit_overheads, spearman, unit_work
from .handout import CHUNK_FACTOR, TASK_PIXELS

SOURCES = {
    "makespan_s": "measured: root clock, first dispatch to last result",
    "full_frame_s": "measured: the whole frame as one launch on one node, same run",
    "true_efficiency": "measured: full_frame_s / (nodes x makespan_s); above 1 only by noise (the "
                       "one-process frame is measured slower than it is)",
    "true_efficiency_spread": "measured: [fastest, slowest] of the one-process frame's trials / (nodes x "
                              "makespan_s): what the reference's noise alone moves the true efficiency by",
    "parallel_efficiency": "busy efficiency (measured): sum of node busy / (nodes x makespan_s); "
                           "per-launch overhead counts as busy",
    "imbalance": "measured: max / mean node busy",
    "nodes_busy[].busy_s": "measured: the sum of the node's launches",
    "units[].seconds": "per unit, see units[].seconds_source: measured (launched alone) or derived "
                       "(cost_model applied to the unit's exact counts)",
    "units[].ray_tests": "exact: the cost AOV (ray-primitive tests)",
    "units[].camera_rays": "exact: pixels x spp",
    "units[].launch_seconds": "measured: the launch the unit was part of",
    "cost_model": "fitted on units launched alone (reference tiles, full frame, the run's lone units)",
    "overheads": "fitted on this run's launches and tasks",
    "rank_correlation.predicted_vs_measured_seconds": "over units launched alone (measured times)",
    "rank_correlation.predicted_vs_ray_tests": "over the run's units (exact counts)",
    "simulator_check": "simulated (this run's strategy and nodes, fitted costs) vs measured makespan",
    "simulation": "simulated",
}



def _cut(intervals, lo, hi) -> list:
    """The union of ``intervals`` within [lo, hi] as sorted disjoint (a, b) pieces."""
    out = []
    for a, b in sorted((max(a, lo), min(b, hi)) for a, b in intervals if min(b, hi) > max(a, lo)):
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out


#: node time categories inside the makespan, in the order the Gantt chart stacks them
NODE_PARTS = ("work_s", "launch_overhead_s", "slowdown_s", "dispatch_s", "transfer_s", "waiting_s")
ROOT_PARTS = ("dispatch_s", "assembly_s", "rendering_s", "waiting_s")

TIME_SPLIT_SOURCES = {
    "work_s": "derived: the cost model's work (pixels and exact ray tests) of the node's units, at the "
              "reference's speed (one node alone); summed over nodes it is the one-process frame less one "
              "launch constant",
    "launch_overhead_s": "derived: the cost model's constant per launch (+ per further unit in a launch) for the "
                         "node's launches, at the reference's speed",
    "slowdown_s": "measured launch time - work - launch overhead: the node ran slower (> 0) or faster (< 0) "
                  "than the reference: contention for cores, the machine's drift",
    "launch_cpu_s": "measured, beside the parts: the node's CPU time (all its threads) in its launches",
    "off_cpu_s": "measured, beside the parts (inside launch time): launch wall time - its CPU time, i.e. the "
                 "node waiting for a core (other processes on it: the part of slowdown that is contention)",
    "dispatch_s": "measured: first dispatch (the clock's start) to the node's first launch",
    "transfer_s": "measured: node not in a launch while one of its results is on its way to the root "
                  "(readied, written or pickled and sent, until the root holds it); in-process: its results "
                  "readied and placed in the frame",
    "waiting_s": "measured: the rest: the node idle with nothing to do (no task queued, or done while "
                 "others work)",
    "startup_s": "measured, before the clock (not in the makespan): process start, scene load, warm-up",
    "root.dispatch_s": "measured: the root handing tasks to nodes (submit calls)",
    "root.assembly_s": "measured: the root placing units' pixels in the frame (and the checkpoint)",
    "root.rendering_s": "measured: in-process, the root renders (its launches)",
    "root.waiting_s": "measured: the rest (the root waiting for results; the pool's thread receiving them)",
    "root.planning_s": "measured, before the clock: scene model (eq. 4.1 load map) and plan",
    "root.root_load_s": "measured, before the clock: the root reading the scene",
}


def time_split(result, launches, tasks, cm, *, planning=None) -> dict:
    """Where the makespan went: per node ``NODE_PARTS`` and for the root
    ``ROOT_PARTS``, each adding up to ``makespan_s`` (the node's clock read against the root's
    wall clock: ``t0_wall`` = first dispatch, the end = ``t0_wall + makespan_s``).

    ``launches``: [{node, start, stop, seconds, units, work}] (wall clock; ``work``: the cost
    model's work of its units), ``tasks``: [{node, stop, received}]; ``cm``: the cost model
    (None: a launch is all work). Start-up and planning happen before the clock and are given
    beside it. ``shares``: each part summed over nodes / (nodes x makespan): ``work`` is about
    the true efficiency, the others say what took the rest.
    """
    T0 = getattr(result, "t0_wall", None)
    span = float(result.makespan_s or 0.0)
    if T0 is None or span <= 0:
        return None
    T1 = T0 + span
    ev = list(getattr(result, "root_events", None) or [])
    in_process = getattr(result, "backend", "") == "inprocess"
    per_launch = (cm or {}).get("per_launch_s", 0.0) or 0.0
    per_unit = (cm or {}).get("per_unit_s", 0.0) or 0.0
    nodes = sorted({str(ln["node"]) for ln in launches} | {str(k) for k in range(int(result.n_nodes or 0))})
    out_nodes, segments = {}, {}
    startup = {str(k): v for k, v in (getattr(result, "startup_s", None) or {}).items()}
    for k in nodes:
        mine = sorted((ln for ln in launches if str(ln["node"]) == k), key=lambda ln: ln["start"])
        busy = _cut([(ln["start"], ln["stop"]) for ln in mine], T0, T1)
        launch_s = sum(b - a for a, b in busy)
        if cm is not None:
            work = sum(ln["work"] for ln in mine)
            ovh = sum(per_launch + per_unit * (ln["units"] - 1) for ln in mine)
        else:
            work, ovh = launch_s, 0.0
        first = busy[0][0] if busy else T1
        gaps = []   # the node's time outside launches, after its first launch
        at = first
        for a, b in busy:
            if a > at:
                gaps.append((at, a))
            at = max(at, b)
        if T1 > at:
            gaps.append((at, T1))
        flight = [(t["stop"], t["received"]) for t in tasks if str(t["node"]) == k and t.get("received") is not None]
        if in_process:  # the node is the root: placing its results in the frame is its transfer
            flight += [(a, b) for kind, a, b in ev if kind == "assembly"]
        xfer = [piece for g in gaps for piece in _cut(flight, *g)]
        transfer = sum(b - a for a, b in xfer)
        dispatch = first - T0
        waiting = span - launch_s - dispatch - transfer
        cpu = [ln.get("cpu_s") for ln in mine]
        known = bool(mine) and all(c is not None and ln.get("seconds") is not None for c, ln in zip(cpu, mine))
        out_nodes[k] = {"work_s": work, "launch_overhead_s": ovh, "slowdown_s": launch_s - work - ovh,
                        "dispatch_s": dispatch, "transfer_s": transfer, "waiting_s": waiting,
                        "launches_s": launch_s, "total_s": span, "startup_s": startup.get(k),
                        # beside the parts, not one of them (within launch time): the node's CPU
                        # time in its launches, and the launch time it spent off its core
                        "launch_cpu_s": sum(cpu) if known else None,
                        "off_cpu_s": sum(max(0.0, ln["seconds"] - c) for c, ln in zip(cpu, mine)) if known else None}
        rel = (lambda iv: [round(iv[0] - T0, 6), round(iv[1] - T0, 6)])
        segments[k] = {"dispatch": [rel((T0, first))] if first > T0 else [],
                       "launch": [rel(iv) + [ln["work"] if cm is not None else iv[1] - iv[0],
                                             per_launch + per_unit * (ln["units"] - 1) if cm is not None else 0.0]
                                  for iv, ln in zip(busy, mine)] if len(busy) == len(mine) else
                       [rel(iv) + [None, None] for iv in busy],
                       "transfer": [rel(iv) for iv in xfer]}
    disp = sum(b - a for a, b in _cut([(a, b) for kind, a, b in ev if kind == "dispatch"], T0, T1))
    asm = sum(b - a for a, b in _cut([(a, b) for kind, a, b in ev if kind == "assembly"], T0, T1))
    rendering = sum(v["launches_s"] for v in out_nodes.values()) if in_process else 0.0
    root = {"dispatch_s": disp, "assembly_s": asm, "rendering_s": rendering,
            "waiting_s": span - disp - asm - rendering, "total_s": span}
    root.update({k: v for k, v in (planning or {}).items()})
    segments["root"] = {kind: [[round(a - T0, 6), round(b - T0, 6)] for a, b in
                               _cut([(a, b) for kd, a, b in ev if kd == kind], T0, T1)]
                        for kind in ("dispatch", "assembly")}
    n = max(len(nodes), 1)
    totals = {p: sum(v[p] for v in out_nodes.values()) for p in NODE_PARTS}
    return {"makespan_s": span, "nodes": out_nodes, "root": root, "totals": totals,
            "shares": {p.removesuffix("_s"): totals[p] / (n * span) for p in NODE_PARTS},
            "off_cpu_share": (sum(v["off_cpu_s"] for v in out_nodes.values()) / (n * span)
                              if all(v["off_cpu_s"] is not None for v in out_nodes.values()) else None),
            "startup_s": {k: v.get("startup_s") for k, v in out_nodes.items()},
            "segments": segments, "sources": dict(TIME_SPLIT_SOURCES)}


def build_report(result, plan, model, *, cost_channel=None, meta=None, reference=None,
                 in_process=None, chunk_factor=None, chunk_by="units", task_pixels=None, planning=None) -> dict:
    """The schedule report of one real run (see the module docstring for the keys)."""
    recs = result.records
    img = result.image
    spp = (meta or {}).get("spp")
    load_map = model.load_map() if model is not None else None
    raw = []
    for i, u in enumerate(plan.units):
        r = recs.get(i)
        if r is None:
            continue
        tests = float(img[u.y0:u.y0 + u.h, u.x0:u.x0 + u.w, cost_channel].sum()) if cost_channel is not None else None
        raw.append((i, u, r, tests))
    # units launched alone: measured times (the reference's tiles and frame, and the run's lone units)
    alone = [a for a in ((reference or {}).get("alone_units") or []) if a.get("ray_tests") is not None]
    frame = next((a for a in alone if a.get("frame")), None)
    tiles = [a for a in alone if not a.get("frame")]
    run_alone = [(i, u, r, t) for i, u, r, t in raw if r.get("launch_units", 1) == 1 and t is not None]
    cm = fit_cost_model([a["pixels"] for a in tiles] + [u.pixels for _, u, _, _ in run_alone],
                        [a["ray_tests"] for a in tiles] + [t for *_, t in run_alone],
                        [a["seconds"] for a in tiles] + [r.get("launch_seconds", r["seconds"])
                                                         for _, _, r, _ in run_alone],
                        frame=frame, per_launch_s=(reference or {}).get("per_launch_overhead_s"))
    if cm is not None:
        cm["per_unit_s"], cm["per_unit_fit"] = 0.0, "none (no batched reference)"
        if frame is not None and (reference or {}).get("batched_s") is not None and len(tiles) > 2:
            # the reference's 2 batches of the tiles: 2 launches + (tiles - 2) further units + the frame's work
            u = (reference["batched_s"] - reference["full_s"] - cm["per_launch_s"]) / (len(tiles) - 2)
            cm["per_unit_s"] = max(0.0, float(u))
            cm["per_unit_fit"] = "the reference's 2 batches: (batched - frame - per_launch) / (tiles - 2)"
        cm["fitted_on"] = (f"{len(tiles)} tiles{' and the frame' if frame else ''} launched alone in the reference, "
                           f"{len(run_alone)} units launched alone in the run")
    t0 = min((r["start"] for _, _, r, _ in raw), default=0.0)
    units, launches, tasks = [], {}, {}
    for i, u, r, tests in raw:
        lid = tuple(r.get("launch", ("unit", i)))
        n_in = int(r.get("launch_units", 1))
        ln = launches.setdefault(lid, {"node": r["node"], "seconds": r.get("launch_seconds"),
                                       "cpu_s": r.get("launch_cpu_s"), "units": 0,
                                       "start": r["start"], "stop": r["stop"], "work": 0.0, "pixels": 0,
                                       "sum_s": 0.0})
        ln["units"] += 1
        ln["pixels"] += u.pixels
        ln["sum_s"] += r["seconds"]
        ln["start"], ln["stop"] = min(ln["start"], r["start"]), max(ln["stop"], r["stop"])
        work = float(unit_work(cm, u.pixels, tests)) if cm is not None and tests is not None else None
        ln["work"] += work or 0.0
        tk = tasks.setdefault((r["node"],) + tuple(r.get("task", lid)), {"stop": r["stop"], "received": r.get("received"),
                                                          "pixels": 0, "node": r["node"], "wire": 0.0})
        tk["stop"] = max(tk["stop"], r["stop"])
        tk["pixels"] += u.pixels
        tk["wire"] += r.get("wire_s") or 0.0
        if r.get("received") is not None:  # the root starts on the task's results at the first
            tk["received"] = min(tk["received"] or r["received"], r["received"])
        if n_in == 1:
            secs, src = r.get("launch_seconds", r["seconds"]), "measured"
        elif work is not None:
            secs, src = cm["per_launch_s"] + work, "derived"
        else:
            secs, src = None, "unavailable"
        units.append({"index": i, "window": list(u.window), "node": r["node"], "pixels": u.pixels,
                      "predicted_load": None if plan.predicted is None else float(plan.predicted[i]),
                      "ray_tests": tests, "camera_rays": None if spp is None else u.pixels * int(spp),
                      "seconds": secs, "seconds_source": src, "work_s": work,
                      "launch": list(lid), "launch_units": n_in, "task": list(r.get("task", lid)),
                      "start": ln["start"] - t0, "stop": ln["stop"] - t0})
    for ln in launches.values():
        if ln["seconds"] is None:
            ln["seconds"] = ln["sum_s"]
    for u in units:  # the launch's measured span (start/stop) once all its units are in
        ln = launches[tuple(u["launch"])]
        u["start"], u["stop"], u["launch_seconds"] = ln["start"] - t0, ln["stop"] - t0, ln["seconds"]
    busy = {}
    for ln in launches.values():
        b = busy.setdefault(str(ln["node"]), [0.0, 0, 0])
        b[0] += ln["seconds"]
        b[1] += ln["units"]
        b[2] += 1
    n = max(result.n_nodes, len(busy), 1)
    busy_s = [v[0] for v in busy.values()] + [0.0] * (n - len(busy))
    makespan = result.makespan_s or 1e-12
    mean = float(np.mean(busy_s)) if busy_s else 0.0
    # rank correlations, named by what they compare
    # (over units launched alone: the reference's tiles and the run's lone units, not the whole frame)
    a_pred = list(unit_loads([_Win(a["window"]) for a in tiles], load_map)) if load_map is not None and tiles \
        else []
    a_pred += [u["predicted_load"] for u in units if u["seconds_source"] == "measured"] if load_map is not None \
        else []
    a_secs = [a["seconds"] for a in tiles] + [u["seconds"] for u in units if u["seconds_source"] == "measured"]
    a_tests = [a["ray_tests"] for a in tiles] + [u["ray_tests"] for u in units if u["seconds_source"] == "measured"]
    pred = [u["predicted_load"] for u in units]
    tests = [u["ray_tests"] for u in units]
    in_process = (result.backend == "inprocess") if in_process is None else in_process
    first = {}
    for ln in launches.values():
        first[ln["node"]] = min(first.get(ln["node"], ln["start"]), ln["start"])
    overheads = None
    if cm is not None:
        overheads = fit_overheads(
            list(launches.values()),
            [{"gap": tk["received"] - tk["stop"] - tk["wire"], "pixels": tk["pixels"]} for tk in tasks.values()
             if tk["received"] is not None],
            list(first.values()), getattr(result, "t0_wall", None), cm, in_process=in_process,
            unit_costs=[{"pixels": u.pixels, "wire_s": r.get("wire_s"), "root_s": r.get("root_s")}
                        for _, u, r, _ in raw])
        overheads.update(chunk_factor=CHUNK_FACTOR if chunk_factor is None else int(chunk_factor),
                         chunk_by=chunk_by or "units", task_pixels=task_pixels or TASK_PIXELS, spp=spp or 1)
    full = None if reference is None else reference["full_s"]
    rep = dict(meta or {})
    rep.update({
        "strategy": plan.strategy, "film": [plan.width, plan.height], "nodes": n,
        "tiles_per_node": plan.meta.get("tiles_per_node"), "unit": plan.meta.get("unit"),
        "order": plan.meta.get("order"), "backend": result.backend,
        "units": units,
        "nodes_busy": [{"node": k, "busy_s": v[0], "units": v[1], "launches": v[2]} for k, v in busy.items()],
        "launches": len(launches),
        "makespan_s": makespan,
        "full_frame_s": full,
        "true_efficiency": None if full is None else full / (n * makespan),
        "true_efficiency_spread": ([min(trials) / (n * makespan), max(trials) / (n * makespan)]
                                   if (trials := (reference or {}).get("full_trials_s")) else None),
        "parallel_efficiency": min(1.0, float(np.sum(busy_s)) / (n * makespan)) if makespan > 0 else None,
        "imbalance": (max(busy_s) / mean) if mean > 0 else None,
        "unit_seconds": {"measured": sum(u["seconds_source"] == "measured" for u in units),
                         "derived": sum(u["seconds_source"] == "derived" for u in units),
                         "unavailable": sum(u["seconds_source"] == "unavailable" for u in units)},
        "rank_correlation": {
            "predicted_vs_measured_seconds": spearman(a_pred, a_secs) if len(a_pred) == len(a_secs) else None,
            "predicted_vs_ray_tests": spearman(pred, tests) if None not in pred and None not in tests else None,
            "ray_tests_vs_measured_seconds": spearman(a_tests, a_secs),
            "n_measured": len(a_secs), "n_units": len(units),
        },
        "reference": reference,
        "data_per_node": model.node_data(plan) if model is not None else None,
        "load_table": model.meta.get("load_table") if model is not None else None,
        "faults": list(result.faults),
        "cost_model": cm,
        "overheads": overheads,
        "sources": dict(SOURCES),
    })
    rep["busy_efficiency"] = rep["parallel_efficiency"]
    rep["time_split"] = time_split(result, list(launches.values()), list(tasks.values()), cm,
                                   planning=planning if planning is not None else plan.meta.get("timing"))
    return rep



class _Win:
    """A window as :func:`unit_loads` reads it."""

    def __init__(self, window):
        self.x0, self.y0, self.w, self.h = (int(v) for v in window)


def efficiency_text(value, spread=None) -> str:
    """A true efficiency as the report prints it. Above 1 a split frame would beat the one-process
    frame, which uses every core itself: that figure is the reference's noise, so it reads as 1
    with the measured value and the spread the reference's own trials give (``spread``:
    :func:`build_report`'s ``true_efficiency_spread``)."""
    if value is None:
        return "n/a"
    if value <= 1.0:
        return f"{value:.3f}"
    trials = f"; the one-process frame's trials give {spread[0]:.3f} to {spread[1]:.3f}" if spread else ""
    if spread and spread[0] > 1.0:
        return (f"1 at most (measured {value:.3f}: above 1 even at the fastest reference trial{trials}; "
                "the reference ran slower than this run's nodes, rerun with more --reference-repeat)")
    return f"1 within noise (measured {value:.3f}{trials})"


def share_text(part: str, share: float) -> str:
    """A share of nodes x makespan (``time_split``'s ``shares``) as the report prints it: a
    negative one (a part is a difference of measured and derived times) is noise, said so."""
    name = part.replace("_", " ")
    if share >= -0.005:
        return f"{name} {max(share, 0.0) * 100:.0f} %"
    if part == "slowdown":
        return (f"slowdown 0 % (the launches took {-share * 100:.0f} % less than the work and overhead "
                "derived at the reference's speed: the reference's noise)")
    return f"{name} 0 % (measured {share * 100:.0f} %: noise)"


