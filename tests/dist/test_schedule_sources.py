"""Scheduling experiments you can trust: every unit time says whether it was measured
(the unit launched alone) or derived (a cost model fitted on units launched alone), and the
simulator replays a known workload exactly as the backends hand it out."""
from __future__ import annotations

import json

import numpy as np
import pytest

from links1_app.partition.executors import RenderResult
from links1_app.partition.costmodel import fit_cost_model, fit_overheads
from links1_app.partition.report import build_report
from links1_app.partition.simulator import replay, simulate
from links1.partition.strategies import make_plan, tile_units

from .conftest import MANY

# a known cost model: seconds of a unit launched alone = L + A * pixels + B * tests
L, A, B = 0.010, 2e-5, 3e-6


def _alone(win, tests):
    return {"window": list(win), "pixels": win[2] * win[3], "ray_tests": float(tests),
            "seconds": L + A * win[2] * win[3] + B * tests}


def test_cost_model_recovers_known_costs_from_units_launched_alone():
    rng = np.random.default_rng(3)
    tiles = [u.window for u in tile_units(32, 16, 8, 4)]
    tests = rng.integers(10, 500, size=len(tiles))
    units = [_alone(w, t) for w, t in zip(tiles, tests)]
    frame = _alone((0, 0, 32, 16), tests.sum())
    cm = fit_cost_model([u["pixels"] for u in units], [u["ray_tests"] for u in units],
                        [u["seconds"] for u in units], frame=frame, per_launch_s=L)
    assert cm["per_launch_s"] == pytest.approx(L)
    assert cm["per_pixel_s"] == pytest.approx(A, rel=1e-6) and cm["per_test_s"] == pytest.approx(B, rel=1e-6)
    # without the frame: the three terms by least squares (the tiles differ in size here)
    sizes = [(0, 0, 4 + k, 3) for k in range(8)]
    us = [_alone(w, 40 * k + 7 * (k % 3)) for k, w in enumerate(sizes)]
    cm2 = fit_cost_model([u["pixels"] for u in us], [u["ray_tests"] for u in us], [u["seconds"] for u in us])
    assert (cm2["per_launch_s"], cm2["per_pixel_s"], cm2["per_test_s"]) == pytest.approx((L, A, B), rel=1e-6)


