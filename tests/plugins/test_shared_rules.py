"""Rules the two renderers share have one home, which both use:

* the side-of-plane rule of shadow-ray planning (links1.maths.halfspace): the core's
  links1.tracing.occluders and the plugin's shadow planning (shadow_plan.py) take it from there, each with its own
  tolerance (kept from before the rule had one home, so the images stay the same bits);
* the sample keys' salts (links1.maths.sampling): the plugin's sources name them and never
  write their values again.
"""
from __future__ import annotations

import os
import re

import numpy as np
import pytest

pytestmark = pytest.mark.mitsuba

PLUGIN = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))),
                      "plugins", "links1_mitsuba")


def test_the_occluder_side_rule_is_one(monkeypatch):
    pytest.importorskip("mitsuba")
    from links1.maths import halfspace
    from links1.tracing import occluders
    from links1_mitsuba import shadow_plan
    assert shadow_plan.box_side is halfspace.box_side is occluders.box_side
    assert shadow_plan.point_side is halfspace.point_side is occluders.point_side
    # each renderer's own helper goes through it (a counting stand-in sees both calls)
    calls = []

    def counted(*a, **kw):
        calls.append(1)
        return halfspace.box_side(*a, **kw)
    monkeypatch.setattr(shadow_plan, "box_side", counted)
    monkeypatch.setattr(occluders, "box_side", counted)
    n = np.array([0.0, 0.0, 1.0])
    assert shadow_plan._side_of_box(n, 1.0, np.array([0.0, 0, 2]), np.array([1.0, 1, 3]), 1e-6) == 1
    assert occluders._box_side([0, 0, -3], [1, 1, 0], n, np.array([0.0, 0.0, 1.0])) == -1
    assert len(calls) == 2


def test_the_sample_key_salts_are_named_not_retyped():
    """No source of the plugin writes the value of a key salt of links1.maths.sampling
    (KEY_*, key_seed's constants) as a literal: it imports the name."""
    from links1.maths import sampling
    values = {v for k, v in vars(sampling).items() if k.startswith("KEY_") and isinstance(v, int)}
    values |= {0x27D4EB2F, 0x165667B1}      # key_seed's multiplier and increment
    assert len(values) >= 8
    found = []
    for name in sorted(os.listdir(PLUGIN)):
        if name.endswith(".py"):
            text = open(os.path.join(PLUGIN, name)).read()
            for lit in re.findall(r"0x[0-9A-Fa-f]{6,8}", text):
                if int(lit, 16) in values:
                    found.append(f"{name}: {lit}")
    assert not found, found
    from links1_mitsuba import camera, launch, raytree, raytree_ad
    assert raytree.KEY_REFLECT == sampling.KEY_REFLECT and raytree.KEY_REFRACT == sampling.KEY_REFRACT
    assert raytree_ad.child_keys is raytree.child_keys   # the derivative pass's levels: the same rule
    assert camera.KEY_PIXEL == sampling.KEY_PIXEL and launch.key_seed is sampling.key_seed
