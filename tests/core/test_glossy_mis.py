"""BSDF samples with multiple importance sampling in the core (glossy materials under area and
environment lights).

The light densities first: each sampled light's ``pdf`` is the density its ``sample`` draws
with (at the sampled directions) and an environment's integrates to one over the sphere (a
quadrature). Then the estimator: under a ``constant`` sky a rough mirror's radiance converges to
the sky times the integral of its BSDF's cosine-weighted ``eval`` over the hemisphere (a
quadrature), so the power-heuristic weights of the light and BSDF samples sum to one. The
comparison with Mitsuba's ``direct`` and with the plugin lives in
``tests/plugins/test_glossy_mis_vs_mitsuba.py``.
"""
from __future__ import annotations

import numpy as np
import pytest

from links1 import load_scene
from links1.imaging.image import write_exr
from links1.maths.sampling import mix32
from links1.shading.lights import AreaLight
from links1.tracing.integrator import WhittedIntegrator

LIGHTS = {
    "rectangle": """<shape type="rectangle"><transform name="to_world"><scale value="0.7"/><rotate x="1" angle="70"/>
      <translate value="0.5, 3, 0.3"/></transform><emitter type="area"><rgb name="radiance" value="8"/></emitter></shape>""",
    "disk": """<shape type="disk"><transform name="to_world"><scale value="0.6"/><rotate x="1" angle="100"/>
      <translate value="-0.5, 3, 0.3"/></transform><emitter type="area"><rgb name="radiance" value="8"/></emitter></shape>""",
    "sphere": """<shape type="sphere"><point name="center" value="-1, 2.6, 0.8"/><float name="radius" value="0.3"/>
      <emitter type="area"><rgb name="radiance" value="10"/></emitter></shape>""",
    "constant": '<emitter type="constant"><rgb name="radiance" value="0.8, 0.9, 1.1"/></emitter>',
    "envmap": """<emitter type="envmap"><string name="filename" value="env.exr"/>
      <transform name="to_world"><rotate y="1" angle="30"/><rotate x="1" angle="20"/></transform></emitter>""",
}


def _scene(tmp_path, light, floor='<bsdf type="diffuse"/>'):
    env = np.broadcast_to(0.2 + 0.3 * (np.arange(16)[:, None, None] < 8) * np.array([0.6, 0.8, 1.0]), (16, 32, 3)).copy()
    env[3:5, 20:23] = [40.0, 30.0, 20.0]
    write_exr(tmp_path / "env.exr", env.astype(np.float32))
    p = tmp_path / "s.xml"
    p.write_text(f"""<scene version="3.0.0">
  <sensor type="perspective"><transform name="to_world"><lookat origin="0, 4, 0.01" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/><rfilter type="box"/></film></sensor>
  <shape type="rectangle"><transform name="to_world"><scale value="50"/><rotate x="1" angle="-90"/></transform>{floor}</shape>
  {light}
</scene>""")
    return load_scene(str(p))


def _sampled(scene):
    return next(lt for lt in scene.lights if getattr(lt, "sampled", False))


@pytest.mark.parametrize("kind", list(LIGHTS))
def test_light_pdf_is_the_density_its_sample_draws_with(kind, tmp_path):
    light = _sampled(_scene(tmp_path, LIGHTS[kind]))
    rng = np.random.default_rng(3)
    n = 2000
    p = rng.uniform(-1.0, 1.0, (n, 3)) * [2.0, 0.0, 2.0] + [0.0, 0.2, 0.0]
    nrm = np.tile([0.0, 1.0, 0.0], (n, 1))
    u, v = rng.uniform(size=n), rng.uniform(size=n)
    wi, dist, Lw, pdf = light.sample_pdf(p, nrm, u, v)
    ng = None
    if isinstance(light, AreaLight) and light.kind == "mesh":
        ng = np.broadcast_to(light.normals[0], (n, 3))
    elif isinstance(light, AreaLight) and light.kind == "disk":
        ng = np.broadcast_to(light.normal, (n, 3))
    ok = pdf > 0
    assert ok.mean() > 0.5
    np.testing.assert_allclose(light.pdf(p[ok], nrm[ok], wi[ok], dist[ok], None if ng is None else ng[ok]),
                               pdf[ok], rtol=1e-9)
    # and the sample's weight is L_e / pdf (untextured lights: L_e is the radiance)
    if kind != "envmap":
        L = light.radiance
        np.testing.assert_allclose(Lw[ok], L * (1.0 / pdf[ok])[:, None], rtol=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["constant", "envmap"])
def test_environment_pdf_integrates_to_one(kind, tmp_path):
    light = _sampled(_scene(tmp_path, LIGHTS[kind]))
    nt, nph = 1200, 2400     # midpoint quadrature over (θ, φ)
    th = (np.arange(nt) + 0.5) * np.pi / nt
    ph = (np.arange(nph) + 0.5) * 2.0 * np.pi / nph
    T, P = np.meshgrid(th, ph, indexing="ij")
    d = np.stack([np.sin(T) * np.cos(P), np.cos(T), np.sin(T) * np.sin(P)], axis=-1).reshape(-1, 3)
    nrm = np.tile([0.0, 1.0, 0.0], (d.shape[0], 1))
    pdf = light.pdf(np.zeros_like(d), nrm, d)
    integral = np.sum(pdf * np.sin(T).ravel()) * (np.pi / nt) * (2.0 * np.pi / nph)
    assert integral == pytest.approx(1.0, abs=2e-3)


def test_rough_mirror_under_a_constant_sky_converges_to_its_reflectance(tmp_path):
    """Light samples (cosine about the normal) and BSDF samples weighted by the power heuristic
    estimate L ∫ f cos dω: the weights of the two strategies sum to one."""
    floor = ('<bsdf type="roughconductor"><string name="material" value="none"/>'
             '<float name="alpha" value="0.3"/></bsdf>')
    L = np.array([0.8, 0.9, 1.1])
    scene = _scene(tmp_path, LIGHTS["constant"], floor)
    # a glossy material under a sampled light: the hits take BSDF samples as well
    assert scene.shapes[0].material.glossy and scene.lights[0].sampled
    integ = WhittedIntegrator(scene, max_depth=1)
    n = 8192
    wo = np.array([0.0, 1.0, 0.0])
    o = np.tile(wo * 0.5, (n, 1))
    keys = mix32(np.arange(n, dtype=np.uint32))
    est, _, _ = integ.trace(o, np.tile(-wo, (n, 1)), np.zeros(n), np.full(n, np.inf),
                            np.zeros(n, dtype=np.int64), keys=keys,
                            sample=(np.full(n, 12345, dtype=np.uint32), np.arange(n), n))
    # the reflectance ∫ f cos dω by a midpoint quadrature of the material's own eval
    mat = scene.shapes[0].material
    nt, nph = 800, 64
    th = (np.arange(nt) + 0.5) * (0.5 * np.pi) / nt
    ph = (np.arange(nph) + 0.5) * 2.0 * np.pi / nph
    T, P = np.meshgrid(th, ph, indexing="ij")
    wi = np.stack([np.sin(T) * np.cos(P), np.cos(T), np.sin(T) * np.sin(P)], axis=-1).reshape(-1, 3)
    m = wi.shape[0]
    up = np.tile(wo, (m, 1))
    f = mat.eval(up, wi, up, up)
    refl = np.sum(f * np.sin(T).ravel()[:, None], axis=0) * (0.5 * np.pi / nt) * (2.0 * np.pi / nph)
    assert 0.5 < refl[0] < 1.0
    np.testing.assert_allclose(est.mean(axis=0), L * refl, rtol=2e-3)
