"""Sequences over the nodes: frame-coherent scheduling against eq. 4.1, dynamic and whole frames.
A benchmark, not a test.

Two sequences, each run by ``links1 animate --report`` (the one-process reference, then every
way on the nodes, the same frames; links1_app.partition.sequence_report):

* ``orbit``: ``scenes/sequences/orbit.xml``, the camera circling ``scenes/many.xml`` (7.5 degrees
  a frame): the load moves across the screen;
* ``blobs``: ``scenes/blobs_moving.xml``, Fig. 6(b)'s blob with five moving centres: the load
  changes in place.

Targets: previous-frame ``subscreen`` imbalance <= 1.05 over the 48-frame orbit at 256^2 on 2
nodes (eq. 4.1's on the same frames next to it); whole frames on 2 nodes >= 1.8x the frames per
second of one process rendering them in turn; simulated 64 nodes: the latency-optimal and
throughput-optimal unit choices with their predicted efficiency.

Usage::

    .venv/bin/python -m compare.sequence [--frames 48] [--res 256] [--nodes 2] [--renderer core]
        [--sequences orbit,blobs] [--simulate 2,4,8,16,64] [--tiles-per-node 64] [--out sequence]
    .venv/bin/python -m compare.sequence --plans [--frames 48] [--res 256] [--nodes 2]   # plan rules, exact
    .venv/bin/python -m compare.sequence --rounds 3                                      # throughput
    .venv/bin/python -m compare.sequence --picture docs/images/sequences.png             # a few frames
    .venv/bin/python -m compare.sequence --setup                                         # set-up per frame

Writes ``compare/results/OUT_<sequence>.{json,png}`` and ``compare/results/OUT.md`` (``--plans``:
``OUT_plans.md``, ``--setup``: ``OUT_setup.md``).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from compare.common import machine_info
from links1_app.cli import main as links1

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "compare" / "results"

SEQUENCES = {
    "orbit": ("scenes/sequences/orbit.xml", [("angle", "7.5*f")]),
    "blobs": ("scenes/blobs_moving.xml", [("x0", "-1.0 - 0.35*sin(t*pi)"), ("y1", "1.0 + 0.4*sin(2*t*pi)"),
                                          ("x2", "1.0 + 0.35*sin(t*pi)"), ("z3", "0.8 + 0.3*cos(t*pi)"),
                                          ("y4", "1.8 - 0.5*abs(sin(t*pi))")]),
}


def run(name, args, tmp) -> dict:
    scene, defines = SEQUENCES[name]
    out = f"{args.out}_{name}"
    argv = ["animate", str(ROOT / scene), "-o", os.path.join(tmp, f"{name}_%03d.png"), "--frames", str(args.frames),
            "--renderer", args.renderer, "--width", str(args.res), "--height", str(args.res), "--spp", "1",
            "--workers", str(args.nodes), "--tiles-per-node", str(args.tiles_per_node), "--report", str(RESULTS / f"{out}.json"), "--plot",
            str(RESULTS / f"{out}.png"), "--simulate", args.simulate, "--progress"]
    for k, v in defines:
        argv += ["-D", f"{k}={v}"]
    code = links1(argv)
    if code:
        raise SystemExit(f"links1 animate failed for {name} (exit {code})")
    return json.loads((RESULTS / f"{out}.json").read_text())


def table(name, rep) -> list[str]:
    one = rep["one_process"]
    lines = [f"### {name}: `{rep['scene'].split('/')[-1]}`, {len(rep['frames'])} frames, {rep['nodes']} nodes", "",
             f"One process, frames in turn: {one['makespan_s']:.2f} s "
             f"({len(one['frames']) / one['makespan_s']:.2f} frames/s); set-up per frame change (the node "
             f"updating its scene) median {_median(one['setup_s']):.3f} s.", "",
             "| way | makespan s | frames/s | x one process | x one process in CPU s | imbalance (busy s) mean / max | "
             "imbalance (CPU s) mean / max | imbalance (ray tests) mean / max | true efficiency | rank corr. predicted "
             "vs ray tests |", "|---|---|---|---|---|---|---|---|---|---|"]
    for s in rep["ways"]:
        lines.append(f"| {s['way']} | {s['makespan_s']:.2f} | {_f(s['frames_per_s'])} | "
                     f"{_f(s['throughput_vs_one_process'])} | {_f(s.get('throughput_cpu_vs_one_process'))} | "
                     f"{_f(s['imbalance_mean'], 3)} / {_f(s['imbalance_max'], 3)} | "
                     f"{_f(s.get('imbalance_cpu_mean'), 3)} / {_f(s.get('imbalance_cpu_max'), 3)} | "
                     f"{_f(s['imbalance_ray_tests_mean'], 3)} / {_f(s['imbalance_ray_tests_max'], 3)} | "
                     f"{_f(s['true_efficiency_mean'])} | {_f(s['predicted_vs_ray_tests_mean'])} |")
    sim = rep.get("simulation")
    if sim:
        lines += ["", f"Simulated (replay of the measured frames; split overhead {sim['overhead_s'] * 1e3:.1f} ms per "
                  "frame task, set-up per launch):", "",
                  "| nodes | latency-optimal (per-frame makespan s, efficiency) | throughput-optimal (frames/s, "
                  "efficiency) |", "|---|---|---|"]
        for n, b in sim["best"].items():
            lat, thr = b["latency"], b["throughput"]
            lines.append(f"| {n} | {lat['way']} ({lat['makespan_s']:.3f}, {lat['efficiency']:.2f}) | "
                         f"{thr['way']} ({thr['frames_per_s']:.2f}, {thr['efficiency']:.2f}) |")
    return lines + [""]


def _median(xs):
    xs = sorted(xs)
    return xs[len(xs) // 2] if xs else 0.0


def _f(v, d=2):
    return "-" if v is None else f"{v:.{d}f}"


def picture(path, names, frames=(0, 12, 24, 36), res=128) -> int:
    """A few frames of each sequence, one row per sequence (rendered in-process by animate())."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from links1.imaging.image import linear_to_srgb
    from links1_app.animate import animate
    fig, axes = plt.subplots(len(names), len(frames), figsize=(2.2 * len(frames), 2.3 * len(names)), squeeze=False)
    for row, name in zip(axes, names):
        scene, defines = SEQUENCES[name]
        res_ = animate(str(ROOT / scene), frames=list(frames), defines=defines, renderer="core", keep_images=True,
                       width=res, height=res, spp=4, progress=False)
        for ax, f in zip(row, frames):
            ax.imshow(np.clip(linear_to_srgb(res_.images[f][..., :3]), 0, 1))
            ax.set_title(f"{name}, frame {f}", fontsize=8)
            ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    return 0