def test_report_labels_match_their_source():
    """A unit launched alone reports its launch's measured seconds; a unit that shared a launch
    reports the cost model's seconds for its exact counts, marked derived; node busy is the
    sum of the node's measured launches."""
    w, h = 8, 4
    plan = make_plan("grid", w, h, 2, tiles_per_node=2)          # 4 tiles of 4x2, dealt 0,1,0,1
    cost = np.arange(w * h, dtype=np.float64).reshape(h, w)      # ray tests per pixel
    img = np.zeros((h, w, 4))
    img[..., 3] = cost
    recs = {}
    # node 0: tiles 0 and 2 in one launch of 0.5 s; node 1: tile 1 alone (0.125 s), tile 3 alone (0.25 s)
    recs[0] = {"node": 0, "seconds": 0.25, "start": 0.0, "stop": 0.25, "launch": (1, 0), "launch_units": 2,
               "launch_seconds": 0.5, "task": (1, 0), "received": 0.55}
    recs[2] = {"node": 0, "seconds": 0.25, "start": 0.25, "stop": 0.5, "launch": (1, 0), "launch_units": 2,
               "launch_seconds": 0.5, "task": (1, 0), "received": 0.55}
    recs[1] = {"node": 1, "seconds": 0.125, "start": 0.0, "stop": 0.125, "launch": (2, 0), "launch_units": 1,
               "launch_seconds": 0.125, "task": (2, 0), "received": 0.13}
    recs[3] = {"node": 1, "seconds": 0.25, "start": 0.125, "stop": 0.375, "launch": (2, 1), "launch_units": 1,
               "launch_seconds": 0.25, "task": (2, 1), "received": 0.38}
    res = RenderResult(img, plan, records=recs, makespan_s=0.6, n_nodes=2, backend="local")
    tiles = [u.window for u in tile_units(w, h, 4, 2)]
    alone = [_alone(t, cost[t[1]:t[1] + t[3], t[0]:t[0] + t[2]].sum()) for t in tiles]
    frame = dict(_alone((0, 0, w, h), cost.sum()), frame=True)
    ref = {"full_s": frame["seconds"], "per_launch_overhead_s": L, "alone_units": alone + [frame]}
    rep = build_report(res, plan, None, cost_channel=3, reference=ref, meta={"spp": 4})
    by = {u["index"]: u for u in rep["units"]}
    for i in (1, 3):
        assert by[i]["seconds_source"] == "measured" and by[i]["seconds"] == recs[i]["launch_seconds"]
    cm = rep["cost_model"]
    for i in (0, 2):
        u = plan.units[i]
        t = cost[u.y0:u.y0 + u.h, u.x0:u.x0 + u.w].sum()
        assert by[i]["seconds_source"] == "derived"
        assert by[i]["ray_tests"] == t and by[i]["camera_rays"] == u.pixels * 4
        assert by[i]["seconds"] == pytest.approx(cm["per_launch_s"] + cm["per_pixel_s"] * u.pixels
                                                 + cm["per_test_s"] * t)
        assert by[i]["launch_seconds"] == 0.5          # the measured launch it shared
    assert rep["unit_seconds"] == {"measured": 2, "derived": 2, "unavailable": 0}
    busy = {b["node"]: b["busy_s"] for b in rep["nodes_busy"]}
    assert busy == {"0": 0.5, "1": pytest.approx(0.375)}
    assert rep["true_efficiency"] == pytest.approx(ref["full_s"] / (2 * 0.6))
    assert rep["busy_efficiency"] == rep["parallel_efficiency"] == pytest.approx(0.875 / 1.2)
    rc = rep["rank_correlation"]
    assert {"predicted_vs_measured_seconds", "predicted_vs_ray_tests"} <= set(rc)
    assert rc["n_measured"] == len(alone) + 2          # the reference's tiles and the run's two lone units
    assert rep["sources"]["units[].seconds"].startswith("per unit")


def test_fit_overheads_scale_and_transfer():
    cm = {"per_launch_s": 0.01, "per_unit_s": 0.001, "per_pixel_s": 0.0, "per_test_s": 1.0}
    launches = [{"seconds": 2 * (0.01 + 0.001 * (n - 1) + wk), "units": n, "work": wk}
                for n, wk in ((1, 0.1), (3, 0.2), (2, 0.05))]
    tasks = [{"gap": 0.002 + 1e-6 * p, "pixels": p} for p in (100, 400, 900)]
    ov = fit_overheads(launches, tasks, [10.003, 10.005], 10.0, cm)
    assert ov["scale"] == pytest.approx(2.0)
    assert ov["per_launch_s"] == pytest.approx(0.02) and ov["per_unit_s"] == pytest.approx(0.002)
    assert ov["transfer_s"] == pytest.approx(0.002) and ov["transfer_per_pixel_s"] == pytest.approx(1e-6)
    assert ov["dispatch_s"] == pytest.approx(0.004)
    ip = fit_overheads(launches, tasks, [10.003], 10.0, cm, in_process=True)
    assert ip["transfer_s"] == ip["dispatch_s"] == 0.0


# ---------------------------------------------------------------- the simulator, exactly
OV = dict(per_launch_s=1.0, per_unit_s=0.1, scale=1.0, transfer_s=0.25, transfer_per_pixel_s=0.0, dispatch_s=0.5)


