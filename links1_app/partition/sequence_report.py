"""The sequence experiment (``links1 animate --report``): how each way of giving frames to the
nodes does on the same frames, frame by frame and for the sequence, and the simulator's
replay of the measured sequence for node counts this machine cannot run.

Ways (:data:`WAYS`): ``eq41`` (each frame split by ``subscreen`` planned from eq. 4.1's object
loads), ``previous`` (``subscreen`` planned from the previous frame's measured ray tests, the
``cost`` AOV; the first frame falls back to eq. 4.1), ``dynamic`` (each frame handed out in
guided chunks of tiles) and ``frames`` (whole frames, one to a node at a time). The reference is
one process rendering the frames in turn (``one_process``), measured in the same run.
"""
from __future__ import annotations

import os
import statistics

import numpy as np

from links1.partition.strategies import make_plan

from .sequence import frame_units_plan, imbalance, reproject
from .simulator import replay

#: name -> (units, partition, plan_from)
WAYS = {"eq41": ("partition", "subscreen", "eq41"), "previous": ("partition", "subscreen", "previous"),
        "dynamic": ("partition", "dynamic", "eq41"), "frames": ("frames", "subscreen", "eq41")}


def _mean(xs):
    xs = [x for x in xs if x is not None]
    return float(np.mean(xs)) if xs else None


def summarise(name, res, one, n_nodes) -> dict:
    """One way's figures: per frame (makespan, imbalance in busy seconds and in exact ray tests,
    true efficiency against the one-process frame, predicted vs measured rank correlation) and
    for the sequence (makespan, frames per second and its ratio to one process)."""
    per_one = {fr["frame"]: fr["render_s"] for fr in one.frames}
    frames = []
    for fr in res.frames:
        row = dict(fr, way=name)
        span = fr.get("makespan_s", fr.get("render_s"))
        if "makespan_s" in fr and per_one.get(fr["frame"]):
            row["true_efficiency"] = per_one[fr["frame"]] / (n_nodes * span)
        frames.append(row)
    # CPU seconds (measured in the nodes): the makespan had every node had its core to itself,
    # derived: per split frame its busiest node's, summed; whole frames: the busiest node's frames
    if all("cpu_s" in fr and isinstance(fr["cpu_s"], list) for fr in res.frames):
        cpu_span = sum(max(fr["cpu_s"]) for fr in res.frames)
    else:
        per_node = {}
        for fr in res.frames:
            k = (fr.get("nodes") or [0])[0]
            per_node[k] = per_node.get(k, 0.0) + fr.get("cpu_s", 0.0)
        cpu_span = max(per_node.values(), default=0.0)
    cpu_one = sum(fr.get("cpu_s", 0.0) for fr in one.frames)
    fps = len(res.frames) / res.makespan_s if res.makespan_s > 0 else None
    fps_one = len(one.frames) / one.makespan_s if one.makespan_s > 0 else None
    return {"way": name, "nodes": n_nodes, "frames": frames, "makespan_s": res.makespan_s, "frames_per_s": fps,
            "startup_s": res.startup_s, "planning_s": res.planning_s, "cpu_makespan_s": cpu_span,
            "one_process_cpu_s": cpu_one,
            "throughput_cpu_vs_one_process": cpu_one / cpu_span if cpu_span > 0 else None,
            "imbalance_cpu_mean": _mean(f.get("imbalance_cpu") for f in frames),
            "imbalance_cpu_max": max((f["imbalance_cpu"] for f in frames if f.get("imbalance_cpu")), default=None),
            "throughput_vs_one_process": fps / fps_one if fps and fps_one else None,
            "imbalance_mean": _mean(f.get("imbalance") for f in frames),
            "imbalance_max": max((f["imbalance"] for f in frames if f.get("imbalance")), default=None),
            "imbalance_ray_tests_mean": _mean(f.get("imbalance_ray_tests") for f in frames),
            "imbalance_ray_tests_max": max((f["imbalance_ray_tests"] for f in frames
                                            if f.get("imbalance_ray_tests")), default=None),
            "true_efficiency_mean": _mean(f.get("true_efficiency") for f in frames),
            "predicted_vs_ray_tests_mean": _mean(f.get("predicted_vs_ray_tests") for f in frames),
            "faults": list(res.faults)}