#: plan rules of --plans: name -> (load source, strategy, tiles per node)
RULES = {"eq41 subscreen 16": ("eq41", "subscreen", 16),
         "previous subscreen 16": ("previous", "subscreen", 16),
         "previous (unmoved) subscreen 16": ("unmoved", "subscreen", 16),
         "previous subscreen 64": ("previous", "subscreen", 64),
         "previous subscreen-balanced 16": ("previous", "subscreen-balanced", 16),
         "previous subscreen-balanced 64": ("previous", "subscreen-balanced", 64),
         "eq41 subscreen-balanced 64": ("eq41", "subscreen-balanced", 64)}


def plans(args) -> int:
    """The imbalance in exact ray tests of each plan rule over each sequence (frames 1..F-1: frame
    0 has no previous frame), from one in-process render of the sequence."""
    import numpy as np
    from links1_app.animate import animate
    from links1_app.partition.sequence_report import plan_imbalance, previous_maps
    from links1.partition.loadmodel import load_table, scene_model
    from links1.tracing.render import CoreRenderer
    from links1_app.expressions import frame_values
    info = machine_info()
    md = [f"# Plan rules on measured sequences (`python -m compare.sequence --plans {' '.join(sys.argv[2:])}`)", "",
          f"{args.frames} frames at {args.res}x{args.res}, core renderer, spp 1, {args.nodes} nodes; imbalance = max / "
          "mean over the nodes of the frame's exact ray tests (the cost AOV) in each node's units. git "
          f"{info.get('git_commit')}.", ""]
    for name in args.sequences.split(","):
        scene, defines = SEQUENCES[name]
        frames = list(range(args.frames))
        one = animate(str(ROOT / scene), frames=frames, defines=defines, renderer="core", units="frames",
                      width=args.res, height=args.res, spp=1, progress=True)
        values = frame_values(defines, frames, 24.0)
        table = load_table(None, renderer="core")
        cams, eq41 = {}, {}
        for f in frames:
            r = CoreRenderer(str(ROOT / scene), params=values[f], width=args.res, height=args.res, spp=1)
            cams[f] = r.scene.camera
            eq41[f] = scene_model(r, path=str(ROOT / scene), params=values[f], table=table).load_map()
        moved = previous_maps(one, cams)
        md += [f"## {name}", "", "| rule | mean | max |", "|---|---|---|"]
        for rule, (src, strategy, tpn) in RULES.items():
            got = []
            for f in frames[1:]:
                load = {"eq41": eq41[f], "previous": moved[f] + 1.0, "unmoved": one.costs[f - 1] + 1.0}[src]
                got.append(plan_imbalance(one.costs[f], load, args.nodes, strategy=strategy, tiles_per_node=tpn))
            md.append(f"| {rule} | {np.mean(got):.3f} | {np.max(got):.3f} |")
        md.append("")
    (RESULTS / f"{args.out}_plans.md").write_text("\n".join(md))
    print("\n".join(md))
    return 0


