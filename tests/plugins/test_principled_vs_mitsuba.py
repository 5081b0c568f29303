"""The core's ``principled`` BSDF (:mod:`links1.shading.principled`) against Mitsuba's own
plugin, direction by direction: ``eval`` and ``pdf`` on random pairs of directions (both
hemispheres), ``sample`` with the same sample values (direction, weight, density), and a
render under a point light (delta light: exact) against Mitsuba's ``direct`` without BSDF
samples. The comparison helpers are those of the glossy BSDFs' test."""
from __future__ import annotations

import pytest

from tests.plugins.test_glossy_bsdfs_vs_mitsuba import check_against_mitsuba, check_point_light_render

pytestmark = pytest.mark.mitsuba

_CHECKER = ('<texture name="{0}" type="checkerboard"><float name="color0" value="{1}"/>'
            '<float name="color1" value="{2}"/><transform name="to_uv"><scale value="4"/></transform></texture>')

CASES = {
    "default": '<bsdf type="principled"/>',
    "every_lobe": ('<bsdf type="principled"><rgb name="base_color" value="0.8, 0.3, 0.1"/>'
                   '<float name="metallic" value="0.3"/><float name="spec_tint" value="0.4"/>'
                   '<float name="roughness" value="0.35"/><float name="anisotropic" value="0.6"/>'
                   '<float name="sheen" value="0.6"/><float name="sheen_tint" value="0.5"/>'
                   '<float name="clearcoat" value="0.7"/><float name="clearcoat_gloss" value="0.6"/>'
                   '<float name="flatness" value="0.4"/><float name="specular" value="0.7"/></bsdf>'),
    "glass": ('<bsdf type="principled"><rgb name="base_color" value="0.9, 0.7, 0.8"/>'
              '<float name="spec_trans" value="0.8"/><float name="eta" value="1.4"/>'
              '<float name="roughness" value="0.3"/><float name="metallic" value="0.1"/></bsdf>'),
    "metal_rates": ('<bsdf type="principled"><rgb name="base_color" value="0.9, 0.6, 0.3"/>'
                    '<float name="metallic" value="0.9"/><float name="roughness" value="0.25"/>'
                    '<float name="clearcoat" value="0.5"/><float name="clearcoat_sampling_rate" value="3"/>'
                    '<float name="diffuse_reflectance_sampling_rate" value="0.5"/></bsdf>'),
    "textured": ('<bsdf type="principled">' + _CHECKER.format("roughness", 0.2, 0.6)
                 + _CHECKER.format("metallic", 0.0, 0.8) + _CHECKER.format("spec_trans", 0.5, 0.1)
                 + '<texture name="base_color" type="checkerboard"><rgb name="color0" value="0.7, 0.2, 0.2"/>'
                 '<rgb name="color1" value="0.1, 0.5, 0.9"/></texture>'
                 '<float name="spec_tint" value="0.5"/><float name="sheen" value="0.3"/></bsdf>'),
    "twosided": ('<bsdf type="twosided"><bsdf type="principled"><float name="roughness" value="0.4"/>'
                 '<float name="clearcoat" value="0.3"/></bsdf></bsdf>'),
    "thin_default": '<bsdf type="principledthin"/>',
    "thin_every_lobe": ('<bsdf type="principledthin"><rgb name="base_color" value="0.3, 0.8, 0.5"/>'
                        '<float name="spec_trans" value="0.6"/><float name="diff_trans" value="0.8"/>'
                        '<float name="eta" value="1.33"/><float name="roughness" value="0.4"/>'
                        '<float name="anisotropic" value="0.5"/><float name="spec_tint" value="0.3"/>'
                        '<float name="sheen" value="0.5"/><float name="sheen_tint" value="0.4"/>'
                        '<float name="flatness" value="0.6"/>'
                        '<float name="diffuse_transmittance_sampling_rate" value="2"/></bsdf>'),
    "thin_textured": ('<bsdf type="principledthin">' + _CHECKER.format("spec_trans", 0.9, 0.2)
                      + _CHECKER.format("eta", 1.2, 1.7) + _CHECKER.format("diff_trans", 0.3, 1.5)
                      + '<float name="roughness" value="0.3"/></bsdf>'),
}


@pytest.mark.parametrize("case", list(CASES))
def test_eval_pdf_sample_match_mitsuba(case, variant):
    """f·cos, the density and BSDF samples (same sample values) equal Mitsuba's to float32
    rounding (beyond 2e-5 relative: what float32 rounding of the directions alone moves)."""
    check_against_mitsuba(CASES[case], seed=3)


@pytest.mark.slow
def test_point_light_render_matches_direct(variant):
    """Under a point light the principled BSDF is evaluated exactly: the core at max_depth 1
    equals Mitsuba's ``direct`` with ``bsdf_samples`` 0 (the same light paths) to the noise of
    pixel sampling (relMSE of Mitsuba's own 64 spp against 256 spp: ~3e-4 per object), the
    anisotropic lobes turned about the sphere's dp/du as Mitsuba's."""
    check_point_light_render(variant, floor=CASES["textured"], right=CASES["glass"], left=CASES["every_lobe"])


@pytest.mark.slow
def test_thin_point_light_render_matches_direct(variant):
    """``principledthin`` likewise: a floor lit from above, spheres seen by the light through their
    diffuse and glossy transmission (thin sheets alike from both sides)."""
    check_point_light_render(variant, floor=CASES["thin_textured"], right=CASES["thin_default"],
                             left=CASES["thin_every_lobe"])
