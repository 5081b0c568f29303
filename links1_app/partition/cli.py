"""Command-line side of the partitioning runtime: the distributed options of ``links1 render``
and the set-up ``links1 schedule`` shares (:mod:`.schedule`).

:mod:`links1_app.cli` calls:

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
"""
from __future__ import annotations

import atexit
import multiprocessing
import os
import sys
import time
import warnings

import numpy as np

from links1.errors import SceneError, UsageError
from links1.interrupts import ignore_interrupts, restore_interrupts
from links1.partition.loadmodel import load_table, scene_model
from links1.partition.strategies import STRATEGIES, UNITS, make_plan
from links1.scene.xmlparse import SceneWarning
from links1.tracing.aovs import channel_names

from ..cli_options import adaptive_options, int_option, progress_choice
from .checkpoint import Checkpoint
from .executors import InProcess, render_plan
from .handout import CHUNK_FACTOR
from .local_pool import LocalPool, default_workers
from .runtime import RendererSpec, get_renderer

#: Frames smaller than this (pixels x samples) render in-process under --workers auto.
AUTO_MIN_WORK = 128 * 128

_BACKENDS: dict = {}  # reused across --repeat frames in one process


def _workers(text):
    return text if text == "auto" else int_option("--workers (an integer or 'auto')", 0)(text)


def positive(name):
    """An argparse type: an integer >= 1, with a message naming the option."""
    return int_option(name, 1)