def throughput(args) -> int:
    """Whole frames on the nodes against one process rendering them in turn (a node's threads),
    alternating, so that both see the machine's load of the same minutes."""
    import statistics
    from links1_app.animate import animate, make_backend
    from links1_app.partition.executors import InProcess
    from links1_app.partition.local_pool import threads_per_worker
    from links1_app.partition.runtime import limit_blas, set_threads
    set_threads(threads_per_worker(args.nodes))
    limit_blas(threads_per_worker(args.nodes))
    info = machine_info()
    md = [f"# Whole frames against one process (`python -m compare.sequence {' '.join(sys.argv[1:])}`)", "",
          f"{args.frames} frames at {args.res}x{args.res}, core, spp 1, {args.nodes} nodes of "
          f"{threads_per_worker(args.nodes)} thread(s), the one process with as many; {info.get('cpu')}, "
          f"{info.get('cores')} cores, load average at start {info.get('load_average_at_start')}, git "
          f"{info.get('git_commit')}.", ""]
    for name in args.sequences.split(","):
        scene, defines = SEQUENCES[name]
        kw = dict(frames=list(range(args.frames)), defines=defines, units="frames", width=args.res, height=args.res,
                  spp=1, progress=False)
        be = make_backend(workers=args.nodes)
        rows = []
        try:
            for _ in range(args.rounds):
                one = animate(str(ROOT / scene), backend=InProcess(chunk_factor=0), **kw).makespan_s
                nodes = animate(str(ROOT / scene), backend=be, **kw).makespan_s
                rows.append((one, nodes, one / nodes))
        finally:
            be.close()
        md += [f"## {name}", "", "| round | one process s | whole frames on the nodes s | ratio |", "|---|---|---|---|"]
        md += [f"| {i} | {a:.2f} | {b:.2f} | {c:.2f} |" for i, (a, b, c) in enumerate(rows)]
        md += [f"| median | {statistics.median(r[0] for r in rows):.2f} | {statistics.median(r[1] for r in rows):.2f} | "
               f"**{statistics.median(r[2] for r in rows):.2f}** |", ""]
    (RESULTS / f"{args.out}_throughput.md").write_text("\n".join(md))
    print("\n".join(md))
    return 0


