"""What is not work stays out of a node's units and the makespan (issue 28, item 2): a node
warms up with a launch of a task's size, the in-process node hands its pixels over unconverted,
and a backend's checks after the last result run after the clock stops."""
from __future__ import annotations

import os
import time

import numpy as np
import pytest

from links1.partition import runtime
from links1.partition.executors import InProcess, render_plan
from links1.partition.runtime import RendererSpec, get_renderer, render_units, warm_samples, warm_up
from links1.partition.strategies import make_plan

from .conftest import MANY, ROOT
from .fake_renderer import FakeRenderer

FIG4 = os.path.join(ROOT, "scenes", "fig4.xml")


class BatchLog(FakeRenderer):
    """The fake renderer with ``render_batch``, logging the windows of every batch it renders."""

    spp = 2

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.batches = []

    def render_batch(self, windows):
        self.batches.append(list(windows))
        return [self.render(window=w) for w in windows]


def test_warm_up_renders_a_batch_of_scanlines_holding_the_samples_asked_for():
    r = BatchLog(width=48, height=32)
    warm_up(r)                              # the tiny windows only
    assert len(r.batches) == 3 and all(w[2] * w[3] <= 16 for b in r.batches for w in b)
    r.batches.clear()
    r.batches.clear()
    warm_up(r, samples=48 * 2 * 10 + 5)     # 10 scanlines of 48 pixels x 2 spp (the rest rounds down)
    rows = [len(b) for b in r.batches[3:]]  # then halved down to one: each size class touched once
    assert r.batches[3] == [(0, y, 48, 1) for y in range(10)] and rows == [10, 5, 2, 1]
    r.batches.clear()
    warm_up(r, samples=10 ** 9)             # never more than the film
    assert r.batches[3] == [(0, y, 48, 1) for y in range(32)]
    assert [len(b) for b in r.batches[3:]] == [32, 16, 8, 4, 2, 1]


def test_warm_samples_none_for_the_core():
    core = RendererSpec.make("core", MANY, params={"res": "24"})
    assert warm_samples(core, get_renderer(core)) == 0   # numpy allocates per launch: nothing to warm


@pytest.mark.mitsuba
def test_warm_samples_the_plugins_film_capped():
    from tests.plugins.conftest import variant_problem
    why = variant_problem("llvm_ad_rgb")
    if why:
        pytest.skip(f"llvm_ad_rgb unavailable: {why}")
    spec = RendererSpec.make("mitsuba", FIG4, params={"res": 24}, spp=3)
    assert warm_samples(spec, get_renderer(spec)) == 24 * 24 * 3
    big = RendererSpec.make("mitsuba", FIG4, params={"res": 24}, spp=4096)
    assert warm_samples(big, get_renderer(big)) == runtime.WARM_SAMPLES
    # after the in-process start, a task of every scanline replays: nothing left to record
    InProcess().start(spec)
    r = get_renderer(spec)
    n = r.integrator._freeze.n_recordings
    r.render_batch([(0, y, 24, 1) for y in range(24)])
    assert r.integrator._freeze.n_recordings == n


def test_in_process_pixels_are_the_renderers_values_unconverted(core_spec):
    windows = [(0, 0, 32, 5), (3, 7, 9, 11)]
    wired = render_units(core_spec, windows)
    direct = render_units(core_spec, windows, wire=False)
    for (a, _), (b, _) in zip(wired, direct):
        assert b.dtype == np.float64 and np.array_equal(a, b)


class CheckedAfter(InProcess):
    """InProcess with a slow check after its last result, reporting one fault."""

    def after_run(self, on_fault):
        time.sleep(0.5)
        on_fault("checked after the run")


def test_checks_after_the_last_result_are_outside_the_makespan(core_spec, core_ref):
    plan = make_plan("subscreen", 32, 32, 1, tiles_per_node=4, unit="tile")
    t = time.perf_counter()
    res = render_plan(plan, core_spec, CheckedAfter(), progress=False, log=lambda m: None)
    assert time.perf_counter() - t >= 0.5          # it ran
    assert res.faults == ["checked after the run"]
    assert res.makespan_s < 0.5                     # but not on the clock
    assert np.array_equal(res.image, core_ref)
