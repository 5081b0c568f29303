"""Strategies partition the screen exactly and follow the paper's rules (pure Python)."""
from __future__ import annotations

import numpy as np
import pytest

from links1.sensor.camera import Camera
from links1.partition.loadmodel import SceneModel, project_boxes
from links1.partition.strategies import STRATEGIES, balanced_groups, make_plan, subscreen_groups

from .fake_renderer import FakeRenderer


@pytest.mark.parametrize("strategy", STRATEGIES)
@pytest.mark.parametrize("nodes", [1, 3, 7])
@pytest.mark.parametrize("unit", ["scanline", "tile"])
def test_every_pixel_once(strategy, nodes, unit):
    rng = np.random.default_rng(nodes)
    plan = make_plan(strategy, 37, 23, nodes, tiles_per_node=4, unit=unit, load_map=rng.random((23, 37)))
    assert (plan.coverage() == 1).all()
    assert sorted(plan.order) == list(range(len(plan.units)))
    if plan.static:
        assert set(plan.owner) <= set(range(nodes))


def test_scanline_interleaving_from_the_bottom():
    plan = make_plan("scanline", 10, 9, 4)
    for i, u in enumerate(plan.units):
        k = 9 - 1 - u.y0  # line k counted from the bottom
        assert (u.h, u.w) == (1, 10)
        assert plan.owner[i] == k % 4


def test_subscreen_walk_hand_computed():
    # average 4: the running sum reaches 4 at tile 3 -> group 0 = tiles 0..3
    assert subscreen_groups([1, 1, 1, 1, 4, 0, 0, 0], 2) == [0, 0, 0, 0, 1, 1, 1, 1]
    # total 12, average 4: sums 3 4 | 6 8 | 9 12
    assert subscreen_groups([3, 1, 2, 2, 1, 3], 3) == [0, 0, 1, 1, 2, 2]
    # a heavy first tile must not leave nodes without tiles
    assert subscreen_groups([10, 1, 1], 3) == [0, 1, 2]


def test_balanced_subscreen_hand_computed():
    # loads 4 1 1 1 1 4 (walk order), 2 nodes, average 6: 4-1 closes group 0 where the sum
    # first reaches 6 (4+1+1 = 6 -> tiles 0-2 | 3-5: 6 and 6); with 3 1 3 1 1 1 and 2 nodes
    # (average 5) 4-1 closes after 3+1+3 = 7 (7 | 3), the least max cut is after 3+1 (4 | 6)
    assert balanced_groups([4, 1, 1, 1, 1, 4], 2) == [0, 0, 0, 1, 1, 1]
    assert subscreen_groups([3, 1, 3, 1, 1, 1], 2) == [0, 0, 0, 1, 1, 1]
    assert balanced_groups([3, 1, 3, 1, 1, 1], 2) == [0, 0, 1, 1, 1, 1]
    # 3 nodes, 9 9 1 1 1 1 1 1: every group gets a tile, the heaviest is one 9
    assert balanced_groups([9, 9, 1, 1, 1, 1, 1, 1], 3) == [0, 1, 2, 2, 2, 2, 2, 2]


def _brute_min_max(loads, n):
    """The least heaviest group over every cut of ``loads`` into ``n`` non-empty runs."""
    from itertools import combinations
    c = np.concatenate([[0.0], np.cumsum(loads)])
    best = np.inf
    for cuts in combinations(range(1, len(loads)), n - 1):
        e = (0,) + cuts + (len(loads),)
        best = min(best, max(c[b] - c[a] for a, b in zip(e, e[1:])))
    return best


@pytest.mark.parametrize("nodes", [1, 2, 3, 4])
def test_balanced_subscreen_is_the_least_max_walk_cut(nodes):
    rng = np.random.default_rng(nodes)
    for _ in range(40):
        loads = rng.exponential(size=9) ** 3
        g = np.array(balanced_groups(loads, nodes))
        assert np.all(np.diff(g) >= 0) and sorted(set(g)) == list(range(nodes))   # runs of the walk
        heaviest = max(loads[g == k].sum() for k in range(nodes))
        assert heaviest == pytest.approx(_brute_min_max(loads, nodes), rel=1e-9)
        paper = np.array(subscreen_groups(loads, nodes))
        assert heaviest <= max(loads[paper == k].sum() for k in range(nodes)) * (1 + 1e-12)


