"""The root's driver and the embedded backends.

:func:`render_plan` runs a :class:`~.strategies.Plan` on a backend: it skips units kept in
a checkpoint, hands the rest to the backend, assembles the film (every unit written once,
in place: the image equals the single-process render bit for bit), saves each finished
unit to the checkpoint, shows a progress bar over units (tqdm, stderr, with an ETA) and
reports on stderr when a node dies and its units are redone elsewhere.

Backends (same interface: ``start(spec)``, ``n_nodes``, ``run(...)``, ``close()``):

InProcess   ``--workers 0``: the root renders every unit itself.
LocalPool   ``--workers N``: N spawned worker processes, one
            :class:`concurrent.futures.ProcessPoolExecutor` (``max_workers=1``) per node, so a
            static strategy's units stay on their node; each worker loads the scene once
            (pool initializer). A SIGKILLed worker breaks only its own pool
            (``BrokenProcessPool``): its unfinished units go to the surviving nodes.
The Dask backend is in :mod:`.dask_backend`.
"""
from __future__ import annotations

import os
import sys
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from .runtime import THREAD_ENV, RendererSpec, get_renderer, init_worker, render_unit

#: A unit that has killed this many workers is reported as an error (Dask's allowed-failures).
ALLOWED_FAILURES = 3


class NodeLost(Exception):
    """Raised inside a backend when the node rendering a unit went away."""


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
    backend: str = ""
    n_nodes: int = 0


def default_log(msg: str) -> None:
    """Write a line to stderr without breaking a tqdm bar."""
    try:
        from tqdm import tqdm
        tqdm.write(msg, file=sys.stderr)
    except ImportError:  # pragma: no cover
        sys.stderr.write(msg + "\n")
    sys.stderr.flush()


