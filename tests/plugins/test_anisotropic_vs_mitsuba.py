"""Anisotropic roughness in the core's shading frame against the plugin's (Mitsuba's own
``si.sh_frame``): ``roughconductor`` with ``alpha_u != alpha_v`` and ``principled`` with
``anisotropic`` on a rectangle, spheres, a cylinder, a disk and two ``obj`` meshes (with texcoords
turned 35 degrees from the mesh's axes, and without: barycentric ``dp_du``), under a point light
(evaluated exactly) and an area light (light and BSDF samples by MIS). Mitsuba turns the
lobes about the tangent of the shape's ``dp_du``, so the core, rendering the same samples,
equals the plugin; with ``coordinate_system(n)``'s tangent instead it would not.
"""
from __future__ import annotations

import numpy as np
import pytest

from tests.scenes import perspective, scene

from .conftest import assert_both_match_mitsuba_direct
from .test_normalmaps_vs_mitsuba import _render

pytestmark = pytest.mark.mitsuba

CONDUCTOR = ('<bsdf type="roughconductor"><string name="material" value="Al"/><string name="distribution" '
             'value="ggx"/><float name="alpha_u" value="0.05"/><float name="alpha_v" value="0.35"/></bsdf>')
PRINCIPLED = ('<bsdf type="principled"><rgb name="base_color" value="0.8, 0.5, 0.2"/><float name="metallic" '
              'value="0.7"/><float name="roughness" value="0.4"/><float name="anisotropic" value="0.9"/></bsdf>')
LIGHTS = {
    "point": ('<emitter type="point"><point name="position" x="1.5" y="4" z="3"/>'
              '<rgb name="intensity" value="30, 28, 25"/></emitter>'),
    "area": ('<shape type="rectangle"><transform name="to_world"><scale value="0.8"/><rotate x="1" angle="120"/>'
             '<translate x="1" y="3" z="2.5"/></transform><emitter type="area">'
             '<rgb name="radiance" value="8, 7.5, 7"/></emitter></shape>'),
}
BODY = """{light}
  <shape type="rectangle"><transform name="to_world"><scale x="3" y="2"/><rotate x="1" angle="-90"/>
    <rotate y="1" angle="30"/></transform>{c}</shape>
  <shape type="sphere"><point name="center" x="-1.1" y="0.8" z="0"/><float name="radius" value="0.8"/>{p}</shape>
  <shape type="obj"><string name="filename" value="grid_uv.obj"/><transform name="to_world"><scale value="0.8"/>
    <rotate x="1" angle="20"/><translate x="1.0" y="0.8" z="0.2"/></transform>{c}</shape>
  <shape type="obj"><string name="filename" value="grid.obj"/><transform name="to_world"><scale value="0.5"/>
    <rotate x="1" angle="50"/><translate x="-1.6" y="0.6" z="1.4"/></transform>{p}</shape>
  <shape type="sphere"><point name="center" x="0.1" y="1.9" z="-0.8"/><float name="radius" value="0.5"/>{c}</shape>
  <shape type="cylinder"><point name="p0" x="1.9" y="0.1" z="-1"/><point name="p1" x="2.1" y="1.6" z="-1.2"/>
    <float name="radius" value="0.35"/>{p}</shape>
  <shape type="disk"><transform name="to_world"><scale value="0.5"/><rotate x="1" angle="-60"/>
    <translate x="0.2" y="0.4" z="1.6"/></transform>{c}</shape>"""


def write_grids(d, n: int = 10) -> None:
    """A wavy n x n grid, as ``grid_uv.obj`` with texcoords turned 35 degrees from its x axis
    (``dp_du`` along that turned axis) and as ``grid.obj`` without (``dp_du`` = an edge)."""
    xs = np.linspace(-1.0, 1.0, n + 1)
    X, Z = np.meshgrid(xs, xs)
    Y = 0.15 * np.sin(2 * X) * np.cos(1.5 * Z)
    a = np.radians(35.0)
    U = 0.5 + 0.5 * (np.cos(a) * X + np.sin(a) * Z)
    V = 0.5 + 0.5 * (-np.sin(a) * X + np.cos(a) * Z)
    v = "".join(f"v {x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in zip(X.ravel(), Y.ravel(), Z.ravel()))
    vt = "".join(f"vt {u:.17g} {w:.17g}\n" for u, w in zip(U.ravel(), V.ravel()))
    quads = [(i * (n + 1) + j + 1) for i in range(n) for j in range(n)]
    tris = [t for k in quads for t in ((k, k + n + 1, k + n + 2), (k, k + n + 2, k + 1))]
    for name, head, fmt in (("grid_uv.obj", v + vt, "{0}/{0}"), ("grid.obj", v, "{0}")):
        faces = "".join("f " + " ".join(fmt.format(x) for x in t) + "\n" for t in tris)
        (d / name).write_text(head + faces)


@pytest.mark.slow
@pytest.mark.parametrize("light", list(LIGHTS))
def test_anisotropic_lobes_turn_with_dp_du(light, tmp_path, variant, monkeypatch):
    """Each renderer within 1.5x the relMSE of Mitsuba's ``direct`` at 16 spp against a 16x
    reference, the core equal to the plugin (relMSE <= 1e-4); and the same core render with the
    lobes turned about ``coordinate_system(n)`` instead departs from the plugin (relMSE > 1e-2),
    so the scene tells the two frames apart."""
    from links1.imaging.diff import relmse
    from links1.maths.vec import coordinate_system
    from links1.tracing.integrator import WhittedIntegrator
    write_grids(tmp_path)
    path = tmp_path / "aniso.xml"
    path.write_text(scene(perspective("0, 2.5, 6", "0, 0.7, 0", fov=40, width=48, height=36, spp=None),
                          BODY.format(light=LIGHTS[light], c=CONDUCTOR, p=PRINCIPLED)))
    assert_both_match_mitsuba_direct(str(path), 16, _render)
    plugin = _render("mitsuba", str(path), 16)
    monkeypatch.setattr(WhittedIntegrator, "_shading_tangents",
                        lambda self, o, d, hits, sel, ns: coordinate_system(ns)[0])
    assert relmse(plugin, _render("core", str(path), 16)) > 1e-2
