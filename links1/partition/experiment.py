"""Tile-scheduling experiments: the schedule report, the simulator and the plots.

Report (``links1 schedule ... --report OUT.json``) keys
------------------------------------------------------
scene, renderer, strategy, unit, order, tiles_per_node, backend, film [w, h], nodes
units[]            per unit: index, window [x0, y0, w, h] (row 0 at the top), node,
                   predicted_load (eq. 4.1), seconds (measured on the node), start/stop
                   (seconds from the first unit's start, node clocks), ray_tests (sum of
                   the cost AOV: ray-primitive tests), pixels
nodes_busy[]       per node: node, busy_s (sum of its units' seconds), units
makespan_s         root clock, first dispatch to last result (scene loading excluded:
                   workers load once, before)
imbalance          max(busy) / mean(busy) over the nodes that were started (>= 1)
parallel_efficiency  sum(busy) / (nodes * makespan_s), in (0, 1]: how busy the nodes were
                   (load balance and dispatch gaps; blind to per-unit overhead)
full_frame_s       the same renderer and options rendering the whole frame as one unit in the
                   root process (all its cores), measured in the same run (median of 3)
true_efficiency    full_frame_s / (nodes * makespan_s): what the partitioned run gained over
                   rendering the frame in one process (1 = perfect speed-up)
launches           kernel launches (tasks' batches) in the run; per node in nodes_busy[]
reference          measure_overhead(): full frame vs the frame as 64 one-unit launches vs the
                   64 units in two batches, and per_launch_overhead_s (fixed cost of a launch)
rank_correlation   Spearman: predicted_vs_seconds, predicted_vs_ray_tests, ray_tests_vs_seconds
load_table         the eq. 4.1 table the plan's loads were predicted with (the renderer's own
                   fitted table, see loadmodel.RENDERER_LOAD_TABLES, or --load-table)
data_per_node[]    4-4: per node of the plan, objects_primary/bytes_primary (projected rectangle
                   touches its region) and objects_secondary/bytes_secondary (what secondary
                   rays may still reach)
faults             messages about lost nodes
cost_model         fit of unit seconds = per_pixel_s * pixels + per_test_s * ray_tests + per_unit_s
simulation         (with --simulate) rows {strategy, nodes, makespan_s, imbalance, efficiency,
                   objects_per_node_mean, objects_per_node_max, units}
"""
from __future__ import annotations

import heapq
import time

import numpy as np

from .strategies import make_plan, unit_loads


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


def fit_cost_model(pixels, tests, seconds) -> dict:
    """Least-squares ``seconds = a * pixels + b * tests + c`` (non-negative; falls back to ``b`` only)."""
    pixels, tests, seconds = (np.asarray(v, float) for v in (pixels, tests, seconds))
    A = np.stack([pixels, tests, np.ones_like(pixels)], axis=1)
    try:
        coef = np.linalg.lstsq(A, seconds, rcond=None)[0]
    except np.linalg.LinAlgError:
        coef = np.array([-1.0, 0, 0])
    if np.any(coef < 0) or not np.all(np.isfinite(coef)):
        b = float(seconds.sum() / max(tests.sum(), 1.0))
        coef = np.array([0.0 if tests.sum() > 0 else float(seconds.sum() / max(pixels.sum(), 1)), b, 0.0])
    return {"per_pixel_s": float(coef[0]), "per_test_s": float(coef[1]), "per_unit_s": float(coef[2])}


