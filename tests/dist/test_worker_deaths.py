"""Local workers SIGKILLed while starting, idle or mid-unit: replaced, units redone, same bits.

Real processes, real SIGKILLs, both renderers. Every wait is bounded
(pytest-timeout and the pool's own death limit).
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from links1.errors import RenderAborted
from links1_app.partition.executors import render_plan
from links1_app.partition.local_pool import LocalPool
from links1_app.partition.runtime import RendererSpec
from links1.partition.strategies import make_plan

from .conftest import MANY, ROOT
from .dying_renderer import DYING
from .fake_renderer import FAKE, pixel_values

RES = 32
OPTS = {"core": dict(params={"res": str(RES)}, aovs=("id",)),
        # (the variant named: a test run before this one in the same process may leave another active)
        "mitsuba": dict(params={"res": str(RES)}, aovs=("id",), variant="llvm_ad_rgb")}


def _renderer_or_skip(kind):
    if kind == "mitsuba":
        from tests.plugins.conftest import variant_problem
        why = variant_problem("llvm_ad_rgb")
        if why:
            pytest.skip(f"llvm_ad_rgb unavailable: {why}")


_REFS = {}


def _reference(kind):
    """The single-process full frame of ``kind`` (rendered in this process)."""
    if kind not in _REFS:
        from links1_app.renderers import make_renderer
        _REFS[kind] = np.asarray(make_renderer(kind, MANY, **OPTS[kind]).render(), dtype=np.float64)
    return _REFS[kind]


def _wait_gone(pid, timeout=30.0):
    deadline = time.time() + timeout
    while time.time() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.02)
    raise AssertionError(f"pid {pid} still alive after {timeout} s")


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["core", pytest.param("mitsuba", marks=pytest.mark.mitsuba)])
@pytest.mark.parametrize("moment, strategy", [("start", "subscreen"), ("idle", "dynamic"), ("unit", "subscreen"),
                                              ("unit", "dynamic")])
def test_a_worker_killed_at_any_moment_is_replaced_and_the_image_is_identical(kind, moment, strategy, tmp_path,
                                                                             capsys):
    _renderer_or_skip(kind)
    ref = _reference(kind)
    plan = make_plan(strategy, RES, RES, 2, tiles_per_node=8, unit="tile")
    marker = str(tmp_path / "died")
    victim = plan.units[plan.node_units(1)[2]] if plan.static else plan.units[plan.order[5]]
    spec = RendererSpec.make(DYING, MANY, inner=kind, die=moment if moment != "idle" else "never",
                             marker=marker, die_window=victim.window, **OPTS[kind])
    with LocalPool(2) as pool:
        pool.start(spec)
        first = dict(pool.pids)
        if moment == "idle":  # a ready worker with nothing to do is killed from outside
            os.kill(first[1], signal.SIGKILL)
            _wait_gone(first[1])
        res = render_plan(plan, spec, pool, progress=False)
        assert pool.deaths == 1
        assert len(pool.pools) == 2  # N workers stay N: the dead one was replaced
        dead = first[1] if moment == "idle" else int(open(marker).read())
        assert dead not in pool.pids.values()
    err = capsys.readouterr().err
    assert f"died {'while starting' if moment == 'start' else 'while idle' if moment == 'idle' else 'mid-unit'}" \
        in err or (moment == "idle" and "died mid-unit" in err), err
    assert np.array_equal(res.image, ref)


@pytest.mark.slow
def test_a_worker_killed_while_starting_is_replaced_before_the_render(tmp_path, capsys):
    spec = RendererSpec.make(DYING, "fake", inner=FAKE, die="start", marker=str(tmp_path / "m"))
    plan = make_plan("scanline", 48, 32, 2)
    with LocalPool(2) as pool:
        res = render_plan(plan, spec, pool, progress=False)
        assert pool.deaths == 1 and len(pool.pids) == 2
        assert int(open(tmp_path / "m").read()) not in pool.pids.values()
    assert np.array_equal(res.image, pixel_values(0, 0, 48, 32, 4))
    assert "died while starting" in capsys.readouterr().err


@pytest.mark.slow
def test_workers_that_always_die_give_up_after_the_documented_limit(tmp_path):
    from links1_app.partition.local_pool import DEATHS_PER_WORKER
    spec = RendererSpec.make(DYING, "fake", inner=FAKE, die="start", always=True, marker=str(tmp_path / "m"))
    pool = LocalPool(2, log=lambda msg: None)
    with pytest.raises(RenderAborted, match=r"7 worker processes died \(the limit is 6 for 2 workers"):
        render_plan(make_plan("dynamic", 48, 32, 2), spec, pool, progress=False)
    assert DEATHS_PER_WORKER * 2 == 6 and not pool.pools  # every process stopped


@pytest.mark.slow
def test_a_unit_that_kills_every_worker_gives_up(tmp_path):
    spec = RendererSpec.make(DYING, "fake", inner=FAKE, die="unit", always=True, die_window=(0, 20, 48, 1),
                             marker=str(tmp_path / "m"))
    pool = LocalPool(2, log=lambda msg: None)
    with pytest.raises(RenderAborted, match=r"unit \(0, 20, 48, 1\) was lost with 3 workers"):
        render_plan(make_plan("scanline", 48, 32, 2), spec, pool, progress=False)
    assert not pool.pools


SITE = """
import os, signal, sys
if "--multiprocessing-fork" in sys.argv:  # every spawned worker dies at once
    os.kill(os.getpid(), signal.SIGKILL)
"""


@pytest.mark.slow
def test_cli_gives_up_in_one_line_with_exit_1_and_writes_nothing(tmp_path):
    (tmp_path / "site").mkdir()
    (tmp_path / "site" / "sitecustomize.py").write_text(SITE)
    out = tmp_path / "out.exr"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path / "site"), ROOT]))
    p = subprocess.run([sys.executable, "-m", "links1_app.cli", "render", MANY, "--width", "32", "--height", "32",
                        "--workers", "2", "--no-progress", "-o", str(out)],
                       capture_output=True, text=True, timeout=120, env=env)
    assert p.returncode == 1, p.stderr
    last = p.stderr.strip().splitlines()[-1]
    assert last.startswith("links1: error: 7 worker processes died (the limit is 6 for 2 workers"), p.stderr
    assert "Traceback" not in p.stderr and "internal error" not in p.stderr
    assert not out.exists() and os.listdir(tmp_path) == ["site"]
