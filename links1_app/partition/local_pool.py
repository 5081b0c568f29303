"""The local-pool backend: ``--workers N`` spawned worker processes on this machine.

One :class:`concurrent.futures.ProcessPoolExecutor` (``max_workers=1``) per node, so a static
strategy's units stay on their node; each worker loads the scene once (its first task). A
worker that dies (starting, idle or mid-unit) breaks only its own pool
(``BrokenProcessPool``): its unfinished units go to the other nodes and a replacement process
starts, up to a documented number of deaths. During a run each node serves a direct line
(``runtime.serve``, opened before the clock): the root's thread writes tasks into it and reads
results from it, no pool helper threads. Nodes write their pixels into a frame the root maps
(``runtime.SharedFrame``, made before the clock), which is the root's image
(``image_buffer``), and send back only the units' records; ``shared_frame=False``: the pixels
come through the line. Where nodes x threads fit the CPUs, each node is bound to CPUs of its
own (:func:`node_cpus`).
"""
from __future__ import annotations

import multiprocessing as mp
import os
import pickle
import time
from collections import deque
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing.connection import wait as wait_connections

from links1.errors import RenderAborted
from links1.interrupts import children_ignore_interrupts

from .executors import default_log
from .handout import ALLOWED_FAILURES, CHUNK_FACTOR, TASK_PIXELS, guided_batch, take_batch
from .runtime import THREAD_ENV, RendererSpec, SharedFrame, limit_blas, release_frame, serve, start_worker

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


def node_cpus(n_workers: int, threads: int, cpus=None) -> list | None:
    """CPUs for each of ``n_workers`` local nodes of ``threads`` threads: disjoint sets of
    ``threads`` CPUs taken in order from ``cpus`` (default: the CPUs this process may use) ->
    one tuple per node, or None when they do not fit (more nodes x threads than CPUs: the
    kernel shares them out). Left to itself the kernel put both one-thread nodes of
    a two-node run on one core of two (docs/partitioning.md, "CPU placement")."""
    if cpus is None:
        try:
            cpus = os.sched_getaffinity(0)
        except AttributeError:  # pragma: no cover - not Linux: no binding
            return None
    cpus = sorted(int(c) for c in cpus)
    n, t = int(n_workers), max(1, int(threads))
    if n < 1 or n * t > len(cpus):
        return None
    return [tuple(cpus[k * t:(k + 1) * t]) for k in range(n)]


#: A local pool gives up after this many worker deaths per worker it runs (``max_deaths``).
DEATHS_PER_WORKER = 3


#: seconds between checks that the processes a local pool waits on are still alive
POLL_S = 1.0


def _alive(pool) -> bool:
    """Whether a one-process pool's worker process is alive (True when it cannot be told)."""
    procs = getattr(pool, "_processes", None)   # None for a missing pool or before it starts
    if not procs:
        return True
    return all(p.is_alive() for p in list(procs.values()))


