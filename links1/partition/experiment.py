"""Tile-scheduling experiments: the schedule report, the cost model, the simulator and the plots.

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

import heapq
import os
import time
from collections import deque

import numpy as np

from .strategies import make_plan, unit_loads

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


def rank(a) -> np.ndarray:
    """Ranks with ties averaged (for Spearman's rho)."""
    a = np.asarray(a, dtype=np.float64)
    order = np.argsort(a, kind="stable")
    r = np.empty(len(a))
    r[order] = np.arange(len(a), dtype=np.float64)
    _, inv, counts = np.unique(a, return_inverse=True, return_counts=True)
    sums = np.bincount(inv, weights=r)
    return (sums / counts)[inv]


def spearman(a, b) -> float | None:
    """Spearman rank correlation, None when undefined (fewer than 3 values or a constant)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if len(a) < 3:
        return None
    ra, rb = rank(a), rank(b)
    if ra.std() == 0 or rb.std() == 0:
        return None
    return float(np.corrcoef(ra, rb)[0, 1])


def nnls(A, b) -> np.ndarray:
    """Least squares with coefficients >= 0 (negative ones are dropped and the rest refitted)."""
    A, b = np.asarray(A, float), np.asarray(b, float)
    free = np.ones(A.shape[1], dtype=bool)
    while True:
        x = np.zeros(A.shape[1])
        if free.any():
            x[free] = np.linalg.lstsq(A[:, free], b, rcond=None)[0]
        if (x >= 0).all() or not free.any():
            return np.clip(x, 0.0, None)
        free &= x > 0


def fit_cost_model(pixels, tests, seconds, *, frame=None, per_launch_s=None) -> dict | None:
    """Cost of a unit launched alone: ``seconds = per_launch_s + per_pixel_s * pixels +
    per_test_s * tests`` (coefficients >= 0), fitted on units that were launched alone.

    With ``frame`` (the whole frame launched alone: {pixels, ray_tests, seconds}) and
    ``per_launch_s`` (the reference's measured launch constant, (64 one-unit launches - frame)
    / 63): the units fix how work splits between pixels and tests (least squares of
    ``seconds - per_launch_s``), the frame fixes how much work there is (both terms scaled so
    the frame costs its measured seconds). Without them: least squares over the three
    terms. None with fewer than 3 units."""
    pixels, tests, seconds = (np.asarray(v, float) for v in (pixels, tests, seconds))
    if len(seconds) < 3:
        return None
    if frame is not None and per_launch_s is not None and frame.get("ray_tests") is not None:
        L = float(per_launch_s)
        x = nnls(np.stack([pixels, tests], axis=1), seconds - L)
        f = np.array([frame["pixels"], frame["ray_tests"]], float)
        if not (x @ f) > 0:
            x = np.array([1.0, 0.0])
        k = (float(frame["seconds"]) - L) / float(x @ f)
        if k <= 0:  # the frame costs less than a launch constant: keep the work, drop the constant
            L, k = 0.0, float(frame["seconds"]) / float(x @ f)
        coef = np.array([L, k * x[0], k * x[1]])
        how = "units launched alone: the work split fitted on the tiles, scaled to the frame launched alone"
    else:
        coef = nnls(np.stack([np.ones_like(pixels), pixels, tests], axis=1), seconds)
        how = "least squares over units launched alone"
    pred = coef[0] + coef[1] * pixels + coef[2] * tests
    ok = seconds > 0
    return {"per_launch_s": float(coef[0]), "per_pixel_s": float(coef[1]), "per_test_s": float(coef[2]),
            "fitted_on_units": int(len(seconds)) + (frame is not None), "fit": how,
            "relative_rms": float(np.sqrt(np.mean((pred - seconds) ** 2)) / np.mean(seconds))
            if ok.any() else None}


def unit_work(cm, pixels, tests):
    """Derived seconds of work (the cost model without its per-launch constant)."""
    return cm["per_pixel_s"] * np.asarray(pixels, float) + cm["per_test_s"] * np.asarray(tests, float)


def _fit_per_unit(values, pixels):
    """``a + b * pixels`` (>= 0) over units, least squares; the mean when the units are all one
    size (not the median: a rare long pause, a garbage collection, is part of the expected cost)."""
    v, p = np.asarray(values, float), np.asarray(pixels, float)
    if len(v) == 0:
        return 0.0, 0.0
    if len(v) >= 3 and np.ptp(p) > 0:
        a, b = nnls(np.stack([np.ones_like(p), p], axis=1), v)
        return float(a), float(b)
    return float(np.mean(v)), 0.0


def fit_overheads(launches, tasks, first_starts, t0_wall, cm, *, in_process=False, unit_costs=None) -> dict:
    """Per-launch, per-unit, scale and transfer costs of this run, fitted on its records.

    ``launches``: [{seconds, units, work}] (measured launch time, units in it, derived work);
    ``tasks``: [{gap, pixels}] (root receipt - the task's end on its node); ``first_starts``:
    per node, wall time of its first launch. A launch is modelled as the cost model has it
    (``per_launch_s + per_unit_s * (units - 1) + work``, the reference's conditions: one node
    rendering alone) times ``scale``, the nodes' speed in this run relative to the reference
    (contention between nodes on shared cores, the machine's drift): the ratio of the run's
    measured launch seconds to the model's. One factor for every launch, so a run of any
    strategy predicts the others; ``node_scale`` gives each node's own (how far the nodes'
    speeds drifted apart in this run, which a one-speed replay cannot follow). ``unit_costs`` ([{pixels, wire_s, root_s}]): each unit's
    measured time outside its launch on the node (``wire_s``: its pixels made ready to send)
    and in the root (``root_s``: placed in the frame), fitted as ``a + b * pixels``."""
    t = np.array([ln["seconds"] for ln in launches], float)
    n = np.array([ln["units"] - 1 for ln in launches], float)
    W = np.array([ln["work"] for ln in launches], float)
    model = cm["per_launch_s"] + cm.get("per_unit_s", 0.0) * n + W
    scale = float(t.sum() / model.sum()) if model.sum() > 0 else 1.0
    per_node = {}
    for ln, ti, mi in zip(launches, t, model):
        a = per_node.setdefault(str(ln.get("node")), [0.0, 0.0])
        a[0] += ti
        a[1] += mi
    node_scale = {k: (v[0] / v[1] if v[1] > 0 else None) for k, v in per_node.items()}
    L, U, how = scale * cm["per_launch_s"], scale * cm.get("per_unit_s", 0.0), "ratio over launches"
    if scale <= 0:
        scale = 1.0
    T0 = Tpx = D = 0.0
    if not in_process:
        if tasks:
            g = np.array([max(t["gap"], 0.0) for t in tasks])
            p = np.array([t["pixels"] for t in tasks], float)
            if len(tasks) >= 3 and np.ptp(p) > 0:
                T0, Tpx = (float(v) for v in nnls(np.stack([np.ones_like(p), p], axis=1), g))
            else:
                T0 = float(np.median(g))
        if first_starts and t0_wall is not None:
            D = max(0.0, float(np.median([s - t0_wall for s in first_starts])))
    uc = unit_costs or []
    na, nb = _fit_per_unit([u["wire_s"] for u in uc if u.get("wire_s") is not None],
                           [u["pixels"] for u in uc if u.get("wire_s") is not None])
    ra, rb = _fit_per_unit([u["root_s"] for u in uc if u.get("root_s") is not None],
                           [u["pixels"] for u in uc if u.get("root_s") is not None])
    return {"per_launch_s": float(L), "per_unit_s": U, "scale": float(scale), "transfer_s": T0,
            "transfer_per_pixel_s": Tpx, "dispatch_s": D,
            "node_unit_s": na, "node_unit_per_pixel_s": nb, "root_unit_s": ra, "root_unit_per_pixel_s": rb,
            "node_scale": node_scale, "fit": how, "launches": len(launches), "tasks": len(tasks),
            "in_process": bool(in_process)}


def _union(intervals, lo, hi) -> float:
    """Total length of the union of ``intervals`` [(a, b)] clipped to [lo, hi]."""
    segs = sorted((max(a, lo), min(b, hi)) for a, b in intervals if min(b, hi) > max(a, lo))
    total, cur_a, cur_b = 0.0, None, None
    for a, b in segs:
        if cur_b is None or a > cur_b:
            if cur_b is not None:
                total += cur_b - cur_a
            cur_a, cur_b = a, b
        else:
            cur_b = max(cur_b, b)
    return total + (0.0 if cur_b is None else cur_b - cur_a)


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
    from .executors import CHUNK_FACTOR, TASK_PIXELS
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


def measure_overhead(spec, n_units: int = 64, repeat: int = 3, batched: bool = True) -> dict:
    """In this process, with the renderer's own threads: the full frame, the same frame as
    ``n_units`` tiles each in its own launch (the paper's one-at-a-time hand-out) and, with
    ``batched``, the tiles in two launches (two nodes' static batches, run one after the
    other). Medians of ``repeat`` after one warm-up of each; the per-launch fixed cost is
    ``(tiled_s - full_s) / (n_units - 1)``. ``alone_units``: each tile and the full frame,
    launched alone, with its measured seconds (median) and exact ray tests (when the renderer
    has the ``cost`` AOV): what the schedule report's cost model is fitted on.
    """
    from ..tracing.aovs import aov_channel
    from .runtime import can_batch, get_renderer
    from .strategies import grid_shape, tile_units
    r = get_renderer(spec)
    w, h = r.film_size
    nx, ny = grid_shape(w, h, n_units)
    wins = [u.window for u in tile_units(w, h, nx, ny)]
    batched = batched and can_batch(r)
    halves = (wins[:len(wins) // 2], wins[len(wins) // 2:])
    cc = aov_channel(list(getattr(r, "channels", []) or []), "cost")
    full, tiled, two = [], [], []
    per_tile = [[] for _ in wins]
    tests = [None] * len(wins)
    frame_tests = None
    for k in range(repeat + 1):  # the first round warms caches (kernels, recordings, accel)
        t = time.perf_counter()
        img = r.render(window=(0, 0, w, h))
        t1 = time.perf_counter()
        if cc is not None and frame_tests is None:
            frame_tests = float(np.asarray(img)[..., cc].sum())
        for j, win in enumerate(wins):
            ta = time.perf_counter()
            im = r.render(window=win)
            if k:
                per_tile[j].append(time.perf_counter() - ta)
            if cc is not None and tests[j] is None:
                tests[j] = float(np.asarray(im)[..., cc].sum())
        t2 = time.perf_counter()
        if batched:
            for half in halves:
                r.render_batch(half)
        t3 = time.perf_counter()
        if k:
            full.append(t1 - t)
            tiled.append(t2 - t1)
            two.append(t3 - t2)
    f, t = float(np.median(full)), float(np.median(tiled))
    out = {"units": len(wins), "full_s": f, "full_trials_s": full, "tiled_s": t, "ratio": t / f,
           "per_launch_overhead_s": max(0.0, (t - f) / max(len(wins) - 1, 1)), "repeat": repeat}
    if batched:
        out.update(batched_s=float(np.median(two)), batched_ratio=float(np.median(two)) / f)
    out["alone_units"] = [{"window": list(win), "pixels": win[2] * win[3], "ray_tests": tests[j],
                           "seconds": float(np.median(per_tile[j]))} for j, win in enumerate(wins)]
    out["alone_units"].append({"window": [0, 0, w, h], "pixels": w * h, "ray_tests": frame_tests, "seconds": f,
                               "frame": True})
    return out


def frame_seconds(spec, repeat: int = 1) -> float:
    """The whole frame as one launch on this node (its threads, warm): median seconds of
    ``repeat`` renders (the benchmark's one-process frame, measured next to each run)."""
    from .runtime import get_renderer
    r = get_renderer(spec)
    w, h = r.film_size
    out = []
    for _ in range(max(1, int(repeat))):
        t = time.perf_counter()
        r.render(window=(0, 0, w, h))
        out.append(time.perf_counter() - t)
    return float(np.median(out))


# ---------------------------------------------------------------------- simulator
def _launch_groups(units, batch, spp, launch_samples):
    """A task's units split into launches as :func:`.runtime.render_units` splits them."""
    out, cur, size = [], [], 0
    for i in batch:
        px = units[i].pixels
        if cur and (size + px) * spp > launch_samples:
            out.append(cur)
            cur, size = [], 0
        cur.append(i)
        size += px
    if cur:
        out.append(cur)
    return out


def replay(plan, work, *, per_launch_s=0.0, per_unit_s=0.0, scale=1.0, transfer_s=0.0, transfer_per_pixel_s=0.0,
           dispatch_s=0.0, node_unit_s=0.0, node_unit_per_pixel_s=0.0, root_unit_s=0.0, root_unit_per_pixel_s=0.0,
           chunk_factor=None, chunk_by="units", task_pixels=None, prefetch=2, spp=1,
           in_process=None, touch=None, object_cost=0.0, launch_samples=None, node_speed=None) -> dict:
    """Replay ``plan`` with per-unit work seconds ``work`` as the backends hand it out.

    Static plans: each node's units in plan order, in tasks of at most ``task_pixels`` pixels
    (:func:`.executors.take_batch`), all sent at once. Dynamic plans: guided chunks
    (:func:`.executors.guided_batch`, ``chunk_factor``, ``chunk_by``), each node keeping
    ``prefetch`` tasks in flight; a node that hands a result back gets its next chunk when the
    root has it. ``in_process`` (default: one node): the root renders every task itself, in
    plan order, with no transfer or dispatch (:class:`.executors.InProcess`).

    Costs: a task reaches its node ``dispatch_s`` after it is sent; each launch of a task
    (split at ``launch_samples`` samples as the nodes do) takes ``per_launch_s + per_unit_s *
    (units - 1) + scale * sum(work)``, plus ``object_cost`` per object its units touch that
    the node does not hold yet; after its launches the node spends ``node_unit_s +
    node_unit_per_pixel_s * pixels`` per unit readying the result, which reaches the root
    ``transfer_s + transfer_per_pixel_s * pixels`` later; the root, one thread, takes results
    in the order they arrive and spends ``root_unit_s + root_unit_per_pixel_s * pixels`` per
    unit placing them, and only then hands that node its next chunk. Makespan: the root done
    with the last result. In-process every cost is paid in turn. ``node_speed`` (one factor per
    node) multiplies each node's launch times: a run's nodes replayed at their own measured
    speeds. Returns makespan_s, busy (per node: launches and readying), launches, tasks,
    objects held per node.
    """
    from .executors import CHUNK_FACTOR, TASK_PIXELS, guided_batch, take_batch
    from .runtime import LAUNCH_SAMPLES
    n = plan.n_nodes
    chunk_factor = CHUNK_FACTOR if chunk_factor is None else int(chunk_factor)
    task_pixels = task_pixels or TASK_PIXELS
    launch_samples = launch_samples or LAUNCH_SAMPLES
    in_process = (n == 1) if in_process is None else in_process
    if in_process:
        transfer_s = transfer_per_pixel_s = dispatch_s = 0.0
    work = np.asarray(work, dtype=np.float64)
    units = plan.units
    held = np.zeros((n, 0 if touch is None else touch.shape[1]), dtype=bool)
    busy = np.zeros(n)
    stats = {"launches": 0, "tasks": 0}

    def task_time(batch, k):
        t = 0.0
        for grp in _launch_groups(units, batch, max(1, int(spp)), launch_samples):
            t += (per_launch_s + per_unit_s * (len(grp) - 1) + scale * float(work[grp].sum())) * \
                (1.0 if node_speed is None else float(node_speed[k]))
            stats["launches"] += 1
        if touch is not None and object_cost:
            need = touch[batch].any(axis=0)
            t += object_cost * float((need & ~held[k]).sum())
            held[k] |= need
        elif touch is not None:
            held[k] |= touch[batch].any(axis=0)
        stats["tasks"] += 1
        return t + sum(node_unit_s + node_unit_per_pixel_s * units[i].pixels for i in batch)

    def transfer(batch):
        return transfer_s + transfer_per_pixel_s * sum(units[i].pixels for i in batch)

    def at_root(batch):
        return sum(root_unit_s + root_unit_per_pixel_s * units[i].pixels for i in batch)

    makespan = 0.0
    if in_process:  # InProcess.run: one queue in plan order (static: pixel budget; dynamic: guided, 1 node)
        q, t = deque(plan.order), 0.0
        while q:
            batch = (take_batch(plan, q, None, task_pixels) if plan.static else
                     guided_batch(plan, q, 1, chunk_factor, task_pixels, by_load=chunk_by == "load"))
            k = plan.owner[batch[0]] % n if plan.static else 0
            dt = task_time(batch, k)
            busy[k] += dt
            t += dt + at_root(batch)
        makespan = t
    elif plan.static:  # LocalPool / Dask static: every task of a node sent at the start
        arrivals = []
        for k in range(n):
            q = deque(i for i in plan.order if plan.owner[i] % n == k)
            t = dispatch_s
            while q:
                batch = take_batch(plan, q, None, task_pixels)
                dt = task_time(batch, k)
                busy[k] += dt
                t += dt
                arrivals.append((t + transfer(batch), at_root(batch)))
        root = 0.0
        for t, cost in sorted(arrivals):  # the root takes results as they come, one at a time
            root = max(root, t) + cost
        makespan = root
    else:  # dynamic: guided chunks, prefetch tasks per node in flight
        shared = deque(plan.order)
        inflight, free = [0] * n, [0.0] * n
        events, seq = [], 0

        def fill(k, now):
            nonlocal seq
            while shared and inflight[k] < prefetch:
                batch = guided_batch(plan, shared, n, chunk_factor, task_pixels, by_load=chunk_by == "load")
                start = max(free[k], now + dispatch_s)
                dt = task_time(batch, k)
                free[k] = start + dt
                busy[k] += dt
                inflight[k] += 1
                heapq.heappush(events, (free[k] + transfer(batch), seq, k, at_root(batch)))
                seq += 1

        for k in range(n):
            fill(k, 0.0)
        root = 0.0
        while events:
            t, _, k, cost = heapq.heappop(events)
            root = max(root, t) + cost       # the root places the result, then hands out more
            inflight[k] -= 1
            makespan = max(makespan, root)
            for j in range(n):
                fill(j, root)
    return {"makespan_s": float(makespan), "busy": busy, "held": held, **stats}


def simulate(cost_map, model, nodes_list, *, strategies=("subscreen", "scanline", "grid", "dynamic/tile",
                                                          "dynamic/scanline"),
             tiles_per_node: int = 16, unit_overhead: float = 0.0, object_cost: float = 0.0,
             load_map=None, overheads: dict | None = None, full_frame_s: float | None = None,
             in_process_one: bool = True, node_speed=None) -> list[dict]:
    """Replay a per-pixel work map (seconds) for node counts this machine cannot run.

    Each strategy's plan is replayed by :func:`replay` with ``overheads`` (the keys of
    :func:`fit_overheads`: per_launch_s, per_unit_s, scale, transfer_s, transfer_per_pixel_s,
    dispatch_s, chunk_factor, chunk_by, task_pixels, spp); ``unit_overhead`` is added to
    per_unit_s (and charged for a launch's first unit too); a node pays ``object_cost`` for
    every object its units' primary rays need that it does not hold yet. One node renders
    in-process (as ``links1 schedule --nodes 1`` does) unless ``in_process_one`` is False.
    ``true_efficiency`` uses ``full_frame_s`` (measured) when given.
    """
    cost_map = np.asarray(cost_map, dtype=np.float64)
    h, w = cost_map.shape
    ov = dict(overheads or {})
    kw = {k: ov[k] for k in ("per_launch_s", "per_unit_s", "scale", "transfer_s", "transfer_per_pixel_s",
                             "dispatch_s", "node_unit_s", "node_unit_per_pixel_s", "root_unit_s",
                             "root_unit_per_pixel_s", "chunk_factor", "chunk_by", "task_pixels", "spp") if k in ov}
    kw["per_launch_s"] = kw.get("per_launch_s", 0.0) + unit_overhead
    kw["per_unit_s"] = kw.get("per_unit_s", 0.0) + unit_overhead
    rows = []
    if load_map is None and model is not None:
        load_map = model.load_map()
    for name in strategies:
        strategy, _, unit = name.partition("/")
        for n in nodes_list:
            plan = make_plan(strategy, w, h, int(n), tiles_per_node=tiles_per_node, unit=unit or "tile",
                             load_map=load_map)
            c = unit_loads(plan.units, cost_map)
            touch = model.touching([u.window for u in plan.units]) if model is not None and len(model.shapes) \
                else None
            out = replay(plan, c, touch=touch, object_cost=object_cost,
                         in_process=(int(n) == 1 and in_process_one),
                         node_speed=node_speed if node_speed is not None and len(node_speed) == int(n) else None, **kw)
            busy, makespan = out["busy"], out["makespan_s"]
            objs = out["held"].sum(axis=1)
            rows.append({"strategy": name, "nodes": int(n), "units": len(plan.units), "launches": out["launches"],
                         "makespan_s": makespan,
                         "imbalance": float(busy.max() / busy.mean()) if busy.mean() > 0 else None,
                         "efficiency": float(busy.sum() / (n * makespan)) if makespan > 0 else None,
                         "true_efficiency": (full_frame_s / (n * makespan)) if full_frame_s and makespan > 0
                         else None,
                         "objects_per_node_mean": float(objs.mean()) if objs.size else 0.0,
                         "objects_per_node_max": int(objs.max()) if objs.size else 0})
    return rows


def work_map(report, tests_map):
    """Per-pixel derived work seconds (cost model without its launch constant) of a report."""
    cm = report.get("cost_model")
    if cm is None:
        return None
    return cm["per_pixel_s"] + cm["per_test_s"] * np.asarray(tests_map, dtype=np.float64)


def strategy_name(report) -> str:
    """``dynamic/tile`` etc.: the name :func:`simulate` knows a report's strategy by."""
    s = report["strategy"]
    return f"{s}/{report.get('unit') or 'tile'}" if s == "dynamic" else s


def check_simulator(report, tests_map, model) -> dict | None:
    """The simulator replaying the report's own strategy and node count with the costs fitted
    in that run (cost model, overheads) against its measured makespan: with one speed for every
    node (``simulated_s``, what ``--simulate`` assumes) and with each node's own measured speed
    (``simulated_node_speeds_s``: what is left is the hand-out, transfer and assembly model)."""
    wm = work_map(report, tests_map)
    ov = report.get("overheads")
    if wm is None or ov is None:
        return None
    n = report["nodes"]
    kw = dict(strategies=(strategy_name(report),), tiles_per_node=report.get("tiles_per_node") or 16, overheads=ov,
              full_frame_s=report.get("full_frame_s"), in_process_one=ov.get("in_process", True))
    (row,) = simulate(wm, model, [n], **kw)
    ns = ov.get("node_scale") or {}
    speeds = [(ns.get(str(k)) or ov["scale"]) / ov["scale"] for k in range(n)] if ov["scale"] else None
    (own,) = simulate(wm, model, [n], node_speed=speeds, **kw)
    m = report["makespan_s"]
    vals = [v for v in ns.values() if v]
    return {"strategy": row["strategy"], "nodes": row["nodes"], "simulated_s": row["makespan_s"], "measured_s": m,
            "error": (row["makespan_s"] - m) / m if m > 0 else None,
            "simulated_node_speeds_s": own["makespan_s"],
            "error_node_speeds": (own["makespan_s"] - m) / m if m > 0 else None,
            "node_speed_spread": (max(vals) / min(vals)) if vals else None}


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


def format_table(rows) -> str:
    head = (f"{'strategy':<18}{'nodes':>6}{'units':>7}{'launches':>9}{'makespan_s':>12}{'imbalance':>10}"
            f"{'busy_eff':>9}{'true_eff':>9}{'obj/node':>9}")
    lines = ["simulated (cost model fitted on units launched alone, overheads fitted on this run):", head]
    for r in rows:
        imb = f"{r['imbalance']:.3f}" if r["imbalance"] is not None else "-"
        eff = f"{r['efficiency']:.2f}" if r["efficiency"] is not None else "-"
        te = f"{r['true_efficiency']:.2f}" if r.get("true_efficiency") is not None else "-"
        lines.append(f"{r['strategy']:<18}{r['nodes']:>6}{r['units']:>7}{r.get('launches', 0):>9}"
                     f"{r['makespan_s']:>12.4g}{imb:>10}{eff:>9}{te:>9}{r['objects_per_node_mean']:>9.1f}")
    return "\n".join(lines)


# ---------------------------------------------------------------------- plots
def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _save(fig, path):
    import io

    from .checkpoint import atomic_write_bytes
    buf = io.BytesIO()
    fig.savefig(buf, format=str(path).rsplit(".", 1)[-1].lower() if "." in str(path) else "png", dpi=110)
    atomic_write_bytes(path, buf.getvalue())


def plot_report(report, path) -> None:
    """Gantt chart of the measured launches per node, and each unit's seconds launched alone
    (measured: filled; derived from counts: open) and exact ray tests against predicted load."""
    plt = _pyplot()
    fig, (ax1, ax2, ax3) = plt.subplots(1, 3, figsize=(18, 4.8), gridspec_kw={"width_ratios": [2, 1, 1]})
    ts = report.get("time_split")
    if ts:
        gantt_time_split(ax1, ts)
    else:
        nodes = sorted({str(u["node"]) for u in report["units"]})
        row = {k: j for j, k in enumerate(nodes)}
        cmap = plt.get_cmap("tab20")
        seen = {}
        for u in report["units"]:
            lid = tuple(u["launch"])
            if lid in seen:
                continue
            seen[lid] = True
            ax1.barh(row[str(u["node"])], u["launch_seconds"], left=u["start"], color=cmap(len(seen) % 20),
                     edgecolor="k", linewidth=0.3)
        ax1.set_yticks(range(len(nodes)), nodes)
        ax1.set_xlabel("seconds (measured launches, node clocks)")
        ax1.set_ylabel("node")
    te = report.get("true_efficiency")
    ax1.set_title(f"{report['strategy']}: makespan {report['makespan_s']:.3g} s (measured)\n"
                  f"true efficiency {'n/a' if te is None else f'{te:.2f}'}, busy efficiency "
                  f"{report['parallel_efficiency'] or 0:.2f}, imbalance {report['imbalance'] or 0:.3f}", fontsize=9)
    rc = report["rank_correlation"]
    fmt = (lambda v: "n/a" if v is None else f"{v:.3f}")
    units = report["units"]
    if None not in [u["predicted_load"] for u in units]:
        for src, mk in (("measured", "o"), ("derived", "o")):
            us = [u for u in units if u["seconds_source"] == src]
            if us:
                ax2.scatter([u["predicted_load"] for u in us], [u["seconds"] for u in us], s=14, marker=mk,
                            facecolors="C0" if src == "measured" else "none", edgecolors="C0",
                            label=f"{src} ({len(us)} units)")
        ax2.legend(fontsize=8)
        ax2.set_title(f"Spearman predicted vs measured seconds {fmt(rc.get('predicted_vs_measured_seconds'))}\n"
                      f"(over {rc.get('n_measured')} units launched alone)", fontsize=9)
        tests = [u["ray_tests"] for u in units]
        if None not in tests:
            ax3.scatter([u["predicted_load"] for u in units], tests, s=10, color="C1")
        ax3.set_title(f"Spearman predicted vs exact ray tests {fmt(rc.get('predicted_vs_ray_tests'))}", fontsize=9)
    ax2.set_xlabel("predicted load (eq. 4.1)")
    ax2.set_ylabel("unit seconds launched alone: measured (filled) / derived from counts (open)", fontsize=8)
    ax3.set_xlabel("predicted load (eq. 4.1)")
    ax3.set_ylabel("ray-primitive tests (exact, cost AOV)")
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


SPLIT_COLOURS = {"work": "#2ca02c", "launch overhead": "#ff7f0e", "slowdown": "#d62728",
                 "dispatch": "#9467bd", "transfer": "#1f77b4", "waiting": "#d9d9d9", "start-up": "#7f7f7f",
                 "assembly": "#8c564b"}


def gantt_time_split(ax, ts) -> None:
    """The makespan's time split as a Gantt chart: one row per node (each launch drawn as its
    work, launch overhead and slowdown, then its results in transfer, dispatch before its first
    launch, waiting the rest) and one for the root (dispatches, assembly); start-up before 0."""
    span = ts["makespan_s"]
    nodes = [k for k in ts["nodes"]]
    rows = nodes + ["root"]
    used = set()

    def bar(y, a, b, name, hatch=None):
        if b > a:
            ax.barh(y, b - a, left=a, color=SPLIT_COLOURS[name], edgecolor="k" if name != "waiting" else "none",
                    linewidth=0.2, height=0.7, hatch=hatch, label=None if name in used else name)
            used.add(name)

    for y, k in enumerate(nodes):
        seg = ts["segments"].get(k, {})
        su = ts["nodes"][k].get("startup_s")
        if su:  # drawn at most a fifth of the makespan long, its measured length written on it
            bar(y, -min(su, 0.2 * span), 0.0, "start-up", hatch="//")
            ax.text(-0.1 * span, y, f"{su:.2g} s", ha="center", va="center", fontsize=6, color="w")
        bar(y, 0.0, span, "waiting")
        for a, b in seg.get("dispatch", []):
            bar(y, a, b, "dispatch")
        for a, b in seg.get("transfer", []):
            bar(y, a, b, "transfer")
        for a, b, work, ovh in seg.get("launch", []):
            if work is None:
                bar(y, a, b, "work")
                continue
            d = b - a
            w, o = max(work, 0.0), max(ovh, 0.0)
            f = min(1.0, d / (w + o)) if w + o > 0 else 1.0   # a node faster than the reference: no slowdown
            bar(y, a, a + w * f, "work")
            bar(y, a + w * f, a + (w + o) * f, "launch overhead")
            bar(y, a + (w + o) * f, b, "slowdown")
    yr = len(nodes)
    root = ts["segments"].get("root", {})
    bar(yr, 0.0, span, "waiting")
    for a, b in root.get("dispatch", []):
        bar(yr, a, max(b, a + span * 2e-3), "dispatch")
    for a, b in root.get("assembly", []):
        bar(yr, a, max(b, a + span * 2e-3), "assembly")
    ax.axvline(0.0, color="k", linewidth=0.5)
    ax.axvline(span, color="k", linewidth=0.5, linestyle="--")
    ax.set_yticks(range(len(rows)), [f"node {k}" for k in nodes] + ["root"])
    ax.invert_yaxis()
    sh = ts["shares"]
    ax.set_xlabel("seconds from the first dispatch (measured; launch parts derived; start-up before 0, "
                  "not to scale)\n"
                  + ", ".join(f"{k} {v:.0%}" for k, v in sh.items()) + " of nodes x makespan", fontsize=8)
    ax.legend(fontsize=6, loc="lower right", ncol=2)


def plot_simulation(rows, path) -> None:
    """Makespan, imbalance and objects per node versus the node count, per strategy."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    for name in dict.fromkeys(r["strategy"] for r in rows):
        rs = [r for r in rows if r["strategy"] == name]
        n = [r["nodes"] for r in rs]
        axes[0].plot(n, [r["makespan_s"] for r in rs], "o-", label=name)
        axes[1].plot(n, [r["imbalance"] or np.nan for r in rs], "o-", label=name)
        axes[2].plot(n, [r["objects_per_node_mean"] for r in rs], "o-", label=name)
    for ax, t in zip(axes, ("simulated makespan (s)", "simulated imbalance max/mean busy",
                            "objects per node (mean)")):
        ax.set_xscale("log", base=2)
        ax.set_xlabel("nodes")
        ax.set_title(t)
    axes[0].set_yscale("log")
    axes[1].axhline(1.1, color="grey", lw=0.8, ls="--")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def plot_sweep(sweep, path) -> None:
    """Makespan, imbalance and true efficiency against node count, per strategy (and unit
    size): measured runs as points, the simulator's curves as lines, on the same axes."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.6))
    rows = sweep["rows"]
    keys = list(dict.fromkeys((r["strategy"], r["tiles_per_node"]) for r in rows))
    names = list(dict.fromkeys(k for k, _ in keys))
    tiles = list(dict.fromkeys(t for _, t in keys))
    many = len(tiles) > 1
    for name, tpn in keys:
        color = f"C{names.index(name) % 10}"   # a colour per strategy, a line style / marker per unit size
        ls, mk = ("-", "--", ":", "-.")[tiles.index(tpn) % 4], ("o", "s", "^", "D")[tiles.index(tpn) % 4]
        label = f"{name}" + (f" ({tpn}/node)" if many else "")
        for kind, style in (("simulated", ls), ("measured", mk)):
            rs = sorted((r for r in rows if r["kind"] == kind and r["strategy"] == name and r["tiles_per_node"] == tpn),
                        key=lambda r: r["nodes"])
            if not rs:
                continue
            n = [r["nodes"] for r in rs]
            kw = dict(color=color, label=f"{label}, {kind}")
            if kind == "measured":
                kw.update(markersize=7, markerfacecolor="none", markeredgewidth=1.5)
            for ax, key in zip(axes, ("makespan_s", "imbalance", "true_efficiency")):
                ax.plot(n, [np.nan if r[key] is None else r[key] for r in rs], style, **kw)
    titles = ("makespan (s): measured points, simulated lines", "imbalance max/mean busy",
              "true efficiency: one-process frame / (nodes x makespan)")
    for ax, t in zip(axes, titles):
        ax.set_xscale("log", base=2)
        ax.set_xlabel("nodes")
        ax.set_title(t, fontsize=9)
    axes[0].set_yscale("log")
    axes[1].axhline(1.1, color="grey", lw=0.8, ls="--")
    axes[2].axhline(1.0, color="grey", lw=0.8, ls="--")
    axes[0].legend(fontsize=6, ncol=2)
    fig.suptitle(f"{os.path.basename(sweep.get('scene', ''))}, {sweep.get('renderer')}, film "
                 f"{'x'.join(str(v) for v in sweep.get('film', []))}: measured at {sweep.get('measured_nodes')} nodes, "
                 f"simulated from the runs on {max(sweep.get('measured_nodes') or [1])}", fontsize=9)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