def setup(args) -> int:
    """A node's set-up per frame change on the core: the loaded scene given the frame's values in
    place (``CoreRenderer.set_params``) against a fresh load of the file with them, each followed
    by what the first ray needs (the BVH, the integrator's plan); the two alternate frame by
    frame (which goes first alternates too), so both see the machine's load of the same seconds."""
    import statistics
    import time
    from links1.tracing.integrator import scene_plan
    from links1.tracing.render import CoreRenderer
    from links1_app.expressions import frame_values
    info = machine_info()
    md = [f"# Set-up per frame change (`python -m compare.sequence {' '.join(sys.argv[1:])}`)", "",
          f"{args.frames} frames at {args.res}x{args.res}, core; {info.get('cpu')}, {info.get('cores')} cores, load "
          f"average at start {info.get('load_average_at_start')}, git {info.get('git_commit')}. Each: the scene "
          "at the frame's values, then its BVH and integrator plan (the first ray's needs).", "",
          "| sequence | fresh load s (median) | in place s (median) | ratio of medians | per-frame ratio median |",
          "|---|---|---|---|---|"]
    opts = dict(width=args.res, height=args.res, spp=1)
    for name in args.sequences.split(","):
        scene, defines = SEQUENCES[name]
        path = str(ROOT / scene)
        values = frame_values(defines, list(range(args.frames)), 24.0)
        live = CoreRenderer(path, params=values[0], **opts)
        scene_plan(live.scene)

        def fresh(v):
            r = CoreRenderer(path, params=v, **opts)
            return r.scene.accel, scene_plan(r.scene)

        def in_place(v):
            live.set_params(v)
            return live.scene.accel, scene_plan(live.scene)

        rows = []
        for k in range(1, args.frames):
            got = {}
            for way in ((fresh, in_place) if k % 2 else (in_place, fresh)):
                t = time.perf_counter()
                way(values[k])
                got[way] = time.perf_counter() - t
            rows.append((got[fresh], got[in_place]))
        a, b = statistics.median(r[0] for r in rows), statistics.median(r[1] for r in rows)
        md.append(f"| {name} | {a:.4f} | {b:.4f} | **{a / b:.1f}** | {statistics.median(r[0] / r[1] for r in rows):.1f} |")
    md.append("")
    (RESULTS / f"{args.out}_setup.md").write_text("\n".join(md))
    print("\n".join(md))
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--nodes", type=int, default=2)
    ap.add_argument("--renderer", default="core")
    ap.add_argument("--sequences", default="orbit,blobs")
    ap.add_argument("--simulate", default="2,4,8,16,64")
    ap.add_argument("--tiles-per-node", type=int, default=64,
                    help="tiles per node of split frames, every way alike (default 64: a tile is then under 1 %% of a "
                         "2-node frame, so a cut between tiles costs little balance; --plans shows 16 against 64)")
    ap.add_argument("--out", default="sequence")
    ap.add_argument("--plans", action="store_true",
                    help="instead: render each sequence once in-process and give, per plan rule, the imbalance in "
                         "exact ray tests its plans would have at --nodes (no timing: OUT_plans.md)")
    ap.add_argument("--rounds", type=int, default=0, metavar="R",
                    help="instead: throughput only, R alternating rounds of one process and whole frames on the "
                         "nodes (the same frames, the pool kept), ratios per round and their median (OUT_throughput.md)")
    ap.add_argument("--picture", default=None, metavar="PNG",
                    help="instead: frames 0, 12, 24, 36 of each sequence at 128^2 side by side (the README's picture)")
    ap.add_argument("--setup", action="store_true",
                    help="instead: a node's set-up per frame change on the core, in place against a fresh load of "
                         "the file, alternating (OUT_setup.md)")
    args = ap.parse_args(argv)
    if args.setup:
        return setup(args)
    if args.picture:
        return picture(args.picture, args.sequences.split(","))
    if args.plans:
        return plans(args)
    if args.rounds:
        return throughput(args)
    import tempfile
    RESULTS.mkdir(parents=True, exist_ok=True)
    info = machine_info()
    md = [f"# Sequences over the nodes (`python -m compare.sequence {' '.join(argv or sys.argv[1:])}`)", "",
          f"Machine: {info.get('cpu')}, {info.get('cores')} cores, load average at start "
          f"{info.get('load_average_at_start')}, git {info.get('git_commit')}; {args.renderer} renderer, "
          f"{args.res}x{args.res}, spp 1.", ""]
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.sequences.split(","):
            md += table(name, run(name, args, tmp))
    (RESULTS / f"{args.out}.md").write_text("\n".join(md))
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    sys.exit(main())
