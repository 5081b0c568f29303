"""The core's glossy BSDFs (:mod:`links1.shading.glossy`) on their own: densities that integrate
to one, samples whose mean weight is the integral of ``eval`` (the sampler draws what ``pdf``
says), Helmholtz reciprocity of the reflection lobes, and the loader's reading and refusals.
Against Mitsuba's own plugins: ``tests/plugins/test_glossy_bsdfs_vs_mitsuba.py``."""
from __future__ import annotations

import numpy as np
import pytest

from links1.errors import SceneError
from links1.scene import loader
from links1.shading import glossy

M = 200_000


def _bsdfs():
    return {
        "conductor_beckmann": glossy.RoughConductor(alpha_u=0.3),
        "conductor_ggx_aniso": glossy.RoughConductor(distribution="ggx", alpha_u=0.1, alpha_v=0.5,
                                                     eta=[0.2, 0.9, 1.1], k=[3.9, 2.4, 2.1]),
        "plastic": glossy.RoughPlastic(alpha=0.2, diffuse_reflectance=[0.7, 0.3, 0.2]),
        "dielectric_ggx": glossy.RoughDielectric(distribution="ggx", alpha_u=0.4),
        "blend": glossy.Blend(bsdf_0=glossy.RoughConductor(alpha_u=0.2),
                              bsdf_1=glossy.RoughPlastic(distribution="ggx", alpha=0.3), weight=0.4),
    }


def _uniform_sphere(rng, m):
    v = rng.normal(size=(m, 3))
    return v / np.linalg.norm(v, axis=1)[:, None]


@pytest.mark.slow
@pytest.mark.parametrize("name", list(_bsdfs()))
def test_pdf_integrates_to_one_and_samples_follow_it(name):
    """∫ pdf dω = 1 (uniform sphere estimate), and E[weight] over samples = ∫ eval dω, per
    viewer elevation: a sampler that drew other directions than ``pdf`` says fails both."""
    check_density_and_samples(_bsdfs()[name], (0.9, 0.4))


def check_density_and_samples(b, elevations, low=0.8):
    """∫ pdf dω (uniform sphere estimate) = the fraction of samples drawn, E[weight] = ∫ eval dω,
    for a viewer at each of ``elevations`` (cos θ) in the xz plane."""
    rng = np.random.default_rng(4)
    z = np.tile([0.0, 0.0, 1.0], (M, 1))
    for cos_v in elevations:
        viewer = np.tile([np.sqrt(1 - cos_v ** 2), 0.0, cos_v], (M, 1))
        light = _uniform_sphere(rng, M)
        integral_pdf = np.mean(b.pdf(viewer, light, z, z)) * 4 * np.pi
        integral_f = np.mean(b.eval(viewer, light, z, z), axis=0) * 4 * np.pi
        _, weight, pdf = b.sample(viewer, z, z, rng.random(M), rng.random((M, 2)))
        # visible normals can send some samples below the horizon (no sample, pdf 0): the
        # density integrates to the fraction of samples drawn
        assert low < integral_pdf <= 1.02
        assert integral_pdf == pytest.approx(np.mean(pdf > 0), rel=0.02)
        np.testing.assert_allclose(np.mean(weight, axis=0), integral_f, rtol=0.03)


@pytest.mark.parametrize("name", ["conductor_beckmann", "conductor_ggx_aniso", "blend"])
def test_reflection_is_reciprocal(name):
    """f(wo, wi) = f(wi, wo) for microfacet reflection (eval is f·cos θ of the light side)."""
    check_reciprocal(_bsdfs()[name])


def check_reciprocal(b):
    """``eval(a, c) / cos θ_c = eval(c, a) / cos θ_a`` on 1000 random pairs above the surface."""
    rng = np.random.default_rng(6)
    a, c = _uniform_sphere(rng, 1000), _uniform_sphere(rng, 1000)
    a[:, 2], c[:, 2] = np.abs(a[:, 2]) + 0.05, np.abs(c[:, 2]) + 0.05
    a, c = a / np.linalg.norm(a, axis=1)[:, None], c / np.linalg.norm(c, axis=1)[:, None]
    z = np.tile([0.0, 0.0, 1.0], (1000, 1))
    f_ac = b.eval(a, c, z, z) / c[:, 2:3]
    f_ca = b.eval(c, a, z, z) / a[:, 2:3]
    np.testing.assert_allclose(f_ac, f_ca, rtol=1e-10, atol=1e-12)


def _material(body):
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sc = loader.load_string(f'<scene version="3.0.0"><shape type="sphere">{body}</shape></scene>')
    return sc.shapes[0].material


@pytest.mark.slow
def test_loader_reads_mitsubas_parameters():
    m = _material('<bsdf type="twosided"><bsdf type="roughconductor"><string name="material" value="Cu"/>'
                  '<float name="alpha_u" value="0.1"/><float name="alpha_v" value="0.3"/>'
                  '<string name="distribution" value="ggx"/></bsdf></bsdf>')
    assert isinstance(m, glossy.RoughConductor) and m.two_sided and m.distribution == "ggx"
    assert (m.alpha_u, m.alpha_v) == (0.1, 0.3)
    np.testing.assert_allclose(m.eta, glossy.conductors()["Cu"][0])
    p = _material('<bsdf type="roughplastic"><float name="int_ior" value="1.6"/></bsdf>')
    assert p.eta == pytest.approx(1.6 / 1.000277) and p.distribution == "beckmann" and p.alpha == 0.1
    d = _material('<bsdf type="roughdielectric"/>')
    assert d.eta == pytest.approx(1.5046 / 1.000277)
    b = _material('<bsdf type="blendbsdf"><float name="weight" value="0.25"/><bsdf type="conductor"/>'
                  '<bsdf type="roughplastic"/></bsdf>')
    assert isinstance(b, glossy.Blend) and b.has_reflection and b.smooth
    r, _, _ = b.specular(np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, 0.0, 1.0]]), np.array([True]))
    np.testing.assert_allclose(r, 0.75)   # (1 - w) of the perfect mirror


@pytest.mark.parametrize("body, message", [
    ('<bsdf type="roughconductor"><string name="material" value="Xx"/></bsdf>', "unknown conductor material 'Xx'"),
    ('<bsdf type="roughconductor"><float name="alpha" value="0.1"/><float name="alpha_u" value="0.1"/>'
     '<float name="alpha_v" value="0.1"/></bsdf>', "either 'alpha' or"),
    ('<bsdf type="roughconductor"><float name="alpha_u" value="0.1"/></bsdf>', "both 'alpha_u' and 'alpha_v'"),
    ('<bsdf type="roughplastic"><float name="alpha_u" value="0.1"/><float name="alpha_v" value="0.2"/></bsdf>',
     "anisotropic"),
    ('<bsdf type="roughdielectric"><string name="distribution" value="phong"/></bsdf>', "invalid distribution"),
    ('<bsdf type="blendbsdf"><bsdf type="diffuse"/></bsdf>', "exactly two nested bsdfs"),
])
def test_loader_refuses_what_mitsuba_refuses(body, message):
    with pytest.raises(SceneError, match=message):
        _material(body)
