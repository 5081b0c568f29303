"""The core's ``principled`` BSDF (:mod:`links1.shading.principled`) on its own: Burley's
diffuse term at a configuration worked by hand, the fully metallic white surface as a perfect
GGX reflector, densities that integrate to the fraction of samples drawn, samples whose mean
weight is the integral of ``eval``, reciprocity of the reflection lobes, and the loader.
Against Mitsuba's own plugin: ``tests/plugins/test_principled_vs_mitsuba.py``."""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from links1.errors import SceneError
from links1.scene import loader
from links1.shading import glossy
from links1.shading.principled import Principled, PrincipledThin
from tests.core.test_glossy_bsdfs import check_density_and_samples, check_reciprocal

Z = np.array([[0.0, 0.0, 1.0]])


def _dirs(*v):
    a = np.array(v, dtype=np.float64)
    return a / np.linalg.norm(a, axis=1)[:, None]


@pytest.mark.parametrize("roughness", [0.0, 0.3, 0.8])
def test_diffuse_term_is_burleys(roughness):
    """specular 0 (η = 1: no specular lobe); viewer along the normal, light at 60°:
    F_i = 0, F_o = (1 - cos 60°)^5 = 1/32, cos θ_d = cos 30°, R_R = 2 r cos² θ_d, so
    f cos θ_o = ρ/π · ½ · ((1 - ½ F_o) + R_R F_o) (Burley 2015, eq. 4)."""
    rho = np.array([0.8, 0.4, 0.2])
    b = Principled(base_color=rho, roughness=roughness, specular=0.0)
    wo, wi = _dirs([0, 0, 1]), _dirs([math.sin(math.pi / 3), 0, 0.5])
    f_o = 1.0 / 32.0
    rr = 2.0 * roughness * math.cos(math.pi / 6) ** 2
    expected = rho / math.pi * 0.5 * ((1.0 - 0.5 * f_o) + rr * f_o)
    np.testing.assert_allclose(b.eval(wo, wi, Z, Z)[0], expected, rtol=1e-12)


def test_white_metal_is_a_perfect_ggx_reflector():
    """metallic 1, base colour 1: Schlick's Fresnel of R0 = 1 is 1, so the BSDF is GGX's
    D G / (4 cos θ_i) of α = roughness², a roughconductor with no absorption."""
    rng = np.random.default_rng(3)
    a, c = rng.normal(size=(2, 500, 3))
    a[:, 2], c[:, 2] = np.abs(a[:, 2]), np.abs(c[:, 2])
    a, c = a / np.linalg.norm(a, axis=1)[:, None], c / np.linalg.norm(c, axis=1)[:, None]
    z = np.repeat(Z, 500, axis=0)
    b = Principled(base_color=1.0, metallic=1.0, roughness=0.6)
    ref = glossy.RoughConductor(distribution="ggx", alpha_u=0.36)
    np.testing.assert_allclose(b.eval(a, c, z, z), ref.eval(a, c, z, z), rtol=1e-12, atol=1e-15)


def _bsdfs():
    return {
        "default": Principled(),
        "every_lobe": Principled(base_color=[0.8, 0.3, 0.1], metallic=0.3, spec_tint=0.4, roughness=0.35,
                                 anisotropic=0.6, sheen=0.6, sheen_tint=0.5, clearcoat=0.7,
                                 clearcoat_gloss=0.6, flatness=0.4, specular=0.7),
        "glass": Principled(base_color=[0.9, 0.7, 0.8], spec_trans=0.8, eta=1.4, roughness=0.5),
        "clearcoat_rates": Principled(roughness=0.7, clearcoat=1.0, clearcoat_gloss=0.3,
                                      clearcoat_sampling_rate=4.0, diffuse_reflectance_sampling_rate=0.5),
        "thin": PrincipledThin(base_color=[0.3, 0.8, 0.5], spec_trans=0.6, diff_trans=0.8, eta=1.33,
                               roughness=0.5, spec_tint=0.3, sheen=0.5, sheen_tint=0.4, flatness=0.6),
    }


def _uniform_sphere(rng, m):
    v = rng.normal(size=(m, 3))
    return v / np.linalg.norm(v, axis=1)[:, None]


