"""The root's driver and the in-process backend.

:func:`render_plan` runs a :class:`~links1.partition.strategies.Plan` on a backend: it skips
units kept in a checkpoint, hands the rest to the backend, assembles the film (every unit
written once, in place: the image equals the single-process render bit for bit), saves each
finished unit to the checkpoint, shows a progress bar over units (tqdm, stderr, with an ETA)
and reports on stderr when a node dies and its units are redone elsewhere.

Backends (same interface: ``start(spec)``, ``n_nodes``, ``run(...)``, ``close()``):

InProcess   ``--workers 0``: the root renders every unit itself (here).
LocalPool   ``--workers N``: N spawned worker processes (:mod:`.local_pool`).
DaskBackend ``--scheduler`` / ``--dask-local``: a Dask cluster's workers (:mod:`.dask_backend`).

How a backend cuts the queue into tasks is :mod:`.handout`.
"""
from __future__ import annotations

import sys
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from .handout import CHUNK_FACTOR, TASK_PIXELS, guided_batch, take_batch
from .runtime import RendererSpec, can_batch, get_renderer, render_units, warm_samples, warm_up


@dataclass
class RenderResult:
    """An assembled frame and what happened while rendering it."""

    image: np.ndarray                  # (H, W, C) float64
    plan: object
    records: dict = field(default_factory=dict)   # unit index -> {node, seconds, start, stop, pid, ...}
    faults: list = field(default_factory=list)    # messages about lost nodes
    rendered: int = 0                  # units rendered in this run
    resumed: int = 0                   # units taken from the checkpoint
    makespan_s: float = 0.0            # first dispatch to last result (root clock)
    t0_wall: float | None = None       # time.time() at the first dispatch (for dispatch latency)
    backend: str = ""
    n_nodes: int = 0
    #: the root's own time inside the makespan, measured (wall clock): [kind, start, stop] with
    #: kind "dispatch" (handing a task to a node) or "assembly" (placing a unit's pixels)
    root_events: list = field(default_factory=list)
    #: node -> seconds its start took (process start, scene load, warm-up: before the clock),
    #: measured by the backend when the node started (maybe in an earlier run of the same pool)
    startup_s: dict = field(default_factory=dict)


def default_log(msg: str) -> None:
    """Write a line to stderr without breaking a tqdm bar."""
    tqdm.write(msg, file=sys.stderr)
    sys.stderr.flush()


