"""A local node's direct line: during a run the root sends each task to a node through
one pipe, written by its own thread, and reads the node's answer from it (``runtime.serve``), not
through the process pool's helper threads; with the shared frame only the units' records come
back that way, and the frame the nodes write into is the root's image (nothing copied)."""
from __future__ import annotations

import numpy as np
import pytest

from links1.errors import UsageError
from links1_app.partition.executors import render_plan
from links1_app.partition.local_pool import LocalPool
from links1.partition.strategies import make_plan


class _Captured(LocalPool):
    """LocalPool remembering the image buffer it offered for the run."""

    def before_run(self, plan):
        super().before_run(plan)
        self.offered = self.image_buffer


@pytest.mark.slow
@pytest.mark.parametrize("strategy", ["subscreen", "dynamic"])
def test_results_land_in_the_frame_and_only_records_cross_the_lines(strategy, core_spec, core_ref):
    plan = make_plan(strategy, 32, 32, 2, tiles_per_node=4, unit="tile")
    with _Captured(2) as pool:
        res = render_plan(plan, core_spec, pool, progress=False)
        dispatches = sum(1 for kind, *_ in res.root_events if kind == "dispatch")
        # every task went through a line, one per dispatch, and every line closed after the clock
        assert pool.line_tasks == dispatches > 0 and not pool.lines
        framed_bytes = pool.line_bytes
        # the image the root returns is the frame the nodes wrote into: not a copy of it
        assert pool.offered is not None and res.image is pool.offered
    with LocalPool(2, shared_frame=False) as pool:
        piped = render_plan(plan, core_spec, pool, progress=False)
        piped_bytes = pool.line_bytes
    assert np.array_equal(res.image, core_ref) and np.array_equal(piped.image, core_ref)
    pixel_bytes = core_ref.shape[0] * core_ref.shape[1] * core_ref.shape[2] * 4   # float32 at least
    # without the frame every pixel crosses a line; with it only records do (~0.3 kB per unit)
    assert piped_bytes >= pixel_bytes
    assert framed_bytes < 600 * len(plan.units) < pixel_bytes
    assert piped_bytes - framed_bytes >= pixel_bytes


@pytest.mark.slow
def test_lines_close_for_pool_tasks_between_runs(core_spec, core_ref):
    """A run's serve loops end after its clock: the workers then take pool tasks (a call), and a
    second run opens new lines."""
    import os
    plan = make_plan("scanline", 32, 32, 2)
    with LocalPool(2) as pool:
        first = render_plan(plan, core_spec, pool, progress=False)
        assert not pool.lines
        assert pool.call(os.getpid) in set(pool.pids.values())
        tasks = pool.line_tasks
        second = render_plan(plan, core_spec, pool, progress=False)
        assert pool.line_tasks > tasks and not pool.lines
    assert np.array_equal(first.image, core_ref) and np.array_equal(second.image, core_ref)


@pytest.mark.slow
def test_a_node_error_reaches_the_root_through_its_line(core_spec):
    """A unit the renderer refuses (a window outside the film) raises that error in the root, as a
    pool task's error did, and the pool stays usable."""
    plan = make_plan("scanline", 32, 32, 2)
    bad = make_plan("scanline", 64, 64, 2)   # windows of a 64² film on a 32² scene
    with LocalPool(2) as pool:
        with pytest.raises(UsageError, match="outside the 32x32 film"):
            render_plan(bad, core_spec, pool, progress=False)
        assert not pool.lines
        assert pool.deaths == 0
        res = render_plan(plan, core_spec, pool, progress=False)
    assert res.image.shape[:2] == (32, 32)


@pytest.mark.slow
def test_a_node_holds_one_guided_chunk_at_a_time(core_spec, core_ref):
    """Dynamic with a batching renderer: a node's next guided chunk leaves the root only once its
    last chunk's results are in (the root sends it after that chunk's launch ended), so a chunk
    handed out early never waits behind another on a node that turned out slow."""
    plan = make_plan("dynamic", 32, 32, 2, unit="scanline")
    with LocalPool(2, chunk_factor=2) as pool:
        res = render_plan(plan, core_spec, pool, progress=False)
    assert np.array_equal(res.image, core_ref)
    tasks = {}
    for info in res.records.values():
        t = tasks.setdefault(info["task"], {"node": info["node"], "sent": info["sent"], "stop": info["stop"],
                                            "units": 0})
        t["stop"] = max(t["stop"], info["stop"])
        t["units"] += 1
        assert info["sent"] <= info["task_in"] <= info["start"]
    assert max(t["units"] for t in tasks.values()) > 1   # guided chunks, not single units
    gaps = []
    for k in (0, 1):
        mine = sorted((t for t in tasks.values() if t["node"] == k), key=lambda t: t["sent"])
        gaps += [b["sent"] - a["stop"] for a, b in zip(mine, mine[1:])]
    assert len(gaps) >= 3 and min(gaps) > 0
