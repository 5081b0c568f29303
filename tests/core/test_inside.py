"""The core seen from inside closed shapes: a closed convex shape shadows its own
points whose light is on the inner side; expectations are analytic (tests/inside_scenes.py)."""
from __future__ import annotations

import numpy as np
import pytest

import links1
from links1.scene.loader import load_string
from tests.inside_scenes import (GLASS, OPAQUE, POINT_OUTSIDE, SHELLS, TWOSIDED, AMBIENT,
                                 glass_expected, scene)


def render(xml, aovs=()):
    return links1.render(load_string(xml), aovs=aovs)


@pytest.mark.parametrize("shell", ["links1_sphere", "sphere", "capped_cylinder", "cube"])
def test_opaque_shell_from_inside_is_ambient_only(shell):
    img = render(scene(SHELLS[shell], OPAQUE))
    np.testing.assert_allclose(img, AMBIENT, rtol=0, atol=1e-12)


@pytest.mark.parametrize("shell", ["links1_sphere", "sphere"])
def test_twosided_diffuse_sphere_from_inside_is_black(shell):
    img = render(scene(SHELLS[shell], TWOSIDED, POINT_OUTSIDE))
    assert np.all(img == 0.0)


def test_an_unrelated_shape_changes_nothing():
    far = ('<shape type="sphere"><point name="center" x="40" y="0" z="0"/><float name="radius" value="0.1"/>'
           '<ref id="m"/></shape>')
    a = render(scene(SHELLS["links1_sphere"], OPAQUE))
    b = render(scene(SHELLS["links1_sphere"] + far, OPAQUE))
    np.testing.assert_array_equal(a, b)


def test_glass_sphere_inner_wall_lit_through_its_own_transmittance():
    img = render(scene(SHELLS["links1_sphere"], GLASS), aovs=("normal",))
    normal = img[..., 3:6]
    np.testing.assert_allclose(np.linalg.norm(normal, axis=-1), 1.0, atol=1e-9)
    np.testing.assert_allclose(img[..., :3], glass_expected(normal)[..., None] * np.ones(3), rtol=1e-9, atol=1e-12)
