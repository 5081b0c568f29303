"""Spectra → RGB in the core (links1.shading.spectra, the loader): closed-form expectations and errors.

Value-by-value agreement with Mitsuba is in tests/plugins/test_spectra_vs_mitsuba.py.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from links1.shading import spectra
from links1.errors import SceneError
from links1.scene.loader import load_string
from links1.scene.xmlparse import SceneWarning

LUMINANCE = np.array([0.212671, 0.715160, 0.072169])  # Mitsuba's luminance weights


def test_tables_are_mitsubas_cie_and_d65():
    xyz, d65 = spectra.cie_tables()
    assert xyz.shape == (95, 3) and d65.shape == (95,)
    assert d65[40] == pytest.approx(100.0)  # D65 is normalised to 100 at 560 nm
    assert np.argmax(xyz[:, 1]) == 39  # y-bar peaks at 555 nm
    assert xyz[39, 1] == pytest.approx(1.0, abs=1e-6)


def test_equal_energy_emitter_has_unit_luminance():
    # Mitsuba scales the CIE curves so that a unit spectrum has luminance 1 (Riemann sum error)
    rgb, clamped = spectra.list_to_rgb([360.0, 830.0], [1.0, 1.0], emitter=True)
    assert clamped is None
    assert rgb @ LUMINANCE == pytest.approx(1.0, abs=2e-3)
    # ... and it is the same purple-ish white as a one-number spectrum on an emitter
    np.testing.assert_allclose(rgb, spectra.uniform_to_rgb(1.0, emitter=True), rtol=3e-3)


def test_constant_reflectance_is_grey_under_d65_weighting():
    rgb, clamped = spectra.list_to_rgb([300.0, 900.0], [0.5, 0.5], emitter=False)
    assert clamped is None
    np.testing.assert_allclose(rgb, 0.5, atol=5e-3)


def test_out_of_gamut_reflectance_is_clamped_with_a_warning():
    narrow = "500:0, 540:1, 545:0"  # a narrow green band lies outside the sRGB gamut
    xml = f'''<scene version="3.0.0"><shape type="sphere"><bsdf type="diffuse">
        <spectrum name="reflectance" value="{narrow}"/></bsdf></shape></scene>'''
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        scene = load_string(xml)
    refl = scene.shapes[0].material.reflectance
    assert np.all((refl >= 0) & (refl <= 1)) and refl[0] == 0.0
    msgs = [str(x.message) for x in w if issubclass(x.category, SceneWarning)]
    assert any("<string>:2:" in m and "clamping out-of-gamut" in m for m in msgs), msgs


def _light(xml_inner):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        return load_string(f'<scene version="3.0.0">{xml_inner}</scene>').lights[0]


def test_one_number_spectrum_differs_between_emitters_and_reflectances():
    light = _light('<emitter type="point"><spectrum name="intensity" value="2"/></emitter>')
    np.testing.assert_allclose(light.L1, 2 * spectra.XYZ_TO_SRGB.astype(float).sum(axis=1),
                               rtol=1e-6)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        scene = load_string('<scene version="3.0.0"><shape type="sphere"><bsdf type="diffuse">'
                            '<spectrum name="reflectance" value="0.25"/></bsdf></shape></scene>')
    np.testing.assert_array_equal(scene.shapes[0].material.reflectance, [0.25] * 3)


def test_blackbody_emitter_warns_and_scales_with_planck():
    def bb(t):
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            light = _light(f'<emitter type="point"><spectrum name="intensity" type="blackbody">'
                           f'<float name="temperature" value="{t}"/></spectrum></emitter>')
        return light.L1, [str(x.message) for x in w]
    hot, _ = bb(9000)
    cool, _ = bb(3000)
    assert hot[2] > hot[0] and cool[0] > cool[2]  # bluish vs reddish
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        load_string('<scene version="3.0.0"><emitter type="point"><spectrum name="intensity" '
                    'type="blackbody"><float name="temperature" value="5000"/></spectrum>'
                    '</emitter></scene>')
    assert any("blackbody (5000 K)" in str(x.message) for x in w)
    assert not any("is ignored" in str(x.message) for x in w)


@pytest.mark.parametrize("value, needle", [
    ("0.1 0.2 0.3", "invalid spectrum entry '0.1'"),
    ("500:0.1, 400:0.2", "increasing order"),
    ("500:0.1", "at least two"),
    ("500:x, 600:1", "cannot parse spectrum value 'x'"),
])
def test_bad_spectra_are_scene_errors_with_their_line(value, needle):
    xml = f'''<scene version="3.0.0">
<shape type="sphere"><bsdf type="diffuse"><spectrum name="reflectance" value="{value}"/></bsdf></shape>
</scene>'''
    with pytest.raises(SceneError, match=needle) as info:
        load_string(xml)
    assert info.value.line == 2


def test_spectrum_plugins_mitsuba_rgb_cannot_evaluate_are_refused():
    xml = '''<scene version="3.0.0"><shape type="sphere"><bsdf type="diffuse">
<spectrum name="reflectance" type="regular"><float name="wavelength_min" value="400"/>
<float name="wavelength_max" value="700"/><string name="values" value="0.1, 0.5"/></spectrum>
</bsdf></shape></scene>'''
    with pytest.raises(SceneError, match="spectrum plugin 'regular' is not supported"):
        load_string(xml)
    with pytest.raises(SceneError, match="only makes sense for emission"):
        load_string(xml.replace('type="regular"', 'type="blackbody"').replace(
            '<float name="wavelength_min" value="400"/>', '<float name="temperature" value="400"/>'))
