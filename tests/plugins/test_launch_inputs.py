"""What a frozen window launch hands dr.freeze of the scene (launch.SceneInputs), and the
fall-back to the whole scene when a recording needs more of it."""
from __future__ import annotations

import os

import numpy as np
import pytest

from .conftest import SCENES

pytestmark = pytest.mark.mitsuba
FIG11 = os.path.join(SCENES, "fig11.xml")
GLASS = os.path.join(SCENES, "mitsuba_glass.xml")


def _variables(obj):
    import drjit as dr
    out = []
    with dr.scoped_set_flag(dr.JitFlag.EnableObjectTraversal, True):
        obj._traverse_1_cb_ro(lambda index, variant, domain: out.append((index, domain)))
    return out


@pytest.mark.slow
@pytest.mark.skipif(not os.path.exists(GLASS), reason="scenes/mitsuba_glass.xml missing")
def test_launches_take_the_scene_once_each_and_without_its_sensors(variant):
    from links1_mitsuba import MitsubaRenderer
    from links1_mitsuba.launch import SceneInputs
    r = MitsubaRenderer(GLASS, params={"res": 16})
    r.render((3, 4, 5, 6))
    scene = r.scene
    held = r.integrator.info()["tables"].scene_input
    assert isinstance(held, SceneInputs)
    indices = [i for i, _, _ in held.items]
    assert len(indices) == len(set(indices))
    every = _variables(scene)
    camera = {i for s in scene.sensors() for i, _ in _variables(s)}
    shapes = {i for objs in (scene.shapes(), scene.emitters()) for o in objs for i, _ in _variables(o)}
    # the launches read no sensor: neither its variables nor the sensor registry's
    assert camera - shapes and not set(indices) & (camera - shapes)
    assert "Sensor" not in {d for _, _, d in held.items}
    # everything else of the scene, once
    assert set(indices) == {i for i, d in every if d != "Sensor"} - (camera - shapes)
    assert len(indices) < len(every)


@pytest.mark.skipif(not os.path.exists(FIG11), reason="scenes/fig11.xml missing")
def test_a_recording_that_needs_more_of_the_scene_is_made_with_all_of_it(variant, monkeypatch):
    import links1_mitsuba.launch as launch
    from links1_mitsuba import MitsubaRenderer
    win = (2, 3, 9, 7)
    ref = MitsubaRenderer(FIG11, params={"res": 16}, spp=2, aovs=("depth", "id")).render(win)
    init = launch.SceneInputs.__init__

    def holding_nothing(self, scene, extra=(), skip=()):
        init(self, scene, extra, skip)
        self.items = ()   # the recording reads shapes and emitters: Dr.Jit refuses it

    monkeypatch.setattr(launch.SceneInputs, "__init__", holding_nothing)
    r = MitsubaRenderer(FIG11, params={"res": 16}, spp=2, aovs=("depth", "id"))
    assert np.array_equal(r.render(win), ref)
    assert r.integrator.info()["tables"].scene_input == launch._WHOLE_SCENE
    recordings = r.integrator.info()["recordings"]
    assert np.array_equal(r.render_batch([win, (0, 0, 16, 16)])[0], ref)
    # a new batch shape replays; in the full suite's order (only there, with the session's other
    # renderers alive) one more recording was seen: a configuration records at most twice
    assert r.integrator.info()["recordings"] <= recordings + 1
    assert np.array_equal(r.render_batch([(0, 0, 16, 16), win])[1], ref)
    assert r.integrator.info()["recordings"] <= recordings + 1


def _live_jit_variables():
    import drjit as dr
    return sum(1 for line in dr.whos(True).splitlines() if line.strip()[:1].isdigit())


@pytest.mark.skipif(not os.path.exists(FIG11), reason="scenes/fig11.xml missing")
def test_a_dropped_renderer_frees_its_scene(variant):
    # the scene owns the integrator, which holds the prepared tables: a scene reached from
    # those (as a first SceneInputs held it) is a cycle through C++ objects that Python's
    # collector cannot break, and every renderer's ~280 variables stayed alive
    import gc
    from links1_mitsuba import MitsubaRenderer
    live = []
    for _ in range(3):
        r = MitsubaRenderer(FIG11, params={"res": 16})
        r.render((1, 1, 5, 5))
        del r
        gc.collect()
        live.append(_live_jit_variables())
    assert live[2] <= live[1] + 10, live
