"""What a node runs: a picklable renderer spec, one renderer per worker process, unit tasks.

Scenes cannot be pickled (Mitsuba's cannot), so nodes receive a :class:`RendererSpec`
(kind, scene path, options) and load the scene themselves, once per process; the renderer
is kept in :data:`_RENDERERS` for every later unit.
"""
from __future__ import annotations

import copy
import ctypes
import glob
import hashlib
import importlib
import itertools
import json
import mmap
import os
import re
import tempfile
import threading
import time
import warnings
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from links1.scene.xmlparse import SceneWarning
from links1.tracing.aovs import aov_channel
from links1.tracing.render import render

from ..renderers import make_renderer, renderer_warnings

#: Per-process cache: spec key -> renderer (a node loads its scene once).
_RENDERERS: dict = {}
#: Per-process cache of culled core scenes: (spec key, object ids) -> scene.
_CULLED: dict = {}
#: Launch numbers in this process (a record's ``launch`` = (pid, number): units sharing one)
_LAUNCHES = itertools.count()
_TASKS = itertools.count()

THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS")


@dataclass(frozen=True)
class RendererSpec:
    """How a node builds its renderer.

    kind : "core" | "mitsuba" (``links1_app.renderers.make_renderer``) or "module:callable"
           (any factory ``f(path, **options)`` following the Renderer contract)
    path : scene file
    options : keyword options of the factory (params, spp, max_depth, seed, aovs, ...)
    threads : renderer threads per node (drjit thread count / BLAS threads), None: leave
    """

    kind: str
    path: str
    options: tuple = ()
    threads: int | None = None

    @classmethod
    def make(cls, kind, path, threads=None, **options):
        opts = tuple(sorted((k, _freeze(v)) for k, v in options.items() if v is not None))
        return cls(str(kind), str(path), opts, threads)

    @property
    def kwargs(self) -> dict:
        return {k: _thaw(v) for k, v in self.options}

    @cached_property
    def key(self) -> str:
        """Identity of the rendered bits: kind, options and the scene file's content."""
        h = hashlib.sha256(json.dumps([self.kind, os.path.abspath(self.path), repr(self.options)]).encode())
        try:
            with open(self.path, "rb") as f:
                h.update(f.read())
        except OSError:
            pass
        return h.hexdigest()[:16]

    def build(self):
        set_threads(self.threads, self.kind)
        if ":" in self.kind:
            mod, _, name = self.kind.partition(":")
            return getattr(importlib.import_module(mod), name)(self.path, **self.kwargs)
        return make_renderer(self.kind, self.path, **self.kwargs)


def _freeze(v):
    if isinstance(v, dict):
        return ("__dict__", tuple(sorted((k, _freeze(x)) for k, x in v.items())))
    if isinstance(v, (list, tuple)):
        return tuple(_freeze(x) for x in v)
    return v


def _thaw(v):
    if isinstance(v, tuple) and len(v) == 2 and v[0] == "__dict__":
        return {k: _thaw(x) for k, x in v[1]}
    if isinstance(v, tuple):
        return tuple(_thaw(x) for x in v)
    return v


def set_threads(threads, kind="core"):
    """Limit the renderer's threads in this process (drjit when already imported / mitsuba),
    and the OpenBLAS that numpy has already loaded (:func:`limit_blas`: the environment
    variables reach only a BLAS loaded later)."""
    if not threads:
        return
    for k in THREAD_ENV:
        os.environ[k] = str(threads)
    limit_blas(int(threads))
    if kind == "mitsuba":
        try:
            import drjit   # lazy: Mitsuba is optional, and only its renderer needs this
            # never below 2: Mitsuba 3.9.1 reads EXR files (a texture, an envmap) with tasks on
            # Dr.Jit's pool, and with a pool of one thread that read waits forever
            drjit.set_thread_count(max(2, int(threads)))
        except Exception:  # noqa: BLE001 - the renderer reports a missing drjit itself
            pass


