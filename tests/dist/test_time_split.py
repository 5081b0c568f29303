"""Where a makespan goes: the schedule report splits each node's time into
work, launch overhead, slowdown, dispatch, transfer and waiting, and the root's into dispatch,
assembly, rendering and waiting; the parts add up to the makespan."""
from __future__ import annotations

import json

import numpy as np
import pytest

from links1_app.partition.executors import RenderResult
from links1_app.partition.report import NODE_PARTS, ROOT_PARTS, build_report, time_split
from links1.partition.strategies import make_plan

from .conftest import MANY


def test_time_split_of_a_hand_made_timeline():
    # node 0: dispatched at 0, launches [0.1, 0.5] and [0.6, 0.8]; its first task's result in flight
    # [0.5, 0.55], its second [0.8, 0.9]; makespan 1.0 -> dispatch 0.1, transfer 0.05 + 0.1,
    # waiting 0.05 (0.55-0.6) + 0.1 (0.9-1.0)
    T0 = 1000.0
    launches = [{"node": 0, "start": T0 + 0.1, "stop": T0 + 0.5, "seconds": 0.4, "units": 2, "work": 0.3},
                {"node": 0, "start": T0 + 0.6, "stop": T0 + 0.8, "seconds": 0.2, "units": 1, "work": 0.15},
                {"node": 1, "start": T0 + 0.0, "stop": T0 + 0.95, "seconds": 0.95, "units": 1, "work": 0.9}]
    tasks = [{"node": 0, "stop": T0 + 0.5, "received": T0 + 0.55}, {"node": 0, "stop": T0 + 0.8, "received": T0 + 0.9},
             {"node": 1, "stop": T0 + 0.95, "received": T0 + 0.97}]
    res = RenderResult(None, None, makespan_s=1.0, t0_wall=T0, n_nodes=2, backend="local",
                       root_events=[["dispatch", T0, T0 + 0.01], ["assembly", T0 + 0.55, T0 + 0.57],
                                    ["assembly", T0 + 0.9, T0 + 0.93], ["assembly", T0 + 0.97, T0 + 1.0]],
                       startup_s={0: 2.0, 1: 2.5})
    cm = {"per_launch_s": 0.04, "per_unit_s": 0.01}
    ts = time_split(res, launches, tasks, cm, planning={"planning_s": 0.2})
    n0, n1 = ts["nodes"]["0"], ts["nodes"]["1"]
    assert n0["work_s"] == pytest.approx(0.45) and n0["launch_overhead_s"] == pytest.approx(0.04 * 2 + 0.01)
    assert n0["slowdown_s"] == pytest.approx(0.6 - 0.45 - 0.09)
    assert n0["dispatch_s"] == pytest.approx(0.1) and n0["transfer_s"] == pytest.approx(0.15)
    assert n0["waiting_s"] == pytest.approx(0.15)
    assert n1["dispatch_s"] == pytest.approx(0.0) and n1["transfer_s"] == pytest.approx(0.02)
    assert n1["waiting_s"] == pytest.approx(0.03) and n1["startup_s"] == 2.5
    root = ts["root"]
    assert root["dispatch_s"] == pytest.approx(0.01) and root["assembly_s"] == pytest.approx(0.08)
    assert root["waiting_s"] == pytest.approx(0.91) and root["planning_s"] == 0.2
    for v in ts["nodes"].values():
        assert sum(v[p] for p in NODE_PARTS) == pytest.approx(1.0)
    assert ts["shares"]["work"] == pytest.approx((0.45 + 0.9) / 2.0)
    # no CPU times in these launches: nothing said about off-CPU time
    assert n0["off_cpu_s"] is None and ts["off_cpu_share"] is None