def test_replay_static_batched_tasks():
    # 4 scanlines of 8 pixels, line k -> node k mod 2; work of line k (plan index) = k + 1
    plan = make_plan("scanline", 8, 4, 2)
    work = np.array([1.0, 2.0, 3.0, 4.0])
    # each node's lines in one task, one launch: D + L + U + (w_a + w_b), then the transfer
    out = replay(plan, work, **OV, in_process=False)
    node0 = 0.5 + 1.0 + 0.1 + (1 + 3)
    node1 = 0.5 + 1.0 + 0.1 + (2 + 4)
    assert out["makespan_s"] == pytest.approx(node1 + 0.25)
    assert out["busy"].tolist() == pytest.approx([node0 - 0.5, node1 - 0.5])
    assert out["launches"] == 2
    # a task of one line each (task_pixels = 8): two launches per node, the result of the last
    out = replay(plan, work, **OV, in_process=False, task_pixels=8)
    assert out["makespan_s"] == pytest.approx(0.5 + 2 * 1.0 + (2 + 4) + 0.25) and out["launches"] == 4
    # launches split at the nodes' sample budget (spp 2: 16 samples a line; 20 -> one line a launch)
    out = replay(plan, work, **OV, in_process=False, spp=2, launch_samples=20)
    assert out["makespan_s"] == pytest.approx(0.5 + 2 * 1.0 + (2 + 4) + 0.25) and out["launches"] == 4


def test_replay_dynamic_guided_chunks_with_two_in_flight():
    # 8 scanlines of equal work 2, walk order, 2 nodes, chunk factor 2 (ceil(remaining / 4)):
    # node 0 gets [2 units] then [2] (prefetch 2); node 1 gets [1] then [1]; then at each result
    # the node that handed it back gets the next chunk of ceil(2/4) = 1, ceil(1/4) = 1
    plan = make_plan("dynamic", 2, 8, 2, unit="scanline", order="walk")
    work = np.full(8, 2.0)
    ov = dict(OV, per_unit_s=0.0)
    out = replay(plan, work, **ov, chunk_factor=2, in_process=False)
    # node 0: 0.5 -> 5.5 (result 5.75), 5.5 -> 10.5 (10.75); node 1: 0.5 -> 3.5 (3.75), 3.5 -> 6.5 (6.75)
    # at 3.75 node 1 gets 1 unit, queued behind its running chunk: 6.5 -> 9.5 (9.75)
    # at 5.75 node 0 gets the last unit: 10.5 -> 13.5 (13.75)
    assert out["makespan_s"] == pytest.approx(13.75)
    assert out["busy"].tolist() == pytest.approx([5 + 5 + 3, 3 + 3 + 3])
    assert out["launches"] == 6
    # one unit per hand-out (the paper's 4-3, --chunk-factor 0): 4 units each, alternating
    out = replay(plan, work, **ov, chunk_factor=0, in_process=False)
    assert out["launches"] == 8
    assert out["makespan_s"] == pytest.approx(0.5 + 4 * 3.0 + 0.25)


def test_replay_in_process_one_node():
    # one node in the root: no dispatch, no transfer; dynamic on one node: every unit in one
    # chunk, one at a time with k = 0
    plan = make_plan("dynamic", 2, 8, 1, unit="scanline", order="walk")
    out = replay(plan, np.full(8, 2.0), **OV, chunk_factor=2)
    assert out["launches"] == 1
    assert out["makespan_s"] == pytest.approx(1.0 + 0.1 * 7 + 8 * 2.0)
    out = replay(plan, np.full(8, 2.0), **OV, chunk_factor=0)
    assert out["launches"] == 8
    assert out["makespan_s"] == pytest.approx(8 * 1.0 + 8 * 2.0)
    # static: the units in tasks of the pixel budget, in plan order, one launch here
    plan = make_plan("subscreen", 8, 4, 1, tiles_per_node=4)
    out = replay(plan, np.array([1.0, 2.0, 3.0, 4.0]), **OV)
    assert out["makespan_s"] == pytest.approx(1.0 + 0.1 * 3 + 10.0) and out["launches"] == 1


def test_simulate_uses_the_fitted_overheads():
    cost = np.full((4, 8), 0.5)                                    # work seconds per pixel
    (row,) = simulate(cost, None, [2], strategies=("scanline",), overheads=dict(OV, chunk_factor=2),
                      full_frame_s=8.0)
    assert row["makespan_s"] == pytest.approx(0.5 + 1.0 + 0.1 + 2 * 8 * 0.5 + 0.25)
    assert row["true_efficiency"] == pytest.approx(8.0 / (2 * row["makespan_s"]))


