"""Spectra → RGB exactly as Mitsuba 3.9.1's ``*_rgb`` variants convert them.

Mitsuba turns a ``<spectrum>`` into an ``srgb`` texture when a plugin asks for a texture
(``Properties::get_texture_impl``); what it computes depends on who asks:

===========================  ===============================  ===============================
``<spectrum value=...>``     reflectance-like (BSDFs)         emitters (``intensity``,
                                                              ``irradiance``, ``radiance``)
===========================  ===============================  ===============================
one number ``v``             ``(v, v, v)``                    ``v · xyz_to_srgb(1, 1, 1)``
                                                              (float32; the purple-ish white
                                                              of an equal-energy spectrum)
``wavelength:value`` list    ``spectrum_list_to_srgb`` with   ``spectrum_list_to_srgb``
(regular or not)             D65 weighting, clamped to        without D65, negatives
                             [0, 1] (warning)                 clamped to 0 (warning)
===========================  ===============================  ===============================

``spectrum_list_to_srgb`` (Mitsuba's ``src/core/spectrum.cpp``, in double precision): 1000
wavelengths evenly spaced over [360, 830] nm; those inside the list's range take the linear
interpolant of the list, times the CIE 1931 colour matching functions (and the CIE D65
illuminant, normalised to unit luminance, for reflectances), both interpolated linearly in
Mitsuba's float32 5 nm tables; the sum times ``470 / 106.7502593994140625 / 1000`` is XYZ,
turned into linear Rec. 709 RGB by Mitsuba's ``xyz_to_srgb`` matrix (float32 entries). The
result is stored as float32. Parameters Mitsuba reads as *unbounded* textures (a conductor's
``eta`` and ``k``) are clamped like emitters but weighted with D65 like reflectances.

``blackbody`` spectra cannot be evaluated by Mitsuba's RGB variants (their ``eval`` throws
"Not implemented for non-spectral modes"); :func:`blackbody_to_rgb` gives the colour its
spectral variants integrate to, for an emitter (Planck's law with Mitsuba's constants,
tabulated every nanometre over the blackbody's wavelength range, then the emitter path above).

The tables are ``links1/data/cie1931_d65.csv``, written once from the installed Mitsuba by
``tools/make_cie_data.py``.
"""
from __future__ import annotations

import functools
import os

import numpy as np

__all__ = ["CIE_MIN", "CIE_MAX", "parse", "to_rgb", "uniform_to_rgb", "list_to_rgb", "blackbody_to_rgb",
           "planck", "cie_tables"]

CIE_MIN, CIE_MAX = 360.0, 830.0
_SAMPLES = 95
#: A unit-valued spectrum integrates to a luminance of 1 (Mitsuba's MI_CIE_Y_NORMALIZATION).
_Y_NORMALIZATION = 1.0 / 106.7502593994140625
#: D65 scaled to unit luminance (MI_CIE_D65_NORMALIZATION).
_D65_NORMALIZATION = 1.0 / 98.99741751876255
#: Mitsuba's xyz_to_srgb matrix (ITU-R BT.709 primaries, D65 white), float32 entries.
XYZ_TO_SRGB = np.array([[3.240479, -1.537150, -0.498535],
                        [-0.969256, 1.875991, 0.041556],
                        [0.055648, -0.204043, 1.057311]], dtype=np.float32)
_STEPS = 1000
_DATA = os.path.join(os.path.dirname(os.path.dirname(__file__)), "data", "cie1931_d65.csv")  # links1/data


@functools.lru_cache(maxsize=1)
def cie_tables() -> tuple:
    """``(xyz, d65)``: the 95 x 3 CIE 1931 table and the D65 table (float32 values, as float64)."""
    data = np.loadtxt(_DATA, delimiter=",", comments="#", skiprows=2, dtype=np.float64)
    if data.shape != (_SAMPLES, 5):  # pragma: no cover - a broken installation
        raise RuntimeError(f"{_DATA}: expected {_SAMPLES} rows of 5 columns, got {data.shape}")
    return data[:, 1:4].astype(np.float32).astype(np.float64), \
        data[:, 4].astype(np.float32).astype(np.float64)