def test_balanced_subscreen_keeps_the_paper_tiles_and_walk():
    rng = np.random.default_rng(5)
    lm = rng.random((23, 37)) ** 4
    a = make_plan("subscreen", 37, 23, 3, tiles_per_node=4, load_map=lm)
    b = make_plan("subscreen-balanced", 37, 23, 3, tiles_per_node=4, load_map=lm)
    assert [u.window for u in a.units] == [u.window for u in b.units] and a.order == b.order
    assert b.static and np.array_equal(a.predicted, b.predicted)


def test_subscreen_walks_bottom_left_to_top_right():
    load = np.zeros((8, 8))
    load[4:, :] = 1.0  # the bottom half (rows 4..7 from the top) carries all the load
    plan = make_plan("subscreen", 8, 8, 2, tiles_per_node=8, load_map=load)
    first = plan.units[0]
    assert (first.x0, first.y0 + first.h) == (0, 8)           # bottom-left tile first
    assert plan.units[-1].x0 + plan.units[-1].w == 8 and plan.units[-1].y0 == 0
    # equal halves of the load: node 0 gets the bottom quarter, node 1 the rest
    bottom = [i for i, u in enumerate(plan.units) if u.y0 >= 6]
    assert {plan.owner[i] for i in bottom} == {0}
    loads = np.bincount(plan.owner, weights=plan.predicted)
    assert loads[0] == pytest.approx(16.0) and loads[1] == pytest.approx(16.0)


def test_dynamic_lpt_order_and_no_owner():
    load = np.arange(16.0).reshape(4, 4)
    plan = make_plan("dynamic", 4, 4, 2, unit="scanline", load_map=load)
    assert plan.owner is None
    assert [plan.units[i].y0 for i in plan.order] == [3, 2, 1, 0]  # heaviest row first
    plan = make_plan("dynamic", 4, 4, 2, unit="scanline", load_map=-load, order="walk")
    assert [plan.units[i].y0 for i in plan.order] == [3, 2, 1, 0]  # walk: bottom row first, whatever the loads


def test_tile_loads_are_eq_4_1():
    # one object of load 2 covering pixels x in [1, 3), y in [0, 2): W_i = w_j A_ij + background * area
    m = SceneModel(4, 4, [{"bounds_lo": [0, 0, 0], "bounds_hi": [1, 1, 1]}], np.array([2.0]),
                   np.array([[1.0, 0.0, 3.0, 2.0]]), background=0.0)
    lm = m.load_map()
    plan = make_plan("grid", 4, 4, 1, tiles_per_node=4, load_map=lm)  # 2x2 tiles of 2x2 pixels
    by_pos = {(u.x0, u.y0): plan.predicted[i] for i, u in enumerate(plan.units)}
    # A_ij = 1 x 2 pixels in each top tile, w_j = 2
    assert by_pos == {(0, 0): 4.0, (2, 0): 4.0, (0, 2): 0.0, (2, 2): 0.0}


def test_projection_handles_boxes_behind_and_around_the_eye():
    cam = Camera(fov_x=90.0, width=100, height=100)  # at the origin, looking down +z
    lo = np.array([[-1, -1, 4], [-1, -1, -5], [-1, -1, -1]], float)
    hi = np.array([[1, 1, 6], [1, 1, -3], [1, 1, 1]], float)
    r = project_boxes(cam, lo, hi, pad=0)
    # front box: nearest face z=4 spans +-1/4 of the half-width tan(45) = 1 -> pixels 37.5 .. 62.5
    assert r[0] == pytest.approx([37.5, 37.5, 62.5, 62.5])
    assert (r[1] == 0).all()                     # wholly behind the eye: empty
    assert r[2] == pytest.approx([0, 0, 100, 100])  # the eye inside the box: the whole film


def test_node_data_primary_and_secondary():
    from links1.partition.loadmodel import scene_model
    model = scene_model(FakeRenderer())
    plan = make_plan("subscreen", 48, 32, 3, tiles_per_node=4, load_map=model.load_map())
    data = model.node_data(plan)
    assert len(data) == 3 and sum(d["units"] for d in data) == len(plan.units)
    for d in data:
        assert 0 <= d["objects_primary"] <= 3
        # lights unknown for the fake: secondary rays may reach everything else
        assert d["objects_primary"] + d["objects_secondary"] == 3
    scan = model.node_data(make_plan("scanline", 48, 32, 3))
    assert all(d["objects_primary"] == 3 for d in scan)  # interleaved lines span the whole screen
