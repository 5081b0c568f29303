"""``links1 animate``: a sequence of frames from one scene file, over the nodes.

Per-frame ``$name`` values are expressions of the frame number ``f`` and time ``t``
(:mod:`links1_app.expressions`), or, from Python, a function that updates the loaded scene
(:func:`animate`'s ``update``). Each node loads the scene once and updates it per frame
(:class:`links1_app.partition.sequence.SequenceRenderer`). Units (``--units``): whole frames,
screen partitions of each frame in turn, or both; a split frame is planned from eq. 4.1's object
loads or from the previous frame's measured cost (the ``cost`` AOV, ray tests per pixel).
Every frame equals the single-process render of that frame bit for bit.
"""
from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from links1.errors import UsageError
from links1.imaging.image import write_image
from links1.interrupts import raise_if_interrupted
from links1.partition.loadmodel import load_table, scene_model
from links1.partition.strategies import STRATEGIES, make_plan
from links1.tracing.aovs import aov_channel, check_aovs, channel_names
from links1.tracing.render import CoreRenderer

from .expressions import frame_values, parse_frames
from .partition.executors import InProcess, default_log, render_plan
from .partition.local_pool import LocalPool
from .partition.runtime import get_renderer
from .partition.sequence import (PLAN_FROM, UNIT_CHOICES, frame_units_plan, imbalance, node_loads, rank_correlation,
                                 reproject, sequence_spec, shifted)

#: whole-frame units: frames per run (a block) at most this many pixels, at least two per node
BLOCK_PIXELS = 1 << 22

ANIMATE_EXAMPLES = """examples:
  links1 animate scenes/sequences/orbit.xml -o out/orbit_%04d.png --frames 0:48 -D angle='7.5*f' --workers 2
  links1 animate scenes/many.xml -o out/f.exr --frames 48 --fps 24 \\
      -D eye='14*sin(radians(7.5*f)), 9, 14*cos(radians(7.5*f))' --units frames --workers 2
  links1 animate scenes/blobs_moving.xml -o out/b_%03d.png --frames 0:24 --report r.json --plot r.png
"""


def output_path(pattern: str, frame: int) -> str:
    """The file of ``frame``: ``pattern`` with a printf field (``out/f_%04d.exr``), else
    ``_NNNN`` before the extension."""
    if "%" in pattern:
        try:
            return pattern % frame
        except (TypeError, ValueError):
            raise UsageError(f"output {pattern!r}: expected one integer field such as %04d") from None
    root, ext = os.path.splitext(pattern)
    return f"{root}_{frame:04d}{ext}"


@dataclass
class SequenceResult:
    """What a sequence run did: the frames written and, per frame, how it was split."""

    written: list = field(default_factory=list)     # paths written in this run
    skipped: list = field(default_factory=list)     # frames already on disk (--checkpoint)
    frames: list = field(default_factory=list)      # per frame rendered: a dict of figures
    makespan_s: float = 0.0                          # the sequence's wall time (root clock, nodes started)
    units: str = ""
    n_nodes: int = 0
    faults: list = field(default_factory=list)
    images: dict = field(default_factory=dict)       # frame -> image, when asked to keep them
    costs: dict = field(default_factory=dict)        # frame -> its ray tests per pixel (the cost AOV)
    depths: dict = field(default_factory=dict)       # frame -> its depth AOV
    setup_s: list = field(default_factory=list)      # in-process: each frame change's set-up on the node
    startup_s: float = 0.0                           # the nodes' start (scene loaded), before the clock
    planning_s: float = 0.0                          # the root's eq. 4.1 loads, before the clock


class _Frames:
    """Collects units of the tall film into frames; a frame is handed on once every pixel is in
    (render_plan's ``checkpoint``: nothing to resume at unit level, every unit saved here)."""

    def __init__(self, width, height, ks, on_frame):
        self.w, self.h = width, height
        self.left = {k: width * height for k in ks}
        self.buf: dict = {}
        self.on_frame = on_frame

    def load(self, unit):
        return None

    def save(self, unit, pixels):
        k = unit.y0 // self.h
        a = self.buf.get(k)
        if a is None:
            a = self.buf[k] = np.zeros((self.h, self.w, pixels.shape[2]), dtype=np.float64)
        y = unit.y0 - k * self.h
        a[y:y + unit.h, unit.x0:unit.x0 + unit.w] = pixels
        self.left[k] -= unit.w * unit.h
        if self.left[k] == 0:
            self.on_frame(k, self.buf.pop(k))