def build_report(result, plan, model, *, cost_channel=None, meta=None, reference=None) -> dict:
    """The schedule report of one real run (see the module docstring for the keys)."""
    recs = result.records
    t0 = min((r["start"] for r in recs.values()), default=0.0)
    units = []
    img = result.image
    for i, u in enumerate(plan.units):
        r = recs.get(i)
        if r is None:
            continue
        tests = float(img[u.y0:u.y0 + u.h, u.x0:u.x0 + u.w, cost_channel].sum()) if cost_channel is not None else None
        units.append({"index": i, "window": list(u.window), "node": r["node"], "pixels": u.pixels,
                      "predicted_load": None if plan.predicted is None else float(plan.predicted[i]),
                      "seconds": r["seconds"], "start": r["start"] - t0, "stop": r["stop"] - t0,
                      "ray_tests": tests})
    busy, launches = {}, {}
    for u in units:
        b = busy.setdefault(str(u["node"]), [0.0, 0])
        b[0] += u["seconds"]
        b[1] += 1
        launches.setdefault(str(u["node"]), set()).add(recs[u["index"]].get("launch", ("unit", u["index"])))
    n = max(result.n_nodes, len(busy), 1)
    busy_s = [v[0] for v in busy.values()] + [0.0] * (n - len(busy))
    makespan = result.makespan_s or 1e-12
    mean = float(np.mean(busy_s)) if busy_s else 0.0
    pred = [u["predicted_load"] for u in units]
    secs = [u["seconds"] for u in units]
    tests = [u["ray_tests"] for u in units]
    rep = dict(meta or {})
    rep.update({
        "strategy": plan.strategy, "film": [plan.width, plan.height], "nodes": n,
        "tiles_per_node": plan.meta.get("tiles_per_node"), "unit": plan.meta.get("unit"),
        "order": plan.meta.get("order"), "backend": result.backend,
        "units": units,
        "nodes_busy": [{"node": k, "busy_s": v[0], "units": v[1], "launches": len(launches[k])}
                       for k, v in busy.items()],
        "launches": sum(len(v) for v in launches.values()),
        "makespan_s": makespan,
        "imbalance": (max(busy_s) / mean) if mean > 0 else None,
        "parallel_efficiency": min(1.0, float(np.sum(busy_s)) / (n * makespan)) if makespan > 0 else None,
        "rank_correlation": {
            "predicted_vs_seconds": spearman(pred, secs) if None not in pred else None,
            "predicted_vs_ray_tests": spearman(pred, tests) if None not in pred and None not in tests else None,
            "ray_tests_vs_seconds": spearman(tests, secs) if None not in tests else None,
        },
        "full_frame_s": None if reference is None else reference["full_s"],
        "true_efficiency": None if reference is None else reference["full_s"] / (n * makespan),
        "reference": reference,
        "data_per_node": model.node_data(plan) if model is not None else None,
        "load_table": model.meta.get("load_table") if model is not None else None,
        "faults": list(result.faults),
        "cost_model": fit_cost_model([u["pixels"] for u in units], tests, secs) if None not in tests and units
        else None,
    })
    return rep


