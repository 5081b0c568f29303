"""Ctrl-C (SIGINT): the root process alone stops, at once and cleanly, whatever renders.

Helpers, standard library only:

* :func:`held_interrupts` / :func:`check_interrupt`: a renderer whose work runs inside
  native calls (the plugin's Dr.Jit launches) holds SIGINT while it works and raises
  :class:`KeyboardInterrupt` itself between launches. Python runs a signal handler only when
  the interpreter regains control, and a ``KeyboardInterrupt`` raised there inside a native
  call can be lost: with Python's own handler, ``mi.render`` of ``links1_whitted`` raised
  nothing at all when SIGINT came during a frozen Dr.Jit launch (the handler ran inside
  ``drjit.freeze``'s C++ call, which dropped the exception).
* :func:`children_ignore_interrupts`: processes started inside it (a local pool's workers,
  a Dask cluster's nannies and workers) never see SIGINT, so a terminal's Ctrl-C, sent to the
  whole process group, reaches only the root, which then ends them itself.
* :func:`ignore_interrupts`: once the root is stopping (or writing a finished frame), a
  second Ctrl-C does not break the clean-up half way.
* :data:`COMMAND_INTERRUPTED` / :func:`raise_if_interrupted`: a Ctrl-C that reached the
  command (its handler sets the event) stops it before each output it writes, also where
  Python dropped the ``KeyboardInterrupt``.
"""
from __future__ import annotations

import _signal
import contextlib
import functools
import signal
import threading

#: the holds in force in this process, innermost last: [the handler held, interrupts caught]
_HOLDS: list = []

#: set when Ctrl-C reaches the command (``links1_app.cli``'s handler): the process is then ending
COMMAND_INTERRUPTED = threading.Event()


def raise_if_interrupted() -> None:
    """KeyboardInterrupt where Ctrl-C reached the command but its exception did not: raised in a
    weak reference's callback or a finaliser (an import's module lock, say), Python prints and
    drops it, and the command would go on to write its output (render, each frame of animate)."""
    if COMMAND_INTERRUPTED.is_set():
        raise KeyboardInterrupt


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextlib.contextmanager
def held_interrupts():
    """Hold SIGINT during the block: a SIGINT is only noted, and :func:`check_interrupt` (or the
    block's end) hands it to the handler that was in force (Python's default: raises
    :class:`KeyboardInterrupt`). Outside the main thread, with SIGINT ignored or left to the
    system's default action, and inside another hold, it changes nothing."""
    if _HOLDS or not _main_thread():
        yield
        return
    # (``_signal``'s functions, which ``signal``'s wrap in enum conversions: a frame holds once,
    # and after its kernels those conversions cost ~60 µs of the host's time)
    old = _signal.getsignal(_signal.SIGINT)
    if not callable(old):   # SIG_IGN (a worker), SIG_DFL, or set outside Python: nothing to hold
        yield
        return
    hold = [old, []]
    _signal.signal(_signal.SIGINT, lambda signum, frame: hold[1].append(frame))
    _HOLDS.append(hold)
    try:
        yield
    finally:
        _HOLDS.remove(hold)
        _signal.signal(_signal.SIGINT, old)
        if hold[1]:
            old(signal.SIGINT, hold[1][0])


def interruptible(fn):
    """``fn`` run inside :func:`held_interrupts` (a method that launches native work)."""
    @functools.wraps(fn)
    def held(*args, **kwargs):
        with held_interrupts():
            return fn(*args, **kwargs)
    return held


def check_interrupt() -> None:
    """Inside :func:`held_interrupts`: hand a SIGINT that came since the hold began to the held
    handler now (Python's default raises :class:`KeyboardInterrupt` here). Anywhere else: nothing."""
    if _HOLDS and _HOLDS[-1][1] and _main_thread():
        old, caught = _HOLDS[-1]
        frame = caught[0]
        caught.clear()
        old(signal.SIGINT, frame)


@contextlib.contextmanager
def children_ignore_interrupts():
    """Block SIGINT in this thread during the block: processes (and threads) started here
    inherit the blocked signal through fork and exec and never receive it. A SIGINT sent to
    this process meanwhile is held (:func:`held_interrupts`: another thread of the process may
    take it, and Python would raise it in the main thread in the middle of starting a child,
    whose start-up data then never arrives) and raised at the block's end."""
    if not hasattr(signal, "pthread_sigmask"):   # pragma: no cover - not POSIX
        yield
        return
    # multiprocessing starts its resource tracker with the first child process and unblocks
    # SIGINT in that thread afterwards (resource_tracker.ensure_running): started first, here
    from multiprocessing import resource_tracker
    with held_interrupts():
        resource_tracker.ensure_running()
        old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            yield
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)


def ignore_interrupts(ignore: bool = True):
    """Ignore SIGINT in this process from now on (main thread only; ``ignore`` False: change
    nothing) -> the handler in force before, for :func:`restore_interrupts` (None: not the
    main thread, or a handler not set from Python)."""
    if not _main_thread():
        return None
    if not ignore:
        return signal.getsignal(signal.SIGINT)
    return signal.signal(signal.SIGINT, signal.SIG_IGN)


def restore_interrupts(handler) -> None:
    """Put back a SIGINT handler :func:`ignore_interrupts` returned (None: nothing to do)."""
    if handler is not None and _main_thread():
        signal.signal(signal.SIGINT, handler)


def stop_resource_sharer() -> None:
    """Stop multiprocessing's resource-sharer thread of this process, if a pool started it
    (it serves connections handed to workers until the interpreter exits). After an interrupt
    the exit can close its listener under it, and its thread then prints a traceback after
    ``links1: interrupted``: asked to stop first, it ends quietly."""
    from multiprocessing import resource_sharer
    sharer = getattr(resource_sharer, "_resource_sharer", None)
    if sharer is None or getattr(sharer, "_address", None) is None:
        return
    try:
        sharer.stop(timeout=1.0)
    except Exception:   # noqa: BLE001 - best effort at an interrupted exit
        pass
