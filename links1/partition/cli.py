"""Command-line side of the partitioning layer.

``links1.frontends.cli`` calls, when present:

``add_render_options(parser)``
    adds --workers/--partition/--tiles-per-node/--unit/--order/--scheduler/--dask-local/
    --checkpoint/--cull/--load-table to ``links1 render``.
``render_distributed(args) -> (image (H, W, C) float64, channel names)``
    renders with those options (``args`` also carries the shared render options: scene,
    renderer, variant, integrator, spp, width, height, max_depth, seed, aov, defines,
    min_weight, no_progress). ``--workers auto`` (the default) uses the usable cores for
    the core renderer when more than one is there and the frame has at least
    ``AUTO_MIN_WORK`` pixel samples; otherwise (and always for the Mitsuba renderer, whose
    Dr.Jit kernels already use every core) it renders the full frame in-process.
``add_cli(subparsers)``
    adds ``links1 schedule``.
"""
from __future__ import annotations

import argparse
import os
import sys
import warnings

from ..frontends.cli_options import add_progress_arguments, int_option, progress_choice
from ..errors import SceneError, UsageError
from ..scene.xmlparse import SceneWarning
from .strategies import STRATEGIES, UNITS

#: Frames smaller than this (pixels x samples) render in-process under --workers auto.
AUTO_MIN_WORK = 128 * 128

_BACKENDS: dict = {}  # reused across --repeat frames in one process


def _workers(text):
    return text if text == "auto" else int_option("--workers (an integer or 'auto')", 0)(text)


def _pos(name):
    return int_option(name, 1)