@pytest.mark.slow
@pytest.mark.parametrize("name", list(_bsdfs()))
def test_pdf_integrates_and_samples_follow_it(name):
    """∫ pdf dω = the fraction of samples drawn (uniform sphere estimate), and E[weight] over
    samples = ∫ eval dω, per viewer elevation (from below too, where light is transmitted).

    With ``spec_trans`` seen from above, Mitsuba picks the lobe with the Fresnel factor of
    the sampled microfacet but gives the density with that of the half vector of the
    direction drawn (a diffuse sample's half vector is not its microfacet): there ``pdf`` is
    not the sampler's density, in Mitsuba as here, and only the side below is checked."""
    b = _bsdfs()[name]
    check_density_and_samples(b, {"glass": (-0.6,), "thin": (0.9, 0.4, -0.6)}.get(name, (0.9, 0.4)), low=0.7)
    if name not in ("glass", "thin"):     # one-sided without transmission: nothing from below
        viewer = np.tile([0.8, 0.0, -0.6], (1000, 1))
        z = np.repeat(Z, 1000, axis=0)
        rng = np.random.default_rng(5)
        _, weight, pdf = b.sample(viewer, z, z, rng.random(1000), rng.random((1000, 2)))
        light = _uniform_sphere(rng, 1000)
        assert not np.any(pdf) and not np.any(weight) and not np.any(b.eval(viewer, light, z, z))


@pytest.mark.parametrize("name", ["default", "every_lobe", "clearcoat_rates", "thin"])
def test_reflection_is_reciprocal(name):
    """f(wo, wi) = f(wi, wo) for the reflection lobes (eval is f·cos θ of the light side)."""
    check_reciprocal(_bsdfs()[name])


def _material(body):
    """The shape's material; no warning about its bsdf (approximated, a parameter ignored)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sc = loader.load_string(f'<scene version="3.0.0"><shape type="sphere">{body}</shape></scene>')
    assert not [w for w in caught if "<bsdf" in str(w.message)]
    return sc.shapes[0].material


def test_loader_reads_mitsubas_parameters():
    m = _material('<bsdf type="principled"><rgb name="base_color" value="0.2, 0.4, 0.6"/>'
                  '<float name="specular" value="0.6"/><float name="clearcoat" value="0.5"/>'
                  '<texture name="metallic" type="checkerboard"/></bsdf>')
    assert isinstance(m, Principled) and m.roughness == 0.5 and m.clearcoat == 0.5
    np.testing.assert_allclose(m.base_color, [0.2, 0.4, 0.6])
    assert m.eta == pytest.approx(2.0 / (1.0 - math.sqrt(0.08 * 0.6)) - 1.0)
    assert m.has["metallic"] and m.has["clearcoat"] and not m.has["sheen"]
    assert _material('<bsdf type="principled"><float name="eta" value="1.33"/></bsdf>').eta == 1.33
    glass = _material('<bsdf type="principled"><float name="spec_trans" value="1"/><float name="eta" value="1"/></bsdf>')
    assert glass.eta == 1.001      # Mitsuba's stand-in for an index of 1 with transmission
    assert _material('<bsdf type="twosided"><bsdf type="principled"/></bsdf>').two_sided


def test_thin_sheet_is_alike_from_both_sides():
    """``principledthin``: eval, pdf and sample with every direction negated (seen from the
    other side) are the same, the sampled direction negated."""
    b = _bsdfs()["thin"]
    rng = np.random.default_rng(7)
    a, c = _uniform_sphere(rng, 1000), _uniform_sphere(rng, 1000)
    z = np.repeat(Z, 1000, axis=0)
    u, uv = rng.random(1000), rng.random((1000, 2))
    np.testing.assert_allclose(b.eval(a, c, z, z), b.eval(-a, -c, z, z), rtol=1e-12)
    np.testing.assert_allclose(b.pdf(a, c, z, z), b.pdf(-a, -c, z, z), rtol=1e-12)
    wi, w, p = b.sample(a, z, z, u, uv)
    wi_f, w_f, p_f = b.sample(-a, z, z, u, uv)
    np.testing.assert_allclose(-wi, wi_f, atol=1e-12)
    np.testing.assert_allclose(w, w_f, rtol=1e-12)
    assert np.array_equal(p, p_f) and np.mean(p > 0) > 0.9


def test_loader_reads_principledthin():
    m = _material('<bsdf type="principledthin"><float name="diff_trans" value="1.2"/>'
                  '<texture name="eta" type="checkerboard"/></bsdf>')
    assert isinstance(m, PrincipledThin) and m.diff_trans == 1.2 and m.roughness == 0.5
    assert m.has["eta"] and m.has["diff_trans"] and not m.has["spec_trans"]
    assert _material('<bsdf type="principledthin"/>').eta == 1.5


def test_loader_refuses_eta_and_specular_together():
    with pytest.raises(SceneError, match="either 'eta' or 'specular'"):
        _material('<bsdf type="principled"><float name="eta" value="1.5"/><float name="specular" value="0.5"/></bsdf>')
