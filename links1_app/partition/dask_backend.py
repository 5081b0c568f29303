"""The Dask backend: an existing cluster (``--scheduler tcp://HOST:PORT``) or a
``LocalCluster`` bound to 127.0.0.1 (``--dask-local N``; the dashboard too).

Nodes are the cluster's workers. A :class:`distributed.WorkerPlugin` loads the scene once
per worker (again on a worker the nanny restarts). Static strategies give every node a
per-worker resource (``links1-<token>-<k>: 1``) and submit each unit with that resource,
so units stay on their node (work stealing cannot move them, and a LocalCluster started
here for a static plan has stealing switched off too). When a node's worker leaves, the
root cancels that node's remaining tasks and resubmits them on the surviving nodes.
Dynamic plans submit about one unit per worker at a time (plus one queued); a worker
that joins mid-render is counted at the next completion and gets units; the scheduler
itself reruns a lost worker's task elsewhere. This module imports dask and distributed (an
optional dependency, about a second to import): the front ends import it only when a Dask
backend is asked for (:mod:`.cli`).
"""
from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import threading
import uuid
from collections import deque

import dask
from distributed import Client, LocalCluster, wait
from distributed.deploy.spec import SpecCluster
from distributed.diagnostics.plugin import WorkerPlugin

from links1.errors import RenderAborted
from links1.interrupts import children_ignore_interrupts

from .handout import ALLOWED_FAILURES, CHUNK_FACTOR, TASK_PIXELS, guided_batch, take_batch
from .local_pool import node_cpus, threads_per_worker
from .runtime import (THREAD_ENV, RendererSpec, get_renderer, limit_blas, pin_cpus, render_units, spec_batches,
                      warm_samples, warm_up)

#: seconds a LocalCluster interrupted while it starts may take to finish starting before it is
#: stopped (its workers then stop cleanly; a start takes a few seconds)
START_GRACE = 30.0


class ScenePreload(WorkerPlugin):
    """Loads the scene on each worker once, on the thread that runs its tasks; first, on a
    LocalCluster started here, binds the worker's process to its node's CPUs (``cpus``: one
    tuple per worker name ``0 .. n-1``, :func:`.local_pool.node_cpus`; a worker the nanny
    restarts is bound again, as this runs on every worker that starts)."""

    def __init__(self, spec, cpus=None):
        self.spec, self.cpus = spec, cpus

    async def setup(self, worker):
        ex = worker.executors.get("default")
        loop = asyncio.get_running_loop()
        name = worker.name
        if self.cpus and isinstance(name, int) and 0 <= name < len(self.cpus):
            pin_cpus(self.cpus[name])   # every thread of the process, and those it starts later
        await loop.run_in_executor(ex, _load_and_warm_up, self.spec)


def _load_and_warm_up(spec):
    r = get_renderer(spec)
    warm_up(r, warm_samples(spec, r))


async def _set_resource(name, value, dask_worker=None):
    await dask_worker.set_resources(**{name: value})