# ---------------------------------------------------------------- the CLI, for real
@pytest.mark.slow
def test_units_launched_alone_are_measured_and_batched_ones_derived(tmp_path):
    from links1_app.cli import main
    out = tmp_path / "alone.json"
    assert main(["schedule", MANY, "--renderer", "core", "-D", "res=16", "--nodes", "1", "--partition", "dynamic",
                 "--tiles-per-node", "4", "--chunk-factor", "0", "--report", str(out), "--no-progress",
                 "--reference-repeat", "1"]) == 0
    r = json.loads(out.read_text())
    assert r["launches"] == 4 and {u["seconds_source"] for u in r["units"]} == {"measured"}
    assert all(u["seconds"] == u["launch_seconds"] and u["launch_units"] == 1 for u in r["units"])
    out = tmp_path / "batched.json"
    assert main(["schedule", MANY, "--renderer", "core", "-D", "res=16", "--nodes", "1", "--partition", "subscreen",
                 "--tiles-per-node", "4", "--report", str(out), "--no-progress", "--reference-repeat", "1"]) == 0
    r = json.loads(out.read_text())
    assert r["launches"] == 1 and {u["seconds_source"] for u in r["units"]} == {"derived"}
    cm = r["cost_model"]
    for u in r["units"]:
        assert u["seconds"] == pytest.approx(cm["per_launch_s"] + cm["per_pixel_s"] * u["pixels"]
                                             + cm["per_test_s"] * u["ray_tests"])
    chk = r["simulator_check"]
    assert chk["measured_s"] == r["makespan_s"] and chk["strategy"] == "subscreen" and chk["nodes"] == 1


@pytest.mark.slow
def test_sweep_writes_a_tidy_table_and_plot(tmp_path):
    from links1_app.cli import main
    out, png = tmp_path / "sw.json", tmp_path / "sw.png"
    assert main(["schedule", MANY, "--renderer", "core", "-D", "res=16", "--sweep", "--sweep-strategies",
                 "subscreen,dynamic/tile", "--sweep-nodes", "1", "--sweep-tiles", "2,4", "--sweep-simulate", "1,2,4",
                 "--report", str(out), "--plot", str(png), "--no-progress", "--reference-repeat", "1"]) == 0
    sw = json.loads(out.read_text())
    measured = [r for r in sw["rows"] if r["kind"] == "measured"]
    simulated = [r for r in sw["rows"] if r["kind"] == "simulated"]
    assert sorted((r["strategy"], r["tiles_per_node"], r["nodes"]) for r in measured) == [
        ("dynamic/tile", 2, 1), ("dynamic/tile", 4, 1), ("subscreen", 2, 1), ("subscreen", 4, 1)]
    assert len(simulated) == 2 * 2 * 3 and {r["nodes"] for r in simulated} == {1, 2, 4}
    for r in measured:
        assert r["true_efficiency"] == pytest.approx(r["full_frame_s"] / (r["nodes"] * r["makespan_s"]))
        assert r["units"] == 1 * r["tiles_per_node"]
    csv = (tmp_path / "sw.csv").read_text().splitlines()
    assert csv[0].split(",")[:4] == ["kind", "strategy", "tiles_per_node", "nodes"] and len(csv) == 1 + len(sw["rows"])
    assert png.stat().st_size > 0


def test_sweep_rejects_an_unknown_strategy(tmp_path, capsys):
    from links1_app.cli import main
    out = tmp_path / "sw.json"
    rc = main(["schedule", MANY, "--renderer", "core", "-D", "res=8", "--sweep", "--sweep-strategies",
               "subscreen,dynamic/blob", "--report", str(out), "--no-progress"])
    assert rc == 2 and not out.exists()
    assert capsys.readouterr().err.strip().startswith("links1: error: --sweep-strategies: unknown strategy")


def test_schedule_needs_nodes_or_sweep(tmp_path, capsys):
    from links1_app.cli import main
    rc = main(["schedule", MANY, "--renderer", "core", "-D", "res=8", "--report", str(tmp_path / "r.json")])
    assert rc == 2 and "schedule needs --nodes N (or --sweep)" in capsys.readouterr().err