def previous_maps(one, cameras) -> dict:
    """Frame -> the previous frame's measured cost moved through the camera's motion
    (:func:`.sequence.reproject`; unmoved where a frame's camera is not known)."""
    order = [fr["frame"] for fr in one.frames]
    out = {}
    for a, b in zip(order, order[1:]):
        if a in cameras and b in cameras and a in one.depths:
            out[b] = reproject(one.costs[a], one.depths[a], cameras[a], cameras[b])
        else:
            out[b] = one.costs[a]
    return out


def simulate_sequence(one, costs, eq41_maps, nodes_list, *, tiles_per_node=16, overhead_s=0.0,
                      previous=None) -> list[dict]:
    """Replay the measured sequence at ``nodes_list`` (:func:`.simulator.replay`).

    ``one``: the one-process run (each frame's seconds, set-up included; the set-up per frame
    change, ``one.setup_s``); ``costs``: frame -> its measured ray tests per pixel; a frame's
    seconds are spread over its pixels by ray tests. Latency (one frame split over N nodes): per
    frame the ``previous`` and ``eq41`` subscreen plans and ``dynamic`` tiles at N nodes, each
    launch paying the set-up (a node sets its scene to the frame) and each task ``overhead_s``
    (measured: a split frame's makespan less its busiest node, median); throughput (frames over
    N nodes): whole frames one at a time (``frames``), and ``both`` (whole frames, the last N
    frames split by ``previous``); ``previous``: frame -> its plan's load from the frame before
    (:func:`previous_maps`; default: that frame's cost unmoved). Rows: nodes, way, kind (latency | throughput), makespan_s
    (per frame, median, for latency; the sequence for throughput), efficiency (the
    one-process seconds / (N x makespan)), frames_per_s."""
    setup = statistics.median(one.setup_s) if one.setup_s else 0.0
    order = [fr["frame"] for fr in one.frames]
    secs = {fr["frame"]: fr["render_s"] for fr in one.frames}
    rows = []
    for n in nodes_list:
        lat = {}
        for way in ("previous", "eq41", "dynamic"):
            spans, effs = [], []
            for j, f in enumerate(order):
                cost = costs[f]
                h, w = cost.shape
                if way == "previous" and j > 0:
                    load = (previous or {}).get(f, costs[order[j - 1]]) + 1.0
                else:
                    load = eq41_maps.get(f)
                    if load is None:
                        load = np.ones_like(cost)
                strategy = "dynamic" if way == "dynamic" else "subscreen"
                plan = make_plan(strategy, w, h, n, tiles_per_node=tiles_per_node, unit="tile", load_map=load)
                tests = cost + 1.0
                per_test = max(secs[f] - setup, 0.0) / float(tests.sum())
                work = [per_test * float(tests[u.y0:u.y0 + u.h, u.x0:u.x0 + u.w].sum()) for u in plan.units]
                r = replay(plan, work, per_launch_s=setup, dispatch_s=overhead_s, in_process=False if n > 1 else None)
                spans.append(r["makespan_s"])
                effs.append(secs[f] / (n * r["makespan_s"]))
            lat[way] = statistics.median(spans)
            rows.append({"nodes": n, "way": way, "kind": "latency", "makespan_s": statistics.median(spans),
                         "efficiency": float(np.mean(effs)), "frames_per_s": len(order) / sum(spans)})
        total = sum(secs.values())
        H, W = costs[order[0]].shape
        plan = frame_units_plan(W, H, list(range(len(order))), n, len(order))
        # one frame in flight per node: the local pool hands every node its first task before any
        # node a second (replay's prefetch fills node by node, which with fewer frames than 2N
        # would queue two frames on the first nodes while the last have none)
        r = replay(plan, [secs[f] for f in order], dispatch_s=overhead_s, chunk_factor=0, prefetch=1,
                   in_process=False if n > 1 else None)
        rows.append({"nodes": n, "way": "frames", "kind": "throughput", "makespan_s": r["makespan_s"],
                     "efficiency": total / (n * r["makespan_s"]), "frames_per_s": len(order) / r["makespan_s"]})
        tail = min(n, len(order)) if n > 1 else 0
        if tail:
            head = order[:len(order) - tail]
            span = 0.0
            if head:
                p = frame_units_plan(W, H, list(range(len(head))), n, len(head))
                span = replay(p, [secs[f] for f in head], dispatch_s=overhead_s, chunk_factor=0, prefetch=1,
                              in_process=False)["makespan_s"]
            # the last frames, each split over every node (the latency replay's per-frame median)
            span += tail * lat["previous"]
            rows.append({"nodes": n, "way": "both", "kind": "throughput", "makespan_s": span,
                         "efficiency": total / (n * span), "frames_per_s": len(order) / span})
    return rows