def render_plan(plan, spec: RendererSpec, backend, *, checkpoint=None, progress: bool = True,
                cull: dict | None = None, log=default_log) -> RenderResult:
    """Render every unit of ``plan`` on ``backend`` and assemble the frame.

    Parameters
    ----------
    plan : Plan
    spec : RendererSpec        what nodes load (the scene path and renderer options)
    backend : InProcess | LocalPool | DaskBackend   started on first use
    checkpoint : Checkpoint, optional   finished units are read from / written to it
    progress : bool            tqdm bar over units on stderr
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
        image[u.y0:u.y0 + u.h, u.x0:u.x0 + u.w] = pixels

    todo = []
    for i in plan.order:
        px = checkpoint.load(plan.units[i]) if checkpoint is not None else None
        if px is not None:
            place(i, px)
            res.resumed += 1
        else:
            todo.append(i)

    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=len(plan.units), initial=res.resumed, unit="unit", desc="links1", file=sys.stderr,
                   dynamic_ncols=True, leave=False, smoothing=0.1)

    def on_done(i, pixels, info):
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

    def on_fault(msg):
        res.faults.append(msg)
        log(f"links1: {msg}")

    try:
        if todo:
            backend.start(spec)
            res.n_nodes = backend.n_nodes
            t0 = time.perf_counter()
            backend.run(plan, todo, spec, cull or {}, on_done, on_fault)
            res.makespan_s = time.perf_counter() - t0
        else:
            res.n_nodes = getattr(backend, "n_nodes", 0)
    finally:
        if bar is not None:
            bar.close()
    if image is None:
        raise RuntimeError("nothing rendered: the plan has no units")
    res.image = image
    return res


def _owners(plan, todo):
    """Initial node of each unit to render (static plans)."""
    return {i: plan.owner[i] for i in todo}


# ---------------------------------------------------------------------- in-process
class InProcess:
    """``--workers 0``: the root renders every unit itself (one renderer, loaded once)."""

    name = "inprocess"
    n_nodes = 1

    def start(self, spec):
        get_renderer(spec)

    def run(self, plan, todo, spec, cull, on_done, on_fault):
        for i in todo:
            px, info = render_unit(spec, plan.units[i].window, cull.get(i))
            info["node"] = plan.owner[i] if plan.static else 0
            on_done(i, px, info)

    def close(self):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


# ---------------------------------------------------------------------- local pool
def default_workers(kind: str = "core") -> int:
    """Worker processes worth starting here: the usable cores (0 = in-process when only one)."""
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        n = os.cpu_count() or 1
    return n if n > 1 else 0


def threads_per_worker(n_workers: int) -> int:
    """Renderer threads per worker so that workers x threads matches the cores."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover
        cores = os.cpu_count() or 1
    return max(1, cores // max(1, n_workers))


class LocalPool:
    """``--workers N``: N spawned worker processes on this machine, one pool per node."""

    name = "local"

    def __init__(self, n_workers: int, threads: int | None = None, prefetch: int = 2):
        if n_workers < 1:
            raise ValueError(f"workers must be >= 1, got {n_workers}")
        self.n = int(n_workers)
        self.threads = threads
        self.prefetch = max(1, int(prefetch))
        self.pools: dict = {}
        self.pids: dict = {}
        self._spec_key = None

    @property
    def n_nodes(self) -> int:
        return len(self.pools) if self.pools else self.n

    def start(self, spec):
        if self.pools and self._spec_key == spec.key:
            return
        self.close()
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor, wait
        threads = self.threads or threads_per_worker(self.n)
        spec = RendererSpec(spec.kind, spec.path, spec.options, spec.threads or threads)
        ctx = mp.get_context("spawn")
        saved = {k: os.environ.get(k) for k in THREAD_ENV}
        os.environ.update({k: str(threads) for k in THREAD_ENV})  # inherited by the spawned workers
        try:
            for k in range(self.n):
                self.pools[k] = ProcessPoolExecutor(1, mp_context=ctx, initializer=init_worker, initargs=(spec,))
            pings = {k: p.submit(os.getpid) for k, p in self.pools.items()}
            wait(list(pings.values()))
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
        for k, f in pings.items():
            self.pids[k] = f.result()  # raises if a worker could not load the scene
        self._spec_key = spec.key
        self._spec = spec

    def run(self, plan, todo, spec, cull, on_done, on_fault):
        from concurrent.futures import FIRST_COMPLETED, wait
        from concurrent.futures.process import BrokenProcessPool
        spec = self._spec
        alive = [k for k in self.pools]
        failures = {}
        if plan.static:
            queues = {k: deque() for k in alive}
            for i in todo:
                queues[plan.owner[i] % self.n].append(i)
        else:
            shared = deque(todo)
        pending = {}  # future -> (unit, node)

        def next_for(k):
            q = queues[k] if plan.static else shared
            return q.popleft() if q else None

        def fill(k):
            busy = sum(1 for (_, n) in pending.values() if n == k)
            limit = len(todo) if plan.static else self.prefetch
            while busy < limit:
                i = next_for(k)
                if i is None:
                    return
                f = self.pools[k].submit(render_unit, spec, plan.units[i].window, cull.get(i))
                pending[f] = (i, k)
                busy += 1

        for k in alive:
            fill(k)
        while pending:
            done, _ = wait(list(pending), return_when=FIRST_COMPLETED)
            lost_nodes = set()
            for f in done:
                i, k = pending.pop(f)
                try:
                    px, info = f.result()
                except BrokenProcessPool:
                    lost_nodes.add(k)
                    self._requeue(i, k, failures, plan, queues if plan.static else None,
                                  None if plan.static else shared)
                    continue
                info["node"] = k
                on_done(i, px, info)
            for k in lost_nodes:
                if k not in alive:
                    continue
                alive.remove(k)
                # every unit still queued on the dead node's pool is lost with it
                for f2, (i2, k2) in list(pending.items()):
                    if k2 == k:
                        pending.pop(f2)
                        self._requeue(i2, k, failures, plan, queues if plan.static else None,
                                      None if plan.static else shared)
                left = list(queues.pop(k)) if plan.static else []
                self.pools.pop(k).shutdown(wait=False, cancel_futures=True)
                if not alive:
                    raise RuntimeError("links1: every worker died; no node left to render on")
                if plan.static:  # the dead node's units go to the survivors, dealt in turn
                    for j, i2 in enumerate(left):
                        queues[alive[j % len(alive)]].append(i2)
                on_fault(f"node {k} (pid {self.pids.get(k)}) died; {len(left) if plan.static else 'its'} "
                         f"unfinished units are redone on the other nodes")
            for k in alive:
                fill(k)

    def _requeue(self, i, k, failures, plan, queues, shared):
        failures[i] = failures.get(i, 0) + 1
        if failures[i] >= ALLOWED_FAILURES:
            raise RuntimeError(f"unit {plan.units[i].window} was lost with {failures[i]} workers; giving up")
        if queues is not None:
            queues[k].appendleft(i)
        else:
            shared.appendleft(i)

    def close(self):
        for p in self.pools.values():
            p.shutdown(wait=True, cancel_futures=True)
        self.pools.clear()
        self.pids.clear()
        self._spec_key = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