class DaskBackend:
    """Render units on a Dask cluster."""

    name = "dask"

    def __init__(self, scheduler: str | None = None, n_local: int | None = None, threads: int | None = None,
                 static: bool = False, client=None, poll_s: float = 0.25, chunk_factor: int = CHUNK_FACTOR,
                 task_pixels: int = TASK_PIXELS, chunk_by: str = "units", pin: bool = True):
        if scheduler is None and not n_local and client is None:
            raise ValueError("give a scheduler address, a LocalCluster size or a client")
        self.scheduler, self.n_local, self.threads = scheduler, n_local, threads
        self.static = static
        self.client, self.cluster = client, None
        self._own_client = client is None
        self.poll_s = poll_s
        self.fetch_s = 5.0   # a finished unit's result that takes longer to fetch is waited for again
        self.chunk_factor, self.task_pixels = int(chunk_factor), int(task_pixels)
        self.chunk_by = chunk_by
        self.token = uuid.uuid4().hex[:8]
        self._plugin = None
        self._root_blas = None   # the root's BLAS thread count before a LocalCluster started
        # a LocalCluster's workers bound to CPUs of their own, as LocalPool's nodes:
        # ``pin`` (default), where they fit; ``cpus`` the sets (None: left to the kernel; a
        # cluster of other machines is never bound)
        self.pin, self.cpus = bool(pin), None

    # ---------------------------------------------------------------- lifecycle
    def start(self, spec):
        if self.client is None:
            if self.scheduler:
                self.client = Client(self.scheduler)
            else:
                t = self.threads or threads_per_worker(self.n_local)
                cfg = {"distributed.scheduler.work-stealing": not self.static}
                # its nannies and workers never see Ctrl-C (SIGINT): the root alone stops, and
                # closes the cluster (terminate)
                with dask.config.set(cfg):
                    self.cluster = self._local_cluster(
                        n_workers=int(self.n_local), threads_per_worker=1, processes=True, host="127.0.0.1",
                        dashboard_address="127.0.0.1:0", env={k: str(t) for k in THREAD_ENV})
                self.client = Client(self.cluster)
                self.threads = t
                self.cpus = node_cpus(int(self.n_local), t) if self.pin else None
                # the nodes share this machine's cores: the root (it renders nothing) keeps
                # one BLAS thread until close, as LocalPool's does (runtime.limit_blas)
                self._root_blas = limit_blas(1) or 0
        if self._plugin != spec.key:
            if spec.threads is None and self.threads:
                spec = RendererSpec(spec.kind, spec.path, spec.options, self.threads)
            self.client.register_plugin(ScenePreload(spec, self.cpus), name=f"links1-preload-{spec.key}")
            self._plugin = spec.key
        self._spec = spec

    def _local_cluster(self, **kwargs):
        """``LocalCluster(**kwargs)`` made by a thread that blocks SIGINT, so that the cluster's
        threads, nannies and workers never see Ctrl-C (they inherit the blocked signal); this
        thread waits for it and stays interruptible. Interrupted, it lets the start finish first
        (a worker process killed while it unpickles its start-up data prints a traceback), for at
        most ``START_GRACE`` seconds; :attr:`cluster` is then the cluster made, or being made, for
        :meth:`terminate`."""
        known, made = set(_clusters()), []

        def make():
            try:
                made.append(LocalCluster(**kwargs))
            except BaseException as e:  # noqa: BLE001 - raised in the caller's thread
                made.append(e)
        with children_ignore_interrupts():
            maker = threading.Thread(target=make, name="links1-cluster-start", daemon=True)
            maker.start()
        try:
            while maker.is_alive():
                maker.join(0.05)
        except KeyboardInterrupt:
            maker.join(START_GRACE)
            done = made and not isinstance(made[0], BaseException)
            self.cluster = made[0] if done else next((c for c in _clusters() if c not in known), None)
            raise
        if isinstance(made[0], BaseException):
            raise made[0]
        return made[0]

    @property
    def n_nodes(self) -> int:
        return len(self.workers()) if self.client is not None else int(self.n_local or 0)

    def call(self, fn, *args):
        """Run ``fn(*args)`` on one worker of the cluster -> the result."""
        return self.client.submit(fn, *args, pure=False, workers=self.workers()[:1]).result(timeout=600)

    def workers(self) -> list:
        return sorted(self.client.scheduler_info(n_workers=-1)["workers"])

    def close(self):
        if self.client is not None and self._plugin and self.cluster is None:
            try:
                self.client.unregister_worker_plugin(f"links1-preload-{self._plugin}")
            except Exception:  # noqa: BLE001 - best effort on a shared cluster
                pass
        if self.client is not None and self._own_client:
            self.client.close()
            self.client = None
        if self.cluster is not None:
            self.cluster.close()
            self.cluster = None
        if self._root_blas:
            limit_blas(self._root_blas)
        self._root_blas = None
        self._plugin = None

    def terminate(self):
        """Stop now (Ctrl-C): kill the workers of a cluster started here (their nannies told
        not to restart them), close the client and that cluster; a cluster of other machines
        is only left. distributed's and asyncio's logs are silenced for the rest of this process:
        a nanny's warnings about the workers it lost, errors of workers still starting and of
        closed connections would follow the CLI's one line as the cluster's threads wind down."""
        for name in ("distributed", "asyncio"):   # asyncio: "Future exception was never retrieved"
            logging.getLogger(name).setLevel(logging.CRITICAL + 1)
        for nanny in list(getattr(self.cluster, "workers", {}).values()):
            with contextlib.suppress(Exception):   # no restart, and its worker ends now
                nanny.close_gracefully(reason="links1-interrupted")
                if nanny.pid:
                    os.kill(nanny.pid, signal.SIGKILL)
        if self.client is not None and self._own_client:
            with contextlib.suppress(Exception):
                self.client.close(timeout=2)
            self.client = None
        if self.cluster is not None:
            with contextlib.suppress(Exception):
                self.cluster.close(timeout=2)
            self.cluster = None
        self.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # ---------------------------------------------------------------- running
    def run(self, plan, todo, spec, cull, on_done, on_fault):
        client, spec = self.client, self._spec
        batches = spec_batches(spec)
        attempts = {}
        pending = {}  # future -> (units, node or None)
        workers = self.workers()
        if not workers:
            client.wait_for_workers(1, timeout=60)
            workers = self.workers()

        def submit(batch, node, resources=None):
            a = attempts[batch[0]] = attempts.get(batch[0], 0) + 1
            f = client.submit(render_units, spec, [plan.units[i].window for i in batch], [cull.get(i) for i in batch],
                              pure=False, key=f"links1-units-{batch[0]}-{len(batch)}-{self.token}-{a}",
                              resources=resources)
            pending[f] = (batch, node)

        def submit_node(k, units):  # a static node's units, in tasks within the pixel budget
            q = deque(units)
            while q:
                submit(take_batch(plan, q, None if batches else 1, self.task_pixels), k,
                       {f"links1-{self.token}-{k}": 1})

        if plan.static:
            node_worker = {}
            n = len(workers)
            for k, addr in enumerate(workers):  # node k <-> a per-worker resource
                res = f"links1-{self.token}-{k}"
                client.run(_set_resource, res, 1, workers=[addr])
                node_worker[k] = addr
            mine = {}
            for i in todo:
                mine.setdefault(plan.owner[i] % n, []).append(i)
            for k, units in sorted(mine.items()):
                submit_node(k, units)
        else:
            queue = deque(todo)

            def top_up():
                nw = max(1, len(self.workers()))
                while queue and len(pending) < nw + 1:
                    if batches:
                        submit(guided_batch(plan, queue, nw, self.chunk_factor, self.task_pixels,
                                            by_load=self.chunk_by == "load"), None)
                    else:
                        submit(take_batch(plan, queue, 1, self.task_pixels), None)
            top_up()

        known = set(workers)
        while pending:
            try:
                done, _ = wait(list(pending), timeout=self.poll_s, return_when="FIRST_COMPLETED")
            except TimeoutError:
                done = ()
            for f in done:
                batch, node = pending[f]
                if f.status not in ("error", "cancelled"):
                    try:  # a result kept on a worker that died since is recomputed: wait in the loop
                        results = f.result(timeout=self.fetch_s)
                    except (TimeoutError, asyncio.TimeoutError):
                        continue  # still pending: if its node left, the loss handling below resubmits it
                    except Exception:  # noqa: BLE001 - the task failed meanwhile: reported below
                        pass
                pending.pop(f)
                if f.status == "error":
                    exc = f.exception()
                    if type(exc).__name__ == "KilledWorker":
                        raise RenderAborted(f"units {[plan.units[i].window for i in batch][:3]} were lost with "
                                            f"{ALLOWED_FAILURES} or more workers; giving up, no image written") from exc
                    raise exc
                if f.status == "cancelled":
                    continue
                f.release()
                for i, (px, info) in zip(batch, results):
                    info["worker"] = f"{info.get('pid')}"
                    info["node"] = node if node is not None else _node_of(info, workers)
                    on_done(i, px, info)
            now = set(self.workers())
            gone, joined = known - now, now - known
            known = now
            if plan.static:
                for k, addr in list(node_worker.items()):
                    if addr in now:
                        continue
                    del node_worker[k]
                    survivors = sorted(node_worker)
                    if not survivors:
                        raise RenderAborted("every node's worker left the cluster; giving up, no image written")
                    lost = []
                    for f, (batch, nd) in list(pending.items()):
                        if nd == k:
                            pending.pop(f)
                            f.cancel()
                            lost += batch
                    lost.sort()
                    for j, k2 in enumerate(survivors):  # dealt in turn to the surviving nodes
                        share = lost[j::len(survivors)]
                        if share:
                            submit_node(k2, share)
                    on_fault(f"node {k} (worker {addr}) left the cluster; its {len(lost)} unfinished units "
                             f"are redone on the other nodes")
            else:
                for addr in sorted(gone):
                    on_fault(f"worker {addr} left the cluster; its units are redone elsewhere")
                for addr in sorted(joined):
                    workers.append(addr)
                top_up()


def _clusters() -> list:
    """The clusters this process has made (distributed keeps them in ``SpecCluster._instances``)."""
    return list(getattr(SpecCluster, "_instances", ()))


def _node_of(info, workers):
    """Node label of a dynamic unit: the rendering worker's pid (stable within a run)."""
    return f"pid{info.get('pid')}"


def cluster_workers(scheduler) -> int:
    """How many workers the Dask cluster at ``scheduler`` (tcp://HOST:PORT) has now."""
    with Client(scheduler) as c:
        return len(c.scheduler_info(n_workers=-1)["workers"])


def local_address(backend) -> str | None:
    """The scheduler address of a backend's cluster (tests hold tasks with distributed.Event)."""
    if backend.client is None:
        return None
    return backend.client.scheduler.address


__all__ = ["DaskBackend", "ScenePreload", "cluster_workers", "local_address"]