def render_plan(plan, spec: RendererSpec, backend, *, checkpoint=None, progress: bool | None = None,
                cull: dict | None = None, log=default_log) -> RenderResult:
    """Render every unit of ``plan`` on ``backend`` and assemble the frame.

    Parameters
    ----------
    plan : Plan
    spec : RendererSpec        what nodes load (the scene path and renderer options)
    backend : InProcess | LocalPool | DaskBackend   started on first use
    checkpoint : Checkpoint, optional   finished units are read from / written to it
    progress : bool or None    tqdm bar over units on stderr: True always, None (default) only
                               when stderr is a terminal (tqdm's ``disable=None``), False never
    cull : dict, optional      unit index -> object ids the unit's node receives (4-4)
    log : callable(str)        where fault messages go (stderr)
    """
    image = None
    res = RenderResult(None, plan, backend=getattr(backend, "name", type(backend).__name__))

    def place(i, pixels):
        nonlocal image
        u = plan.units[i]
        if image is None:
            image = np.zeros((plan.height, plan.width, pixels.shape[2]), dtype=np.float64)
        at = image[u.y0:u.y0 + u.h, u.x0:u.x0 + u.w]
        if _same_place(at, pixels):   # a node wrote them into the image itself (image_buffer)
            return
        at[...] = pixels

    todo = []
    for i in plan.order:
        px = checkpoint.load(plan.units[i]) if checkpoint is not None else None
        if px is not None:
            place(i, px)
            res.resumed += 1
        else:
            todo.append(i)

    bar = None
    if progress is not False:
        bar = tqdm(total=len(plan.units), initial=res.resumed, unit="unit", desc="links1", file=sys.stderr,
                   dynamic_ncols=True, leave=False, smoothing=0.1,
                   disable=None if progress is None else False)

    def on_done(i, pixels, info):
        t = time.perf_counter()
        w0 = time.time()
        info.setdefault("received", w0)  # root clock (wall): the result is here
        u = plan.units[i]
        if pixels.shape[:2] != (u.h, u.w):
            raise RuntimeError(f"unit {u.window}: node returned {pixels.shape[:2]}, expected {(u.h, u.w)}")
        place(i, pixels)
        res.records[i] = info
        res.rendered += 1
        if checkpoint is not None:
            checkpoint.save(u, pixels)
        if bar is not None:
            bar.update(1)
        info["root_s"] = time.perf_counter() - t  # the root's own time for this unit (assembly)
        res.root_events.append(["assembly", w0, w0 + info["root_s"]])

    def on_fault(msg):
        res.faults.append(msg)
        log(f"links1: {msg}")

    try:
        if todo:
            backend.start(spec)
            res.n_nodes = backend.n_nodes
            res.startup_s = dict(getattr(backend, "startup_s", None) or {})
            backend.root_events = res.root_events   # a backend may log its dispatches here
            before = getattr(backend, "before_run", None)   # a backend's set-up for this plan
            if before is not None:
                before(plan)
            buf = getattr(backend, "image_buffer", None)   # where its nodes write pixels themselves
            if buf is not None and buf.shape[:2] == (plan.height, plan.width):
                if image is not None:   # units from the checkpoint
                    buf[...] = image
                image = buf
            res.t0_wall = time.time()   # the nodes' records use wall clocks (same machine)
            t0 = time.perf_counter()
            backend.run(plan, todo, spec, cull or {}, on_done, on_fault)
            res.makespan_s = time.perf_counter() - t0
            after = getattr(backend, "after_run", None)   # a backend's checks past the last result
            if after is not None:
                after(on_fault)
        else:
            res.n_nodes = getattr(backend, "n_nodes", 0)
    finally:
        if bar is not None:
            bar.close()
    if image is None:
        raise RuntimeError("nothing rendered: the plan has no units")
    res.image = image
    return res


def _same_place(a, b) -> bool:
    """Whether arrays ``a`` and ``b`` are the same memory (address, shape, strides, dtype)."""
    return (a.shape == b.shape and a.strides == b.strides and a.dtype == b.dtype
            and a.__array_interface__["data"][0] == b.__array_interface__["data"][0])


def _owners(plan, todo):
    """Initial node of each unit to render (static plans)."""
    return {i: plan.owner[i] for i in todo}


# ---------------------------------------------------------------------- in-process
class InProcess:
    """``--workers 0``: the root renders every unit itself (one renderer, loaded once)."""

    name = "inprocess"
    n_nodes = 1
    root_events = None

    def __init__(self, chunk_factor: int = CHUNK_FACTOR, task_pixels: int = TASK_PIXELS, chunk_by: str = "units"):
        self.chunk_factor, self.task_pixels = int(chunk_factor), int(task_pixels)
        self.chunk_by = chunk_by

    def start(self, spec):
        # as a local worker's start (start_worker): recordings and caches before the first
        # unit, so a unit's time is work, not the frozen launch's recording (a first launch
        # costs several warm ones); its time is the node's start-up
        t = time.perf_counter()
        r = get_renderer(spec)
        warm_up(r, warm_samples(spec, r))
        self.startup_s = {0: time.perf_counter() - t}

    def call(self, fn, *args):
        """Run ``fn(*args)`` on a node (here: this process)."""
        return fn(*args)

    def run(self, plan, todo, spec, cull, on_done, on_fault):
        batches = can_batch(get_renderer(spec))
        queue = deque(todo)
        while queue:  # static: the pixel budget per task; dynamic: guided chunks
            if plan.static or not batches:
                batch = take_batch(plan, queue, None if batches else 1, self.task_pixels)
            else:
                batch = guided_batch(plan, queue, 1, self.chunk_factor, self.task_pixels,
                                     by_load=self.chunk_by == "load")
            for i, (px, info) in zip(batch, render_units(spec, [plan.units[i].window for i in batch],
                                                         [cull.get(i) for i in batch], wire=False)):
                info["node"] = plan.owner[i] if plan.static else 0
                on_done(i, px, info)

    def close(self):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