def _nodes_list(text):
    try:
        v = [int(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"--simulate expects a list like 1,4,16,64, got {text!r}") from None
    if not v or min(v) < 1:
        raise argparse.ArgumentTypeError(f"--simulate node counts must be >= 1, got {text!r}")
    return v


def _partition_options(p, *, nodes_option: bool):
    g = p.add_argument_group("screen partitioning (paper section 4)")
    if not nodes_option:
        g.add_argument("--workers", type=_workers, default="auto",
                       help="local worker processes: 0 renders in-process; default auto: the usable cores "
                            "when more than one (and the frame is not tiny)")
    g.add_argument("--partition", choices=STRATEGIES, default="dynamic",
                   help="subscreen (4-1, eq. 4.1), scanline (4-2), dynamic (4-3, default), grid (baseline), "
                        "subscreen-balanced (4-1's tiles and walk, cuts at the least max load; not the paper's)")
    g.add_argument("--tiles-per-node", type=_pos("--tiles-per-node"), default=16,
                   help="tiles per node for subscreen/grid/dynamic tiles (paper: 16 or 64; default 16)")
    g.add_argument("--unit", choices=UNITS, default="tile", help="unit handed out by dynamic (default tile)")
    g.add_argument("--chunk-factor", type=int_option("--chunk-factor", 0), default=None, metavar="K",
                   help="dynamic: a node that asks for work gets ceil(remaining / (K x nodes)) units in one launch "
                        "(guided self-scheduling; default 2); 0 = one unit at a time (the paper's 4-3)")
    g.add_argument("--chunk-by", choices=("units", "load"), default="units",
                   help="dynamic: a guided chunk counts units (default: ceil(remaining / (K x nodes)) of them) or "
                        "predicted load (eq. 4.1: units up to remaining load / (K x nodes)): with lpt order the "
                        "first chunks hold the heaviest units, and 'load' keeps them from unbalancing the tail")
    g.add_argument("--order", choices=("lpt", "walk"), default=None,
                   help="dynamic dispatch order: lpt = largest predicted load first (default), walk = bottom-left first")
    g.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT", help="render on an existing Dask cluster")
    g.add_argument("--dask-local", type=_pos("--dask-local"), default=None, metavar="N",
                   help="start a Dask LocalCluster of N workers bound to 127.0.0.1")
    g.add_argument("--checkpoint", default=None, metavar="DIR",
                   help="keep finished units in DIR; a re-run renders only what is missing")
    g.add_argument("--cull", action="store_true",
                   help="give nodes only the objects their units need (4-4; --renderer core)")
    g.add_argument("--load-table", default=None, metavar="JSON", help="per-object load table (eq. 4.1) overrides")


def add_render_options(parser) -> None:
    """Add the distributed-rendering options to ``links1 render``."""
    _partition_options(parser, nodes_option=False)


# ---------------------------------------------------------------------- shared set-up
def _spec_from_args(args):
    from .runtime import RendererSpec
    opts = dict(params=dict(getattr(args, "defines", []) or []), spp=args.spp, max_depth=args.max_depth,
                seed=args.seed, aovs=tuple(getattr(args, "aov", ()) or ()), width=args.width, height=args.height)
    if getattr(args, "sensor", None) is not None:
        opts["sensor"] = args.sensor
    if getattr(args, "min_weight", None) is not None:   # 0 is a value (trace every branch)
        opts["min_weight"] = args.min_weight
    if getattr(args, "light_samples", None) is not None:
        opts["light_samples"] = args.light_samples
    from ..frontends.cli_options import adaptive_options
    opts.update(adaptive_options(args))
    if args.renderer == "mitsuba":
        opts["variant"] = getattr(args, "variant", None)
        if getattr(args, "integrator", "links1") == "scene":
            opts["integrator"] = "scene"
    elif getattr(args, "variant", None) is not None or getattr(args, "integrator", "links1") != "links1":
        raise UsageError("--variant and --integrator apply to --renderer mitsuba only")
    return RendererSpec.make(args.renderer, args.scene, **opts)


def _check_backend_args(args, workers):
    if args.scheduler and args.dask_local:
        raise UsageError("--scheduler and --dask-local are exclusive")
    if (args.scheduler or args.dask_local) and workers not in ("auto", 0, None):
        raise UsageError("--workers is for the local pool; with Dask give --scheduler or --dask-local only")


def _model_and_channels(spec, args, timing=None):
    """The root's scene model (core loader: shapes, camera) and the output channel names
    (``timing``: a dict that gets ``root_load_s``, the root's scene read, and ``model_s``)."""
    import time

    from ..tracing.aovs import channel_names
    timing = {} if timing is None else timing
    from .loadmodel import load_table, scene_model
    table = load_table(getattr(args, "load_table", None), renderer=spec.kind)
    root_spec = spec
    if spec.kind != "core":  # the root only needs shapes and the camera: read them with the core
        from .runtime import RendererSpec
        kw = {k: v for k, v in spec.kwargs.items() if k in ("params", "spp", "max_depth", "seed", "aovs", "width",
                                                             "height", "sensor")}
        root_spec = RendererSpec.make("core", spec.path, **kw)
    try:
        from .runtime import get_renderer
        with warnings.catch_warnings():
            if root_spec is not spec:  # the core's approximations do not concern another renderer
                warnings.simplefilter("ignore", SceneWarning)
            t = time.perf_counter()
            r = get_renderer(root_spec)
            timing["root_load_s"] = time.perf_counter() - t
        t = time.perf_counter()
        model = scene_model(r, path=spec.path, params=spec.kwargs.get("params"), table=table)
        timing["model_s"] = time.perf_counter() - t
        channels = list(r.channels)
    except UsageError:
        raise
    except Exception as e:  # noqa: BLE001 - the core cannot read a Mitsuba-only scene: build the real one
        if root_spec is spec or (isinstance(e, SceneError) and "not supported by the core" not in e.message):
            raise   # a bad scene: the renderer refuses it too (renderers._validate_for_mitsuba), one error line
        warnings.warn(f"the core cannot read {spec.path} ({e}); loading it with {spec.kind} in the root")
        from .runtime import get_renderer
        r = get_renderer(spec)
        model = scene_model(r, path=spec.path, params=spec.kwargs.get("params"), table=table)
        channels = list(r.channels)
    if spec.kind != "core":
        channels = channel_names(spec.kwargs.get("aovs", ()))
    return model, channels


def _backend(args, workers, static):
    from .executors import CHUNK_FACTOR
    k = CHUNK_FACTOR if getattr(args, "chunk_factor", None) is None else args.chunk_factor
    by = getattr(args, "chunk_by", None) or "units"
    key = (args.scheduler, args.dask_local, workers, static)
    be = _BACKENDS.get(key)
    if be is not None:
        be.chunk_factor, be.chunk_by = k, by
        return be
    if args.scheduler or args.dask_local:
        try:
            from .dask_backend import DaskBackend
        except ImportError as e:
            raise UsageError(f"Dask is not installed ({e}); pip install 'links1[dask]'") from None
        be = DaskBackend(scheduler=args.scheduler, n_local=args.dask_local, static=static, chunk_factor=k,
                         chunk_by=by)
    elif workers == 0:
        from .executors import InProcess
        be = InProcess(chunk_factor=k, chunk_by=by)
    else:
        from .executors import LocalPool
        be = LocalPool(int(workers), chunk_factor=k, chunk_by=by)
    _BACKENDS[key] = be
    import atexit
    atexit.register(be.close)
    return be


def _cull_map(plan, model, spec):
    if spec.kind != "core":
        warnings.warn("--cull needs --renderer core (the Mitsuba scene cannot drop objects); ignored")
        return None
    import numpy as np
    touch = model.touching([u.window for u in plan.units])
    out = {}
    if plan.static:
        for k in range(plan.n_nodes):
            ids = plan.node_units(k)
            prim = touch[ids].any(axis=0)
            need = tuple(int(j) for j in np.flatnonzero(prim | model.secondary(prim)))
            out.update({i: need for i in ids})
    else:
        for i in range(len(plan.units)):
            prim = touch[i]
            out[i] = tuple(int(j) for j in np.flatnonzero(prim | model.secondary(prim)))
    return out


def prepare(args, *, nodes=None):
    """Spec, model, channels, plan and backend for ``args`` (shared by render and schedule)."""
    from .strategies import make_plan
    workers = getattr(args, "workers", nodes)
    _check_backend_args(args, workers)
    import time
    spec = _spec_from_args(args)
    timing = {}
    model, channels = _model_and_channels(spec, args, timing)
    if workers == "auto":
        from .executors import default_workers
        work = model.width * model.height * (spec.kwargs.get("spp") or 1)
        workers = default_workers() if work >= AUTO_MIN_WORK else 0
    if args.scheduler or args.dask_local:
        n_nodes = args.dask_local or nodes or 0
        if not n_nodes:  # an existing cluster: one node per worker
            from .dask_backend import DaskBackend  # noqa: F401 - raises early if dask is missing
            from distributed import Client
            with Client(args.scheduler) as c:
                n_nodes = max(1, len(c.scheduler_info(n_workers=-1)["workers"]))
    else:
        n_nodes = max(1, int(workers))
    t = time.perf_counter()
    plan = make_plan(args.partition, model.width, model.height, n_nodes, tiles_per_node=args.tiles_per_node,
                     unit=args.unit, load_map=model.load_map(), order=args.order)
    # the root's time before the clock (measured): the scene read (cached: 0 after the first
    # run in this process) and planning (eq. 4.1 load map and the plan)
    plan.meta["timing"] = {"root_load_s": timing.get("root_load_s"),
                           "planning_s": timing.get("model_s", 0.0) + time.perf_counter() - t}
    backend = _backend(args, workers, plan.static)
    return spec, model, channels, plan, backend


def _auto_in_process(args) -> bool:
    """--workers auto resolves to in-process: one core, a Mitsuba renderer (Dr.Jit already uses every
    core and a window costs more than its share of a frame there), or a frame under AUTO_MIN_WORK."""
    if getattr(args, "workers", None) != "auto" or args.scheduler or args.dask_local or args.checkpoint or args.cull:
        return False
    from .executors import default_workers
    if default_workers() == 0 or args.renderer != "core":
        return True
    from .runtime import get_renderer
    w, h = get_renderer(_spec_from_args(args)).film_size
    return w * h * (args.spp or 1) < AUTO_MIN_WORK


def render_distributed(args):
    """Render per ``args`` on the chosen nodes -> ``(image (H, W, C) float64, channel names)``.
    Interrupted (Ctrl-C): every back end of this process is stopped at once (workers killed,
    clusters closed, :func:`_stop_backends`) before the ``KeyboardInterrupt`` goes on."""
    import multiprocessing
    before = {p.pid for p in multiprocessing.active_children()}
    try:
        return _render_distributed(args)
    except KeyboardInterrupt:
        from ..interrupts import ignore_interrupts, restore_interrupts
        handler = ignore_interrupts()   # the stop is not itself interrupted
        try:
            _stop_backends()
            # and any process started here that no back end knew of yet (a cluster interrupted
            # while it started its workers)
            for p in multiprocessing.active_children():
                if p.pid not in before:
                    p.kill()
                    p.join(timeout=5)
        finally:
            restore_interrupts(handler)
        raise


def _render_distributed(args):
    from .executors import render_plan
    if _auto_in_process(args):  # --workers auto found nothing worth distributing: one full frame here
        from .runtime import get_renderer
        r = get_renderer(_spec_from_args(args))
        return r.render(window=(0, 0, *r.film_size)), list(r.channels)
    spec, model, channels, plan, backend = prepare(args)
    ckpt = None
    if args.checkpoint:
        from .checkpoint import Checkpoint
        ckpt = Checkpoint(args.checkpoint, spec.key, {"scene": os.path.abspath(spec.path), "kind": spec.kind,
                                                      "options": repr(spec.options)})
    cull = _cull_map(plan, model, spec) if args.cull else None
    res = render_plan(plan, spec, backend, checkpoint=ckpt, progress=progress_choice(args),
                      cull=cull)
    if res.resumed:
        print(f"links1: resumed {res.resumed} of {len(plan.units)} units from the checkpoint {ckpt.dir}",
              file=sys.stderr)
    if res.faults:
        print(f"links1: {len(res.faults)} node(s) lost during the render; their units were redone and the image "
              f"is complete", file=sys.stderr)
    return res.image, channels


# ---------------------------------------------------------------------- schedule
SCHEDULE_EXAMPLES = """examples:
  links1 schedule scenes/many.xml --renderer core --nodes 2 --partition dynamic --report r.json --plot r.png
  links1 schedule scenes/many.xml --renderer core --nodes 2 --partition subscreen --tiles-per-node 64 \\
      --report s.json --simulate 1,4,16,64,256,1024 --sim-plot sim.png
  links1 schedule scenes/fig11.xml --nodes 4 --dask-local 4 --partition scanline --report d.json
"""


def add_cli(subparsers) -> None:
    """Add ``links1 schedule`` to the main parser's subcommands."""
    from ..frontends.cli_options import add_render_arguments
    p = subparsers.add_parser("schedule", help="run a root/node screen-partitioning experiment",
                              epilog=SCHEDULE_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter,
                              description="Render a scene on N nodes with a partitioning strategy and report per "
                              "unit predicted load (eq. 4.1), measured seconds and ray-primitive tests, per node busy "
                              "time, makespan, imbalance, parallel efficiency; optionally simulate more nodes.")
    add_render_arguments(p)
    p.add_argument("--nodes", type=_pos("--nodes"), default=None,
                   help="node count (local worker processes); required unless --sweep")
    _partition_options(p, nodes_option=True)
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
    p.add_argument("--reference-repeat", type=_pos("--reference-repeat"), default=3, metavar="N",
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
    from .checkpoint import atomic_write_json
    from .experiment import format_table, plot_report, plot_simulation, simulate, work_map
    if args.renderer == "mitsuba":
        from ..frontends.renderers import require_mitsuba
        require_mitsuba(args.variant)
    if args.plot or args.sim_plot:  # matplotlib is an extra: say so before rendering, not after
        try:
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
    from ..tracing.aovs import aov_channel
    from .executors import render_plan
    from .experiment import build_report, check_simulator
    args.workers = 0 if nodes == 1 and not (args.scheduler or args.dask_local) else nodes
    spec, model, channels, plan, backend = prepare(args, nodes=nodes)
    cull = _cull_map(plan, model, spec) if args.cull else None
    res = render_plan(plan, spec, backend, progress=progress_choice(args), cull=cull)
    if reference is None:
        reference = _reference(backend, spec, args.reference_repeat)
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
    import copy

    from .checkpoint import atomic_write_bytes, atomic_write_json
    from .experiment import efficiency_text, plot_sweep, simulate, work_map
    from .strategies import STRATEGIES as KNOWN
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
        _close_backends()
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


def _close_backends():
    for be in list(_BACKENDS.values()):
        be.close()
    _BACKENDS.clear()


def _stop_backends():
    """Stop every back end at once (``terminate``: no waiting on work in flight), forget them."""
    for be in list(_BACKENDS.values()):
        getattr(be, "terminate", be.close)()
    _BACKENDS.clear()


def _reference(backend, spec, repeat=3):
    """The same renderer on one node (its threads, warm): full frame, 64 one-unit launches, the
    64 units in 2 batches, measured in the same run after the partitioned render."""
    from functools import partial

    from .experiment import measure_overhead
    try:
        return backend.call(partial(measure_overhead, repeat=repeat), spec)
    except Exception as e:  # noqa: BLE001 - e.g. a cluster whose renderer this machine lacks
        warnings.warn(f"no single-process reference here ({type(e).__name__}: {e}); true efficiency not reported")
        return None


def summary_line(report, strategy) -> str:
    """One line, every figure named with its source (docs/partitioning.md, "Reading the report")."""
    from .experiment import efficiency_text
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
    from .experiment import share_text
    ts = report.get("time_split")
    if not ts:
        return ""
    sh = ts["shares"]
    su = [v for v in (ts.get("startup_s") or {}).values() if v is not None]
    return ("; nodes x makespan went to " + ", ".join(share_text(k, v) for k, v in sh.items())
            + " (work, launch overhead: derived; the rest measured)"
            + (f", start-up before the clock {max(su):.2f} s (measured)" if su else ""))
