"""Faults, checkpoints and atomic files: killed real processes, identical images, no lost work."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from links1_app.partition.checkpoint import Checkpoint, atomic_write_json
from links1_app.partition.executors import InProcess, render_plan
from links1_app.partition.local_pool import LocalPool
from links1_app.partition.runtime import RendererSpec
from links1.partition.strategies import make_plan

from .conftest import ROOT
from .fake_renderer import FAKE, pixel_values

REF = pixel_values(0, 0, 48, 32, 4)


@pytest.mark.slow
@pytest.mark.parametrize("strategy", ["scanline", "dynamic"])
def test_local_worker_sigkilled_mid_render(strategy, tmp_path, capsys):
    # the first process to render line 20 SIGKILLs itself; earlier lines are already done
    spec = RendererSpec.make(FAKE, "fake", kill_window=(0, 20, 48, 1), marker=str(tmp_path / "killed"),
                             sleep_per_row=0.005)
    plan = make_plan(strategy, 48, 32, 2, unit="scanline")
    with LocalPool(2) as pool:
        res = render_plan(plan, spec, pool, progress=False)
    assert (tmp_path / "killed").exists()
    assert np.array_equal(res.image, REF)
    assert len(res.faults) == 1
    assert "died" in capsys.readouterr().err


class _KillAfter:
    """A checkpoint stand-in whose save() SIGKILLs node 1's worker after a few units."""

    def __init__(self, pool, after):
        self.pool, self.after, self.saved = pool, after, 0

    def load(self, unit):
        return None

    def save(self, unit, pixels):
        self.saved += 1
        if self.saved == self.after:
            os.kill(self.pool.pids[1], signal.SIGKILL)


@pytest.mark.slow
def test_core_worker_sigkilled_from_outside(core_spec, core_ref, capsys):
    plan = make_plan("subscreen", 32, 32, 2, tiles_per_node=8)
    with LocalPool(2) as pool:
        res = render_plan(plan, core_spec, pool, progress=False, checkpoint=_KillAfter(pool, 3))
    assert np.array_equal(res.image, core_ref)
    assert res.faults and "node 1" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.dask
@pytest.mark.parametrize("strategy", ["scanline", "dynamic"])
def test_dask_worker_killed_while_holding_a_unit(strategy, tmp_path, capsys):
    pytest.importorskip("distributed")
    from distributed import Event

    from links1_app.partition.dask_backend import DaskBackend
    marker = tmp_path / "holding"
    event = f"links1-test-{strategy}-{os.getpid()}"
    spec = RendererSpec.make(FAKE, "fake", hold_window=(0, 20, 48, 1), marker=str(marker), event=event)
    plan = make_plan(strategy, 48, 32, 2, unit="scanline")

    with DaskBackend(n_local=2, static=plan.static) as be:
        be.start(spec)

        def killer():
            deadline = time.time() + 60
            while not marker.exists() and time.time() < deadline:
                time.sleep(0.02)
            time.sleep(0.1)
            os.kill(int(marker.read_text()), signal.SIGKILL)  # the worker holding line 20
            time.sleep(0.3)
            Event(event, client=be.client).set()

        t = threading.Thread(target=killer, daemon=True)
        t.start()
        res = render_plan(plan, spec, be, progress=False)
        t.join(10)
    assert np.array_equal(res.image, REF)
    assert res.faults and "left the cluster" in capsys.readouterr().err


ROOT_SCRIPT = """
import sys
sys.path.insert(0, {root!r})
from links1_app.partition.checkpoint import Checkpoint
from links1_app.partition.executors import InProcess, render_plan
from links1_app.partition.runtime import RendererSpec
from links1.partition.strategies import make_plan
spec = RendererSpec.make({fake!r}, "fake", kill_window={kill!r}, marker={marker!r}, count_file={count!r})
plan = make_plan("scanline", 48, 32, 1)
ck = Checkpoint({ck!r}, RendererSpec.make({fake!r}, "fake").key)
render_plan(plan, spec, InProcess(), checkpoint=ck, progress=False)
"""


def test_checkpoint_resume_after_the_root_is_killed(tmp_path):
    ck, count = str(tmp_path / "ck"), str(tmp_path / "count")
    # in-process: line 10 (from the bottom: y0 = 21) kills the root itself
    script = ROOT_SCRIPT.format(root=ROOT, fake=FAKE, kill=(0, 21, 48, 1), marker=str(tmp_path / "m"),
                                count=count, ck=ck)
    p = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert p.returncode == -signal.SIGKILL, p.stderr
    saved = len([f for f in os.listdir(os.path.join(ck, os.listdir(ck)[0])) if f.endswith(".npy")])
    assert saved == 10
    assert not [f for f in os.listdir(os.path.join(ck, os.listdir(ck)[0])) if f.startswith(".")]   # no temporary file left
    os.unlink(count)
    # the re-run renders only the 22 missing lines and assembles the full frame
    spec = RendererSpec.make(FAKE, "fake", count_file=count)
    res = render_plan(make_plan("scanline", 48, 32, 1), spec, InProcess(), progress=False,
                      checkpoint=Checkpoint(ck, RendererSpec.make(FAKE, "fake").key))
    assert res.resumed == 10 and res.rendered == 22
    assert len(open(count).read().splitlines()) == 22
    assert np.array_equal(res.image, REF)


