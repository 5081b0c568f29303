"""What is not work stays out of a node's units and the makespan: a node
warms up with a launch of a task's size, the in-process node hands its pixels over unconverted,
and a backend's checks after the last result run after the clock stops."""
from __future__ import annotations

import os
import time

import numpy as np
import pytest

from links1_app.partition import runtime
from links1_app.partition.executors import InProcess, render_plan
from links1_app.partition.runtime import RendererSpec, get_renderer, render_units, warm_samples, warm_up
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
    n = r.integrator.info()["recordings"]
    r.render_batch([(0, y, 24, 1) for y in range(24)])
    assert r.integrator.info()["recordings"] == n


def test_in_process_pixels_are_the_renderers_values_unconverted(core_spec):
    windows = [(0, 0, 32, 5), (3, 7, 9, 11)]
    wired = render_units(core_spec, windows)
    direct = render_units(core_spec, windows, wire=False)
    for (a, _), (b, _) in zip(wired, direct):
        assert b.dtype == np.float64 and np.array_equal(a, b)


class CheckedAfter(InProcess):
    """InProcess with a slow check after its last result, reporting one fault; it notes when
    each of its hooks ran (the root's clock starts after ``before_run``, runs through ``run``)."""

    def before_run(self, plan):
        self.times = {"before_run": time.perf_counter()}

    def run(self, *args):
        self.times["run_start"] = time.perf_counter()
        super().run(*args)
        self.times["run_end"] = time.perf_counter()

    def after_run(self, on_fault):
        self.times["check_start"] = time.perf_counter()
        time.sleep(0.5)
        on_fault("checked after the run")
        self.times["check_end"] = time.perf_counter()


def test_checks_after_the_last_result_are_outside_the_makespan(core_spec, core_ref):
    """Relations between the clock and the hooks' own times, whatever the machine's load: the
    clock starts between ``before_run`` and ``run`` and stops between the run's end and the
    check's start. Were the check on the clock, the makespan would outlast the check's 0.5 s
    from the run's start, past the bound below by the sleep less the instant before ``run``."""
    plan = make_plan("subscreen", 32, 32, 1, tiles_per_node=4, unit="tile")
    backend = CheckedAfter()
    res = render_plan(plan, core_spec, backend, progress=False, log=lambda m: None)
    t = backend.times
    assert res.faults == ["checked after the run"]                       # it ran
    assert t["before_run"] <= t["run_start"] <= t["run_end"] <= t["check_start"] < t["check_end"]
    assert res.makespan_s >= t["run_end"] - t["run_start"]              # the run is on the clock
    assert res.makespan_s <= t["check_start"] - t["before_run"]         # the check is not
    assert np.array_equal(res.image, core_ref)
