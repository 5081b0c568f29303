"""Where local nodes run: left to itself the
kernel put both one-thread nodes of a two-node run on one core of this 2-core machine (each
launch as long in the run queue as on the core), so a local pool binds each node's process to
CPUs of its own where they fit; and no thread of a node or of the root burns CPU while it waits."""
from __future__ import annotations

import os
import time

import numpy as np
import pytest

from links1_app.partition.executors import render_plan
from links1_app.partition.local_pool import LocalPool, node_cpus
from links1.partition.strategies import make_plan

linux = pytest.mark.skipif(not (hasattr(os, "sched_getaffinity") and os.path.isdir("/proc/self/task")),
                           reason="needs Linux CPU affinity and /proc")
two_cpus = pytest.mark.skipif(not hasattr(os, "sched_getaffinity") or len(os.sched_getaffinity(0)) < 2,
                              reason="needs 2 CPUs")


def _tids(pid):
    return [int(t) for t in os.listdir(f"/proc/{pid}/task")]


def _cpu_ns(pid):
    """CPU time of every thread of process ``pid`` (ns, /proc/PID/task/*/schedstat)."""
    total = 0
    for tid in _tids(pid):
        try:
            with open(f"/proc/{pid}/task/{tid}/schedstat") as f:
                total += int(f.read().split()[0])
        except OSError:   # a thread that ended meanwhile
            pass
    return total


def test_node_cpus_deals_disjoint_sets_in_order():
    assert node_cpus(2, 1, [0, 1]) == [(0,), (1,)]
    assert node_cpus(2, 2, [5, 0, 1, 2, 3]) == [(0, 1), (2, 3)]   # sorted, the rest unused
    assert node_cpus(1, 1, [3, 7]) == [(3,)]
    assert node_cpus(3, 1, [0, 1]) is None                           # more nodes than CPUs
    assert node_cpus(2, 2, [0, 1, 2]) is None                        # more threads than CPUs
    assert node_cpus(0, 1, [0, 1]) is None


@pytest.mark.slow
@linux
@two_cpus
def test_each_node_is_bound_to_cpus_of_its_own(core_spec, core_ref):
    cpus = os.sched_getaffinity(0)
    plan = make_plan("grid", 32, 32, 2, tiles_per_node=2)
    with LocalPool(2, threads=1) as pool:
        res = render_plan(plan, core_spec, pool, progress=False)
        assert pool.cpus == node_cpus(2, 1, cpus)
        bound = []
        for k in range(2):
            for tid in _tids(pool.pids[k]):   # every thread of the node, Dr.Jit's/BLAS's too
                assert os.sched_getaffinity(tid) == set(pool.cpus[k])
            bound.append(set(pool.cpus[k]))
        assert len(bound[0]) == 1 and not bound[0] & bound[1]
    assert os.sched_getaffinity(0) == cpus          # the root is not bound
    assert np.array_equal(res.image, core_ref)
    with LocalPool(2, threads=1, pin=False) as pool:
        render_plan(plan, core_spec, pool, progress=False)
        assert pool.cpus is None
        assert all(os.sched_getaffinity(pool.pids[k]) == cpus for k in range(2))


@pytest.mark.slow
@linux
@two_cpus
def test_more_nodes_than_cpus_are_left_to_the_kernel(core_spec, core_ref):
    cpus = os.sched_getaffinity(0)
    n = len(cpus) + 1
    plan = make_plan("grid", 32, 32, n, tiles_per_node=1)
    with LocalPool(n, threads=1) as pool:
        res = render_plan(plan, core_spec, pool, progress=False)
        assert pool.cpus is None
        assert all(os.sched_getaffinity(pool.pids[k]) == cpus for k in range(n))
    assert np.array_equal(res.image, core_ref)


@pytest.mark.slow
@linux
@two_cpus
@pytest.mark.mitsuba
def test_plugin_nodes_and_root_use_no_cpu_while_they_wait():
    """Plugin nodes with one Dr.Jit thread: every thread of a node bound to its CPU (Dr.Jit's
    pool threads inherit it), no thread of a node spins between tasks (nanothread's workers
    sleep), and the root sleeps while its nodes render (it does not poll the lines)."""
    from links1_app.partition.runtime import RendererSpec
    from tests.plugins.conftest import variant_problem

    from .conftest import ROOT
    why = variant_problem("llvm_ad_rgb")
    if why:
        pytest.skip(f"llvm_ad_rgb unavailable: {why}")
    spec = RendererSpec.make("mitsuba", os.path.join(ROOT, "scenes", "fig11.xml"), params={"res": 96}, spp=16)

    class Watched(LocalPool):
        root_cpu = wall = None

        def _run(self, *args):   # the root's CPU time, all its threads, inside the clock
            c0, t0 = _cpu_ns(os.getpid()), time.perf_counter()
            try:
                return super()._run(*args)
            finally:
                self.root_cpu = (_cpu_ns(os.getpid()) - c0) / 1e9
                self.wall = time.perf_counter() - t0

    plan = make_plan("subscreen", 96, 96, 2, tiles_per_node=2)
    with Watched(2, threads=1) as pool:
        render_plan(plan, spec, pool, progress=False)   # warm: kernels and recordings
        res = render_plan(plan, spec, pool, progress=False)
        # a root that polled its lines would take about the whole run on a core
        assert pool.root_cpu < 0.5 * pool.wall, (pool.root_cpu, pool.wall)
        for k in range(2):
            for tid in _tids(pool.pids[k]):
                assert os.sched_getaffinity(tid) == set(pool.cpus[k])
        before = [_cpu_ns(pool.pids[k]) for k in range(2)]
        time.sleep(0.3)
        idle = [(_cpu_ns(pool.pids[k]) - b) / 1e9 for k, b in zip(range(2), before)]
        # a spinning worker would take most of the 0.3 s; measured here: 0.00 s
        assert max(idle) < 0.03, idle
    assert np.isfinite(res.image[..., :3]).all() and res.image[..., :3].any()


def _affinities():
    """{thread id: its CPUs} of every thread of this process (run on a Dask worker)."""
    out = {}
    for tid in _tids(os.getpid()):
        try:
            out[tid] = sorted(os.sched_getaffinity(tid))
        except OSError:   # a thread that ended meanwhile
            pass
    return out


@pytest.mark.slow
@linux
@two_cpus
@pytest.mark.parametrize("pin", [True, False])
def test_dask_local_workers_are_bound_like_local_nodes(core_spec, core_ref, pin):
    """A LocalCluster started for ``--dask-local`` binds each worker's process (every thread)
    to CPUs of its own, as LocalPool does (``pin=False``: left to the kernel); its frame is
    the same."""
    pytest.importorskip("distributed")
    from links1_app.partition.dask_backend import DaskBackend
    cpus = os.sched_getaffinity(0)
    plan = make_plan("grid", 32, 32, 2, tiles_per_node=2)
    with DaskBackend(n_local=2, static=True, pin=pin) as be:
        res = render_plan(plan, core_spec, be, progress=False)
        got = be.client.run(_affinities)
        names = be.client.run(lambda dask_worker: dask_worker.name)
    np.testing.assert_array_equal(res.image, core_ref)
    assert len(got) == 2
    if not pin:
        assert be.cpus is None
        assert all(set(c) == cpus for per in got.values() for c in per.values())
        return
    assert be.cpus == node_cpus(2, be.threads, cpus)
    for addr, per in got.items():
        want = list(be.cpus[names[addr]])
        assert per and all(c == want for c in per.values()), (addr, per)
    assert not set(be.cpus[0]) & set(be.cpus[1])