def test_atomic_output_survives_a_failed_write(tmp_path):
    out = tmp_path / "report.json"
    atomic_write_json(out, {"ok": 1})
    with pytest.raises(TypeError):
        atomic_write_json(out, {"bad": object()})
    assert out.read_text().strip().replace(" ", "").replace("\n", "") == '{"ok":1}'
    assert os.listdir(tmp_path) == ["report.json"]  # no temporary file left behind


def test_checkpoint_ignores_other_configurations(tmp_path):
    plan = make_plan("grid", 48, 32, 2, tiles_per_node=2)
    spec = RendererSpec.make(FAKE, "fake")
    render_plan(plan, spec, InProcess(), progress=False, checkpoint=Checkpoint(tmp_path, spec.key))
    other = RendererSpec.make(FAKE, "fake", nc=3)
    assert other.key != spec.key
    res = render_plan(plan, other, InProcess(), progress=False, checkpoint=Checkpoint(tmp_path, other.key))
    assert res.resumed == 0 and res.image.shape[2] == 3


@pytest.mark.slow
@pytest.mark.dask
def test_dask_worker_joining_mid_render_gets_units(tmp_path):
    """A worker that joins mid-render gets units. Deterministic: the first worker
    holds its first chunk on a ``distributed.Event`` while the second one starts; the event is
    set when a unit finishes during the hold, which only the joiner can have rendered. If the
    joiner never gets work, the hold times out (60 s) and the pid check fails."""
    pytest.importorskip("distributed")
    from distributed import Event

    from links1_app.partition.dask_backend import DaskBackend
    plan = make_plan("dynamic", 48, 32, 1, unit="scanline", order="walk")
    marker, event = tmp_path / "holding", f"links1-join-{os.getpid()}"
    spec = RendererSpec.make(FAKE, "fake", hold_window=plan.units[plan.order[0]].window, marker=str(marker),
                             event=event)
    released = []

    with DaskBackend(n_local=1) as be:
        class _ReleaseOnFirstSave:
            def load(self, unit):
                return None

            def save(self, unit, pixels):
                if not released:
                    assert marker.exists()  # nothing finishes before the first worker holds
                    released.append(unit)
                    Event(event, client=be.client).set()

        def grow():  # the second worker joins once the first one holds its chunk
            deadline = time.time() + 60
            while not marker.exists() and time.time() < deadline:
                time.sleep(0.02)
            be.cluster.scale(2)

        t = threading.Thread(target=grow, daemon=True)
        t.start()
        res = render_plan(plan, spec, be, progress=False, checkpoint=_ReleaseOnFirstSave())
        t.join(10)
    assert np.array_equal(res.image, REF)
    holder = int(marker.read_text())
    pids = {r["pid"] for r in res.records.values()}
    assert len(pids) == 2 and holder in pids
    assert res.records[released[0].index]["pid"] != holder  # the unit that ended the hold: the joiner's


@pytest.mark.slow
@pytest.mark.parametrize("delay", [0.0, 0.05, 0.15])
def test_local_worker_killed_while_sending_its_result(tmp_path, delay):
    """A worker SIGKILLed around the moment its result is on its way to the root: CPython's
    pool can then wait forever on a half-read message; the render must go on (the unit is
    redone elsewhere), finish with the right image and close without hanging. The delays put
    the kill before, during and after the transfer. (512² keeps the process's memory small: a
    2048² version, 128 MB per image, left glibc's heap growing and shrinking and made every
    later numpy-heavy test in the session several times slower.)"""
    W, H = 512, 512
    spec = RendererSpec.make(FAKE, "fake", width=W, height=H, nc=4, kill_in_send=((0, 0, 256, 256), delay),
                             marker=str(tmp_path / "killed"))
    plan = make_plan("grid", W, H, 2, tiles_per_node=2)
    assert (0, 0, 256, 256) in [u.window for u in plan.units]
    t = time.perf_counter()
    with LocalPool(2) as pool:
        res = render_plan(plan, spec, pool, progress=False)
    assert (tmp_path / "killed").exists()
    assert np.array_equal(res.image, pixel_values(0, 0, W, H, 4))
    assert time.perf_counter() - t < 120


@pytest.mark.slow
def test_local_workers_end_when_their_root_is_killed(tmp_path):
    """A root killed by a signal (or crashed) closes no pool: its local workers notice that
    their parent is gone (``runtime.watch_root``) and end within a second or two, instead of
    waiting for tasks forever."""
    script = tmp_path / "root.py"
    script.write_text(f"""
import os, signal, sys
sys.path.insert(0, {str(ROOT)!r})
from links1_app.partition.executors import render_plan
from links1_app.partition.local_pool import LocalPool
from links1_app.partition.runtime import RendererSpec
from links1.partition.strategies import make_plan
from tests.dist.fake_renderer import FAKE
if __name__ == "__main__":
    pool = LocalPool(2)
    plan = make_plan("scanline", 16, 8, 2, unit="scanline")
    render_plan(plan, RendererSpec.make(FAKE, "fake"), pool, progress=False)
    print(" ".join(str(p) for p in pool.pids.values()), flush=True)
    os.kill(os.getpid(), signal.SIGKILL)
""")
    # (the workers inherit its stdout: run() returns once they are gone too)
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=60)
    assert out.returncode == -signal.SIGKILL, out.stderr[-2000:]
    pids = [int(p) for p in out.stdout.split()]
    assert len(pids) == 2

    def alive(pid):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        return True
    deadline = time.monotonic() + 10
    while any(alive(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = [p for p in pids if alive(p)]
    for p in left:                     # not to leave them behind when the test fails
        os.kill(p, signal.SIGKILL)
    assert not left, f"workers {left} outlived their root"
