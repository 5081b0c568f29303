"""Scenes seen from inside a closed shape, with their analytic radiance.

Shared by ``tests/core/test_inside.py`` and ``tests/plugins/test_inside.py``: both renderers
are checked against the same closed-form expectations, not against each other.

The eye sits at the centre of a sphere of radius R (or inside a capped cylinder / cube), the
lights are outside. An opaque shell shadows every inner point from an outside light, so the
image is the ambient term alone. A transparent shell (transmittance t, ior 1) lets the light
through once (3-3-3: once per object), so an inner point with outward normal n is
``a + kd E max(-n . wi, 0) t``; with the eye at the centre the normal is the view direction.
"""
from __future__ import annotations

import numpy as np

from tests import scenes

AMBIENT, KD, E, T = 0.1, 0.7, 0.9, 0.7
WI = np.array([0.3, 1.0, 0.2]) / np.linalg.norm([0.3, 1.0, 0.2])  # toward the directional light
RES = 24


def scene(shell: str, bsdf: str, light: str | None = None, max_depth: int = 3) -> str:
    light = light or (f'<emitter type="directional"><vector name="direction" x="{-WI[0]}" '
                      f'y="{-WI[1]}" z="{-WI[2]}"/><rgb name="irradiance" value="{E}"/></emitter>')
    return scenes.scene(scenes.perspective("0, 0, 0", "0.3, -0.8, 1", fov=70, width=RES),
                        scenes.whitted(max_depth), f"<bsdf {bsdf}",
                        shell.replace("BSDF", '<ref id="m"/>'), light)


OPAQUE = f'type="links1_phong" id="m"><rgb name="ambient" value="{AMBIENT}"/><rgb name="diffuse" value="{KD}"/></bsdf>'
GLASS = (f'type="links1_phong" id="m"><rgb name="ambient" value="{AMBIENT}"/><rgb name="diffuse" value="{KD}"/>'
         f'<rgb name="transmittance" value="{T}"/><float name="ior" value="1"/></bsdf>')
TWOSIDED = 'type="twosided" id="m"><bsdf type="diffuse"><rgb name="reflectance" value="0.8"/></bsdf></bsdf>'
POINT_OUTSIDE = ('<emitter type="point"><point name="position" x="1" y="6" z="2"/>'
                 '<rgb name="intensity" value="30"/></emitter>')

SHELLS = {
    "links1_sphere": '<shape type="links1_quadric"><string name="kind" value="sphere"/>'
                     '<transform name="to_world"><scale value="2"/></transform>BSDF</shape>',
    "sphere": '<shape type="sphere"><float name="radius" value="2"/>BSDF</shape>',
    "capped_cylinder": '<shape type="links1_quadric"><string name="kind" value="cylinder"/>'
                       '<boolean name="capped" value="true"/>'
                       '<vector name="clip_0" x="0" y="0" z="1"/><float name="clip_0_offset" value="1"/>'
                       '<vector name="clip_1" x="0" y="0" z="-1"/><float name="clip_1_offset" value="1"/>'
                       '<transform name="to_world"><scale x="2" y="2" z="3"/></transform>BSDF</shape>',
    "cube": '<shape type="cube"><transform name="to_world"><scale value="2"/></transform>BSDF</shape>',
}


def glass_expected(normal: np.ndarray) -> np.ndarray:
    """Radiance of the inner wall of the transparent sphere centred on the eye (module doc)."""
    cos = np.maximum(-(normal @ WI), 0.0)
    return AMBIENT + KD * E * cos * T