def best_choices(rows) -> dict:
    """Per node count: the latency-optimal way (least per-frame makespan) and the throughput-optimal
    one (most frames per second over every way), each with its predicted efficiency."""
    out = {}
    for n in sorted({r["nodes"] for r in rows}):
        lat = min((r for r in rows if r["nodes"] == n and r["kind"] == "latency"), key=lambda r: r["makespan_s"])
        thr = max((r for r in rows if r["nodes"] == n), key=lambda r: r["frames_per_s"])
        out[n] = {"latency": {"way": lat["way"], "makespan_s": lat["makespan_s"], "efficiency": lat["efficiency"]},
                  "throughput": {"way": thr["way"], "frames_per_s": thr["frames_per_s"],
                                 "efficiency": thr["efficiency"]}}
    return out


def split_overhead(summaries) -> float:
    """A split frame's makespan less its busiest node (dispatch, transfer, assembly), median over
    the split frames of every way."""
    gaps = [fr["makespan_s"] - max(fr["busy_s"]) for s in summaries for fr in s["frames"]
            if "busy_s" in fr and fr.get("makespan_s")]
    return max(0.0, statistics.median(gaps)) if gaps else 0.0


def plot(report, path) -> None:
    """Imbalance (busy seconds and ray tests) and makespan per frame, one line per way."""
    import matplotlib   # lazy: plotting is optional
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for s in report["ways"]:
        xs = [fr["frame"] for fr in s["frames"]]
        if s["way"] != "frames":
            axes[0].plot(xs, [fr.get("imbalance") for fr in s["frames"]], label=s["way"])
            axes[1].plot(xs, [fr.get("imbalance_ray_tests") for fr in s["frames"]], label=s["way"])
            axes[2].plot(xs, [fr["makespan_s"] for fr in s["frames"]], label=s["way"])
    one = report["one_process"]
    axes[2].plot([fr["frame"] for fr in one["frames"]], [fr["render_s"] for fr in one["frames"]], "k--",
                 label="one process")
    axes[0].set_title(f"imbalance, busy seconds ({report['nodes']} nodes)")
    axes[1].set_title("imbalance, ray tests (exact)")
    axes[2].set_title("makespan per frame (s)")
    for ax in axes:
        ax.set_xlabel("frame")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"{os.path.basename(report['scene'])}: frames over {report['nodes']} nodes; whole frames: "
                 f"{_fmt(report['throughput'].get('frames'))} x one process's frames per second")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _fmt(v):
    return "?" if v is None else f"{v:.2f}"


def format_summary(report) -> str:
    lines = [f"{'way':<10} {'makespan':>9} {'frames/s':>9} {'vs one':>7} {'cpu vs':>7} {'imb(s)':>7} {'imb(cpu)':>8} "
             f"{'imb(tests)':>10} {'true eff':>8} {'corr':>6}"]
    for s in report["ways"]:
        def g(k, f="{:.3f}"):
            v = s.get(k)
            return "-" if v is None else f.format(v)
        lines.append(f"{s['way']:<10} {g('makespan_s', '{:.2f}'):>9} {g('frames_per_s', '{:.2f}'):>9} "
                     f"{g('throughput_vs_one_process', '{:.2f}'):>7} {g('throughput_cpu_vs_one_process', '{:.2f}'):>7} "
                     f"{g('imbalance_mean'):>7} {g('imbalance_cpu_mean'):>8} "
                     f"{g('imbalance_ray_tests_mean'):>10} {g('true_efficiency_mean'):>8} "
                     f"{g('predicted_vs_ray_tests_mean', '{:.2f}'):>6}")
    return "\n".join(lines)


def plan_imbalance(cost, load, n_nodes, *, strategy="subscreen", tiles_per_node=16) -> float:
    """The imbalance in exact ray tests (max / mean over the nodes) of the static plan that
    ``load`` (a per-pixel predicted load) gives for a frame whose measured cost is ``cost``:
    what a plan rule achieves, free of timing noise."""
    h, w = cost.shape
    plan = make_plan(strategy, w, h, n_nodes, tiles_per_node=tiles_per_node, unit="tile", load_map=load)
    tests = np.zeros(n_nodes)
    for u, k in zip(plan.units, plan.owner):
        tests[k] += float(cost[u.y0:u.y0 + u.h, u.x0:u.x0 + u.w].sum())
    return imbalance(tests)