def test_off_cpu_time_is_launch_time_without_cpu():
    # node 0's launches of 0.4 s and 0.2 s used 0.3 s and 0.2 s of CPU: 0.1 s off its core;
    # node 1's 0.95 s launch used 0.5 s: 0.45 s; share (0.1 + 0.45) / (2 nodes x 1 s)
    T0 = 1000.0
    launches = [{"node": 0, "start": T0 + 0.1, "stop": T0 + 0.5, "seconds": 0.4, "cpu_s": 0.3, "units": 1, "work": 0.3},
                {"node": 0, "start": T0 + 0.6, "stop": T0 + 0.8, "seconds": 0.2, "cpu_s": 0.2, "units": 1, "work": 0.2},
                {"node": 1, "start": T0, "stop": T0 + 0.95, "seconds": 0.95, "cpu_s": 0.5, "units": 1, "work": 0.5}]
    res = RenderResult(None, None, makespan_s=1.0, t0_wall=T0, n_nodes=2, backend="local")
    ts = time_split(res, launches, [], None)
    assert ts["nodes"]["0"]["launch_cpu_s"] == pytest.approx(0.5)
    assert ts["nodes"]["0"]["off_cpu_s"] == pytest.approx(0.1)
    assert ts["nodes"]["1"]["off_cpu_s"] == pytest.approx(0.45)
    assert ts["off_cpu_share"] == pytest.approx(0.275)
    for v in ts["nodes"].values():   # beside the parts: they still add up to the makespan
        assert sum(v[p] for p in NODE_PARTS) == pytest.approx(1.0)


def _check_adds_up(rep, in_process):
    ts = rep["time_split"]
    span = rep["makespan_s"]
    eps = 2e-3  # wall clock (nodes, root events) against the root's perf_counter makespan
    assert ts["makespan_s"] == span
    busy = {str(n["node"]): n["busy_s"] for n in rep["nodes_busy"]}
    assert set(ts["nodes"]) == set(busy) and len(busy) == rep["nodes"]
    for k, v in ts["nodes"].items():
        assert sum(v[p] for p in NODE_PARTS) == pytest.approx(span, abs=1e-9)
        # every measured part fits in the makespan: the node clocks agree with the root's
        assert v["launches_s"] == pytest.approx(busy[k], abs=eps)  # no launch outside the clock
        assert v["work_s"] > 0 and v["launch_overhead_s"] > 0
        assert v["work_s"] + v["launch_overhead_s"] + v["slowdown_s"] == pytest.approx(busy[k], abs=eps)
        for p in ("dispatch_s", "transfer_s", "waiting_s"):
            assert v[p] >= -eps
        assert v["startup_s"] is not None and v["startup_s"] > 0
        # measured in the node: CPU time within its launches' wall time (one thread: at most it)
        assert 0 < v["launch_cpu_s"] and v["off_cpu_s"] >= 0
    root = ts["root"]
    assert sum(root[p] for p in ROOT_PARTS) == pytest.approx(span, abs=1e-9)
    assert root["assembly_s"] > 0
    assert root["waiting_s"] >= -eps and root["planning_s"] > 0
    if in_process:
        assert root["rendering_s"] == pytest.approx(sum(busy.values()), abs=eps)
        assert root["dispatch_s"] == 0.0
    else:
        assert root["rendering_s"] == 0.0 and root["dispatch_s"] > 0
    # summed over nodes, work is the one-process frame's work: the cost model is scaled so that the
    # frame costs its measured seconds (one launch constant + work), and work is linear in the
    # units' pixels and exact ray tests, which add up to the frame's
    cm = rep["cost_model"]
    frame_work = rep["reference"]["full_s"] - cm["per_launch_s"]
    assert ts["totals"]["work_s"] == pytest.approx(frame_work, rel=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize("nodes,partition", [(2, "dynamic"), (2, "subscreen"), (1, "dynamic")])
def test_schedule_time_split_adds_up_to_the_makespan(tmp_path, capsys, nodes, partition):
    from links1_app.cli import main
    out = tmp_path / "r.json"
    rc = main(["schedule", MANY, "--renderer", "core", "-D", "res=32", "--nodes", str(nodes), "--partition",
               partition, "--tiles-per-node", "4", "--report", str(out), "--no-progress",
               "--reference-repeat", "1", "--plot", str(tmp_path / "r.png")])
    assert rc == 0
    rep = json.loads(out.read_text())
    _check_adds_up(rep, in_process=nodes == 1)
    assert (tmp_path / "r.png").stat().st_size > 0
    assert "nodes x makespan went to work" in capsys.readouterr().err
