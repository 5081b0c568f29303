"""The core's glossy BSDFs (``roughconductor``, ``roughplastic``, ``roughdielectric``,
``blendbsdf``; :mod:`links1.shading.glossy`) against Mitsuba's own plugins, direction by
direction: ``eval`` and ``pdf`` on random pairs of directions (both hemispheres), ``sample``
with the same sample values (direction, weight, density), the conductor presets' RGB table,
and a render under a point light (delta light: exact) against Mitsuba's ``direct`` without
BSDF samples.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from tests.scenes import integrator, perspective, scene

pytestmark = pytest.mark.mitsuba

N = 1500

CASES = {
    "roughconductor": '<bsdf type="roughconductor"/>',
    "roughconductor_au_ggx": ('<bsdf type="roughconductor"><string name="material" value="Au"/>'
                              '<float name="alpha" value="0.3"/><string name="distribution" value="ggx"/>'
                              '<rgb name="specular_reflectance" value="0.9, 0.8, 0.7"/></bsdf>'),
    "roughconductor_anisotropic": ('<bsdf type="roughconductor"><rgb name="eta" value="0.2, 0.9, 1.1"/>'
                                   '<rgb name="k" value="3.9, 2.4, 2.1"/><float name="alpha_u" value="0.05"/>'
                                   '<float name="alpha_v" value="0.4"/></bsdf>'),
    "roughconductor_not_visible": ('<bsdf type="roughconductor"><boolean name="sample_visible" value="false"/>'
                                   '<float name="alpha" value="0.2"/></bsdf>'),
    "roughconductor_textured_alpha": ('<bsdf type="roughconductor"><texture name="alpha" type="checkerboard">'
                                      '<float name="color0" value="0.1"/><float name="color1" value="0.4"/>'
                                      '<transform name="to_uv"><scale value="4"/></transform></texture></bsdf>'),
    "twosided_roughconductor": '<bsdf type="twosided"><bsdf type="roughconductor"><float name="alpha" value="0.25"/></bsdf></bsdf>',
    "roughplastic": '<bsdf type="roughplastic"/>',
    "roughplastic_ggx_nonlinear": ('<bsdf type="roughplastic"><string name="distribution" value="ggx"/>'
                                   '<float name="alpha" value="0.3"/><rgb name="diffuse_reflectance" value="0.8, 0.2, 0.1"/>'
                                   '<boolean name="nonlinear" value="true"/><float name="int_ior" value="1.7"/></bsdf>'),
    "roughdielectric": '<bsdf type="roughdielectric"/>',
    "roughdielectric_ggx": ('<bsdf type="roughdielectric"><string name="distribution" value="ggx"/>'
                            '<float name="alpha" value="0.3"/><float name="int_ior" value="1.33"/>'
                            '<rgb name="specular_transmittance" value="0.9, 0.7, 1"/></bsdf>'),
    "blend_roughconductor_diffuse": ('<bsdf type="blendbsdf"><float name="weight" value="0.3"/>'
                                     '<bsdf type="roughconductor"/><bsdf type="diffuse"/></bsdf>'),
    "blend_roughplastic_roughdielectric": ('<bsdf type="blendbsdf"><float name="weight" value="0.6"/>'
                                           '<bsdf type="roughplastic"/><bsdf type="roughdielectric">'
                                           '<float name="alpha" value="0.2"/></bsdf></bsdf>'),
}


def _core_material(bsdf_xml):
    from links1.scene.loader import load_string
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sc = load_string(f'<scene version="3.0.0"><shape type="sphere">{bsdf_xml}</shape></scene>')
    return sc.shapes[0].material


def _directions(seed=1):
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(2, N, 3))
    v /= np.linalg.norm(v, axis=2)[..., None]
    viewer, light = v
    viewer[:, 2] = np.abs(viewer[:, 2])
    viewer[: N // 8, 2] *= -1      # some viewers below the surface
    f32 = lambda a: a.astype(np.float32).astype(np.float64)   # what Mitsuba receives
    return f32(viewer), f32(light), f32(rng.random(N)), f32(rng.random((N, 2)))


def _mitsuba(bsdf_xml, viewer, light, u, uv):
    import drjit as dr
    import mitsuba as mi
    bsdf = mi.load_string(bsdf_xml.replace("<bsdf ", '<bsdf version="3.0.0" ', 1))
    ctx = mi.BSDFContext()
    si = dr.zeros(mi.SurfaceInteraction3f, N)
    si.sh_frame = mi.Frame3f(mi.Normal3f(0, 0, 1))
    si.wi = mi.Vector3f(*viewer.T)
    si.uv = mi.Point2f(*uv.T)           # where textures are looked up (the sample values reused)
    wo = mi.Vector3f(*light.T)
    bs, weight = bsdf.sample(ctx, si, mi.Float(u), mi.Point2f(*uv.T))
    return (np.array(bsdf.eval(ctx, si, wo), dtype=np.float64).T,
            np.array(bsdf.pdf(ctx, si, wo), dtype=np.float64),
            np.array(bs.wo, dtype=np.float64).T, np.array(weight, dtype=np.float64).T,
            np.array(bs.pdf, dtype=np.float64))


def _core(m, viewer, light, u, uv):
    z = np.tile([0.0, 0.0, 1.0], (N, 1))
    n = z * np.where(viewer[:, 2] >= 0, 1.0, -1.0)[:, None]    # the normal facing the viewer
    wi, weight, pdf = m.sample(viewer, n, z, u, uv)
    return m.eval(viewer, light, n, z), m.pdf(viewer, light, n, z), wi, weight, pdf


def _close(a, b, rtol, floor=1e-3, slack=0.0):
    """``a`` within ``rtol`` (relative, above ``floor``) plus ``slack`` (per lane) of ``b``."""
    err = np.abs(a - b) / np.maximum(np.abs(b), floor)
    if np.ndim(err) > 1:
        err = np.max(err, axis=1)
    return bool(np.all(err <= rtol + slack)), float(np.max(err - slack))


def _float32_sensitivity(fn, viewer, light, floor=1e-3):
    """How much ``fn(viewer, light)`` moves (relative) when the directions move by float32
    rounding: the largest change over three random perturbations of 1e-7."""
    rng = np.random.default_rng(5)
    base = fn(viewer, light)
    out = np.zeros(viewer.shape[0])
    for _ in range(3):
        d = fn(viewer + rng.normal(size=viewer.shape) * 1e-7, light + rng.normal(size=light.shape) * 1e-7)
        err = np.abs(d - base) / np.maximum(np.abs(base), floor)
        out = np.maximum(out, err.max(axis=1) if err.ndim > 1 else err)
    return out


@pytest.mark.slow
@pytest.mark.parametrize("case", list(CASES))
def test_eval_pdf_sample_match_mitsuba(case, variant):
    """f·cos, the density and BSDF samples (same sample values) equal Mitsuba's to float32
    rounding. Mitsuba leaves ``pdf`` unmasked where it has no sample (``bs.pdf`` of an invalid
    sample, roughplastic's density below the horizon): those lanes are compared through the
    weights (0) only."""
    def lit(viewer, light):
        on = (light[:, 2] * viewer[:, 2] > 0) | case.startswith(("roughdielectric", "blend_roughplastic"))
        return on & (viewer[:, 2] > 0) if "blend" in case or "plastic" in case else on
    check_against_mitsuba(CASES[case], lit)


def check_against_mitsuba(bsdf_xml, lit=None, seed=1):
    """The core's ``eval``, ``pdf`` and ``sample`` of ``bsdf_xml`` equal Mitsuba's on random
    directions; ``lit(viewer, light)``: the lanes whose ``pdf`` is compared (default: where
    Mitsuba's is finite)."""
    viewer, light, u, uv = _directions(seed)
    E, P, WO, W, PS = _mitsuba(bsdf_xml, viewer, light, u, uv)
    m = _core_material(bsdf_xml).at(uv)
    e, p, wo, w, ps = _core(m, viewer, light, u, uv)
    z = np.tile([0.0, 0.0, 1.0], (N, 1))
    n = z * np.where(viewer[:, 2] >= 0, 1.0, -1.0)[:, None]
    # beyond 2e-5, the differences float32 rounding of the directions alone makes (rough glass
    # refracting near grazing: up to ~5e-4)
    slack = 10.0 * _float32_sensitivity(lambda a, b: m.eval(a, b, n, z), viewer, light)
    ok, err = _close(e, E, 2e-5, slack=slack)
    assert ok, ("eval", err)
    lit = np.isfinite(P) if lit is None else lit(viewer, light)
    slack = 10.0 * _float32_sensitivity(lambda a, b: m.pdf(a, b, n, z), viewer, light)
    ok, err = _close(p[lit], P[lit], 2e-5, slack=slack[lit])
    assert ok, ("pdf", err)
    # sample weights; grazing viewers and samples are ill-conditioned in float32 (the direction
    # moves by up to ~1e-4), so the tight bound holds away from the horizon. Mitsuba's blend
    # gives NaN for a viewer below a one-sided diffuse lobe: those lanes are left out.
    finite = np.all(np.isfinite(W), axis=1)
    ok, err = _close(w[finite], W[finite], 5e-3)
    assert ok, ("sample weight", err)
    tame = finite & (np.abs(viewer[:, 2]) > 0.1) & (np.abs(WO[:, 2]) > 0.02)
    ok, err = _close(w[tame], W[tame], 5e-4)
    assert ok, ("sample weight away from the horizon", err)
    valid = finite & np.any(W > 0, axis=1)
    assert valid.sum() > N // 2
    assert np.max(np.abs(wo[valid] - WO[valid])) < 5e-4
    # the density of a sample: the core's pdf() of its own sample, and of Mitsuba's direction
    drawn = ps > 0
    assert np.allclose(ps[drawn], m.pdf(viewer, wo, n, z)[drawn], rtol=1e-9, atol=0)
    assert np.array_equal(drawn, np.any(w > 0, axis=1))
    slack = 10.0 * _float32_sensitivity(lambda a, b: m.pdf(a, b, n, z), viewer, WO)
    ok, err = _close(m.pdf(viewer, WO, n, z)[valid], PS[valid], 2e-4, slack=slack[valid])
    assert ok, ("sample pdf", err)


@pytest.mark.slow
def test_blend_delta_lobe_is_a_weighted_mirror_ray(variant):
    """A ``blendbsdf`` holding a smooth ``conductor``: the mirror ray's weight is (1 − w) times
    the conductor's Fresnel (Mitsuba's own conductor sample), its glossy part w times the
    nested roughplastic, and BSDF sampling draws from the glossy part alone."""
    import drjit as dr
    import mitsuba as mi
    w = 0.35
    xml = (f'<bsdf type="blendbsdf"><float name="weight" value="{w}"/><bsdf type="conductor">'
           '<string name="material" value="Cu"/></bsdf><bsdf type="roughplastic"/></bsdf>')
    m = _core_material(xml)
    viewer, light, u, uv = _directions(2)
    up = viewer[:, 2] > 0
    z = np.tile([0.0, 0.0, 1.0], (N, 1))
    r, t, _ = m.specular(viewer[up], z[up], np.ones(up.sum(), dtype=bool))
    cond = mi.load_dict({"type": "conductor", "material": "Cu"})
    si = dr.zeros(mi.SurfaceInteraction3f, int(up.sum()))
    si.wi = mi.Vector3f(*viewer[up].T)
    _, fres = cond.sample(mi.BSDFContext(), si, mi.Float(0.5), mi.Point2f(0.5, 0.5))
    assert np.allclose(r, (1 - w) * np.array(fres, dtype=np.float64).T, rtol=2e-5, atol=1e-7)
    assert not np.any(t)
    plastic = _core_material('<bsdf type="roughplastic"/>')
    assert np.allclose(m.eval(viewer, light, z, z), w * plastic.eval(viewer, light, z, z))
    wi, weight, pdf = m.sample(viewer, z, z, u, uv)
    wi2, _, pdf2 = plastic.sample(viewer, z, z, u, uv)
    assert np.allclose(wi, wi2) and np.allclose(pdf, pdf2)


def test_conductor_presets_are_mitsubas(scalar_rgb):
    """Every ``material`` preset's RGB (eta, k) equals what Mitsuba's RGB variants load."""
    import mitsuba as mi
    from links1.shading import glossy
    table = glossy.conductors()
    assert len(table) > 60
    for name, (eta, k) in table.items():
        params = mi.traverse(mi.load_dict({"type": "roughconductor", "material": name}))
        assert np.allclose(eta, np.array(params["eta.value"]), rtol=1e-6), name
        assert np.allclose(k, np.array(params["k.value"]), rtol=1e-6), name


SCENE = scene(perspective("0, 2.5, 6", "0, 0.5, 0", fov=40, width=40, height=32, spp=4), "{integrator}", """
  <emitter type="point"><point name="position" x="1.5" y="4" z="3"/><rgb name="intensity" value="30, 28, 25"/></emitter>
  <shape type="rectangle"><transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/></transform>
    {floor}</shape>
  <shape type="sphere"><point name="center" x="-1.2" y="0.8" z="0"/><float name="radius" value="0.8"/>
    {left}</shape>
  <shape type="sphere"><point name="center" x="0.9" y="0.8" z="0"/><float name="radius" value="0.8"/>
    {right}</shape>""")


@pytest.mark.slow
def test_point_light_render_matches_direct(variant):
    """Under a point light the glossy BSDFs are evaluated exactly: the core at max_depth 1 equals
    Mitsuba's ``direct`` with ``bsdf_samples`` 0 (the same light paths) to the noise of pixel
    sampling."""
    check_point_light_render(
        variant,
        floor='<bsdf type="roughplastic"><rgb name="diffuse_reflectance" value="0.3, 0.5, 0.6"/>'
              '<float name="alpha" value="0.2"/></bsdf>',
        left='<bsdf type="roughconductor"><string name="material" value="Au"/><float name="alpha" value="0.25"/></bsdf>',
        right='<bsdf type="blendbsdf"><float name="weight" value="0.5"/><bsdf type="roughconductor">'
              '<string name="distribution" value="ggx"/><float name="alpha" value="0.1"/></bsdf>'
              '<bsdf type="roughdielectric"><float name="alpha" value="0.15"/></bsdf></bsdf>')


def check_point_light_render(variant, **bsdfs):
    """A floor and two spheres with the given bsdfs (``floor``, ``left``, ``right``) under a
    point light: the core at max_depth 1 equals Mitsuba's ``direct`` without BSDF samples
    (relMSE < 2e-3 at 64 vs 256 spp), and the core loads them without a warning about a bsdf."""
    import mitsuba as mi
    import links1
    from links1.scene.loader import load_string
    from links1_mitsuba import load_string as mi_load
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        core = links1.render(load_string(SCENE.format(integrator="", **bsdfs)), spp=64, max_depth=1)
    assert not [w for w in caught if "<bsdf" in str(w.message)]
    direct = integrator("direct", bsdf_samples=0)
    sc = mi_load(SCENE.format(integrator=direct, **bsdfs), links1_integrator="scene", variant=variant)
    ref = np.array(mi.render(sc, spp=256), dtype=np.float64)[..., :3]
    err = float(np.sum((core - ref) ** 2) / np.sum(ref ** 2))
    assert err < 2e-3, err
    assert abs(core.mean() - ref.mean()) / ref.mean() < 1e-2
    return err
