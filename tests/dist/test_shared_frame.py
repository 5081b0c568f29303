"""Results through a shared frame: local nodes write each unit's pixels into a
frame the root maps instead of sending them through the process pipe; the image is the same bits
and the frame's file is gone after the run."""
from __future__ import annotations

import glob
import os

import numpy as np
import pytest

from links1_app.partition import runtime
from links1_app.partition.executors import render_plan
from links1_app.partition.local_pool import LocalPool
from links1.partition.strategies import make_plan


def _frames():
    """This process's frames (the name holds the root's pid: other runs on the machine, e.g. a
    second test session, make and remove their own meanwhile)."""
    pat = f"links1-frame-{os.getpid()}-*"
    return set(glob.glob(os.path.join("/dev/shm", pat))) | set(glob.glob(os.path.join("/tmp", pat)))


@pytest.mark.slow
@pytest.mark.parametrize("strategy", ["subscreen", "dynamic"])
def test_shared_frame_gives_the_same_bits_as_the_pipe(strategy, core_spec, core_ref):
    before = _frames()
    plan = make_plan(strategy, 32, 32, 2, tiles_per_node=4, unit="tile")
    with LocalPool(2, shared_frame=True) as pool:
        res = render_plan(plan, core_spec, pool, progress=False)
        assert pool.channels == core_ref.shape[2]
        piped = LocalPool(2, shared_frame=False)
        try:
            res_pipe = render_plan(plan, core_spec, piped, progress=False)
        finally:
            piped.close()
    assert np.array_equal(res.image, core_ref) and np.array_equal(res_pipe.image, core_ref)
    assert _frames() == before   # the run removed its frame


def test_units_written_to_the_frame_are_not_sent(tmp_path, core_spec, core_ref):
    # in this process: render_units with a frame writes the pixels there and returns None for them
    frame = runtime.SharedFrame(32, 32, core_ref.shape[2], directory=str(tmp_path))
    try:
        wins = [(0, 0, 16, 32), (16, 0, 16, 32)]
        out = runtime.render_units(core_spec, wins, None, frame.ref)
        assert [px for px, _ in out] == [None, None]
        assert np.array_equal(np.asarray(frame.array), core_ref)
        # a window whose pixels do not match the frame's channels goes through the pipe instead
        bad = runtime._to_frame(frame.ref, (0, 0, 2, 2), np.zeros((2, 2, 1)))
        assert bad is not None and bad.shape == (2, 2, 1)
    finally:
        runtime.release_frame()
        frame.close()
    assert not os.path.exists(frame.path)


class _Watched(LocalPool):
    """LocalPool noting whether its shared frame existed when each result arrived."""

    def _run(self, plan, todo, spec, cull, on_done, on_fault, frame):
        self.seen = []

        def done(i, px, info):
            self.seen.append(frame is not None and os.path.exists(frame.path))
            on_done(i, px, info)
        return super()._run(plan, todo, spec, cull, done, on_fault, frame)


@pytest.mark.slow
def test_local_pool_writes_into_the_frame_by_default_and_leaves_none_behind(core_spec, core_ref):
    before = _frames()
    plan = make_plan("scanline", 32, 32, 2)
    with _Watched(2) as pool:
        res = render_plan(plan, core_spec, pool, progress=False)
        assert pool.shared_frame and pool.seen and all(pool.seen)   # every result came by the frame
        assert pool._frame is None and _frames() == before          # removed as the run ended
        res2 = render_plan(plan, core_spec, pool, progress=False)   # a second run makes a new one
    assert np.array_equal(res.image, core_ref) and np.array_equal(res2.image, core_ref)
    assert _frames() == before


@pytest.mark.slow
@pytest.mark.mitsuba
def test_plugin_results_through_the_frame_are_the_pipes_bits():
    """The plugin's float32-exact results written as float64 into the frame: the same bits as
    through the pipe (float32 on the wire, placed in the root's float64 frame). Both in worker
    processes: this test process keeps no plugin renderer (the plugin tests count recordings)."""
    from links1_app.partition.runtime import RendererSpec
    from tests.plugins.conftest import variant_problem

    from .conftest import ROOT
    why = variant_problem("llvm_ad_rgb")
    if why:
        pytest.skip(f"llvm_ad_rgb unavailable: {why}")
    spec = RendererSpec.make("mitsuba", os.path.join(ROOT, "scenes", "fig11.xml"), params={"res": 24}, spp=2,
                             aovs=("depth", "cost"))
    before = _frames()
    plan = make_plan("subscreen", 24, 24, 2, tiles_per_node=4, unit="tile")
    with LocalPool(2, threads=1) as pool:
        framed = render_plan(plan, spec, pool, progress=False)
    with LocalPool(2, threads=1, shared_frame=False) as pool:
        piped = render_plan(plan, spec, pool, progress=False)
    assert framed.image.shape[2] == 5 and np.array_equal(framed.image, piped.image, equal_nan=True)
    assert np.isfinite(framed.image[..., :3]).all() and framed.image[..., :3].any()
    assert _frames() == before


@pytest.mark.slow
def test_no_room_for_the_frame_falls_back_to_the_pipe(monkeypatch, core_spec, core_ref):
    """A full /dev/shm: SharedFrame raises ENOSPC (posix_fallocate) and the run goes by the pipe."""
    import errno

    from links1_app.partition import local_pool

    def full(*a, **kw):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(local_pool, "SharedFrame", full)
    plan = make_plan("subscreen", 32, 32, 2, tiles_per_node=4, unit="tile")
    with _Watched(2) as pool:
        res = render_plan(plan, core_spec, pool, progress=False)
        assert pool.seen and not any(pool.seen)   # no frame: every result by the pipe
    assert np.array_equal(res.image, core_ref)


def test_a_killed_roots_frame_is_removed_by_the_next_frame(tmp_path):
    """A root killed with SIGKILL leaves its frame file; the next frame made in that directory
    removes it, and keeps those of live processes (this one's, another's)."""
    import signal
    import subprocess
    import sys
    code = ("import os, sys; from links1_app.partition import runtime; "
            "f = runtime.SharedFrame(4, 4, 3, directory=sys.argv[1]); print(f.path, flush=True); "
            "os.kill(os.getpid(), 9)")
    proc = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True)
    assert proc.returncode == -signal.SIGKILL
    dead = proc.stdout.strip()
    assert os.path.exists(dead)
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        alive = tmp_path / f"links1-frame-{live.pid}-x.f64"
        alive.write_bytes(b"")
        mine = runtime.SharedFrame(4, 4, 3, directory=str(tmp_path))
        try:
            assert not os.path.exists(dead)
            assert alive.exists() and os.path.exists(mine.path)
        finally:
            mine.close()
    finally:
        live.kill()
        live.wait()