def _lerp_table(table: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Mitsuba's table lookup (``cie1931_xyz`` / ``cie_d65``): linear between 5 nm samples, 0
    outside [360, 830] nm."""
    t = (w - CIE_MIN) * ((_SAMPLES - 1) / (CIE_MAX - CIE_MIN))
    i0 = np.clip(t.astype(np.int64), 0, _SAMPLES - 2)
    w1 = t - i0
    w0 = 1.0 - w1
    if table.ndim == 2:
        w0, w1 = w0[:, None], w1[:, None]
    v = w0 * table[i0] + w1 * table[i0 + 1]
    inside = (w >= CIE_MIN) & (w <= CIE_MAX)
    return np.where(inside[:, None] if table.ndim == 2 else inside, v, 0.0)


def _f32(rgb) -> np.ndarray:
    return np.asarray(rgb, dtype=np.float32).astype(np.float64)


def uniform_to_rgb(value: float, *, emitter: bool) -> np.ndarray:
    """``<spectrum value="v">``: ``(v, v, v)``, or for an emitter ``v · xyz_to_srgb(1, 1, 1)``."""
    if not emitter:
        return np.full(3, float(value))
    white = XYZ_TO_SRGB.sum(axis=1, dtype=np.float32)  # float32, as Mitsuba's Color3f
    return (np.float32(value) * white).astype(np.float64)


def list_to_rgb(wavelengths, values, *, emitter: bool, unbounded: bool = False):
    """A ``wavelength:value`` list as Mitsuba's RGB variants read it.

    Returns ``(rgb, clamped)``: the float32 colour (as float64) and, when Mitsuba clamps an
    out-of-gamut colour (and warns), the colour before clamping, else None.
    """
    wl = np.asarray(wavelengths, dtype=np.float64)
    val = np.asarray(values, dtype=np.float64)
    if wl.ndim != 1 or wl.shape != val.shape or wl.size < 2:
        raise ValueError("a spectrum needs at least two wavelength:value pairs")
    if not np.all(np.diff(wl) > 0):
        raise ValueError("wavelengths must be given in increasing order")
    xyz_tab, d65_tab = cie_tables()
    i = np.arange(_STEPS, dtype=np.float64)
    w = CIE_MIN + (i / (_STEPS - 1)) * (CIE_MAX - CIE_MIN)
    w = w[(w >= wl[0]) & (w <= wl[-1])]
    idx = np.clip(np.searchsorted(wl, w, side="right") - 1, 0, wl.size - 2)
    w0, w1, v0, v1 = wl[idx], wl[idx + 1], val[idx], val[idx + 1]
    v = ((w - w1) * v0 + (w0 - w) * v1) / (w0 - w1)
    terms = _lerp_table(xyz_tab, w) * v[:, None]
    if not emitter:
        terms = terms * (_lerp_table(d65_tab, w) * _D65_NORMALIZATION)[:, None]
    xyz = np.zeros(3)
    for row in terms:  # Mitsuba's summation order
        xyz += row
    xyz *= (CIE_MAX - CIE_MIN) * _Y_NORMALIZATION / _STEPS
    rgb = XYZ_TO_SRGB.astype(np.float64) @ xyz
    bounded = not (emitter or unbounded)
    raw = rgb.copy()
    if bounded and np.any((rgb < 0) | (rgb > 1)):
        return _f32(np.clip(rgb, 0.0, 1.0)), raw
    if not bounded and np.any(rgb < 0):
        return _f32(np.maximum(rgb, 0.0)), raw
    return _f32(rgb), None


def to_rgb(wavelengths, values, *, emitter: bool, unbounded: bool = False):
    """:func:`uniform_to_rgb` when ``wavelengths`` is empty (one value), else
    :func:`list_to_rgb`: ``(rgb, clamped)`` either way. Takes what Mitsuba's parser keeps of a
    ``<spectrum>`` too (``Properties`` spectra have ``.wavelengths`` and ``.values``)."""
    values = np.atleast_1d(np.asarray(values, dtype=np.float64))
    if wavelengths is None or len(wavelengths) == 0:
        return uniform_to_rgb(float(values[0]), emitter=emitter), None
    return list_to_rgb(wavelengths, values, emitter=emitter, unbounded=unbounded)


# Planck's law with Mitsuba's constants (src/spectra/blackbody.cpp)
_C = 2.99792458e8       # speed of light
_H = 6.62607004e-34     # Planck constant
_K = 1.38064852e-23     # Boltzmann constant


def planck(wavelength_nm, temperature: float) -> np.ndarray:
    """Spectral radiance of a black body, W m^-2 sr^-1 nm^-1 (Mitsuba's ``blackbody``)."""
    lam = np.asarray(wavelength_nm, dtype=np.float64) * 1e-9
    c0, c1 = 2.0 * _H * _C * _C, _H * _C / _K
    return 1e-9 * c0 / (lam ** 5 * np.expm1(c1 / (lam * temperature)))


def blackbody_to_rgb(temperature: float, wavelength_min: float = CIE_MIN,
                     wavelength_max: float = CIE_MAX) -> np.ndarray:
    """The emitted colour of a black body as Mitsuba's spectral variants integrate it."""
    if not temperature > 0:
        raise ValueError(f"blackbody 'temperature' must be > 0 K, got {temperature:g}")
    if not wavelength_min < wavelength_max:
        raise ValueError("blackbody: 'wavelength_min' must be below 'wavelength_max'")
    n = max(2, int(np.ceil(wavelength_max - wavelength_min)) + 1)
    wl = np.linspace(wavelength_min, wavelength_max, n)
    rgb, _ = list_to_rgb(wl, planck(wl, temperature), emitter=True)
    return rgb


def parse(text: str):
    """A ``<spectrum value=...>`` text as Mitsuba reads it: ``(None, v)`` for one number, else
    ``(wavelengths, values)``; a ValueError says what is wrong."""
    tokens = [t for t in text.replace(",", " ").split() if t]
    if len(tokens) == 1 and ":" not in tokens[0]:
        return None, _number(tokens[0], "spectrum value")
    wl, val = [], []
    for tok in tokens:
        parts = tok.split(":")
        if len(parts) != 2 or not all(parts):
            raise ValueError(f"invalid spectrum entry '{tok}' (expected one number, or "
                             "wavelength:value pairs)")
        wl.append(_number(parts[0], "wavelength"))
        val.append(_number(parts[1], "spectrum value"))
    if len(wl) < 2:
        raise ValueError("a spectrum needs one number or at least two wavelength:value pairs")
    if any(b <= a for a, b in zip(wl, wl[1:])):
        raise ValueError("spectrum wavelengths must be given in increasing order")
    return np.array(wl), np.array(val)


def _number(text: str, what: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise ValueError(f"cannot parse {what} '{text}'") from None
    if not np.isfinite(v):
        raise ValueError(f"{what} must be finite, got '{text}'")
    return v
