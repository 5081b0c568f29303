"""A real Dask cluster that links1 did not start: ``dask scheduler`` and two
``dask worker`` processes started with Dask's own command line on 127.0.0.1 (free ports),
``links1 render --scheduler`` with both renderers and every strategy, one worker SIGKILLed
mid-render. Every process the test starts is stopped (bounded waits), whatever happens."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from links1_app.partition.runtime import RendererSpec
from links1.partition.strategies import STRATEGIES, make_plan

from .conftest import MANY, ROOT
from .fake_renderer import FAKE, pixel_values

pytestmark = [pytest.mark.dask, pytest.mark.slow]
DASK = os.path.join(os.path.dirname(sys.executable), "dask")


def _wait_for_file(path, timeout):
    deadline = time.time() + timeout
    while not path.exists():
        if time.time() > deadline:
            raise TimeoutError(f"{path} did not appear in {timeout} s")
        time.sleep(0.02)


def _scheduler_address(path, timeout):
    """The address a scheduler wrote to ``path``, once the file is there whole."""
    deadline = time.time() + timeout
    while True:
        try:
            return json.loads(path.read_text())["address"]
        except (OSError, ValueError, KeyError):
            if time.time() > deadline:
                raise TimeoutError(f"no scheduler address in {path} after {timeout} s") from None
            time.sleep(0.02)


def _stop(procs):
    """Stop the workers first, then the scheduler (a worker whose scheduler is gone waits for it
    before exiting on SIGTERM: stopping the scheduler first cost 15 s per test); SIGKILL after 5 s."""
    for p in reversed(procs):
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
        try:
            p.wait(timeout=5)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout=10)


@pytest.fixture
def cli_cluster(tmp_path):
    """(scheduler address, [worker Popen]) of a cluster started with `dask scheduler` / `dask worker`."""
    pytest.importorskip("distributed")
    if not os.path.exists(DASK):
        pytest.skip("the dask command line is not installed")
    from distributed import Client
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([ROOT, os.environ.get("PYTHONPATH", "")]))
    log = open(tmp_path / "dask.log", "w")
    procs = []
    try:
        # port 0: the scheduler binds a free port itself and writes its address to the file (a port
        # picked here and bound later could be taken meanwhile, by the other test process)
        sched = tmp_path / "scheduler.json"
        procs.append(subprocess.Popen([DASK, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                                       "--scheduler-file", str(sched), "--idle-timeout", "600"],
                                      stdout=log, stderr=log, env=env))
        addr = _scheduler_address(sched, 60)
        workers = [subprocess.Popen([DASK, "worker", addr, "--host", "127.0.0.1", "--nthreads", "1", "--no-nanny",
                                     "--no-dashboard", "--death-timeout", "60", "--name", f"w{k}"],
                                    stdout=log, stderr=log, env=env) for k in range(2)]
        procs += workers
        with Client(addr, timeout=60) as c:
            c.wait_for_workers(2, timeout=60)
        yield addr, workers
    finally:
        _stop(procs)
        log.close()


DRIVER = """
import json, sys
from links1_app.cli import main
codes = [main(a) for a in json.loads(sys.argv[1])]
print(json.dumps(codes))
"""


def test_cli_renders_on_a_cluster_it_did_not_start(cli_cluster, tmp_path):
    addr, _ = cli_cluster
    from links1.imaging.image import read_image
    from links1_app.renderers import make_renderer
    runs, expect = [], []
    for kind in ("core", "mitsuba"):
        if kind == "mitsuba":
            from tests.plugins.conftest import variant_problem
            if variant_problem("llvm_ad_rgb"):
                continue
        ref = np.asarray(make_renderer(kind, MANY, params={"res": "32"}).render(), dtype=np.float32)
        for strategy in STRATEGIES:
            out = tmp_path / f"{kind}-{strategy}.exr"
            runs.append(["render", MANY, "--renderer", kind, "-D", "res=32", "--scheduler", addr, "--partition",
                         strategy, "--tiles-per-node", "4", "--no-progress", "-o", str(out)])
            expect.append((out, ref))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([ROOT, os.environ.get("PYTHONPATH", "")]))
    p = subprocess.run([sys.executable, "-c", DRIVER, json.dumps(runs)], capture_output=True, text=True,
                       timeout=240, env=env)
    assert p.returncode == 0 and json.loads(p.stdout.strip().splitlines()[-1]) == [0] * len(runs), p.stderr[-2000:]
    for out, ref in expect:
        img = read_image(str(out))
        assert np.array_equal(np.asarray(img, dtype=np.float32)[..., :3], ref[..., :3]), out.name


def test_a_worker_killed_mid_render_on_that_cluster(cli_cluster, tmp_path, capsys):
    from distributed import Event

    from links1_app.partition.dask_backend import DaskBackend
    from links1_app.partition.executors import render_plan
    addr, workers = cli_cluster
    marker = tmp_path / "holding"
    event = f"links1-cli-cluster-{os.getpid()}"
    spec = RendererSpec.make(FAKE, "fake", hold_window=(0, 20, 48, 1), marker=str(marker), event=event)
    plan = make_plan("dynamic", 48, 32, 2, unit="scanline")
    with DaskBackend(scheduler=addr) as be:
        be.start(spec)

        def killer():  # SIGKILL the worker process that holds line 20, then release the held unit
            _wait_for_file(marker, 60)
            holder = int(marker.read_text())
            os.kill(holder, signal.SIGKILL)
            next(w for w in workers if w.pid == holder).wait(timeout=30)
            Event(event, client=be.client).set()

        t = threading.Thread(target=killer, daemon=True)
        t.start()
        res = render_plan(plan, spec, be, progress=False)
        t.join(10)
    assert int(marker.read_text()) in [w.pid for w in workers]
    assert sum(w.poll() is not None for w in workers) == 1  # that worker is gone, the other rendered the rest
    assert np.array_equal(res.image, pixel_values(0, 0, 48, 32, 4))
    assert res.faults and "left the cluster" in capsys.readouterr().err


def test_animate_on_that_cluster(cli_cluster, tmp_path):
    """``links1 animate --scheduler``: a sequence on a cluster links1 did not start, in whole frames,
    in split frames (planned from eq. 4.1 then from the previous frame) and in both: every frame
    written equals the single-process render of that frame, loaded with its values, bit for bit."""
    from links1.imaging.image import read_image
    from links1_app.expressions import frame_values
    from links1_app.renderers import make_renderer
    addr, _ = cli_cluster
    orbit = ("eye", "14*sin(radians(30*f)), 9, 14*cos(radians(30*f))")
    frames = [0, 1, 2]
    refs = [make_renderer("core", MANY, params=v, width=32, height=32, spp=1, aovs=("cost",)).render()
            for v in frame_values([orbit], frames, 24.0)]
    runs = [["animate", MANY, "--renderer", "core", "-D", "=".join(orbit), "--frames", "3", "--width", "32",
             "--height", "32", "--spp", "1", "--aov", "cost", "--units", units, "--scheduler", addr,
             "--tiles-per-node", "4", "--no-progress", "-o", str(tmp_path / units / "f_%02d.exr")]
            for units in ("frames", "partition", "both")]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([ROOT, os.environ.get("PYTHONPATH", "")]))
    p = subprocess.run([sys.executable, "-c", DRIVER, json.dumps(runs)], capture_output=True, text=True,
                       timeout=240, env=env)
    assert p.returncode == 0 and json.loads(p.stdout.strip().splitlines()[-1]) == [0] * len(runs), p.stderr[-2000:]
    assert p.stderr.count("2 node(s)") == len(runs), p.stderr[-2000:]      # both workers of that cluster
    for units in ("frames", "partition", "both"):
        for f in frames:
            img = read_image(str(tmp_path / units / f"f_{f:02d}.exr"))
            assert np.array_equal(img, refs[f].astype(np.float32)), (units, f)