def make_backend(*, workers=0, dask_local=None, scheduler=None, static=False, chunk_factor=0):
    """The nodes of a sequence: in-process, the local pool, or Dask (results through the pipe:
    a tall film has no shared frame)."""
    if scheduler and dask_local:
        raise UsageError("--scheduler and --dask-local are exclusive")
    if scheduler or dask_local:
        from .partition.cli import _dask_backend
        return _dask_backend().DaskBackend(scheduler=scheduler, n_local=dask_local, static=static,
                                           chunk_factor=chunk_factor)
    if not workers:
        return InProcess(chunk_factor=chunk_factor)
    return LocalPool(int(workers), chunk_factor=chunk_factor, shared_frame=False)


def animate(scene, output=None, *, frames, defines=(), fps=24.0, renderer="core", update=None, backend=None,
            units="partition", partition="subscreen", plan_from="previous", tiles_per_node=16, resume=False,
            progress=None, keep_images=False, aovs=(), log=default_log, cache=None, **options) -> SequenceResult:
    """Render ``frames`` (frame numbers) of ``scene`` to ``output`` (a pattern, :func:`output_path`;
    None: nothing written, ``keep_images`` keeps them in the result).

    ``defines``: ``[(name, text)]`` per-frame values (:func:`links1_app.expressions.frame_values`);
    ``update``: a module-level function ``update(params, f, t)`` that changes the loaded scene
    (Mitsuba: ``mi.traverse(scene)``, the core: its Scene); ``backend``: the nodes
    (:func:`make_backend`; default in-process), kept open for the caller; ``units``:
    :data:`~links1_app.partition.sequence.UNIT_CHOICES`; ``partition`` / ``plan_from``: how a split
    frame is planned; ``resume``: frames whose file exists are not rendered again; ``cache``: a
    dict kept across calls (``"eq41"``: frame -> eq. 4.1 load map, ``"camera"``: frame -> the core's
    camera), so experiments read each frame once.
    ``options``: the renderer's (spp, width, height, max_depth, seed, params, ...)."""
    if units not in UNIT_CHOICES:
        raise UsageError(f"unknown --units {units!r}; choose from {', '.join(UNIT_CHOICES)}")
    if plan_from not in PLAN_FROM:
        raise UsageError(f"unknown --plan-from {plan_from!r}; choose from {', '.join(PLAN_FROM)}")
    if partition not in STRATEGIES:
        raise UsageError(f"unknown --partition {partition!r}; choose from {', '.join(STRATEGIES)}")
    frames = list(frames)
    values = frame_values(list(defines), frames, float(fps))
    user_aovs = check_aovs(aovs)
    # the next frame's plan reads the cost (and, to follow the camera, the depth) of this one
    all_aovs = user_aovs + tuple(a for a in ("cost", "depth") if a not in user_aovs)
    res = SequenceResult(units=units)
    paths = {f: output_path(output, f) for f in frames} if output else {}
    for p in paths.values():
        if not p.lower().endswith((".exr", ".png")):
            raise UsageError(f"output {p!r}: unknown image type (use .exr or .png)")
        if p.lower().endswith(".png") and user_aovs:
            raise UsageError("AOVs need an EXR output (-o something_%04d.exr)")
    todo = [k for k, f in enumerate(frames) if not (resume and paths and os.path.exists(paths[f]))]
    res.skipped = [frames[k] for k in range(len(frames)) if k not in set(todo)]
    backend = backend or InProcess(chunk_factor=0)
    spec = sequence_spec(renderer, scene, values, numbers=frames, times=[f / fps for f in frames],
                         update=update, aovs=all_aovs, **options)
    if not todo:
        return res
    # the root reads the scene with the core (shapes, camera: eq. 4.1) for the film size and loads
    core_opts = {k: v for k, v in options.items() if k in ("spp", "max_depth", "seed", "width", "height", "sensor")}
    base = dict(options.get("params") or {})
    probe = CoreRenderer(scene, params={**base, **values[0]}, **core_opts)
    W, H = probe.film_size
    channels = channel_names(all_aovs)
    c_cost, c_depth = aov_channel(channels, "cost"), aov_channel(channels, "depth")
    keep = [i for i, c in enumerate(channels) if "." not in c or c.split(".")[0] in user_aovs]
    bar = tqdm(total=len(frames), initial=len(res.skipped), unit="frame", desc="links1 animate", file=sys.stderr,
               dynamic_ncols=True, leave=False, disable=None if progress is None else not progress)
    costs: dict = {}
    depths: dict = {}

    def on_frame(k, img):
        costs[k] = img[..., c_cost]
        depths[k] = img[..., c_depth]
        res.costs[frames[k]] = costs[k]
        res.depths[frames[k]] = depths[k]
        out = img[..., keep]
        f = frames[k]
        if f in paths:
            raise_if_interrupted()   # a Ctrl-C whose exception Python dropped: no frame written after it
            p = paths[f]
            os.makedirs(os.path.dirname(os.path.abspath(p)), exist_ok=True)
            if p.lower().endswith(".png"):
                write_image(p, out[..., :3])
            else:
                write_image(p, out, [channels[i] for i in keep])
            res.written.append(p)
        if keep_images:
            res.images[f] = out
        bar.update(1)

    table = load_table(None, renderer=renderer)

    cache = {} if cache is None else cache
    maps, cams = cache.setdefault("eq41", {}), cache.setdefault("camera", {})
    cams[frames[0]] = probe.scene.camera

    def read(k):      # the root's scene with frame k's values (updated in place: one load)
        probe.set_params({**base, **values[k]})
        cams[frames[k]] = probe.scene.camera
        return probe

    def eq41_map(k):
        if frames[k] not in maps:
            maps[frames[k]] = scene_model(read(k), path=scene, params={**base, **values[k]}, table=table).load_map()
        return maps[frames[k]]

    def previous_map(k):
        """Frame k-1's measured cost, moved through the camera's motion (sequence.reproject)."""
        return reproject(costs[k - 1], depths[k - 1], cams[frames[k - 1]], cams[frames[k]])

    if units == "partition":   # the root's eq. 4.1 loads, read before the clock (planning)
        t = time.perf_counter()
        for k in todo:
            if plan_from == "eq41" or (k - 1) not in set(todo):
                eq41_map(k)
            elif frames[k] not in cams:
                read(k)      # its camera: the previous frame's cost is moved through the motion
        res.planning_s = time.perf_counter() - t
    try:
        t = time.perf_counter()
        backend.start(spec)      # nodes started, the scene loaded on each: before the clock
        res.startup_s = time.perf_counter() - t
        t0 = time.perf_counter()
        n = max(1, int(backend.n_nodes))
        res.n_nodes = n
        if units == "partition":
            for k in todo:
                _split_frame(k, frames, W, H, n, backend, spec, res, on_frame, costs, eq41_map, previous_map,
                             partition, plan_from, tiles_per_node, log)
        else:
            # blocks of frames, each one run: the root's frame buffer holds a block, not the sequence
            size = max(2 * n, BLOCK_PIXELS // (W * H))
            per = {}
            for b in range(0, len(todo), size):
                block = todo[b:b + size]
                last = b + size >= len(todo)
                split = min(n, len(block)) if units == "both" and n > 1 and last else 0
                plan = frame_units_plan(W, H, block, n, len(frames), split_last=split, tiles_per_node=tiles_per_node)
                r = render_plan(plan, spec, backend, checkpoint=_Frames(W, H, block, on_frame), progress=False,
                                log=log)
                res.faults += r.faults
                for i, info in r.records.items():
                    per.setdefault(plan.units[i].y0 // H, []).append(info)
            for k in todo:
                infos = per.get(k, [])
                launches = {tuple(i["launch"]): (i["launch_seconds"], i.get("launch_cpu_s", 0.0), i.get("node", 0))
                            for i in infos if i.get("launch")}
                res.frames.append({"frame": frames[k], "units": len(infos),
                                   "render_s": float(sum(v[0] for v in launches.values())),
                                   "cpu_s": float(sum(v[1] for v in launches.values())),
                                   "nodes": sorted({str(v[2]) for v in launches.values()}),
                                   "ray_tests": float(costs[k].sum()) if k in costs else None})
    finally:
        bar.close()
    res.makespan_s = time.perf_counter() - t0
    if isinstance(backend, InProcess):   # the root's own node: its set-up per frame change
        res.setup_s = list(getattr(get_renderer(spec), "setup_s", []))
    return res


def _split_frame(k, frames, W, H, n, backend, spec, res, on_frame, costs, eq41_map, previous_map, partition,
                 plan_from, tiles_per_node, log):
    """Frame ``k`` split over the nodes, planned from eq. 4.1 or the previous frame's cost."""
    source = "previous" if plan_from == "previous" and (k - 1) in costs else "eq41"
    t = time.perf_counter()
    load = previous_map(k) + 1.0 if source == "previous" else eq41_map(k)   # + the camera ray itself
    plan = make_plan(partition, W, H, n, tiles_per_node=tiles_per_node, unit="tile", load_map=load)
    planning_s = time.perf_counter() - t
    tall = shifted(plan, k, H, len(frames))
    sink = _Frames(W, H, [k], on_frame)
    r = render_plan(tall, spec, backend, checkpoint=sink, progress=False, log=log)
    res.faults += r.faults
    cost = costs.get(k)
    busy, cpu, tests = node_loads(tall, r.records, cost, H, n)
    unit_tests = [float(cost[u.y0:u.y0 + u.h, u.x0:u.x0 + u.w].sum()) for u in plan.units] if cost is not None else []
    res.frames.append({
        "frame": frames[k], "plan_from": source, "partition": partition, "units": len(plan.units),
        "makespan_s": r.makespan_s, "planning_s": planning_s, "busy_s": busy.tolist(), "cpu_s": cpu.tolist(),
        "ray_tests": tests.tolist(), "imbalance": imbalance(busy), "imbalance_cpu": imbalance(cpu),
        "imbalance_ray_tests": imbalance(tests),
        "predicted_vs_ray_tests": rank_correlation(plan.predicted, unit_tests) if plan.predicted is not None else None,
    })


# ---------------------------------------------------------------------- command line
def add_cli(sub) -> None:
    """``links1 animate`` (its ``func`` is :func:`run_cli`)."""
    import argparse
    from .cli_options import add_progress_arguments, add_render_arguments, int_option
    p = sub.add_parser("animate", help="render a sequence of frames (per-frame $name values) over the nodes",
                       epilog=ANIMATE_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter,
                       description="Render frames of one scene file, its $name parameters given per frame as "
                       "expressions of the frame number f and time t (-D angle='7.5*f'); each node loads the "
                       "scene once and updates it per frame.")
    add_render_arguments(p)
    p.add_argument("-o", "--output", required=True,
                   help="frame files: a pattern with one integer field (out/f_%%04d.exr), else _NNNN is added")
    p.add_argument("--frames", required=True, help="START:STOP[:STEP] or COUNT (frame numbers, as Python's range)")
    p.add_argument("--fps", type=float, default=24.0, help="frames per second: t = f / fps (default 24)")
    p.add_argument("--units", choices=UNIT_CHOICES, default="partition",
                   help="what a node is given: whole frames, screen partitions of each frame in turn "
                        "(default), or both (whole frames, the last frames split)")
    p.add_argument("--partition", choices=STRATEGIES, default="subscreen", help="how a split frame is cut (default subscreen)")
    p.add_argument("--plan-from", choices=PLAN_FROM, default="previous",
                   help="a split frame's loads: eq. 4.1's object counts, or the previous frame's measured cost "
                        "(default; the first frame uses eq. 4.1)")
    p.add_argument("--tiles-per-node", type=int_option("--tiles-per-node", 1), default=16)
    p.add_argument("--workers", type=int_option("--workers", 0), default=0, help="local worker processes (0: in-process)")
    p.add_argument("--dask-local", type=int_option("--dask-local", 1), default=None, metavar="N")
    p.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT")
    p.add_argument("--checkpoint", action="store_true",
                   help="frames already on disk are not rendered again (every written frame is whole)")
    p.add_argument("--video", default=None, metavar="MP4",
                   help="also encode the frames (sRGB, 8 bit) as a video at --fps (needs links1[video]: imageio-ffmpeg)")
    g = p.add_argument_group("sequence experiment")
    g.add_argument("--report", default=None, metavar="JSON",
                   help="run the experiment: one process rendering the frames in turn (with a node's threads; it "
                        "writes the frames), then "
                        "each of --ways on the nodes; per frame and for the sequence: makespan, imbalance, true "
                        "efficiency, predicted vs measured correlation, throughput")
    g.add_argument("--ways", default="eq41,previous,dynamic,frames", metavar="LIST",
                   help="--report's ways: eq41, previous (subscreen from eq. 4.1 / the previous frame's cost), "
                        "dynamic (guided tiles), frames (whole frames); default all four")
    g.add_argument("--plot", default=None, metavar="PNG", help="--report's plot: imbalance and makespan per frame by way")
    g.add_argument("--simulate", default=None, metavar="N,...",
                   help="--report: replay the measured sequence at these node counts, latency (one frame split "
                        "over N) and throughput (frames over N)")
    add_progress_arguments(p)
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    p.set_defaults(func=run_cli)


def run_cli(args) -> int:
    from .cli_options import adaptive_options, progress_choice
    frames = parse_frames(args.frames)
    frame_values(args.defines, frames[:1], args.fps)    # a bad -D: one line before anything starts
    if args.video:
        _video_writer()                                  # a missing encoder: one line before rendering
    opts = dict(spp=args.spp, width=args.width, height=args.height, max_depth=args.max_depth, seed=args.seed)
    if args.sensor is not None:
        opts["sensor"] = args.sensor
    if args.light_samples is not None:
        opts["light_samples"] = args.light_samples
    opts.update(adaptive_options(args))
    opts = {k: v for k, v in opts.items() if v is not None}
    if args.renderer == "mitsuba":
        from .renderers import require_mitsuba
        require_mitsuba(args.variant)
        if args.variant:
            opts["variant"] = args.variant
    if args.report:
        return _experiment(args, frames, opts)
    if args.plot or args.simulate:
        raise UsageError("--plot and --simulate need --report JSON")
    static = args.units == "partition" and args.partition != "dynamic"
    backend = make_backend(workers=args.workers, dask_local=args.dask_local, scheduler=args.scheduler,
                           static=static)
    try:
        res = animate(args.scene, args.output, frames=frames, defines=args.defines, fps=args.fps,
                      renderer=args.renderer, backend=backend, units=args.units, partition=args.partition,
                      plan_from=args.plan_from, tiles_per_node=args.tiles_per_node, resume=args.checkpoint,
                      progress=progress_choice(args), aovs=args.aov, **opts)
    except KeyboardInterrupt:
        getattr(backend, "terminate", backend.close)()
        raise
    finally:
        backend.close()
    if res.skipped:
        print(f"links1: {len(res.skipped)} of {len(frames)} frames were on disk already", file=sys.stderr)
    print(f"links1: wrote {len(res.written)} frames ({args.output}, {res.units} units, {res.n_nodes} node(s), "
          f"{res.makespan_s:.2f} s)", file=sys.stderr)
    if args.video:
        raise_if_interrupted()
        write_video(args.video, [output_path(args.output, f) for f in frames], args.fps)
        print(f"links1: wrote {args.video} ({len(frames)} frames at {args.fps:g} fps)", file=sys.stderr)
    return 0


def _video_writer():
    """imageio-ffmpeg's frame writer (it ships its own ffmpeg), or a one-line error naming the extra."""
    try:
        import imageio_ffmpeg   # lazy: an optional extra
    except ImportError:
        raise UsageError("--video needs imageio-ffmpeg (it ships its own encoder): pip install 'links1[video]'") from None
    return imageio_ffmpeg.write_frames


def write_video(path, frame_paths, fps) -> None:
    """Encode the frame files (EXR: linear, to sRGB; PNG: as stored) as a video, written atomically."""
    from links1.imaging.image import atomic_write, linear_to_srgb, read_image
    write_frames = _video_writer()

    def encode(tmp):
        gen = None
        for p in frame_paths:
            img = np.clip(linear_to_srgb(read_image(p)[..., :3]), 0.0, 1.0)
            px = np.ascontiguousarray((img * 255.0 + 0.5).astype(np.uint8))
            if gen is None:
                h, w = px.shape[:2]
                gen = write_frames(tmp, (w, h), fps=fps, macro_block_size=1)
                gen.send(None)
            gen.send(px)
        if gen is not None:
            gen.close()
    atomic_write(path, encode)


def _experiment(args, frames, opts) -> int:
    """``animate --report``: the one-process reference, then each way on the nodes (sequence_report)."""
    from .partition import sequence_report as sr
    from .partition.checkpoint import atomic_write_json
    from .partition.handout import CHUNK_FACTOR
    from .partition.local_pool import threads_per_worker
    from .partition.runtime import limit_blas, set_threads
    ways = [w.strip() for w in args.ways.split(",") if w.strip()]
    bad = [w for w in ways if w not in sr.WAYS]
    if bad:
        raise UsageError(f"--ways: unknown {', '.join(bad)}; choose from {', '.join(sr.WAYS)}")
    sims = [int(v) for v in args.simulate.split(",")] if args.simulate else []
    if any(v < 1 for v in sims):
        raise UsageError(f"--simulate {args.simulate!r}: node counts must be >= 1")
    common = dict(frames=frames, defines=args.defines, fps=args.fps, renderer=args.renderer, progress=progress_of(args),
                  tiles_per_node=args.tiles_per_node, aovs=args.aov, **opts)
    cache: dict = {}
    nodes = args.dask_local or args.workers or 2
    # the reference is one node as the nodes are: the renderer threads each of them gets
    # (cores / nodes; the core's BLAS would otherwise use every core for the one process alone)
    threads = threads_per_worker(nodes)
    set_threads(threads, args.renderer)
    old = limit_blas(threads)
    try:
        one = animate(args.scene, args.output, backend=InProcess(chunk_factor=0), units="frames", cache=cache,
                      **common)
    finally:
        limit_blas(old or 0)
    print(f"links1: one process: {len(frames)} frames in {one.makespan_s:.2f} s", file=sys.stderr)
    be = make_backend(workers=nodes if not (args.dask_local or args.scheduler) else 0,
                      dask_local=args.dask_local, scheduler=args.scheduler, static=False)
    summaries = []
    try:
        for way in ways:
            units, partition, plan_from = sr.WAYS[way]
            be.chunk_factor = CHUNK_FACTOR if way == "dynamic" else 0
            res = animate(args.scene, None, backend=be, units=units, partition=partition, plan_from=plan_from,
                          cache=cache, **common)
            summaries.append(sr.summarise(way, res, one, res.n_nodes))
            print(f"links1: {way}: {res.makespan_s:.2f} s", file=sys.stderr)
    except KeyboardInterrupt:
        getattr(be, "terminate", be.close)()
        raise
    finally:
        be.close()
    n = summaries[0]["nodes"] if summaries else 1
    report = {"scene": args.scene, "renderer": args.renderer, "frames": frames, "nodes": n, "threads_per_node": threads,
              "defines": [list(d) for d in args.defines], "options": opts,
              "one_process": {"frames": one.frames, "makespan_s": one.makespan_s, "setup_s": one.setup_s},
              "ways": summaries,
              "throughput": {s["way"]: s["throughput_vs_one_process"] for s in summaries}}
    if sims:
        overhead = sr.split_overhead(summaries)
        prev = sr.previous_maps(one, cache.get("camera", {}))
        rows = sr.simulate_sequence(one, one.costs, cache.get("eq41", {}), sims, tiles_per_node=args.tiles_per_node,
                                    overhead_s=overhead, previous=prev)
        report["simulation"] = {"overhead_s": overhead, "rows": rows, "best": sr.best_choices(rows)}
    atomic_write_json(args.report, report)
    if args.plot:
        sr.plot(report, args.plot)
    print(sr.format_summary(report), file=sys.stderr)
    for k, b in (report.get("simulation") or {}).get("best", {}).items():
        print(f"links1: simulated {k} nodes: latency-optimal {b['latency']['way']} (efficiency "
              f"{b['latency']['efficiency']:.2f}), throughput-optimal {b['throughput']['way']} (efficiency "
              f"{b['throughput']['efficiency']:.2f})", file=sys.stderr)
    return 0


def progress_of(args):
    from .cli_options import progress_choice
    return progress_choice(args)