def measure_overhead(spec, n_units: int = 64, repeat: int = 3, batched: bool = True) -> dict:
    """In this process, with the renderer's own threads: the full frame, the same frame as
    ``n_units`` tiles each in its own launch (the paper's one-at-a-time hand-out) and, with
    ``batched``, the tiles in two launches (two nodes' static batches, run one after the
    other). Medians of ``repeat`` after one warm-up of each; the per-launch fixed cost is
    ``(tiled_s - full_s) / (n_units - 1)``.
    """
    from .runtime import can_batch, get_renderer
    from .strategies import grid_shape, tile_units
    r = get_renderer(spec)
    w, h = r.film_size
    nx, ny = grid_shape(w, h, n_units)
    wins = [u.window for u in tile_units(w, h, nx, ny)]
    batched = batched and can_batch(r)
    halves = (wins[:len(wins) // 2], wins[len(wins) // 2:])
    full, tiled, two = [], [], []
    for k in range(repeat + 1):  # the first round warms caches (kernels, recordings, accel)
        t = time.perf_counter()
        r.render(window=(0, 0, w, h))
        t1 = time.perf_counter()
        for win in wins:
            r.render(window=win)
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
    out = {"units": len(wins), "full_s": f, "tiled_s": t, "ratio": t / f,
           "per_launch_overhead_s": max(0.0, (t - f) / max(len(wins) - 1, 1)), "repeat": repeat}
    if batched:
        out.update(batched_s=float(np.median(two)), batched_ratio=float(np.median(two)) / f)
    return out


def simulate(cost_map, model, nodes_list, *, strategies=("subscreen", "scanline", "grid", "dynamic/tile",
                                                          "dynamic/scanline"),
             tiles_per_node: int = 16, unit_overhead: float = 0.0, object_cost: float = 0.0,
             load_map=None) -> list[dict]:
    """Replay a measured per-pixel cost map (seconds) for node counts this machine cannot run.

    Each unit costs the sum of its pixels' cost plus ``unit_overhead``; a node pays
    ``object_cost`` for every object its units need that it does not hold yet (primary
    rays: projected rectangle touches the unit). Static plans sum per node; dynamic plans
    are list-scheduled (the next unit goes to the node that frees first, in the plan's
    dispatch order).
    """
    cost_map = np.asarray(cost_map, dtype=np.float64)
    h, w = cost_map.shape
    rows = []
    if load_map is None and model is not None:
        load_map = model.load_map()
    for name in strategies:
        strategy, _, unit = name.partition("/")
        for n in nodes_list:
            plan = make_plan(strategy, w, h, int(n), tiles_per_node=tiles_per_node, unit=unit or "tile",
                             load_map=load_map)
            c = unit_loads(plan.units, cost_map) + unit_overhead
            touch = model.touching([u.window for u in plan.units]) if model is not None and len(model.shapes) \
                else np.zeros((len(plan.units), 0), bool)
            held = np.zeros((n, touch.shape[1]), dtype=bool)
            busy = np.zeros(n)
            if plan.static:
                for i in plan.order:
                    k = plan.owner[i]
                    new = touch[i] & ~held[k]
                    busy[k] += c[i] + object_cost * new.sum()
                    held[k] |= touch[i]
            else:
                heap = [(0.0, k) for k in range(n)]
                for i in plan.order:
                    t, k = heapq.heappop(heap)
                    new = touch[i] & ~held[k]
                    held[k] |= touch[i]
                    t += c[i] + object_cost * new.sum()
                    busy[k] = t
                    heapq.heappush(heap, (t, k))
            makespan = float(busy.max())
            objs = held.sum(axis=1)
            rows.append({"strategy": name, "nodes": int(n), "units": len(plan.units), "makespan_s": makespan,
                         "imbalance": makespan / busy.mean() if busy.mean() > 0 else None,
                         "efficiency": float(busy.sum() / (n * makespan)) if makespan > 0 else None,
                         "objects_per_node_mean": float(objs.mean()) if len(objs) else 0.0,
                         "objects_per_node_max": int(objs.max()) if len(objs) else 0})
    return rows


def format_table(rows) -> str:
    head = f"{'strategy':<18}{'nodes':>6}{'units':>7}{'makespan_s':>12}{'imbalance':>10}{'eff':>6}{'obj/node':>9}"
    lines = [head]
    for r in rows:
        imb = f"{r['imbalance']:.3f}" if r["imbalance"] is not None else "-"
        eff = f"{r['efficiency']:.2f}" if r["efficiency"] is not None else "-"
        lines.append(f"{r['strategy']:<18}{r['nodes']:>6}{r['units']:>7}{r['makespan_s']:>12.4g}{imb:>10}{eff:>6}"
                     f"{r['objects_per_node_mean']:>9.1f}")
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
    """Gantt chart per node and predicted-vs-measured unit cost scatter."""
    plt = _pyplot()
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.5))
    nodes = sorted({str(u["node"]) for u in report["units"]})
    row = {k: j for j, k in enumerate(nodes)}
    cmap = plt.get_cmap("tab20")
    for u in report["units"]:
        ax1.barh(row[str(u["node"])], u["seconds"], left=u["start"], color=cmap(u["index"] % 20),
                 edgecolor="k", linewidth=0.3)
    ax1.set_yticks(range(len(nodes)), nodes)
    ax1.set_xlabel("seconds")
    ax1.set_ylabel("node")
    ax1.set_title(f"{report['strategy']}: makespan {report['makespan_s']:.3g} s, imbalance "
                  f"{report['imbalance'] or 0:.3f}, efficiency {report['parallel_efficiency'] or 0:.2f}")
    pred = [u["predicted_load"] for u in report["units"]]
    if None not in pred:
        ax2.scatter(pred, [u["seconds"] for u in report["units"]], s=10)
        rc = report["rank_correlation"]["predicted_vs_seconds"]
        ax2.set_title(f"predicted (eq. 4.1) vs measured, Spearman {rc if rc is None else round(rc, 3)}")
    ax2.set_xlabel("predicted load")
    ax2.set_ylabel("measured seconds")
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


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
    for ax, t in zip(axes, ("makespan (s)", "imbalance max/mean", "objects per node (mean)")):
        ax.set_xscale("log", base=2)
        ax.set_xlabel("nodes")
        ax.set_title(t)
    axes[0].set_yscale("log")
    axes[1].axhline(1.1, color="grey", lw=0.8, ls="--")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