def partition_options(p, *, nodes_option: bool):
    """The screen-partitioning options of ``links1 render`` and (``nodes_option``: --nodes
    instead of --workers) ``links1 schedule``."""
    g = p.add_argument_group("screen partitioning (paper section 4)")
    if not nodes_option:
        g.add_argument("--workers", type=_workers, default="auto",
                       help="local worker processes: 0 renders in-process; default auto: the usable cores "
                            "when more than one (and the frame is not tiny)")
    g.add_argument("--partition", choices=STRATEGIES, default="dynamic",
                   help="subscreen (4-1, eq. 4.1), scanline (4-2), dynamic (4-3, default), grid (baseline), "
                        "subscreen-balanced (4-1's tiles and walk, cuts at the least max load; not the paper's)")
    g.add_argument("--tiles-per-node", type=positive("--tiles-per-node"), default=16,
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
    g.add_argument("--dask-local", type=positive("--dask-local"), default=None, metavar="N",
                   help="start a Dask LocalCluster of N workers bound to 127.0.0.1")
    g.add_argument("--checkpoint", default=None, metavar="DIR",
                   help="keep finished units in DIR; a re-run renders only what is missing")
    g.add_argument("--cull", action="store_true",
                   help="give nodes only the objects their units need (4-4; --renderer core)")
    g.add_argument("--load-table", default=None, metavar="JSON", help="per-object load table (eq. 4.1) overrides")


def add_render_options(parser) -> None:
    """Add the distributed-rendering options to ``links1 render``."""
    partition_options(parser, nodes_option=False)


# ---------------------------------------------------------------------- shared set-up
def _spec_from_args(args):
    opts = dict(params=dict(getattr(args, "defines", []) or []), spp=args.spp, max_depth=args.max_depth,
                seed=args.seed, aovs=tuple(getattr(args, "aov", ()) or ()), width=args.width, height=args.height)
    if getattr(args, "sensor", None) is not None:
        opts["sensor"] = args.sensor
    if getattr(args, "min_weight", None) is not None:   # 0 is a value (trace every branch)
        opts["min_weight"] = args.min_weight
    if getattr(args, "light_samples", None) is not None:
        opts["light_samples"] = args.light_samples
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
    timing = {} if timing is None else timing
    table = load_table(getattr(args, "load_table", None), renderer=spec.kind)
    root_spec = spec
    if spec.kind != "core":  # the root only needs shapes and the camera: read them with the core
        kw = {k: v for k, v in spec.kwargs.items() if k in ("params", "spp", "max_depth", "seed", "aovs", "width",
                                                             "height", "sensor")}
        root_spec = RendererSpec.make("core", spec.path, **kw)
    try:
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
        r = get_renderer(spec)
        model = scene_model(r, path=spec.path, params=spec.kwargs.get("params"), table=table)
        channels = list(r.channels)
    if spec.kind != "core":
        channels = channel_names(spec.kwargs.get("aovs", ()))
    return model, channels


def _dask_backend():
    """The module :mod:`.dask_backend`, or a one-line error naming the extra to install."""
    try:   # lazy: dask is optional and takes about a second to import
        from . import dask_backend
    except ImportError as e:
        raise UsageError(f"Dask is not installed ({e}); pip install 'links1[dask]'") from None
    return dask_backend


def _backend(args, workers, static):
    k = CHUNK_FACTOR if getattr(args, "chunk_factor", None) is None else args.chunk_factor
    by = getattr(args, "chunk_by", None) or "units"
    key = (args.scheduler, args.dask_local, workers, static)
    be = _BACKENDS.get(key)
    if be is not None:
        be.chunk_factor, be.chunk_by = k, by
        return be
    if args.scheduler or args.dask_local:
        be = _dask_backend().DaskBackend(scheduler=args.scheduler, n_local=args.dask_local, static=static, chunk_factor=k,
                         chunk_by=by)
    elif workers == 0:
        be = InProcess(chunk_factor=k, chunk_by=by)
    else:
        be = LocalPool(int(workers), chunk_factor=k, chunk_by=by)
    _BACKENDS[key] = be
    atexit.register(be.close)
    return be


def cull_map(plan, model, spec):
    """Unit index -> the object ids its node receives (4-4: primary and secondary rays), or
    None (a renderer that cannot drop objects)."""
    if spec.kind != "core":
        warnings.warn("--cull needs --renderer core (the Mitsuba scene cannot drop objects); ignored")
        return None
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
    workers = getattr(args, "workers", nodes)
    _check_backend_args(args, workers)
    spec = _spec_from_args(args)
    timing = {}
    model, channels = _model_and_channels(spec, args, timing)
    if workers == "auto":
        work = model.width * model.height * (spec.kwargs.get("spp") or 1)
        workers = default_workers() if work >= AUTO_MIN_WORK else 0
    if args.scheduler or args.dask_local:
        n_nodes = args.dask_local or nodes or 0
        if not n_nodes:  # an existing cluster: one node per worker
            n_nodes = max(1, _dask_backend().cluster_workers(args.scheduler))
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
    if default_workers() == 0 or args.renderer != "core":
        return True
    w, h = get_renderer(_spec_from_args(args)).film_size
    return w * h * (args.spp or 1) < AUTO_MIN_WORK


def render_distributed(args):
    """Render per ``args`` on the chosen nodes -> ``(image (H, W, C) float64, channel names)``.
    Interrupted (Ctrl-C): every back end of this process is stopped at once (workers killed,
    clusters closed, :func:`stop_backends`) before the ``KeyboardInterrupt`` goes on."""
    before = {p.pid for p in multiprocessing.active_children()}
    try:
        return _render_distributed(args)
    except KeyboardInterrupt:
        handler = ignore_interrupts()   # the stop is not itself interrupted
        try:
            stop_backends()
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
    if _auto_in_process(args):  # --workers auto found nothing worth distributing: one full frame here
        r = get_renderer(_spec_from_args(args))
        return r.render(window=(0, 0, *r.film_size)), list(r.channels)
    spec, model, channels, plan, backend = prepare(args)
    ckpt = None
    if args.checkpoint:
        ckpt = Checkpoint(args.checkpoint, spec.key, {"scene": os.path.abspath(spec.path), "kind": spec.kind,
                                                      "options": repr(spec.options)})
    cull = cull_map(plan, model, spec) if args.cull else None
    res = render_plan(plan, spec, backend, checkpoint=ckpt, progress=progress_choice(args),
                      cull=cull)
    if res.resumed:
        print(f"links1: resumed {res.resumed} of {len(plan.units)} units from the checkpoint {ckpt.dir}",
              file=sys.stderr)
    if res.faults:
        print(f"links1: {len(res.faults)} node(s) lost during the render; their units were redone and the image "
              f"is complete", file=sys.stderr)
    return res.image, channels


def close_backends():
    """Close every back end of this process (kept across --repeat frames and sweep runs)."""
    for be in list(_BACKENDS.values()):
        be.close()
    _BACKENDS.clear()


def stop_backends():
    """Stop every back end at once (``terminate``: no waiting on work in flight), forget them."""
    for be in list(_BACKENDS.values()):
        getattr(be, "terminate", be.close)()
    _BACKENDS.clear()