def _abandon(pool) -> None:
    """Shut down a pool whose worker died, without waiting on it.

    CPython's ProcessPoolExecutor reads results in a manager thread; a worker SIGKILLed while
    it writes a result leaves that thread blocked forever in the middle of the message (the
    parent keeps the pipe's write end open, so no EOF comes), no future ever completes and
    ``shutdown(wait=True)``, or the interpreter's exit, waits on it. Closing the parent's copy
    of the write end once the worker is gone gives the thread its EOF: it marks the pool broken
    and ends."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in procs:
        if proc.is_alive():
            proc.kill()
        proc.join(timeout=10)
    writer = getattr(getattr(pool, "_result_queue", None), "_writer", None)
    if writer is not None:
        try:
            writer.close()
        except OSError:
            pass


class LocalPool:
    """``--workers N``: N spawned worker processes on this machine, one pool per node.

    A worker that dies (SIGKILL, out of memory) while starting, idle or mid-unit is one
    event: the node's unfinished units are redone on the other nodes (dynamic: they go back
    to the queue), stderr says so, and a replacement process is started for the node, so N
    workers stay N. After ``max_deaths`` deaths (default ``DEATHS_PER_WORKER × N``) in the
    pool's life, or when one unit was lost with ``ALLOWED_FAILURES`` workers, the render
    stops with :class:`~links1.errors.RenderAborted` (CLI: one line, exit 1, no output).

    ``pin`` (default): where nodes x threads fit the CPUs this process may use, each node's
    process is bound to CPUs of its own (:func:`node_cpus`, :attr:`cpus`); the root is not
    bound (it sleeps while the nodes render).
    """

    name = "local"

    def __init__(self, n_workers: int, threads: int | None = None, prefetch: int = 2,
                 max_deaths: int | None = None, log=default_log, chunk_factor: int = CHUNK_FACTOR,
                 task_pixels: int = TASK_PIXELS, chunk_by: str = "units", shared_frame: bool = True,
                 pin: bool = True):
        if n_workers < 1:
            raise ValueError(f"workers must be >= 1, got {n_workers}")
        self.n = int(n_workers)
        self.threads = threads
        self.prefetch = max(1, int(prefetch))
        self.chunk_factor, self.task_pixels = int(chunk_factor), int(task_pixels)
        self.chunk_by = chunk_by
        self.batches = True        # the renderer renders batches (set when a worker is ready)
        self.channels = None       # channels of its pixels (set when a worker is ready)
        #: nodes write results into a frame the root maps (runtime.SharedFrame) instead of
        #: sending them through the pipe; False, or no room for the frame: the pipe
        self.shared_frame = bool(shared_frame)
        self._frame = None
        #: node -> (the root's end of its direct line, the node's serve future), open from before
        #: the clock to after it (runtime.serve): tasks and results of a run travel there
        self.lines: dict = {}
        self.line_tasks = 0        # tasks sent through lines (counted: tests see that they were)
        self.line_bytes = 0        # bytes of results received through lines (pixels only without a frame)
        self._root_blas = None   # the root's BLAS thread count during a run (limit_blas)
        self.pin = bool(pin)
        #: node -> the CPUs its process is bound to (node_cpus), None: not bound (set by start)
        self.cpus: list | None = None
        self.max_deaths = DEATHS_PER_WORKER * self.n if max_deaths is None else int(max_deaths)
        self.log = log
        self.deaths = 0
        self.pools: dict = {}
        self.pids: dict = {}       # node -> pid of its ready worker
        self.hello: dict = {}      # node -> start_worker future while the node is starting
        self._spec_key = None
        self._spec = None
        self.spawned: dict = {}    # node -> wall time its process was asked to start
        self.startup_s: dict = {}  # node -> seconds from that to its scene loaded and warm (measured)
        self.root_events = None    # render_plan's list: the root's dispatches are logged there

    @property
    def n_nodes(self) -> int:
        return self.n

    def _log(self, kind, w0):
        ev = self.root_events
        if ev is not None:
            ev.append([kind, w0, time.time()])

    def _spawn(self, k):
        """Start node k's worker process: a one-process pool whose first task loads the scene."""
        threads = str(self._spec.threads)
        saved = {v: os.environ.get(v) for v in THREAD_ENV}
        os.environ.update({v: threads for v in THREAD_ENV})  # inherited by the spawned worker
        try:
            pool = ProcessPoolExecutor(1, mp_context=mp.get_context("spawn"))
            self.pools[k] = pool
            self.pids.pop(k, None)
            self.spawned[k] = time.time()
            cpus = self.cpus[k] if self.cpus else None
            # the process starts here, deaf to Ctrl-C (SIGINT): the root alone stops, and ends it
            with children_ignore_interrupts():
                self.hello[k] = pool.submit(start_worker, self._spec, cpus, os.getpid())
        finally:
            for v, old in saved.items():
                if old is None:
                    os.environ.pop(v, None)
                else:
                    os.environ[v] = old

    def _died(self, k, when):
        """Node k's process is gone: count it, give up past the limit, else start a replacement."""
        pid = self.pids.get(k)
        self.deaths += 1
        line = self.lines.pop(k, None)
        if line is not None:
            line[0].close()
        old = self.pools.pop(k, None)
        self.hello.pop(k, None)
        if old is not None:
            _abandon(old)
        who = f"node {k} (pid {pid})" if pid else f"node {k}"
        if self.deaths > self.max_deaths:
            self.close()
            raise RenderAborted(f"{self.deaths} worker processes died (the limit is {self.max_deaths} for "
                                f"{self.n} workers; the last: {who}, {when}); giving up, no image written")
        self._spawn(k)
        return f"{who} died {when}"

    def start(self, spec):
        """Start the N workers and wait until each has loaded the scene (replacing any that die)."""
        if self.pools and self._spec_key == spec.key:
            return
        self.close()
        self._limit_root_blas()
        threads = spec.threads or self.threads or threads_per_worker(self.n)
        self._spec = RendererSpec(spec.kind, spec.path, spec.options, threads)
        self._spec_key = spec.key
        self.cpus = node_cpus(self.n, threads) if self.pin else None
        # computed here, the key travels with every pickled task: a node does not re-read and
        # re-hash the scene file per task (a cost that grows with the file)
        self._spec.key  # noqa: B018
        self.deaths = 0
        try:
            for k in range(self.n):
                self._spawn(k)
            while self.hello:
                self._await_hello(timeout=None)
        except BaseException as e:
            self.close(kill=isinstance(e, KeyboardInterrupt))
            raise

    def _await_hello(self, timeout):
        """Wait for starting nodes; a ready one records its pid, a dead one gets a replacement."""
        by_future = {f: k for k, f in self.hello.items()}
        done, _ = wait(list(by_future), timeout=POLL_S if timeout is None else timeout,
                       return_when=FIRST_COMPLETED)
        for f, k in by_future.items():  # dead without a result (see _abandon): as if broken
            if f not in done and not _alive(self.pools.get(k)):
                self.log(f"links1: {self._died(k, 'while starting')}; a replacement is starting")
        for f in done:
            k = by_future[f]
            try:
                pid = f.result()  # (pid, batches); a scene error is raised here, as that error
            except BrokenProcessPool:
                self.log(f"links1: {self._died(k, 'while starting')}; a replacement is starting")
                continue
            self.hello.pop(k, None)
            self.pids[k], self.batches = pid[:2]
            self.channels = pid[2] if len(pid) > 2 else None
            self.startup_s[k] = time.time() - self.spawned.get(k, time.time())

    def before_run(self, plan):
        """Before the clock (:func:`render_plan`): map the shared frame the nodes write into, as
        the root allocates its frame buffer (a 512² frame's file and pages: a few ms)."""
        self._close_lines()
        self._drop_frame()
        self._limit_root_blas()
        if self.shared_frame and self.channels:
            try:
                self._frame = SharedFrame(plan.height, plan.width, self.channels)
            except OSError:  # no room for it: results go through the pipe
                self._frame = None
        for k in range(self.n):   # a node that fails here is found dead by the run (fill)
            if k not in self.hello:
                self._open_line(k)

    @property
    def image_buffer(self):
        """The run's shared frame as the root's image (:func:`render_plan`): a unit a node wrote
        there is in place when its record arrives, nothing to copy (None: no shared frame)."""
        return None if self._frame is None else self._frame.array

    def _open_line(self, k) -> bool:
        """Open node k's direct line for this run (:func:`.runtime.serve`): a pipe whose other end
        goes to the node as its pool task; wait for its ``ready`` (the node has mapped the frame)
        -> whether it is open. False: the node is gone (its pool broken) or never answered."""
        if k in self.lines:
            return True
        ours, theirs = mp.Pipe(duplex=True)
        ref = None if self._frame is None else self._frame.ref
        try:
            fut = self.pools[k].submit(serve, self._spec, theirs, ref)
            while not ours.poll(POLL_S):
                if fut.done() or not _alive(self.pools.get(k)):
                    raise EOFError
            tag, _ = ours.recv()
        except (BrokenProcessPool, RuntimeError, EOFError, OSError, KeyError):
            ours.close()
            return False
        finally:   # the node holds its own copy now (or is gone): its death closes the line
            theirs.close()
        self.lines[k] = (ours, fut)
        return True

    def _close_lines(self):
        """End the nodes' serve loops (after the clock): each returns and its worker takes pool
        tasks again (pings, calls)."""
        for ours, _ in self.lines.values():
            try:
                ours.send(None)
            except (OSError, ValueError):
                pass
            ours.close()
        self.lines.clear()

    def _drop_frame(self):
        if self._frame is not None:
            self._frame.close()
            self._frame = None

    def run(self, plan, todo, spec, cull, on_done, on_fault):
        spec = self._spec
        alone = not self.lines   # called without render_plan's before_run: lines opened here
        if alone or (self._frame is not None and self._frame.shape[:2] != (plan.height, plan.width)):
            self.before_run(plan)
        try:
            self._run(plan, todo, spec, cull, on_done, on_fault, self._frame)
        except KeyboardInterrupt:
            self.terminate()
            raise
        except BaseException:
            self._close_lines()
            raise
        finally:   # its file is removed at once; the nodes unmap it at their next task or ping
            self._drop_frame()
        if alone:
            self._close_lines()

    def _run(self, plan, todo, spec, cull, on_done, on_fault, frame):
        failures = {}
        if plan.static:
            queues = {k: deque() for k in range(self.n)}
            for i in todo:
                queues[plan.owner[i] % self.n].append(i)
        else:
            shared = deque(todo)
        inflight = {k: deque() for k in range(self.n)}   # node -> its tasks on the line, in order
        # static plans and one-unit tasks: up to ``prefetch`` tasks on a node's line, the next
        # queued behind the running one to hide the round trip (result back, next task out),
        # and so few that a line's buffer never fills. Guided chunks: one per node at a time.
        # A second chunk queued at once was handed out when chunks are largest and waited
        # behind the first, while through the lines the round trip it hid is small (it was
        # far larger per chunk through the pool's threads)
        prefetch = self.prefetch

        def queue_of(k):
            return queues[k] if plan.static else shared

        def fill(k, depth=prefetch):
            if k in self.hello:  # still starting: units wait for a ready node
                return
            q = queue_of(k)
            if q and k not in self.lines and not self._open_line(k):
                lose(k, "while idle")   # it died while idle: noticed as its line would not open
                return
            while q and len(inflight[k]) < (depth if plan.static or not self.batches else 1):  # (above)
                if plan.static or not self.batches:
                    batch = take_batch(plan, q, None if self.batches else 1, self.task_pixels)
                else:
                    batch = guided_batch(plan, q, self.n, self.chunk_factor, self.task_pixels,
                                         by_load=self.chunk_by == "load")
                w0 = time.time()
                try:
                    self.lines[k][0].send(([plan.units[i].window for i in batch], [cull.get(i) for i in batch]))
                except (OSError, ValueError):  # it died while idle: noticed at this send
                    q.extendleft(reversed(batch))
                    lose(k, "while idle")
                    return
                self._log("dispatch", w0)
                self.line_tasks += 1
                inflight[k].append((batch, w0))

        def lose(k, when):
            mine = sorted(i for b, _ in inflight[k] for i in b)
            inflight[k].clear()   # (its line is closed by _died, or by close() when giving up)
            for i in mine:
                failures[i] = failures.get(i, 0) + 1
                if failures[i] >= ALLOWED_FAILURES:
                    self.close()
                    raise RenderAborted(f"unit {plan.units[i].window} was lost with {failures[i]} workers; "
                                        f"giving up, no image written")
            msg = self._died(k, when)
            if plan.static:
                left = mine + list(queues[k])
                queues[k].clear()
                others = [n for n in range(self.n) if n != k and n not in self.hello] or [k]
                for j, i in enumerate(left):  # dealt in turn to the ready nodes
                    queues[others[j % len(others)]].append(i)
                on_fault(f"{msg}; its {len(left)} unfinished units are redone on other nodes; "
                         f"a replacement is starting")
            else:
                shared.extendleft(reversed(mine))
                on_fault(f"{msg}; its {len(mine)} units in flight go back to the queue; a replacement is starting")

        def receive(k):
            """Node k's next result from its line -> False when the line is dead."""
            try:
                data = self.lines[k][0].recv_bytes()
            except (EOFError, OSError):
                return False
            self.line_bytes += len(data)
            tag, payload = pickle.loads(data)
            if tag == "error":
                raise payload
            batch, sent = inflight[k].popleft()
            fill(k)   # the node's next task leaves before the root places this one's units
            for i, (px, info) in zip(batch, payload):
                info["node"], info["sent"] = k, sent   # sent: when the root wrote the task (wall)
                if px is None:  # written into the shared frame by the node
                    u = plan.units[i]
                    px = frame.array[u.y0:u.y0 + u.h, u.x0:u.x0 + u.w]
                on_done(i, px, info)
            return True

        for depth in range(1, prefetch + 1):   # every node's first task before any node's second
            for k in range(self.n):
                fill(k, depth)
        while any(inflight.values()) or (self.hello and any(queue_of(k) for k in range(self.n))):
            busy = [k for k in range(self.n) if inflight[k]]
            if busy:
                # the root's thread sleeps until a line has a result or a node's process ends
                # (its sentinel: a node killed mid-message); bounded while nodes are starting,
                # to give them work as soon as they are ready
                lines = {self.lines[k][0]: k for k in busy}
                ends = {p.sentinel: k for k in busy
                        for p in list((getattr(self.pools.get(k), "_processes", None) or {}).values())}
                ready = wait_connections(list(lines) + list(ends), timeout=0.05 if self.hello else POLL_S)
                if self.hello:
                    self._await_hello(timeout=0)
            else:  # only starting nodes are left to render the remaining units
                self._await_hello(timeout=None)
                ready = []
            lost = set()
            for r in ready:
                if r in lines:
                    k = lines[r]
                    if not receive(k):
                        lost.add(k)
            for r in ready:
                if r in ends and inflight[ends[r]]:
                    k = ends[r]
                    while inflight[k] and k not in lost and k in self.lines and self.lines[k][0].poll(0):
                        if not receive(k):   # what it sent before it died, then its end
                            lost.add(k)
                    lost.add(k)
            for k in sorted(lost):
                lose(k, "mid-unit")
            for k in range(self.n):
                fill(k)

    def call(self, fn, *args):
        """Run ``fn(*args)`` on a ready node (its threads, its loaded renderer) -> the result."""
        self._close_lines()   # a worker in its serve loop takes no other task
        k = min(k for k in range(self.n) if k not in self.hello)
        return self.pools[k].submit(fn, *args).result(timeout=600)

    def after_run(self, on_fault):
        """Ping every ready worker: one that died after its last unit is replaced now (N stay N).

        A SIGKILLed process cannot answer, so a death before this point is always seen.
        :func:`render_plan` calls it after the clock stops: the makespan runs from the first
        dispatch to the last result, and this round trip to every node (2-4 ms at 2 nodes)
        is neither."""
        self._close_lines()   # the serve loops end; each worker then answers its ping
        pings = {}
        for k in [k for k in range(self.n) if k not in self.hello]:
            try:
                pings[k] = self.pools[k].submit(release_frame)  # -> its pid, the frame unmapped
            except (BrokenProcessPool, RuntimeError):
                pings[k] = None
        wait([f for f in pings.values() if f is not None], timeout=60)
        for k, f in pings.items():
            try:
                if f is not None and f.done():
                    f.result()
                    continue
            except BrokenProcessPool:
                pass
            if f is None or f.done():
                on_fault(f"{self._died(k, 'while idle')}; it had no unfinished units; a replacement is starting")

    def close(self, kill: bool = False):
        """Shut the workers down (they finish the task in hand); ``kill``: :meth:`terminate`."""
        self._close_lines()
        self._drop_frame()
        if kill:   # every process at once, then each pool is left without waiting on it
            for p in self.pools.values():
                for proc in list((getattr(p, "_processes", None) or {}).values()):
                    if proc.is_alive():
                        proc.kill()
        for p in self.pools.values():
            if _alive(p) and not kill:
                p.shutdown(wait=True, cancel_futures=True)
            else:
                _abandon(p)
        self.pools.clear()
        self.pids.clear()
        self.hello.clear()
        self._spec_key = None
        if self._root_blas:   # the root's BLAS threads as they were before the pool started
            limit_blas(self._root_blas)
        self._root_blas = None

    def terminate(self):
        """Stop now (Ctrl-C): kill every worker process, whatever it is doing, and leave its
        pool without waiting on it (:func:`_abandon`: no task in flight, no pool thread and no
        ``multiprocessing`` exit handler waits on a worker); the shared frame is removed. The
        pool starts afresh on its next :meth:`start`."""
        self.close(kill=True)

    def _limit_root_blas(self):
        """The root renders nothing: one BLAS thread from the pool's start to its close, so that
        no OpenBLAS worker of the root spins on a core the nodes need (:func:`.runtime.limit_blas`;
        a worker spins ~40-50 ms after each threaded BLAS call, whatever the limit set later:
        the planning of the next run, right before the clock, then runs on one BLAS thread)."""
        if self._root_blas is None:
            self._root_blas = limit_blas(1) or 0

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
