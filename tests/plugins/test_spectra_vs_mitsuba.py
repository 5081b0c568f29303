"""The core's spectrum → RGB conversion against Mitsuba 3.9.1's own, value by value.

Each spectrum is written into XML once and read by both: the core's loader, and Mitsuba
(scalar_rgb ``mi.load_string`` then ``mi.traverse``). They must agree to the last float32 bit
(one unit in the last place allowed for fused multiply-adds).
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from links1.shading import spectra
from links1.scene.loader import load_string
from links1.scene.xmlparse import SceneWarning

mi = pytest.importorskip("mitsuba")

pytestmark = [pytest.mark.mitsuba, pytest.mark.usefixtures("scalar_rgb")]



def _spectra():
    """Uniform values, regular and irregular lists, inside, across and beyond 360-830 nm."""
    rng = np.random.default_rng(20261124)
    out = ["0.5", "0", "1", "2.75"]
    for i in range(24):
        n = int(rng.integers(2, 40))
        if i % 3 == 0:  # regular
            lo = float(rng.choice([300, 360, 380, 400, 450]))
            step = float(rng.choice([1, 5, 10, 20, 2.5]))
            wl = lo + step * np.arange(n)
        else:  # irregular
            wl = np.unique(np.round(rng.uniform(250, 950, n), 2))
        scale = 1.0 if i % 4 else 5.0
        v = np.round(rng.uniform(0, scale, wl.size), 4)
        out.append(", ".join(f"{a:g}:{b:g}" for a, b in zip(wl, v)))
    out.append("400:0.343, 404:0.445, 408:0.551, 412:0.624, 416:0.665, 420:0.687, 600:0.2, 700:0.5")
    return out


SPECTRA = _spectra()

#: (XML with {v} for the spectrum, Mitsuba's traverse key, core accessor)
CASES = {
    "diffuse": ('<bsdf type="diffuse"><spectrum name="reflectance" value="{v}"/></bsdf>',
                "reflectance.value", lambda s: s.shapes[0].material.reflectance),
    "conductor_eta": ('<bsdf type="conductor"><spectrum name="eta" value="{v}"/>'
                      '<rgb name="k" value="1"/></bsdf>',
                      "eta.value", lambda s: s.shapes[0].material.eta),
    "point": ('<emitter type="point"><spectrum name="intensity" value="{v}"/></emitter>',
              "intensity.value", lambda s: s.lights[0].L1),
    "directional": ('<emitter type="directional"><spectrum name="irradiance" value="{v}"/></emitter>',
                    "irradiance.value", lambda s: s.lights[0].irradiance),
    "spot": ('<emitter type="spot"><spectrum name="intensity" value="{v}"/></emitter>',
             "intensity.value", lambda s: s.lights[0].intensity),
    "constant": ('<emitter type="constant"><spectrum name="radiance" value="{v}"/></emitter>',
                 "radiance.value", lambda s: s.background),
    "area": ('<emitter type="area"><spectrum name="radiance" value="{v}"/></emitter>',
             "emitter.radiance.value", lambda s: s.shapes[0].emission),
}


def _ours(kind, v):
    inner = CASES[kind][0].format(v=v)
    if kind in ("diffuse", "conductor_eta", "area"):
        inner = f'<shape type="sphere">{inner}</shape>'
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        return np.asarray(CASES[kind][2](load_string(f'<scene version="3.0.0">{inner}</scene>')))


def _mitsuba(kind, v):
    xml = CASES[kind][0].format(v=v)
    if kind == "area":
        xml = f'<shape type="sphere">{xml}</shape>'
    xml = xml.replace(" type=", ' version="3.0.0" type=', 1)
    params = mi.traverse(mi.load_string(xml))
    value = np.array(params[CASES[kind][1]], dtype=np.float64).ravel()
    return np.broadcast_to(value, (3,))  # a one-number spectrum is Mitsuba's 'uniform' texture


@pytest.mark.parametrize("kind", sorted(CASES))
def test_spectrum_rgb_matches_mitsuba(kind):
    mi.set_log_level(mi.LogLevel.Error)  # Mitsuba's own clamping warnings
    try:
        for v in SPECTRA:
            theirs = _mitsuba(kind, v).astype(np.float32)
            ours = _ours(kind, v).astype(np.float32)
            np.testing.assert_array_max_ulp(ours, theirs, maxulp=1)
    finally:
        mi.set_log_level(mi.LogLevel.Warn)


def test_rgb_values_on_emitters_are_used_as_given():
    for kind, key in (("point", "intensity"), ("spot", "intensity")):
        xml = CASES[kind][0].replace('<spectrum name="intensity" value="{v}"/>',
                                     '<rgb name="intensity" value="3, 0.5, 7"/>')
        params = mi.traverse(mi.load_string(xml.replace(" type=", ' version="3.0.0" type=', 1)))
        np.testing.assert_array_equal(np.array(params[f"{key}.value"]).ravel(), [3, 0.5, 7])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SceneWarning)
            s = load_string(f'<scene version="3.0.0">{xml}</scene>')
        np.testing.assert_array_equal(CASES[kind][2](s), [3, 0.5, 7])


@pytest.mark.parametrize("temperature", [1500.0, 3200.0, 5000.0, 6500.0, 12000.0])
def test_blackbody_is_the_colour_of_mitsubas_spectral_planck(temperature):
    """Mitsuba's RGB variants cannot evaluate blackbody; its spectral variant's Planck spectrum,
    integrated by Mitsuba's spectrum_list_to_srgb, is the colour the core uses."""
    wl = np.linspace(spectra.CIE_MIN, spectra.CIE_MAX, 471)
    mi.set_variant("scalar_spectral")
    try:
        bb = mi.load_dict({"type": "blackbody", "temperature": temperature})
        si = mi.SurfaceInteraction3f()
        vals = []
        for chunk in wl.reshape(-1, 1):
            si.wavelengths = [float(chunk[0])] * 4
            vals.append(float(bb.eval(si)[0]))
        theirs = np.array(mi.spectrum_list_to_srgb(wl.tolist(), vals, bounded=False, d65=False))
    finally:
        mi.set_variant("scalar_rgb")
    np.testing.assert_allclose(spectra.planck(wl, temperature), vals, rtol=2e-5)
    np.testing.assert_allclose(spectra.blackbody_to_rgb(temperature), theirs, rtol=5e-5)
