"""Transparent shadows through many Mitsuba shapes: no cap on how many transparent
shapes are told apart (was 31) or how many surfaces a shadow ray crosses (was 64).

A wall (links1_phong, ambient 0, diffuse kd) is lit by a directional light at 45 degrees
through 70 transparent panes and one transparent sphere (crossed twice, counted once), all
Mitsuba shapes outside the camera's narrow view. Eq. 3.11 with 3-3-3: every wall pixel is
``kd * E * cos 45 * t_sphere * prod t_k``."""
from __future__ import annotations

import numpy as np
import pytest

from tests.scenes import perspective, scene, whitted

KD, E, T_SPHERE = 0.8, 1.0, 0.5
PANES = [0.99 - 0.002 * (k % 7) for k in range(70)]
EXPECTED = KD * E * np.sqrt(0.5) * T_SPHERE * np.prod(PANES)


def _phong(t):
    return (f'<bsdf type="links1_phong"><rgb name="ambient" value="0"/><rgb name="diffuse" value="0.1"/>'
            f'<rgb name="transmittance" value="{t}"/><float name="ior" value="1"/></bsdf>')


def _scene():
    panes = "".join(f'<shape type="rectangle"><transform name="to_world"><scale x="0.5" y="2" z="1"/>'
                    f'<translate x="{1 + 0.5 * k}" y="0" z="{1 + 0.5 * k}"/></transform>{_phong(t)}</shape>'
                    for k, t in enumerate(PANES))
    return scene(perspective("0, 0, 100", "0, 0, 0", fov=0.4, width=8, spp=None), whitted(1), f"""
  <shape type="rectangle"><transform name="to_world"><scale value="2"/></transform>
    <bsdf type="links1_phong"><rgb name="ambient" value="0"/><rgb name="diffuse" value="{KD}"/></bsdf></shape>
  {panes}
  <shape type="sphere"><point name="center" x="45" y="0" z="45"/><float name="radius" value="0.8"/>{_phong(T_SPHERE)}</shape>
  <emitter type="directional"><vector name="direction" x="-1" y="0" z="-1"/><rgb name="irradiance" value="{E}"/></emitter>""")


def test_core():
    import links1
    from links1.scene.loader import load_string
    img = links1.render(load_string(_scene()), spp=1)
    np.testing.assert_allclose(img, EXPECTED, rtol=1e-9)


@pytest.mark.slow
@pytest.mark.mitsuba
def test_plugin(variant):
    from links1_mitsuba import load_string
    s = load_string(_scene(), variant=variant)
    img = s.integrator().render_window(s, None, spp=1)
    np.testing.assert_allclose(img, EXPECTED, rtol=2e-5)
