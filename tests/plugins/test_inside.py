"""links1_whitted seen from inside closed shapes: analytic expectations
(tests/inside_scenes.py) and Mitsuba's own ``direct`` integrator, not the core."""
from __future__ import annotations

import numpy as np
import pytest

from tests.inside_scenes import (GLASS, OPAQUE, POINT_OUTSIDE, SHELLS, TWOSIDED, AMBIENT,
                                 glass_expected, scene)

pytestmark = pytest.mark.mitsuba


def render(xml, variant, aovs=()):
    from links1_mitsuba import load_string
    s = load_string(xml, variant=variant)
    return s.integrator().render_window(s, None, spp=1, aovs=aovs)


@pytest.mark.parametrize("shell", ["links1_sphere", "sphere", "capped_cylinder", "cube"])
def test_opaque_shell_from_inside_is_ambient_only(variant, shell):
    img = render(scene(SHELLS[shell], OPAQUE), variant)
    np.testing.assert_allclose(img, AMBIENT, rtol=1e-6)


@pytest.mark.parametrize("shell", ["links1_sphere", "sphere"])
def test_twosided_diffuse_sphere_from_inside_is_black(variant, shell):
    img = render(scene(SHELLS[shell], TWOSIDED, POINT_OUTSIDE), variant)
    assert np.all(img == 0.0)


def test_mitsuba_direct_agrees_inside_a_sphere(variant):
    import mitsuba as mi
    from links1_mitsuba import load_string
    xml = scene(SHELLS["sphere"], TWOSIDED, POINT_OUTSIDE).replace(
        '<integrator type="links1_whitted"><integer name="max_depth" value="3"/></integrator>',
        '<integrator type="direct"/>')
    ref = np.asarray(mi.render(load_string(xml, variant=variant, links1_integrator="scene"), spp=4))
    assert np.all(ref == 0.0)  # Mitsuba's own integrator: the shell hides the light


def test_glass_sphere_inner_wall_lit_through_its_own_transmittance(variant):
    img = render(scene(SHELLS["links1_sphere"], GLASS), variant, aovs=("normal",))
    normal = img[..., 3:6].astype(np.float64)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    np.testing.assert_allclose(img[..., :3], glass_expected(normal)[..., None] * np.ones(3), rtol=2e-5, atol=1e-6)
