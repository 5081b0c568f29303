"""Ctrl-C at random moments of a ``links1 render``: shared by the core, pool, Dask and plugin tests.

Each try starts ``links1 render`` in a session of its own, waits until the command line's
``main`` handles Ctrl-C (the process has imported links1 and ``main`` has set its handler;
before that an interrupt is Python's own start-up traceback, which no program can turn into
one line), sleeps a seeded
random delay, and sends SIGINT: to the whole process group, as a terminal's Ctrl-C does, or
to the root alone, as ``kill -INT`` does. The process must then end within ``timeout`` seconds
with status 130 and the one line ``links1: interrupted`` on stderr, leave no output file (nor a
temporary one) and no process of its session behind.
"""
from __future__ import annotations

import os
import random
import select
import signal
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

#: the console script's two lines, with a byte written to fd ``argv[1]`` once ``main`` handles
#: Ctrl-C (its first statements done, ``_main`` about to parse the command line): a SIGINT
#: between the import and those statements is Python's own, as in any console script's
#: start-up, and under load the child could still be there when a short delay had passed
_MAIN = ("import os, sys\nfrom links1_app import cli\nparse = cli._main\n"
         "def ready_then_parse(argv):\n    os.write(int(sys.argv[1]), b'r')\n    os.close(int(sys.argv[1]))\n"
         "    return parse(argv)\n"
         "cli._main = ready_then_parse\nsys.exit(cli.main(sys.argv[2:], program=True))")


def session_processes(sid: int) -> list:
    """Pids of the live (not zombie) processes of session ``sid`` (from /proc)."""
    out = []
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        state, session = fields[0], int(fields[3])
        if session == sid and state != "Z":
            out.append(int(name))
    return out


def processes_left(sid: int, timeout: float = 5.0) -> list:
    """Pids of session ``sid`` still there after up to ``timeout`` seconds (a child the root
    killed may take a moment to end and be reaped, the longer the busier the machine)."""
    deadline = time.monotonic() + timeout
    while session_processes(sid) and time.monotonic() < deadline:
        time.sleep(0.05)
    return session_processes(sid)


def _kill_session(sid: int) -> None:
    for pid in session_processes(sid):
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def interrupt_once(args, out, delay: float, to_group: bool, timeout: float = 30.0, stops=None) -> str | None:
    """One try: ``links1 render ARGS -o OUT`` interrupted ``delay`` s after start-up -> None when
    it stopped as it should, else what went wrong (one line). ``stops``: a list that gets the
    seconds from SIGINT to the root's exit."""
    r, w = os.pipe()
    p = subprocess.Popen([sys.executable, "-c", _MAIN, str(w), "render", *args, "-o", str(out), "--no-progress"],
                         cwd=ROOT, pass_fds=(w,), start_new_session=True,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    os.close(w)
    try:
        ready, _, _ = select.select([r], [], [], timeout)
        started = bool(ready) and os.read(r, 1) == b"r"
    finally:
        os.close(r)
    what = f"delay {delay:.2f} s, SIGINT to {'the group' if to_group else 'the root'}"
    try:
        if not started:
            return f"{what}: never reached main()"
        time.sleep(delay)
        if p.poll() is not None:
            return f"{what}: the render ended (status {p.returncode}) before the interrupt; make it longer"
        (os.killpg if to_group else os.kill)(p.pid, signal.SIGINT)
        t = time.monotonic()
        try:
            _, err = p.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            return f"{what}: still running {timeout:.0f} s after SIGINT (hung)"
        if stops is not None:
            stops.append(time.monotonic() - t)
        lines = err.decode(errors="replace").strip().splitlines()
        if p.returncode != 130 or lines != ["links1: interrupted"]:
            return f"{what}: status {p.returncode}, stderr {lines[-20:]!r}"
        left = processes_left(p.pid)
        if left:
            return f"{what}: processes left behind: {left}"
        written = [n for n in os.listdir(os.path.dirname(str(out)) or ".") if os.path.basename(str(out)) in n]
        if written:
            return f"{what}: files left behind: {written}"
        return None
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
        _kill_session(p.pid)


def interrupt_tries(args, tmp_path, seed: int, tries: int = 20, delays=(0.0, 1.0), timeout: float = 30.0,
                    stops=None, parallel: int = 2) -> list:
    """``tries`` seeded tries of :func:`interrupt_once`, ``parallel`` at a time (each waits most
    of its time) -> the failures (empty: every one stopped as it should)."""
    from concurrent.futures import ThreadPoolExecutor
    rng = random.Random(seed)
    plan = [(k, rng.uniform(*delays), rng.random() < 0.5) for k in range(tries)]
    with ThreadPoolExecutor(parallel) as ex:
        errs = list(ex.map(lambda t: interrupt_once(args, tmp_path / f"out{t[0]}.exr", t[1], t[2], timeout, stops),
                           plan))
    return [f"try {k}: {e}" for (k, _, _), e in zip(plan, errs) if e]