#: the OpenBLAS of this process (numpy's) as [library, setter, getter]; [None] * 3 when none
_BLAS: list = []
_BLAS_SYMBOLS = (("openblas_set_num_threads", "openblas_get_num_threads"),
                 ("openblas_set_num_threads64_", "openblas_get_num_threads64_"),
                 ("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
                 ("scipy_openblas_set_num_threads", "scipy_openblas_get_num_threads"))


def _blas():
    """The loaded OpenBLAS's thread setter and getter (found among the libraries this process
    has mapped, ``/proc/self/maps``), or ``(None, None)`` (no OpenBLAS, not Linux)."""
    if not _BLAS:
        found = [None, None, None]
        try:
            with open("/proc/self/maps") as f:
                paths = (ln.split()[-1] for ln in f if ln.strip())
                libs = sorted({p for p in paths if "openblas" in os.path.basename(p).lower() and ".so" in p})
        except OSError:
            libs = []
        for path in libs:
            try:
                lib = ctypes.CDLL(path)   # the mapped one: dlopen returns the same handle
            except OSError:
                continue
            for setter, getter in _BLAS_SYMBOLS:
                if hasattr(lib, setter) and hasattr(lib, getter):
                    found = [lib, getattr(lib, setter), getattr(lib, getter)]
                    found[1].argtypes, found[2].restype = [ctypes.c_int], ctypes.c_int
                    break
            if found[0] is not None:
                break
        _BLAS.extend(found)
    return _BLAS[1], _BLAS[2]


def limit_blas(threads: int):
    """Set the thread count of the OpenBLAS numpy has loaded in this process -> the count it
    had (None where there is none to set). An OpenBLAS worker thread keeps spinning
    on a core for ~0.1 s after each threaded BLAS call (the root's cost model, a node's
    matrix products), which is a whole plugin frame (30-40 ms): in the root of a two-node
    plugin render it took 28 ms of CPU inside a 40 ms makespan on this 2-core machine, and
    each node's half-frame launch (17 ms of CPU) took 33 ms of wall time. One thread stops
    the spinning thread at once; numpy's environment variables act only before its import."""
    setter, getter = _blas()
    if setter is None:
        return None
    old = int(getter())
    if threads and int(threads) != old:
        setter(int(threads))
    return old


def get_renderer(spec: RendererSpec):
    """This process's renderer for ``spec`` (loaded on first use, then kept)."""
    key = spec.key
    r = _RENDERERS.get(key)
    if r is None:
        r = _RENDERERS[key] = spec.build()
    return r


#: Seconds between a local worker's checks that its root is alive (:func:`watch_root`).
ROOT_WATCH_S = 0.5


def watch_root(root: int) -> None:
    """End this worker process when its root (pid ``root``, its parent) is gone. A root that
    crashes or is killed by a signal closes no pool, and its workers, orphaned, would wait for
    tasks forever (seen: 18 idle workers left by test runs whose process segfaulted). A
    daemon thread compares the parent pid every :data:`ROOT_WATCH_S` seconds."""
    def watch():
        while True:
            time.sleep(ROOT_WATCH_S)
            if os.getppid() != root:
                os._exit(0)
    threading.Thread(target=watch, name="links1-root-watch", daemon=True).start()


def pin_cpus(cpus) -> tuple | None:
    """Bind every thread of this process to the CPUs ``cpus`` (threads it starts later inherit
    the binding) -> the CPUs its main thread is bound to, or None where nothing was bound
    (``cpus`` empty or None, no ``sched_setaffinity``: not Linux). A local node's
    process is bound to CPUs of its own (:func:`.local_pool.node_cpus`), because the kernel put
    both one-thread nodes of a two-node plugin run on one core of this 2-core machine, each node's
    half-frame launch waiting in the run queue as long as it ran (docs/partitioning.md)."""
    if not cpus or not hasattr(os, "sched_setaffinity"):
        return None
    cpus = {int(c) for c in cpus}
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        tids = [0]
    for tid in tids:
        try:
            os.sched_setaffinity(tid, cpus)
        except (ProcessLookupError, PermissionError):   # a thread that ended meanwhile
            pass
    os.sched_setaffinity(0, cpus)   # this thread at least: a bad CPU set raises here
    return tuple(sorted(os.sched_getaffinity(0)))


def start_worker(spec: RendererSpec, cpus=None, root: int | None = None) -> tuple:
    """A local worker's first task: bind it to ``cpus`` (:func:`pin_cpus`; None: leave it to the
    kernel), with ``root`` (the root's pid) end it when the root is gone (:func:`watch_root`),
    set its threads, load the scene once -> ``(pid, batches, channels)`` (``batches``: the
    renderer renders many units per launch, see :func:`render_units`).

    A task rather than a pool initializer, so that a scene error comes back as that error
    and only a dead process breaks the pool. Warnings print as one line; the scene's own
    (:class:`~links1.scene.xmlparse.SceneWarning`) are left to the root, which read the scene too.
    """
    pin_cpus(cpus)   # before the renderer starts its threads (Dr.Jit's pool): they inherit it
    if root is not None:
        watch_root(root)
    renderer_warnings(spec.kind)
    warnings.simplefilter("ignore", SceneWarning)
    r = get_renderer(spec)
    warm_up(r, warm_samples(spec, r))
    return os.getpid(), can_batch(r), channel_count(r)


def channel_count(renderer):
    """Channels of the renderer's pixels (``len(renderer.channels)``), None when it does not say."""
    try:
        return len(renderer.channels)
    except Exception:  # noqa: BLE001 - a renderer without channel names: results go through the pipe
        return None


#: Samples of the full-size warm-up launch (:func:`warm_samples`): at most this many, so that a
#: node's start-up stays a fraction of a second (512², spp 4 on the plugin: ~0.15 s here).
WARM_SAMPLES = 1 << 20


def warm_samples(spec: RendererSpec, renderer) -> int:
    """Samples of the large warm-up launch ``spec``'s node renders before its first unit: the
    plugin's (a Dr.Jit renderer keeps the memory of its launches): the film's pixels x spp, at most
    :data:`WARM_SAMPLES` and :data:`LAUNCH_SAMPLES`; 0 for the core (numpy allocates per launch,
    nothing to warm; a core frame is seconds)."""
    if spec.kind != "mitsuba" or not can_batch(renderer):
        return 0
    w, h = renderer.film_size
    spp = max(1, int(getattr(renderer, "spp", 1) or 1))
    return min(w * h * spp, WARM_SAMPLES, LAUNCH_SAMPLES)


def warm_up(renderer, samples: int = 0):
    """Render a few tiny windows and batches of different sizes, so that kernels, Dr.Jit's
    frozen recordings (the first call records, the second makes changed literals opaque) and
    caches are ready before the node's first unit: start-up, not work.

    ``samples`` > 0 (:func:`warm_samples`): then one batch of scanlines holding about that many
    samples, so that the renderer's memory for a launch of a task's size is allocated and
    touched before the clock too, then
    batches of half as many scanlines, a quarter, ... down to one: Dr.Jit keeps freed memory for
    a later launch of the same size class only, so a node's first half-frame launch after a
    whole-frame warm-up still took fresh pages (fig11 at 512², 2 nodes: ~4800 page faults and
    8-12 ms of system time per node in the first run, 0-20 after these batches; start-up about
    one more frame)."""
    w, h = renderer.film_size
    tiny = [(0, 0, min(w, 3), min(h, 2)), (0, 0, min(w, 2), min(h, 3)), (0, 0, min(w, 4), min(h, 4))]
    if can_batch(renderer):  # the links1 renderers (others are left as they are)
        for k in range(3):
            renderer.render_batch(tiny[k:] + tiny[:k][:1])
        if samples > 0:
            spp = max(1, int(getattr(renderer, "spp", 1) or 1))
            rows = max(1, min(h, samples // max(1, w * spp)))
            while True:   # then half as many, and so on down to one scanline (above)
                renderer.render_batch([(0, y, w, 1) for y in range(rows)])
                if rows == 1:
                    break
                rows //= 2


def spec_batches(spec: RendererSpec) -> bool:
    """Whether ``spec``'s renderer batches, known without building it (the root of a cluster):
    the links1 renderers do; a ``module:callable`` factory does if it has ``render_batch``."""
    if ":" not in spec.kind:
        return True
    mod, _, name = spec.kind.partition(":")
    return can_batch(getattr(importlib.import_module(mod), name))


def can_batch(renderer) -> bool:
    """Whether units are worth sending to ``renderer`` in batches (it has ``render_batch``)."""
    return callable(getattr(renderer, "render_batch", None))


def wire_pixels(img) -> np.ndarray:
    """A unit's pixels as a node sends them to the root: float32 when that holds every value
    exactly (the plugin renderer computes in float32), else float64. The root places them in
    its float64 frame, so the image is the same bits; half the bytes cross the pipe (a
    256x512x4 result: 12 ms as float64, 1.2 ms as float32 through a process pipe here)."""
    a = np.asarray(img, dtype=np.float64)
    b = a.astype(np.float32)
    return b if np.array_equal(b, a, equal_nan=True) else a


class SharedFrame:
    """A float64 frame (H, W, C) in a file that the root and the local nodes map (``/dev/shm``
    when there is one: memory, not disk). A node writes each unit's pixels at its window right
    after its launch and sends the root only the unit's record, so a result does not travel
    through the process pipe (a 256x512x4 float64 half frame: ~10 ms pickled, sent, unpickled
    one after another by the root) and the root copies it into the image from memory.
    The values written are the renderer's, as float64: the bits of ``wire_pixels`` placed in
    the root's float64 frame. The local pool's default (``LocalPool(shared_frame=False)``: the
    pipe); the root makes it before the clock and removes its file when the run ends, whatever
    happens; a root killed with SIGKILL leaves it in ``/dev/shm`` (``links1-frame-<root pid>-*``),
    and the next frame made in that directory removes it (:func:`remove_stale_frames`)."""

    def __init__(self, height, width, channels, directory=None):
        d = directory or ("/dev/shm" if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK) else None)
        remove_stale_frames(d or tempfile.gettempdir())
        fd, self.path = tempfile.mkstemp(prefix=f"links1-frame-{os.getpid()}-", suffix=".f64", dir=d)
        os.close(fd)
        self.shape = (int(height), int(width), int(channels))
        try:
            with open(self.path, "r+b") as f:
                f.truncate(8 * int(np.prod(self.shape)))
                if hasattr(os, "posix_fallocate"):
                    # reserve the pages now: a full /dev/shm (a container's 64 MiB) raises
                    # ENOSPC here, and the pool uses the pipe, instead of a node's SIGBUS later
                    os.posix_fallocate(f.fileno(), 0, 8 * int(np.prod(self.shape)))
            self.array = _map(self.path, self.shape)
        except BaseException:
            os.unlink(self.path)
            raise

    @property
    def ref(self) -> tuple:
        """What a node needs to map it (picklable)."""
        return (self.path, self.shape)

    def close(self):
        self.array = None
        try:
            os.unlink(self.path)
        except OSError:
            pass


def remove_stale_frames(directory) -> list:
    """Remove the shared frames in ``directory`` whose root process is gone (its pid is in the
    name: ``links1-frame-<pid>-*.f64``; a root killed with SIGKILL leaves its file, which would
    hold memory in ``/dev/shm`` until reboot). A frame of a live process (any user's: its pid
    exists) is kept. Returns the paths removed."""
    gone = []
    for path in glob.glob(os.path.join(directory, "links1-frame-*-*.f64")):
        m = re.fullmatch(r"links1-frame-(\d+)-.*\.f64", os.path.basename(path))
        if m is None or int(m.group(1)) == os.getpid():
            continue
        try:
            os.kill(int(m.group(1)), 0)
            continue                      # alive
        except ProcessLookupError:
            pass                          # gone: its file is stale
        except (PermissionError, OverflowError):
            continue                      # another user's live process, or no such pid
        try:
            os.unlink(path)
            gone.append(path)
        except OSError:
            pass
    return gone


def _map(path, shape):
    """The file as a float64 array, its pages mapped at once (``MAP_POPULATE``: one call instead of
    a page fault per 4 KiB on first touch, which cost as much as the pipe it replaces)."""
    with open(path, "r+b") as f:
        flags = mmap.MAP_SHARED | getattr(mmap, "MAP_POPULATE", 0)
        mm = mmap.mmap(f.fileno(), 8 * int(np.prod(shape)), flags=flags)
    return np.ndarray(shape, dtype=np.float64, buffer=mm)


#: this process's mapping of the root's current shared frame: (path, array)
_FRAME: list = [None, None]


def _frame_array(ref):
    path, shape = ref
    if _FRAME[0] != path:
        _FRAME[0], _FRAME[1] = None, None   # unmap the last run's frame (its file is gone)
        _FRAME[1] = _map(path, shape)
        _FRAME[0] = path
    return _FRAME[1]


def release_frame():
    """Unmap the shared frame in this process -> pid (the root pings its nodes with it at the end)."""
    _FRAME[0], _FRAME[1] = None, None
    return os.getpid()


def _to_frame(frame, window, img):
    """Write ``img`` at ``window`` of the shared frame -> None (written) or the pixels to send."""
    a = _frame_array(frame)
    x0, y0, w, h = window
    img = np.asarray(img)
    if img.shape != (h, w, a.shape[2]):
        return wire_pixels(img)   # not what the frame holds: the root checks it as it always did
    a[y0:y0 + h, x0:x0 + w] = img
    return None


def _ready(img, frame, window, wire):
    """A unit's pixels as :func:`render_units` returns them: written into the shared ``frame``
    (None), as :func:`wire_pixels` sends them, or (``wire`` False: the root is this process,
    nothing crosses a pipe) the renderer's array as it is: the same values either way."""
    if frame is not None:
        return _to_frame(frame, window, img)
    return wire_pixels(img) if wire else np.asarray(img)


def render_unit(spec: RendererSpec, window, cull=None, frame=None, wire=True):
    """Render one window on this node -> (pixels (h, w, C), info dict); pixels as
    :func:`wire_pixels` sends them (float32 when exact, else float64), see :func:`_ready`."""
    renderer = get_renderer(spec)
    t0, w0, c0 = time.perf_counter(), time.time(), time.process_time()
    if cull is not None:
        img = _render_culled(spec, renderer, window, cull)
    else:
        img = renderer.render(window=tuple(int(v) for v in window))
    dt = time.perf_counter() - t0
    cpu = time.process_time() - c0
    px = _ready(img, frame, tuple(int(v) for v in window), wire)
    return px, {"seconds": dt, "start": w0, "stop": w0 + dt, "pid": os.getpid(), "launch_seconds": dt,
                "launch_cpu_s": cpu,
                "launch_units": 1, "launch": (os.getpid(), next(_LAUNCHES)),
                "wire_s": time.perf_counter() - t0 - dt}


#: Samples (pixels x spp) one launch may hold on a node; a larger batch is split into
#: launches of at most this many (bounds the renderer's memory: Dr.Jit keeps a few hundred
#: bytes per sample in flight).
LAUNCH_SAMPLES = 1 << 22


def render_units(spec: RendererSpec, windows, culls=None, frame=None, wire=True):
    """Render a batch of units on this node -> ``[(pixels, info), ...]`` in ``windows`` order.
    With ``frame`` (a :attr:`SharedFrame.ref`) each unit's pixels are written into the shared
    frame after its launch and ``pixels`` is None; ``wire`` False (the in-process node) returns
    the renderer's arrays unconverted (:func:`_ready`).

    Renderers with ``render_batch(windows)`` (both links1 renderers) render the batch in as
    few launches as :data:`LAUNCH_SAMPLES` allows; each unit's pixels are exactly what
    ``render(window)`` returns for it. A unit's ``seconds`` is then its share of its launch by
    pixel count, not a measurement (``launch_seconds`` and ``launch_units`` say which launch it
    shared; ``launch_cpu_s``: the CPU time this process spent in that launch, all its threads:
    below ``launch_seconds`` when the node was off its core; the schedule report measures or derives unit times itself, see
    :mod:`.report`); ``task`` names the task (this call), ``task_in`` is when it reached this
    node (wall clock). Units
    with a cull list, or renderers without ``render_batch``, are rendered one by one.
    """
    task_in = time.time()   # the task reached this node (wall clock): its record's ``task_in``
    windows = [tuple(int(v) for v in w) for w in windows]
    culls = list(culls) if culls is not None else [None] * len(windows)
    renderer = get_renderer(spec)
    batch = getattr(renderer, "render_batch", None) if can_batch(renderer) else None
    task = (os.getpid(), next(_TASKS))  # one task = the units sent to this node in one message
    if batch is None or len(windows) == 1 or any(c is not None for c in culls):
        out = [render_unit(spec, w, c, frame, wire) for w, c in zip(windows, culls)]
        for _, info in out:
            info["task"], info["task_in"] = task, task_in
        return out
    spp = max(1, int(getattr(renderer, "spp", 1) or 1))
    launches, cur, size = [], [], 0
    for w in windows:  # consecutive units, at most LAUNCH_SAMPLES samples per launch (>= 1 unit)
        if cur and (size + w[2] * w[3]) * spp > LAUNCH_SAMPLES:
            launches.append(cur)
            cur, size = [], 0
        cur.append(w)
        size += w[2] * w[3]
    launches.append(cur)
    out = []
    for launch in launches:
        t0, w0, c0 = time.perf_counter(), time.time(), time.process_time()
        lid = (os.getpid(), next(_LAUNCHES))
        imgs = batch(launch)
        dt = time.perf_counter() - t0
        cpu = time.process_time() - c0
        total = sum(a[2] * a[3] for a in launch)
        # the launch's units readied together (into the frame: one loop of copies, not
        # per-unit calls and timers after the launch), each
        # unit's ``wire_s`` its share of that time by pixel count, as ``seconds`` is of the launch
        tw = time.perf_counter()
        pxs = _ready_all(imgs, frame, launch, wire)
        ready_s = time.perf_counter() - tw
        pid, n_in, at = os.getpid(), len(launch), w0
        for px, a in zip(pxs, launch):
            f = a[2] * a[3] / total
            share = dt * f
            out.append((px, {"seconds": share, "start": at, "stop": at + share, "pid": pid,
                             "launch_seconds": dt, "launch_cpu_s": cpu, "launch_units": n_in, "launch": lid,
                             "task": task, "task_in": task_in, "wire_s": ready_s * f}))
            at += share
    return out


def _ready_all(imgs, frame, windows, wire):
    """:func:`_ready` for a launch's units -> their pixels as :func:`render_units` returns them."""
    return [_ready(img, frame, a, wire) for img, a in zip(imgs, windows)]


def serve(spec: RendererSpec, line, frame=None):
    """A local node's side of its direct line to the root for one run: map the run's
    shared ``frame`` (a :attr:`SharedFrame.ref`, before the root's clock starts), say
    ``("ready", pid)``, then render each task the root sends, ``(windows, culls)``, with
    :func:`render_units` and send back ``("ok", results)`` (or ``("error", exception)``), until
    the root sends None or closes its end -> pid.

    The line is one end of a :func:`multiprocessing.Pipe` the root made; the task arrives as this
    process's pool task, so the process pool still starts, watches and replaces the node. Through
    the line a task is one pickled message written by the root's own thread and read by this
    loop, instead of passing a pool's two helper threads in the root each way (its queue
    manager and queue feeder: with every core rendering, a task waited for them to be
    scheduled)."""
    if frame is not None:
        _frame_array(frame)
    line.send(("ready", os.getpid()))
    try:
        while True:
            try:
                msg = line.recv()
            except (EOFError, OSError):   # the root closed its end
                break
            if msg is None:
                break
            windows, culls = msg
            try:
                out = ("ok", render_units(spec, windows, culls, frame))
            except Exception as e:  # noqa: BLE001 - the root raises it, as a pool task's error
                out = ("error", e)
            try:
                line.send(out)
            except (BrokenPipeError, OSError):
                break
            except Exception as e:  # noqa: BLE001 - an exception that does not pickle
                line.send(("error", RuntimeError(f"{type(out[1]).__name__}: {out[1]}")))
    finally:
        line.close()
    return os.getpid()


def _render_culled(spec, renderer, window, ids):
    """Render with only the objects ``ids`` present (4-4 culling).

    Renderers may implement ``render(window=..., shapes=ids)``; the core renderer is
    culled here by rendering a copy of its scene that holds copies of those shapes. The id
    AOV is mapped back to the full scene's indices.
    """
    ids = tuple(int(i) for i in ids)
    if getattr(renderer, "supports_cull", False):
        return renderer.render(window=tuple(window), shapes=ids)
    scene = getattr(renderer, "scene", None)
    if scene is None or not hasattr(scene, "shapes"):
        return renderer.render(window=tuple(window))  # cannot cull: render everything
    key = (spec.key, ids)
    sub = _CULLED.get(key)
    if sub is None:
        if len(_CULLED) > 64:
            _CULLED.clear()
        sub = _CULLED[key] = replace(scene, shapes=[copy.copy(scene.shapes[i]) for i in ids])
    img = render(sub, spp=renderer.spp, max_depth=renderer.max_depth, seed=renderer.seed, window=tuple(window),
                 aovs=renderer.aovs, min_weight=getattr(renderer, "min_weight", 0.0),
                 light_samples=getattr(renderer, "light_samples", 1))
    c = aov_channel(renderer.channels, "id")
    if c is not None:
        idc = img[..., c]
        lut = np.asarray(ids, dtype=np.float64)
        hit = idc >= 0
        img[..., c] = np.where(hit, lut[np.clip(idc, 0, max(len(ids) - 1, 0)).astype(np.int64)] if ids else -1, -1.0)
    return img
