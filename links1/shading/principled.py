"""Mitsuba's ``principled`` BSDF in float64, evaluated, sampled and given a density as Mitsuba
3.9.1 does (``src/bsdfs/principled.cpp``, ``principledhelpers.h``): Burley's "Physically Based
Shading at Disney" (SIGGRAPH 2012 course notes) and its 2015 extension "Extending the Disney
BRDF to a BSDF with Integrated Subsurface Scattering" as Mitsuba implements them.

Lobes (each weighted as Mitsuba weights it; ``brdf = (1 - metallic)(1 - spec_trans)``,
``bsdf = (1 - metallic) spec_trans``):

* main specular reflection: GGX ``D G / (4 |cos θ_i|)`` (Walter et al. 2007, eq. 20) times
  Mitsuba's ``principled_fresnel`` (true dielectric Fresnel blended with Schlick's for the
  metallic and ``spec_tint`` parts; from below, ``bsdf`` times the dielectric Fresnel);
* specular transmission (``spec_trans``): Walter et al. eq. 21 times ``sqrt(base_color)``,
  radiance scaled by ``(η_i/η_t)²``;
* clear coat: GTR1 (Burley 2012, eq. 4 with γ = 1), Schlick's Fresnel of ``R0 = 0.04`` and
  the separable GGX Smith term of roughness 0.25, weighted ``clearcoat / 4``;
* diffuse (Burley 2015, eq. 4: ``f_d`` with retro-reflection ``f_retro``; ``flatness`` blends
  in the Hanrahan-Krueger-like ``f_ss``) and ``sheen`` (Schlick's weight of the half angle,
  tinted by ``sheen_tint``).

The interface is that of :mod:`links1.shading.glossy` (``eval``, ``pdf``,
``sample(wo, n, n_raw, u, uv)``); there is no delta lobe. Every parameter but ``eta`` /
``specular`` and the sampling rates may be a texture (``base_color`` read as RGB, the others
as Mitsuba's ``eval_1``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import microfacet as mf
from .glossy import _Local, _scalar
from .materials import _rgb
from .textures import LUMINANCE, Texture
from ..maths.vec import dot

_SCALARS = ("roughness", "anisotropic", "spec_trans", "metallic", "clearcoat", "clearcoat_gloss",
            "sheen", "sheen_tint", "flatness", "spec_tint")


# ------------------------------------------------------------------ principledhelpers.h
def schlick_weight(cos_i):
    """``(1 - cos)^5``, the argument clamped to [0, 1] (Schlick 1994)."""
    m = np.clip(1.0 - cos_i, 0.0, 1.0)
    return (m * m) * (m * m) * m


def calc_schlick(r0, cos_i, eta):
    """Schlick's Fresnel ``R0 + (1 - R0)(1 - cos)^5`` (N,) or (N, 3), with the transmitted
    angle's cosine where light leaves the denser side (Mitsuba's ``calc_schlick``)."""
    outside = cos_i >= 0.0
    eta_it = np.where(outside, eta, 1.0 / eta)
    eta_ti = np.where(outside, 1.0 / eta, eta)
    cos_t = np.sqrt(np.maximum(1.0 - (1.0 - cos_i * cos_i) * eta_ti * eta_ti, 0.0))
    w = np.where(eta_it > 1.0, schlick_weight(np.abs(cos_i)), schlick_weight(cos_t))
    r0 = np.asarray(r0, dtype=np.float64)
    if r0.ndim == 2:
        w = w[:, None]
    return w * (1.0 - r0) + r0


def schlick_r0(eta):
    """``((η - 1)/(η + 1))²``: Fresnel reflectance at normal incidence."""
    return ((eta - 1.0) / (eta + 1.0)) ** 2


def dist_params(anisotropic, roughness, has_anisotropic: bool):
    """GGX ``(α_x, α_y)`` from ``roughness`` and ``anisotropic`` (Burley 2012, addendum B.2:
    ``α = roughness²``, aspect ``sqrt(1 - 0.9 anisotropic)``), at least 0.001."""
    r2 = roughness * roughness
    if not has_anisotropic:
        a = np.maximum(0.001, r2)
        return a, a
    aspect = np.sqrt(1.0 - 0.9 * anisotropic)
    return np.maximum(0.001, r2 / aspect), np.maximum(0.001, r2 * aspect)


def compatible(m, wi, wo, cos_i, reflection: bool):
    """Mitsuba's ``mac_mic_compatibility``: both directions on the sides of the microfacet
    ``m`` (turned to the viewer's side) that reflection / refraction needs."""
    ms = m * np.copysign(1.0, cos_i)[:, None]
    if reflection:
        return (dot(wi, ms) > 0.0) & (dot(wo, ms) > 0.0)
    return (dot(wi, ms) > 0.0) & (dot(wo, -ms) > 0.0)


def smith_ggx1(v, wh, alpha):
    """Smith's G1 of an isotropic GGX of roughness ``alpha`` (Walter et al. eq. 34)."""
    c = np.abs(v[:, 2])
    with np.errstate(divide="ignore", invalid="ignore"):
        tan2 = (1.0 - c * c) / (c * c)
        g = 2.0 / (1.0 + np.sqrt(1.0 + alpha * alpha * tan2))
    g = np.where(v[:, 2] == 1.0, 1.0, g)
    return np.where(dot(v, wh) * v[:, 2] <= 0.0, 0.0, g)


class GTR1:
    """Burley's GTR1 distribution (2012, eq. 4, γ = 1) of the clear coat."""

    def __init__(self, alpha):
        self.alpha2 = np.asarray(alpha, dtype=np.float64) ** 2

    def eval(self, m):
        ct = m[:, 2]
        a2 = self.alpha2
        d = (a2 - 1.0) / (math.pi * np.log(a2) * (1.0 + (a2 - 1.0) * ct * ct))
        return np.where(d * ct > 1e-20, d, 0.0)

    def pdf(self, m):
        return np.where(m[:, 2] < 0.0, 0.0, m[:, 2] * self.eval(m))

    def sample(self, u1, u2):
        phi = 2.0 * math.pi * u1
        a2 = self.alpha2
        cos2 = (1.0 - a2 ** (1.0 - u2)) / (1.0 - a2)
        st, ct = np.sqrt(np.maximum(0.0, 1.0 - cos2)), np.sqrt(np.maximum(0.0, cos2))
        return np.stack([np.cos(phi) * st, np.sin(phi) * st, ct], axis=-1)


def _half(wi, wo, reflect, eta_path):
    """The generalised half vector (Walter et al. eq. 16), turned outward."""
    wh = mf._normalize(wi + wo * np.where(reflect, 1.0, eta_path)[:, None])
    return wh * np.copysign(1.0, wh[:, 2])[:, None]


def _diffuse(co, ci, cos_d, roughness, flatness=None):
    """Burley's diffuse factor (2015, eq. 4): ``f_d`` with retro-reflection, blended toward the
    fake subsurface term ``f_ss`` by ``flatness`` (None: off); ``co``, ``ci`` are |cos θ|."""
    f_o, f_i = schlick_weight(co), schlick_weight(ci)
    rr = 2.0 * roughness * cos_d * cos_d
    f = (1.0 - 0.5 * f_i) * (1.0 - 0.5 * f_o) + rr * (f_o + f_i + f_o * f_i * (rr - 1.0))
    if flatness is None:
        return f
    fss90 = 0.5 * rr
    fss = (1.0 + (fss90 - 1.0) * f_o) * (1.0 + (fss90 - 1.0) * f_i)
    f_ss = 1.25 * (fss * (1.0 / (co + ci) - 0.5) + 0.5)
    return f * (1.0 - flatness) + f_ss * flatness


class _Disney(_Local):
    """What ``principled`` and ``principledthin`` share: per-hit weights (0 where a lobe is
    off, as Mitsuba's ``get_flag``), the base colour and its luminance-normalised tint."""

    always_read = ("roughness",)

    def _flags(self):
        for k in self.scalar_params:
            v = getattr(self, k)
            if not isinstance(v, Texture):
                setattr(self, k, float(v))
        self.has = {k: isinstance(getattr(self, k), Texture) or getattr(self, k) != 0.0
                    for k in self.scalar_params}

    def _w(self, k, n):
        """Parameter ``k`` at the N hits (N,), 0 where its lobe is off."""
        if not self.has[k] and k not in self.always_read:
            return np.zeros(n)
        return np.broadcast_to(np.asarray(_scalar(getattr(self, k)), dtype=np.float64), (n,))

    def _base(self, n):
        return np.broadcast_to(np.asarray(self.base_color, dtype=np.float64), (n, 3))

    @staticmethod
    def _tint(base):
        lum = base @ LUMINANCE
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where((lum > 0.0)[:, None], base / lum[:, None], 1.0)

    def _sheen_tint(self, base, n):
        if not self.has["sheen_tint"]:
            return np.ones((n, 3))
        st = self._w("sheen_tint", n)[:, None]
        return (1.0 - st) + st * self._tint(base)

    def _distr(self, n, scale=1.0):
        ax, ay = dist_params(self._w("anisotropic", n), scale * self._w("roughness", n),
                             self.has["anisotropic"])
        return mf.Microfacet(mf.GGX, ax, ay)


# ------------------------------------------------------------------ the BSDFs
@dataclass
class Principled(_Disney):
    """Mitsuba ``principled``. ``eta`` (interior over exterior) or ``specular`` (which sets
    ``eta = 2 / (1 - sqrt(0.08 specular)) - 1``) gives the dielectric's index; a lobe whose
    weight is 0 (not a texture) is off, as Mitsuba's ``get_flag``."""

    scalar_params = _SCALARS
    always_read = ("roughness", "clearcoat_gloss")

    base_color: object = 0.5
    roughness: object = 0.5
    anisotropic: object = 0.0
    metallic: object = 0.0
    spec_trans: object = 0.0
    eta: float | None = None
    specular: float | None = None
    spec_tint: object = 0.0
    sheen: object = 0.0
    sheen_tint: object = 0.0
    clearcoat: object = 0.0
    clearcoat_gloss: object = 0.0
    flatness: object = 0.0
    main_specular_sampling_rate: float = 1.0
    clearcoat_sampling_rate: float = 1.0
    diffuse_reflectance_sampling_rate: float = 1.0
    two_sided: bool = False
    name: str = ""

    def __post_init__(self):
        self.base_color = _rgb(self.base_color)
        self._flags()
        on = self.has
        if self.eta is not None and self.specular is not None:
            raise ValueError("give either 'eta' or 'specular', not both")
        if self.eta is not None:
            self.eta = float(self.eta)
            if not (np.isfinite(self.eta) and self.eta > 0):
                raise ValueError(f"'eta' must be > 0, got {self.eta}")
            if on["spec_trans"] and self.eta == 1.0:   # not plausible for transmission
                self.eta = 1.001
        else:
            spec = 0.5 if self.specular is None else float(self.specular)
            if on["spec_trans"] and spec == 0.0:
                spec = 1e-3
            if not (0.0 <= spec < 12.5):
                raise ValueError(f"'specular' must be in [0, 12.5), got {spec}")
            self.eta = 2.0 / (1.0 - math.sqrt(0.08 * spec)) - 1.0

    def _gtr1(self, n):
        g = self._w("clearcoat_gloss", n)
        return GTR1(0.1 * (1.0 - g) + 0.001 * g)

    def _probabilities(self, n, front, F):
        """Lobe selection probabilities (diffuse, clear coat, transmission, reflection),
        normalised: Mitsuba's sampling weights from the lobes' energies and rates."""
        metallic, spec_trans = self._w("metallic", n), self._w("spec_trans", n)
        brdf = (1.0 - metallic) * (1.0 - spec_trans)
        bsdf = (1.0 - metallic) * spec_trans
        rs = self.main_specular_sampling_rate
        p_r = np.where(front, rs * (1.0 - bsdf * (1.0 - F)), F)
        p_t = (np.where(front, rs * bsdf * (1.0 - F), 1.0 - F) if self.has["spec_trans"]
               else np.zeros(n))
        p_c = (np.where(front, 0.25 * self._w("clearcoat", n) * self.clearcoat_sampling_rate, 0.0)
               if self.has["clearcoat"] else np.zeros(n))
        p_d = np.where(front, brdf * self.diffuse_reflectance_sampling_rate, 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / (p_r + p_t + p_c + p_d)
        return p_d * inv, p_c * inv, p_t * inv, p_r * inv

    # -- eval / pdf / sample in the local frame (wi: viewer, wo: light) ---------------------
    def _eval(self, wi, wo):
        n = wi.shape[0]
        ci, co = wi[:, 2], wo[:, 2]
        active = ci != 0.0
        metallic, spec_trans = self._w("metallic", n), self._w("spec_trans", n)
        roughness = self._w("roughness", n)
        base = self._base(n)
        brdf = (1.0 - metallic) * (1.0 - spec_trans)
        bsdf = (1.0 - metallic) * spec_trans
        reflect, refract, front = ci * co > 0.0, ci * co < 0.0, ci > 0.0
        eta = self.eta
        eta_path = np.where(front, eta, 1.0 / eta)
        d = self._distr(n)
        wh = _half(wi, wo, reflect, eta_path)
        cos_ih, cos_oh = dot(wi, wh), dot(wo, wh)
        F = mf.fresnel(cos_ih, eta)[0]
        r_ok = compatible(wh, wi, wo, ci, True)
        t_ok = compatible(wh, wi, wo, ci, False)
        D, G = d.eval(wh), d.G(wi, wo, wh)
        value = np.zeros((n, 3))
        err = np.errstate(divide="ignore", invalid="ignore", over="ignore")
        with err:
            # main specular reflection
            on = active & reflect & r_ok & (F > 0.0)
            spec_tint = self._w("spec_tint", n)
            f_schlick = np.zeros((n, 3))
            if self.has["metallic"]:
                f_schlick += metallic[:, None] * calc_schlick(base, cos_ih, eta)
            if self.has["spec_tint"]:
                eta_it = np.where(cos_ih >= 0.0, eta, 1.0 / eta)
                f0 = self._tint(base) * schlick_r0(eta_it)[:, None]
                f_schlick += ((1.0 - metallic) * spec_tint)[:, None] * calc_schlick(f0, cos_ih, eta)
            f_front = ((1.0 - metallic) * (1.0 - spec_tint) * F)[:, None] + f_schlick
            f_p = np.where(front[:, None], f_front, (bsdf * F)[:, None])
            lobe = D * G / (4.0 * np.abs(ci))                            # Walter et al. eq. (20)
            value += np.where(on[:, None], f_p * lobe[:, None], 0.0)
            # specular transmission, Walter et al. eq. (21), radiance scaled by (η_i/η_t)²
            if self.has["spec_trans"]:
                on = active & (bsdf > 0.0) & refract & t_ok & (F < 1.0)
                t = np.abs((1.0 - F) * D * G * cos_ih * cos_oh
                           / (ci * (cos_ih + eta_path * cos_oh) ** 2))
                value += np.where(on[:, None], np.sqrt(base) * (bsdf * t)[:, None], 0.0)
            # clear coat
            if self.has["clearcoat"]:
                cc = self._w("clearcoat", n)
                on = active & (cc > 0.0) & reflect & r_ok & front
                f_cc = calc_schlick(0.04, cos_ih, eta)
                g_cc = smith_ggx1(wi, wh, 0.25) * smith_ggx1(wo, wh, 0.25)
                c = cc * 0.25 * f_cc * self._gtr1(n).eval(wh) * g_cc * np.abs(co)
                value += np.where(on, c, 0.0)[:, None]
            # diffuse with retro-reflection and flattening (Burley 2015, eq. 4), sheen
            on = active & (brdf > 0.0) & reflect & front
            cos_d = dot(wh, wo)
            f = _diffuse(np.abs(co), np.abs(ci), cos_d, roughness,
                         self._w("flatness", n) if self.has["flatness"] else None)
            value += np.where(on[:, None], base * (brdf * np.abs(co) / math.pi * f)[:, None], 0.0)
            if self.has["sheen"]:
                sheen = self._w("sheen", n)
                on = active & (sheen > 0.0) & reflect & (1.0 - metallic > 0.0) & front
                s = sheen * (1.0 - metallic) * schlick_weight(np.abs(cos_d)) * np.abs(co)
                value += np.where(on[:, None], s[:, None] * self._sheen_tint(base, n), 0.0)
        return np.where(active[:, None], np.nan_to_num(value), 0.0)

    def _pdf(self, wi, wo):
        n = wi.shape[0]
        ci, co = wi[:, 2], wo[:, 2]
        reflect, refract, front = ci * co > 0.0, ci * co < 0.0, ci > 0.0
        eta_path = np.where(front, self.eta, 1.0 / self.eta)
        wh = _half(wi, wo, reflect, eta_path)
        d = self._distr(n)
        F = mf.fresnel(dot(wi, wh), self.eta)[0]
        p_d, p_c, p_t, p_r = self._probabilities(n, front, F)
        cos_ih, cos_oh = dot(wi, wh), dot(wo, wh)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            if self.has["spec_trans"]:
                dwh = np.abs(np.where(reflect, 1.0 / (4.0 * cos_oh),
                                      eta_path ** 2 * cos_oh / (cos_ih + eta_path * cos_oh) ** 2))
            else:
                dwh = np.abs(1.0 / (4.0 * cos_oh))
            p_m = d.pdf(wi * np.copysign(1.0, ci)[:, None], wh) * dwh
            r_on = compatible(wh, wi, wo, ci, True) & reflect
            pdf = np.where(r_on, p_r * p_m, 0.0)
            pdf += np.where(reflect, p_d * co / math.pi, 0.0)
            if self.has["spec_trans"]:
                pdf += np.where(compatible(wh, wi, wo, ci, False) & refract, p_t * p_m, 0.0)
            if self.has["clearcoat"]:
                pdf += np.where(r_on, p_c * self._gtr1(n).pdf(wh) * dwh, 0.0)
        return np.where(ci != 0.0, np.nan_to_num(pdf, posinf=0.0, neginf=0.0), 0.0)

    def _sample(self, wi, u, uv):
        n = wi.shape[0]
        ci = wi[:, 2]
        active = ci != 0.0
        front = ci > 0.0
        bsdf = ((1.0 - self._w("metallic", n)) * self._w("spec_trans", n) if self.has["spec_trans"]
                else np.zeros(n))
        m_spec, _ = self._distr(n).sample(wi * np.copysign(1.0, ci)[:, None], uv[:, 0], uv[:, 1])
        F, cos_t, _, eta_ti = mf.fresnel(dot(wi, m_spec), self.eta)
        active &= front | (bsdf > 0.0)
        p_d, p_c, p_t, _ = self._probabilities(n, front, F)
        pick_d = active & (u < p_d)
        pick_c = self.has["clearcoat"] & active & (u >= p_d) & (u < p_d + p_c)
        pick_t = self.has["spec_trans"] & active & (u >= p_d + p_c) & (u < p_d + p_c + p_t)
        pick_r = active & (u >= p_d + p_c + p_t)
        wo = np.zeros((n, 3))
        wr = mf.reflect(wi, m_spec)
        wo[pick_r] = wr[pick_r]
        active &= ~pick_r | (compatible(m_spec, wi, wr, ci, True) & (ci * wr[:, 2] > 0.0))
        if self.has["spec_trans"]:
            wt = mf.refract(wi, m_spec, cos_t, eta_ti)
            wo[pick_t] = wt[pick_t]
            active &= ~pick_t | (compatible(m_spec, wi, wt, ci, False) & (ci * wt[:, 2] < 0.0))
        if self.has["clearcoat"]:
            m_cc = self._gtr1(n).sample(uv[:, 0], uv[:, 1])
            wc = mf.reflect(wi, m_cc)
            wo[pick_c] = wc[pick_c]
            active &= ~pick_c | (compatible(m_cc, wi, wc, ci, True) & (ci * wc[:, 2] > 0.0))
        wd = mf.square_to_cosine_hemisphere(uv[:, 0], uv[:, 1])
        wo[pick_d] = wd[pick_d]
        active &= ~pick_d | (ci * wd[:, 2] > 0.0)
        pdf = self._pdf(wi, wo)
        active &= pdf > 0.0
        with np.errstate(divide="ignore", invalid="ignore"):
            weight = self._eval(wi, wo) / pdf[:, None]
        return wo, np.where(active[:, None], weight, 0.0), np.where(active, pdf, 0.0)


@dataclass
class PrincipledThin(_Disney):
    """Mitsuba ``principledthin``: the principled model on a thin sheet, alike from both
    sides. The specular lobe reflects (GGX of ``roughness``) and transmits straight through
    (the reflection mirrored below, GGX of roughness ``(0.65 η - 0.35) roughness``), both
    weighted ``spec_trans``; a Fresnel of ``eta`` (a float or texture, default 1.5) tinted by
    ``spec_tint``; diffuse reflection as ``principled``'s and diffuse transmission
    ``diff_trans / 2`` (``diff_trans`` in [0, 2])."""

    scalar_params = ("roughness", "anisotropic", "spec_trans", "sheen", "sheen_tint", "flatness",
                     "spec_tint", "eta", "diff_trans")
    always_read = ("roughness", "eta")
    both_sides = True

    base_color: object = 0.5
    roughness: object = 0.5
    anisotropic: object = 0.0
    spec_trans: object = 0.0
    eta: object = 1.5
    spec_tint: object = 0.0
    sheen: object = 0.0
    sheen_tint: object = 0.0
    flatness: object = 0.0
    diff_trans: object = 0.0
    specular_reflectance_sampling_rate: float = 1.0
    specular_transmittance_sampling_rate: float = 1.0
    diffuse_reflectance_sampling_rate: float = 1.0
    diffuse_transmittance_sampling_rate: float = 1.0
    name: str = ""

    def __post_init__(self):
        self.base_color = _rgb(self.base_color)
        self._flags()

    def _weights(self, n):
        return (self._w("spec_trans", n), 0.5 * self._w("diff_trans", n), self._w("eta", n))

    def _probabilities(self, n):
        """Lobe selection probabilities (specular reflection, specular transmission, diffuse
        reflection, diffuse transmission), normalised."""
        st, dt, _ = self._weights(n)
        z = np.zeros(n)
        p_sr = st * self.specular_reflectance_sampling_rate / 2.0 if self.has["spec_trans"] else z
        p_st = st * self.specular_transmittance_sampling_rate / 2.0 if self.has["spec_trans"] else z
        p_dr = self.diffuse_reflectance_sampling_rate * (1.0 - st) * (1.0 - dt)
        p_dt = self.diffuse_transmittance_sampling_rate * (1.0 - st) * dt if self.has["diff_trans"] else z
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / (p_sr + p_st + p_dr + p_dt)
        return p_sr * inv, p_st * inv, p_dr * inv, p_dt * inv

    @staticmethod
    def _upper(wi, wo):
        """The viewer turned above the sheet, the light turned alike, the half vector of the
        light mirrored above (transmission is reflection mirrored below)."""
        s = np.copysign(1.0, wi[:, 2])[:, None]
        wi, wo_t = wi * s, wo * s
        wo_r = wo_t * np.array([1.0, 1.0, 0.0]) + np.abs(wo_t) * np.array([0.0, 0.0, 1.0])
        return wi, wo_t, mf._normalize(wi + wo_r), wo_r

    def _eval(self, wi, wo):
        n = wi.shape[0]
        active = wi[:, 2] != 0.0
        st, dt, eta = self._weights(n)
        roughness = self._w("roughness", n)
        base = self._base(n)
        wi, wo_t, wh, _ = self._upper(wi, wo)
        ci, co = wi[:, 2], wo_t[:, 2]
        reflect, refract = co > 0.0, co < 0.0
        value = np.zeros((n, 3))
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            if self.has["spec_trans"]:
                F = mf.fresnel(dot(wi, wh), eta)[0]
                on = active & (st > 0.0) & reflect & compatible(wh, wi, wo_t, ci, True)
                d = self._distr(n)
                f_thin = np.broadcast_to(F[:, None], (n, 3))
                if self.has["spec_tint"]:
                    tint = self._w("spec_tint", n)[:, None]
                    f0 = self._tint(base) * schlick_r0(eta)[:, None]
                    f_thin = f_thin * (1.0 - tint) + calc_schlick(f0, dot(wi, wh), eta) * tint
                lobe = st * d.eval(wh) * d.G(wi, wo_t, wh) / (4.0 * ci)     # Walter et al. eq. (20)
                value += np.where(on[:, None], f_thin * lobe[:, None], 0.0)
                on = active & refract & (st > 0.0) & compatible(wh, wi, wo_t, ci, False)
                d = self._distr(n, 0.65 * eta - 0.35)
                lobe = st * (1.0 - F) * d.eval(wh) * d.G(wi, wo_t, wh) / (4.0 * ci)
                value += np.where(on[:, None], base * lobe[:, None], 0.0)
            on = active & reflect & (st < 1.0) & (dt < 1.0)
            cos_d = dot(wh, wo_t)
            f = _diffuse(np.abs(co), ci, cos_d, roughness,
                         self._w("flatness", n) if self.has["flatness"] else None)
            value += np.where(on[:, None], base * ((1.0 - st) * co / math.pi * (1.0 - dt) * f)[:, None], 0.0)
            if self.has["sheen"]:
                s = (self._w("sheen", n) * (1.0 - st) * schlick_weight(np.abs(cos_d)) * (1.0 - dt)
                     * np.abs(co))
                value += np.where(on[:, None], s[:, None] * self._sheen_tint(base, n), 0.0)
            if self.has["diff_trans"]:
                on = active & refract & (st < 1.0) & (dt > 0.0)
                value += np.where(on[:, None], base * ((1.0 - st) * dt / math.pi * np.abs(co))[:, None], 0.0)
        return np.where(active[:, None], np.nan_to_num(value), 0.0)

    def _pdf(self, wi, wo):
        n = wi.shape[0]
        _, _, eta = self._weights(n)
        active = wi[:, 2] != 0.0
        wi, wo_t, wh, wo_r = self._upper(wi, wo)
        co = wo_t[:, 2]
        reflect, refract = co > 0.0, co < 0.0
        p_sr, p_st, p_dr, p_dt = self._probabilities(n)
        pdf = np.zeros(n)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            if self.has["spec_trans"]:
                dwh = np.abs(1.0 / (4.0 * dot(wo_r, wh)))
                on = compatible(wh, wi, wo_t, wi[:, 2], True) & reflect
                pdf += np.where(on, p_sr * self._distr(n).pdf(wi, wh) * dwh, 0.0)
                on = compatible(wh, wi, wo_t, wi[:, 2], False) & refract
                pdf += np.where(on, p_st * self._distr(n, 0.65 * eta - 0.35).pdf(wi, wh) * dwh, 0.0)
            pdf += np.where(reflect, p_dr * co / math.pi, 0.0)
            if self.has["diff_trans"]:
                pdf += np.where(refract, p_dt * -co / math.pi, 0.0)
        return np.where(active, np.nan_to_num(pdf, posinf=0.0, neginf=0.0), 0.0)

    def _sample(self, wi, u, uv):
        n = wi.shape[0]
        active = wi[:, 2] != 0.0
        sign = np.copysign(1.0, wi[:, 2])[:, None]
        up = wi * sign
        _, _, eta = self._weights(n)
        p_sr, p_st, p_dr, _ = self._probabilities(n)
        has_st = self.has["spec_trans"]
        pick_sr = has_st & active & (u < p_sr)
        pick_st = has_st & active & (u >= p_sr) & (u < p_sr + p_st)
        pick_dr = active & (u >= p_sr + p_st) & (u < p_sr + p_st + p_dr)
        pick_dt = self.has["diff_trans"] & active & (u >= p_sr + p_st + p_dr)
        wo = np.zeros((n, 3))
        if has_st:
            m, _ = self._distr(n).sample(up, uv[:, 0], uv[:, 1])
            wr = mf.reflect(up, m)
            wo[pick_sr] = wr[pick_sr]
            active &= ~pick_sr | (compatible(m, up, wr, up[:, 2], True) & (wr[:, 2] > 0.0))
            m, _ = self._distr(n, 0.65 * eta - 0.35).sample(up, uv[:, 0], uv[:, 1])
            wt = mf.reflect(up, m) * np.array([1.0, 1.0, -1.0])
            wo[pick_st] = wt[pick_st]
            active &= ~pick_st | (compatible(m, up, wt, up[:, 2], False) & (wt[:, 2] < 0.0))
        wd = mf.square_to_cosine_hemisphere(uv[:, 0], uv[:, 1])
        wo[pick_dr] = wd[pick_dr]
        wo[pick_dt] = -wd[pick_dt]
        wo = wo * sign
        pdf = self._pdf(wi, wo)
        active &= pdf > 0.0
        with np.errstate(divide="ignore", invalid="ignore"):
            weight = self._eval(wi, wo) / pdf[:, None]
        return wo, np.where(active[:, None], weight, 0.0), np.where(active, pdf, 0.0)
