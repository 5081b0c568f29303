"""Replaying a plan with fitted costs: node counts this machine cannot run.

:func:`replay` hands a plan's units out as the backends do (:mod:`.handout`) with the costs
of :func:`.costmodel.fit_overheads`; :func:`simulate` does it per strategy and node count
over a per-pixel work map; :func:`check_simulator` replays a run's own strategy against its
measured makespan.
"""
from __future__ import annotations

import heapq
from collections import deque

import numpy as np

from links1.partition.strategies import make_plan, unit_loads

from .handout import CHUNK_FACTOR, TASK_PIXELS, guided_batch, take_batch
from .runtime import LAUNCH_SAMPLES

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
    (:func:`.handout.take_batch`), all sent at once. Dynamic plans: guided chunks
    (:func:`.handout.guided_batch`, ``chunk_factor``, ``chunk_by``), each node keeping
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


