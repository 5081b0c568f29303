"""A shape without a BSDF gets Mitsuba's default (``diffuse``, reflectance
0.5) in both renderers whatever its neighbours have.

The scenes mix shapes with and without a BSDF of every kind links1_whitted handles: quadrics
few enough to be unrolled and many enough for the BVH (``tuning.Tuning.bvh_min``), a blob, a bicubic
mesh, Mitsuba's own sphere and rectangle. Before the fix the default BSDF made in
``tables.prepare`` was freed while its registry id stayed in the BSDF pointer table, and a
quadric without a BSDF beside quadrics with one crashed the process (exit 139). The images
must match the float64 core (relative MSE ≤ 1e-5, as test_plugins_vs_core) and the shapes
without a BSDF must look like the same shapes given ``<bsdf type="diffuse"/>`` explicitly.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from tests.scenes import perspective, scene, whitted

pytestmark = pytest.mark.mitsuba

RES = 48
PHONG = ('<bsdf type="links1_phong"><rgb name="diffuse" value="0.7, 0.3, 0.2"/>'
         '<rgb name="specular" value="0.3"/><rgb name="reflectance" value="0.2"/></bsdf>')
PATCH = " ".join(f"{x} {y} 0" for y in (-1, -0.3, 0.3, 1) for x in (-1, -0.3, 0.3, 1))


def _scene(n_quadrics: int, explicit_default: bool) -> str:
    none = '<bsdf type="diffuse"/>' if explicit_default else ""
    parts = []
    for i in range(n_quadrics):
        x, z = -3 + 6 * (i % 5) / 4, -1.5 - 1.2 * (i // 5)
        mat = PHONG if i % 2 else none   # the first quadric has none, as in the failing fig4 edit
        parts.append(f'<shape type="links1_quadric"><string name="kind" value="sphere"/>'
                     f'<transform name="to_world"><scale value="0.45"/><translate x="{x}" y="0.5" z="{z}"/>'
                     f'</transform>{mat}</shape>')
    parts.append(f'<shape type="links1_blob"><string name="centers" value="0 0.6 1.2 1 0.6  0.5 0.7 1.3 1 0.5"/>'
                 f'<float name="threshold" value="0.5"/>{none}</shape>')
    parts.append(f'<shape type="links1_bicubic"><string name="control_points" value="{PATCH}"/>'
                 f'<transform name="to_world"><scale value="0.6"/><translate x="2" y="1.2" z="1"/></transform>{none}</shape>')
    parts.append(f'<shape type="sphere"><point name="center" x="-2" y="0.5" z="1"/><float name="radius" value="0.5"/>{none}</shape>')
    parts.append(f'<shape type="rectangle"><transform name="to_world"><scale value="6"/><rotate x="1" angle="-90"/>'
                 f'</transform>{none}</shape>')
    parts.append(f'<shape type="sphere"><point name="center" x="0.8" y="1.6" z="0"/><float name="radius" value="0.4"/>{PHONG}</shape>')
    return scene(whitted(3), perspective("0, 4, 7", "0, 0.5, -1", fov=60, width=RES, spp=None), f"""
  <emitter type="links1_point"><point name="position" x="2" y="6" z="4"/><rgb name="L1" value="1"/></emitter>
  {''.join(parts)}""")


def _render_both(path):
    from links1_mitsuba import MitsubaRenderer

    from links1.scene.loader import load_scene
    from links1.tracing.render import render
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = MitsubaRenderer(str(path))
        plug = r.integrator.render_window(r.scene, None, spp=1, seed=0)
        core = render(load_scene(str(path)), spp=1, seed=0)
    return plug[..., :3], core[..., :3]


def _rel_mse(a, b):
    return float(np.sum((a - b) ** 2) / max(np.sum(b ** 2), 1e-30))


@pytest.mark.slow
@pytest.mark.parametrize("n_quadrics", [3, 12], ids=["unrolled", "bvh"])
def test_shapes_without_bsdf_render_as_default_diffuse(variant, tmp_path, n_quadrics):
    from links1_mitsuba import tuning
    # 3 stays under the BVH threshold, 12 is over it (both sides of the rule that crashed)
    assert (n_quadrics >= tuning.current().bvh_min) == (n_quadrics == 12)
    images = {}
    for explicit in (False, True):
        path = tmp_path / f"mixed_{explicit}.xml"
        path.write_text(_scene(n_quadrics, explicit))
        plug, core = _render_both(path)
        assert np.all(np.isfinite(plug)) and np.all(np.isfinite(core))
        assert _rel_mse(plug, core) <= 1e-5, f"plugin vs core: {_rel_mse(plug, core):.3g}"
        images[explicit] = plug, core
    # no BSDF renders exactly as an explicit Mitsuba default diffuse, in each renderer
    for k in (0, 1):
        a, b = images[False][k], images[True][k]
        assert _rel_mse(a, b) <= 1e-10, ("plugin", "core")[k]
    assert np.any(images[False][1] > 0.05)   # lit, not a black image that would match anything
