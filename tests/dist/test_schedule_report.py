"""Honest schedule reports: the full frame of the same renderer measured in
the same run, true efficiency = full / (nodes x makespan), launches, per-launch overhead."""
from __future__ import annotations

import json

import pytest

from links1_app.partition.executors import RenderResult
from links1_app.partition.report import build_report
from links1.partition.strategies import make_plan

from .conftest import MANY


def test_true_efficiency_is_full_frame_over_nodes_times_makespan():
    import numpy as np
    plan = make_plan("scanline", 4, 4, 2)
    recs = {i: {"node": i % 2, "seconds": 0.25, "start": 10.0 + (i // 2) * 0.25, "stop": 10.25 + (i // 2) * 0.25,
                "pid": 100 + i % 2, "launch": (100 + i % 2, 0), "launch_units": 2} for i in range(4)}
    res = RenderResult(np.zeros((4, 4, 3)), plan, records=recs, makespan_s=0.6, n_nodes=2)
    rep = build_report(res, plan, None, reference={"full_s": 0.3, "per_launch_overhead_s": 0.001})
    assert rep["parallel_efficiency"] == pytest.approx(1.0 / (2 * 0.6))  # busy 0.5 s per node
    assert rep["true_efficiency"] == pytest.approx(0.3 / (2 * 0.6))
    assert rep["launches"] == 2 and [n["launches"] for n in rep["nodes_busy"]] == [1, 1]


@pytest.mark.slow
def test_schedule_reports_the_reference_measured_in_the_same_run(tmp_path, capsys):
    from links1_app.cli import main
    out = tmp_path / "r.json"
    rc = main(["schedule", MANY, "--renderer", "core", "-D", "res=32", "--nodes", "2", "--partition", "subscreen",
               "--tiles-per-node", "4", "--report", str(out), "--no-progress", "--simulate", "1,4",
               "--reference-repeat", "1"])
    assert rc == 0
    r = json.loads(out.read_text())
    ref = r["reference"]
    assert r["full_frame_s"] == ref["full_s"] > 0 and ref["units"] == 64 and ref["tiled_s"] > 0
    assert ref["repeat"] == 1   # --reference-repeat
    assert r["true_efficiency"] == pytest.approx(r["full_frame_s"] / (r["nodes"] * r["makespan_s"]))
    assert ref["per_launch_overhead_s"] == pytest.approx(max(0.0, (ref["tiled_s"] - ref["full_s"]) / 63))
    assert r["launches"] == 2  # each node's 4 tiles in one launch
    # the simulation replays the overheads fitted in this run, not a fixed per-unit charge
    assert r["simulation"]["overheads"] == r["overheads"]
    assert r["overheads"]["per_launch_s"] == pytest.approx(r["cost_model"]["per_launch_s"] * r["overheads"]["scale"])
    from links1.partition.loadmodel import load_table
    assert r["load_table"] == load_table(renderer="core")  # the table the plan was made with
    err = capsys.readouterr().err
    assert "TRUE EFFICIENCY" in err and "one-process frame" in err and "per-launch overhead" in err
    assert "busy efficiency" in err and "with measured seconds" in err and "with exact ray tests" in err


def _one_node_report(full_trials):
    """A one-node run of makespan 0.6 s against a reference whose trials are ``full_trials``."""
    import numpy as np
    plan = make_plan("scanline", 4, 4, 1)
    recs = {i: {"node": 0, "seconds": 0.15, "start": 10.0 + i * 0.15, "stop": 10.15 + i * 0.15,
                "pid": 100, "launch": (100, i), "launch_units": 1} for i in range(4)}
    res = RenderResult(np.zeros((4, 4, 3)), plan, records=recs, makespan_s=0.6, n_nodes=1)
    return build_report(res, plan, None, reference={"full_s": float(np.median(full_trials)),
                                                    "full_trials_s": list(full_trials),
                                                    "per_launch_overhead_s": 0.001})


def test_a_true_efficiency_above_one_is_reported_as_noise():
    from links1_app.partition.schedule import summary_line
    from links1_app.partition.report import efficiency_text
    rep = _one_node_report([0.57, 0.66, 0.69])        # one node faster than the one-process frame
    assert rep["true_efficiency"] == pytest.approx(1.1)
    assert rep["true_efficiency_spread"] == pytest.approx([0.95, 1.15])
    line = summary_line(rep, "scanline")
    assert "TRUE EFFICIENCY 1 within noise (measured 1.100; the one-process frame's trials give 0.950 to " \
           "1.150)" in line
    assert "1 at most (measured 1.100: above 1 even at the fastest reference trial" in \
        efficiency_text(1.1, [1.05, 1.15])
    assert efficiency_text(0.75, [0.7, 0.8]) == "0.750" and efficiency_text(None) == "n/a"
    assert efficiency_text(1.1) == "1 within noise (measured 1.100)"


def test_a_negative_share_is_reported_as_noise():
    from links1_app.partition.report import share_text
    assert share_text("slowdown", 0.12) == "slowdown 12 %"
    said = share_text("slowdown", -0.14)
    assert said.startswith("slowdown 0 % (the launches took 14 % less than the work and overhead")
    assert "-" not in said and share_text("waiting", -0.0001) == "waiting 0 %"
    assert share_text("launch_overhead", -0.03) == "launch overhead 0 % (measured -3 %: noise)"
