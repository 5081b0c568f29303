"""The cost of rendering a unit, fitted on measured launches.

:func:`fit_cost_model`: a unit launched alone costs ``per_launch_s + per_pixel_s * pixels +
per_test_s * ray_tests``, fitted on units that were launched alone (the reference's tiles and
frame, :func:`measure_overhead`, and the run's lone units); :func:`fit_overheads`: what this
run's launches and tasks cost beyond that (per unit, node speed, transfer, dispatch).
The schedule report (:mod:`.report`) and the simulator (:mod:`.simulator`) read both.
"""
from __future__ import annotations

import time

import numpy as np

from links1.partition.strategies import grid_shape, tile_units
from links1.tracing.aovs import aov_channel

from .runtime import can_batch, get_renderer

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



def measure_overhead(spec, n_units: int = 64, repeat: int = 3, batched: bool = True) -> dict:
    """In this process, with the renderer's own threads: the full frame, the same frame as
    ``n_units`` tiles each in its own launch (the paper's one-at-a-time hand-out) and, with
    ``batched``, the tiles in two launches (two nodes' static batches, run one after the
    other). Medians of ``repeat`` after one warm-up of each; the per-launch fixed cost is
    ``(tiled_s - full_s) / (n_units - 1)``. ``alone_units``: each tile and the full frame,
    launched alone, with its measured seconds (median) and exact ray tests (when the renderer
    has the ``cost`` AOV): what the schedule report's cost model is fitted on.
    """
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
    r = get_renderer(spec)
    w, h = r.film_size
    out = []
    for _ in range(max(1, int(repeat))):
        t = time.perf_counter()
        r.render(window=(0, 0, w, h))
        out.append(time.perf_counter() - t)
    return float(np.median(out))


