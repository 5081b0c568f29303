"""Mitsuba's glossy BSDFs in float64: ``roughconductor``, ``roughplastic``, ``roughdielectric``
and ``blendbsdf``, evaluated, sampled and given a density as Mitsuba 3.9.1 does
(``src/bsdfs/roughconductor.cpp``, ``roughplastic.cpp``, ``roughdielectric.cpp``,
``blendbsdf.cpp``), on the microfacet model of :mod:`links1.shading.microfacet`.

They answer the interface of :mod:`links1.shading.materials` (``eval``, ``specular``) and,
for BSDF sampling, two more calls on a batch of N hits (world directions, ``wo`` toward the
viewer, ``wi`` toward the light, ``n`` the shading normal facing the viewer, ``n_raw`` the
shading normal as the surface has it):

* ``sample(wo, n, n_raw, u, uv)`` → ``(wi, weight, pdf)``: a direction drawn from the BSDF's
  non-delta lobes with sample ``u`` (N,) and ``uv`` (N, 2) (Mitsuba's ``sample1``,
  ``sample2``), ``weight = eval / pdf`` (N, 3), ``pdf`` (N,) in solid angle (0: no sample);
* ``pdf(wo, wi, n, n_raw)`` (N,): the density ``sample`` draws ``wi`` with.

``tangent`` (N, 3), a keyword of all three and ``eval``, orients anisotropic roughness
(Mitsuba's ``dp_du``); without it the frame is Mitsuba's ``coordinate_system(n)``.
"""
from __future__ import annotations

import copy
import functools
import json
import math
import os
from dataclasses import dataclass, field

import numpy as np

from . import microfacet as mf
from .materials import Material, _rgb
from .textures import LUMINANCE, Bitmap, Texture
from ..maths.vec import coordinate_system, cross, dot

_DATA = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data")


@functools.lru_cache(maxsize=1)
def conductors() -> dict:
    """Mitsuba 3.9.1's RGB ``(eta, k)`` of its conductor presets (the ``material`` parameter):
    ``data/ior/<name>.{eta,k}.spd`` through ``spectrum_list_to_srgb``, as its RGB variants use
    them (``links1/data/conductors_rgb.json``, written by ``tools/make_conductor_rgb.py``)."""
    with open(os.path.join(_DATA, "conductors_rgb.json")) as fh:
        table = json.load(fh)
    return {k: (np.array(v["eta"]), np.array(v["k"])) for k, v in table.items()}


def _scalar(v):
    """A roughness or weight bound to N hits as Mitsuba's ``eval_1`` reads it: (N, 3) RGB (a
    mesh attribute) → luminance; (N,) or a constant as it is."""
    a = np.asarray(v, dtype=np.float64)
    return a @ LUMINANCE if a.ndim == 2 else a


def _texture_mean(v) -> float:
    """Mitsuba's ``Texture::mean``: a bitmap's mean luminance, else the mean of the channels."""
    if isinstance(v, Bitmap):
        return float(v.mean() @ LUMINANCE)
    if isinstance(v, Texture):
        return float(np.mean(v.mean()))
    return float(np.mean(v))


class _Local(Material):
    """Common part: world ↔ local frame, and the world-space doors around ``_eval``,
    ``_pdf`` and ``_sample`` (local frame, Mitsuba's naming: ``wi`` viewer, ``wo`` light)."""

    smooth = True
    glossy = True
    two_sided = False
    #: evaluates both sides itself (roughdielectric): the frame's normal is ``n_raw``
    both_sides = False

    def _frame(self, n, n_raw, tangent):
        z = n_raw if self.both_sides or not self.two_sided else n
        base = n_raw
        if tangent is None:
            s, t = coordinate_system(base)
        else:
            s = tangent - base * dot(base, tangent)[:, None]
            s = s / np.sqrt(dot(s, s))[:, None]
            t = cross(base, s)
        return s, t, z

    @staticmethod
    def _local(v, frame):
        s, t, z = frame
        return np.stack([dot(v, s), dot(v, t), dot(v, z)], axis=-1)

    @staticmethod
    def _world(v, frame):
        s, t, z = frame
        return v[:, 0:1] * s + v[:, 1:2] * t + v[:, 2:3] * z

    def eval(self, wo, wi, n, n_raw, tangent=None):
        fr = self._frame(n, n_raw, tangent)
        return self._eval(self._local(wo, fr), self._local(wi, fr))

    def pdf(self, wo, wi, n, n_raw, tangent=None):
        fr = self._frame(n, n_raw, tangent)
        return self._pdf(self._local(wo, fr), self._local(wi, fr))

    def sample(self, wo, n, n_raw, u, uv, tangent=None):
        fr = self._frame(n, n_raw, tangent)
        wl, weight, pdf = self._sample(self._local(wo, fr), np.asarray(u, dtype=np.float64),
                                       np.asarray(uv, dtype=np.float64))
        ok = np.any(weight != 0, axis=1)   # no sample (pdf 0) where nothing is carried
        return self._world(wl, fr), weight, np.where(ok, pdf, 0.0)

    def _bcast(self, v, n):
        return np.broadcast_to(np.asarray(v, dtype=np.float64), (n, 3))

    #: parameters Mitsuba reads with ``eval_1`` (one value per point): a texture's scalar
    #: lookup, which is not always the luminance of ``eval`` (``checkerboard`` swaps its colours)
    scalar_params: tuple = ()

    def at(self, uv, given=None):
        bound = super().at(uv, given)
        for k in self.scalar_params:
            v = getattr(self, k)
            if isinstance(v, Texture) and not (given and k in given):
                setattr(bound, k, v.eval_1(uv))
        return bound


@dataclass
class RoughConductor(_Local):
    """Mitsuba ``roughconductor``: a microfacet metal, f = F D G / (4 cos θ_i cos θ_o)
    (Walter et al. eq. 20), Fresnel of the complex index ``eta + i k``; ``eta = 0, k = 1``
    (Mitsuba's ``material='none'``) is a perfect reflector."""

    scalar_params = ("alpha_u", "alpha_v")

    distribution: str = mf.BECKMANN
    alpha_u: object = 0.1
    alpha_v: object = None
    eta: object = 0.0
    k: object = 1.0
    specular_reflectance: object = 1.0
    sample_visible: bool = True
    two_sided: bool = False
    name: str = ""

    def __post_init__(self):
        if self.alpha_v is None:
            self.alpha_v = self.alpha_u
        self.eta, self.k = _rgb(self.eta), _rgb(self.k)
        self.specular_reflectance = _rgb(self.specular_reflectance)
        mf.Microfacet(self.distribution, 0.1)   # checks the name

    def _distr(self):
        return mf.Microfacet(self.distribution, _scalar(self.alpha_u), _scalar(self.alpha_v),
                             self.sample_visible)

    def _fresnel(self, cos_i, n):
        return (mf.fresnel_conductor(cos_i, self._bcast(self.eta, n), self._bcast(self.k, n))
                * self.specular_reflectance)

    def _eval(self, wi, wo):
        n = wi.shape[0]
        ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        h = mf._normalize(wi + wo)
        d = self._distr()
        D = d.eval(h)
        with np.errstate(divide="ignore", invalid="ignore"):
            val = D * d.G(wi, wo, h) / (4.0 * wi[:, 2])   # Walter et al. eq. (20), times cos θ_o
        f = val[:, None] * self._fresnel(dot(wi, h), n)
        return np.where((ok & (D != 0))[:, None], np.nan_to_num(f), 0.0)

    def _pdf(self, wi, wo):
        h = mf._normalize(wi + wo)
        ok = (wi[:, 2] > 0) & (wo[:, 2] > 0) & (dot(wi, h) > 0) & (dot(wo, h) > 0)
        d = self._distr()
        with np.errstate(divide="ignore", invalid="ignore"):
            if self.sample_visible:
                p = d.eval(h) * d.smith_g1(wi, h) / (4.0 * wi[:, 2])
            else:
                p = d.pdf(wi, h) / (4.0 * dot(wo, h))
        return np.where(ok, np.nan_to_num(p), 0.0)

    def _sample(self, wi, u, uv):
        n = wi.shape[0]
        d = self._distr()
        active = wi[:, 2] > 0
        m, pdf = d.sample(wi, uv[:, 0], uv[:, 1])
        wo = mf.reflect(wi, m)
        active &= (pdf != 0) & (wo[:, 2] > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            if self.sample_visible:
                w = d.smith_g1(wo, m)
            else:
                w = d.G(wi, wo, m) * dot(wi, m) / (wi[:, 2] * m[:, 2])
            pdf = pdf / (4.0 * dot(wo, m))
        weight = w[:, None] * self._fresnel(dot(wi, m), n)
        return (wo, np.where(active[:, None], np.nan_to_num(weight), 0.0),
                np.where(active, np.nan_to_num(pdf), 0.0))


@dataclass
class RoughPlastic(_Local):
    """Mitsuba ``roughplastic``: a rough dielectric coating (``eta``, inside over outside) over a
    diffuse base, with Mitsuba's precomputed rough transmittance and internal reflectance
    (:func:`links1.shading.microfacet.rough_plastic_tables`)."""

    distribution: str = mf.BECKMANN
    alpha: float = 0.1
    eta: float = 1.49 / 1.000277
    diffuse_reflectance: object = 0.5
    specular_reflectance: object = 1.0
    nonlinear: bool = False
    sample_visible: bool = True
    two_sided: bool = False
    name: str = ""

    def __post_init__(self):
        self.alpha = float(self.alpha)
        self.eta = float(self.eta)
        if not (np.isfinite(self.eta) and self.eta > 0 and self.eta != 1.0):
            raise ValueError(f"relative ior must be > 0 and differ from 1, got {self.eta}")
        self.diffuse_reflectance = _rgb(self.diffuse_reflectance)
        self.specular_reflectance = _rgb(self.specular_reflectance)
        d_mean = _texture_mean(self.diffuse_reflectance)
        s_mean = _texture_mean(self.specular_reflectance)
        self.specular_sampling_weight = s_mean / (d_mean + s_mean)
        self.inv_eta2 = 1.0 / (self.eta * self.eta)
        self.external_transmittance, self.internal_reflectance = mf.rough_plastic_tables(
            self.distribution, max(self.alpha, 1e-4), self.eta)

    def _distr(self):
        return mf.Microfacet(self.distribution, self.alpha, None, self.sample_visible)

    def _prob_specular(self, cos_i):
        t_i = mf.lerp_table(self.external_transmittance, cos_i)
        ps = (1.0 - t_i) * self.specular_sampling_weight
        pd = t_i * (1.0 - self.specular_sampling_weight)
        return ps / (ps + pd)

    def _coat(self, wi, wo):
        """Both sides above the surface, and the rough coat's ``F D G / (4 cos θ_i)`` (Walter
        et al. eq. 20 times cos θ_o): the specular lobe of roughplastic and pplastic."""
        ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        d = self._distr()
        h = mf._normalize(wi + wo)
        F = mf.fresnel(dot(wi, h), self.eta)[0]
        with np.errstate(divide="ignore", invalid="ignore"):
            return ok, np.nan_to_num(F * d.eval(h) * d.G(wi, wo, h) / (4.0 * wi[:, 2]))

    def _eval(self, wi, wo):
        ok, spec = self._coat(wi, wo)
        t_i = mf.lerp_table(self.external_transmittance, wi[:, 2])
        t_o = mf.lerp_table(self.external_transmittance, wo[:, 2])
        diff = np.asarray(self.diffuse_reflectance)
        diff = diff / (1.0 - (diff * self.internal_reflectance if self.nonlinear
                              else self.internal_reflectance))
        val = (spec[:, None] * self.specular_reflectance
               + diff * (self.inv_eta2 / math.pi * wo[:, 2] * t_i * t_o)[:, None])
        return np.where(ok[:, None], val, 0.0)

    def _pdf(self, wi, wo):
        ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        ps = self._prob_specular(wi[:, 2])
        d = self._distr()
        h = mf._normalize(wi + wo)
        with np.errstate(divide="ignore", invalid="ignore"):
            if self.sample_visible:
                p = d.eval(h) * d.smith_g1(wi, h) / (4.0 * wi[:, 2])
            else:
                p = d.pdf(wi, h) / (4.0 * dot(wo, h))
        p = np.nan_to_num(p) * ps + (1.0 - ps) * mf.cosine_hemisphere_pdf(wo)
        return np.where(ok, p, 0.0)

    def _sample(self, wi, u, uv):
        active = wi[:, 2] > 0
        spec = active & (u < self._prob_specular(wi[:, 2]))
        m, _ = self._distr().sample(wi, uv[:, 0], uv[:, 1])
        wo = np.where(spec[:, None], mf.reflect(wi, m),
                      mf.square_to_cosine_hemisphere(uv[:, 0], uv[:, 1]))
        pdf = self._pdf(wi, wo)
        active &= pdf > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            weight = self._eval(wi, wo) / pdf[:, None]
        return wo, np.where(active[:, None], weight, 0.0), np.where(active, pdf, 0.0)


@dataclass
class RoughDielectric(_Local):
    """Mitsuba ``roughdielectric``: rough glass (Walter et al. eq. 20 reflected, eq. 21
    transmitted, with Mitsuba's radiance scaling (η_i/η_t)² of the transmitted part).
    Both sides act; ``eta`` is inside over outside."""

    scalar_params = ("alpha_u", "alpha_v")

    distribution: str = mf.BECKMANN
    alpha_u: object = 0.1
    alpha_v: object = None
    eta: float = 1.5046 / 1.000277
    specular_reflectance: object = 1.0
    specular_transmittance: object = 1.0
    sample_visible: bool = True
    name: str = ""
    both_sides = True

    def __post_init__(self):
        if self.alpha_v is None:
            self.alpha_v = self.alpha_u
        self.eta = float(self.eta)
        if not (np.isfinite(self.eta) and self.eta > 0 and self.eta != 1.0):
            raise ValueError(f"relative ior must be > 0 and differ from 1, got {self.eta}")
        self.specular_reflectance = _rgb(self.specular_reflectance)
        self.specular_transmittance = _rgb(self.specular_transmittance)
        mf.Microfacet(self.distribution, 0.1)

    def _distr(self):
        return mf.Microfacet(self.distribution, _scalar(self.alpha_u), _scalar(self.alpha_v),
                             self.sample_visible)

    def _half(self, wi, wo):
        reflect = wi[:, 2] * wo[:, 2] > 0
        eta = np.where(wi[:, 2] > 0, self.eta, 1.0 / self.eta)
        m = mf._normalize(wi + wo * np.where(reflect, 1.0, eta)[:, None])
        m = m * np.where(m[:, 2] < 0, -1.0, 1.0)[:, None]
        return reflect, eta, m

    def _eval(self, wi, wo):
        active = wi[:, 2] != 0
        reflect, eta, m = self._half(wi, wo)
        d = self._distr()
        D = d.eval(m)
        F = mf.fresnel(dot(wi, m), self.eta)[0]
        G = d.G(wi, wo, m)
        with np.errstate(divide="ignore", invalid="ignore"):
            r = F * D * G / (4.0 * np.abs(wi[:, 2]))                       # eq. (20)
            dwm, dom = dot(wi, m), dot(wo, m)
            t = np.abs((1.0 - F) * D * G * eta * eta * dwm * dom          # eq. (21), times
                       / (wi[:, 2] * (dwm + eta * dom) ** 2)) / (eta * eta)  # 1/η² (radiance)
        val = np.where(reflect[:, None], np.nan_to_num(r)[:, None] * self.specular_reflectance,
                       np.nan_to_num(t)[:, None] * self.specular_transmittance)
        return np.where(active[:, None], val, 0.0)

    def _pdf(self, wi, wo):
        active = wi[:, 2] != 0
        reflect, eta, m = self._half(wi, wo)
        active &= (dot(wi, m) * wi[:, 2] > 0) & (dot(wo, m) * wo[:, 2] > 0)
        dom = dot(wo, m)
        with np.errstate(divide="ignore", invalid="ignore"):
            dwh = np.where(reflect, 1.0 / (4.0 * dom), eta * eta * dom / (dot(wi, m) + eta * dom) ** 2)
            d = self._distr()
            if not self.sample_visible:
                d = d.scaled(1.2 - 0.2 * np.sqrt(np.abs(wi[:, 2])))
            prob = d.pdf(wi * np.where(wi[:, 2] < 0, -1.0, 1.0)[:, None], m)
            F = mf.fresnel(dot(wi, m), self.eta)[0]
            prob = prob * np.where(reflect, F, 1.0 - F)
            p = np.nan_to_num(prob * np.abs(dwh))
        return np.where(active, p, 0.0)

    def _sample(self, wi, u, uv):
        active = wi[:, 2] != 0
        d = self._distr()
        sd = d if self.sample_visible else d.scaled(1.2 - 0.2 * np.sqrt(np.abs(wi[:, 2])))
        m, pdf = sd.sample(wi * np.where(wi[:, 2] < 0, -1.0, 1.0)[:, None], uv[:, 0], uv[:, 1])
        active &= pdf != 0
        F, cos_t, eta_it, eta_ti = mf.fresnel(dot(wi, m), self.eta)
        sel_r = u <= F
        pdf = pdf * np.where(sel_r, F, 1.0 - F)
        wo_r = mf.reflect(wi, m)
        wo_t = mf.refract(wi, m, cos_t, eta_ti)
        wo = np.where(sel_r[:, None], wo_r, wo_t)
        bs_eta = np.where(sel_r, 1.0, eta_it)
        weight = np.where(sel_r[:, None], self._bcast(self.specular_reflectance, wi.shape[0]),
                          (eta_ti * eta_ti)[:, None] * self.specular_transmittance)
        with np.errstate(divide="ignore", invalid="ignore"):
            dwh = np.where(sel_r, 1.0 / (4.0 * dot(wo, m)),
                           bs_eta * bs_eta * dot(wo, m) / (dot(wi, m) + bs_eta * dot(wo, m)) ** 2)
            if self.sample_visible:
                g = d.smith_g1(wo, m)
            else:
                g = d.G(wi, wo, m) * dot(wi, m) / (wi[:, 2] * m[:, 2])
            pdf = np.nan_to_num(pdf * np.abs(dwh))
        weight = np.nan_to_num(weight * g[:, None])
        return wo, np.where(active[:, None], weight, 0.0), np.where(active, pdf, 0.0)


@dataclass
class Blend(Material):
    """Mitsuba ``blendbsdf``: ``(1 - w) bsdf_0 + w bsdf_1`` with ``w`` the weight (a float or a
    texture read as its luminance, clamped to [0, 1]).

    Non-delta lobes are evaluated and sampled as Mitsuba mixes them (``sample`` draws from
    ``bsdf_1`` where ``u ≤ w``, the one-sample mixture density); delta lobes of nested
    conductors, dielectrics and plastics become the mirror and refraction rays of eq. (3.13)
    and (3.16), weighted alike. Where one nested BSDF has no non-delta lobe, ``sample`` draws
    from the other alone (the delta lobe is traced as a ray, not sampled).
    """

    bsdf_0: Material = None
    bsdf_1: Material = None
    weight: object = 0.5
    name: str = ""

    def __post_init__(self):
        if not isinstance(self.weight, Texture):
            w = np.asarray(self.weight, dtype=np.float64)
            w = w if w.ndim == 0 or np.all(w == w.flat[0]) else w @ LUMINANCE
            self.weight = np.asarray(np.clip(float(np.ravel(w)[0]), 0.0, 1.0))
        a, b = self.bsdf_0, self.bsdf_1
        self.smooth = bool(getattr(a, "smooth", True) or getattr(b, "smooth", True))
        self.glossy = bool(a.glossy or b.glossy)
        self.has_reflection = a.has_reflection or b.has_reflection
        self.has_transmission = a.has_transmission or b.has_transmission
        refr = [m for m in (a, b) if m.has_transmission]
        self.scale_radiance = any(m.scale_radiance for m in refr)
        self.straight_transmission = all(m.straight_transmission for m in refr) if refr else False
        w = float(np.mean(self._w())) if not isinstance(self.weight, Texture) else 0.5
        self.shadow_t = (1.0 - w) * np.asarray(a.shadow_t) + w * np.asarray(b.shadow_t)
        self.ambient = (1.0 - w) * np.asarray(a.ambient) + w * np.asarray(b.ambient)

    @property
    def two_sided(self) -> bool:
        return all(getattr(m, "two_sided", True) for m in (self.bsdf_0, self.bsdf_1))

    @two_sided.setter
    def two_sided(self, value: bool):   # Mitsuba's twosided around a blend: both nested alike
        for m in (self.bsdf_0, self.bsdf_1):
            if hasattr(m, "two_sided"):
                m.two_sided = value

    @property
    def textured(self) -> tuple:
        own = ("weight",) if isinstance(self.weight, Texture) else ()
        return own + tuple(k for k in ("bsdf_0", "bsdf_1") if getattr(self, k).textured)

    def at(self, uv, given=None):
        if not self.textured:
            return self
        bound = copy.copy(self)
        if isinstance(self.weight, Texture):
            bound.weight = np.clip(self.weight.eval_1(uv), 0.0, 1.0)
        bound.bsdf_0 = self.bsdf_0.at(uv, given)
        bound.bsdf_1 = self.bsdf_1.at(uv, given)
        return bound

    def _w(self):
        w = np.asarray(self.weight, dtype=np.float64)
        return w[:, None] if w.ndim == 1 else w.reshape(1, 1)

    def eval(self, wo, wi, n, n_raw, tangent=None):
        w = self._w()
        return ((1.0 - w) * _call(self.bsdf_0.eval, wo, wi, n, n_raw, tangent)
                + w * _call(self.bsdf_1.eval, wo, wi, n, n_raw, tangent))

    def pdf(self, wo, wi, n, n_raw, tangent=None):
        w0, w1 = self._sample_weights(wo.shape[0])
        p = np.zeros(wo.shape[0])
        if np.any(w0 > 0):
            p += w0 * _call(self.bsdf_0.pdf, wo, wi, n, n_raw, tangent)
        if np.any(w1 > 0):
            p += w1 * _call(self.bsdf_1.pdf, wo, wi, n, n_raw, tangent)
        return p

    def _sample_weights(self, n):
        """Probabilities of drawing from bsdf_0 and bsdf_1 (those without non-delta lobes: 0)."""
        w = np.broadcast_to(self._w()[:, 0], (n,)).astype(np.float64)
        s0, s1 = getattr(self.bsdf_0, "smooth", True), getattr(self.bsdf_1, "smooth", True)
        if s0 and not s1:
            w = np.zeros(n)
        elif s1 and not s0:
            w = np.ones(n)
        elif not (s0 or s1):
            return np.zeros(n), np.zeros(n)
        return 1.0 - w, w

    def sample(self, wo, n, n_raw, u, uv, tangent=None):
        m = wo.shape[0]
        u = np.asarray(u, dtype=np.float64)
        w0, w1 = self._sample_weights(m)
        pick1 = u <= w1
        wi = np.zeros((m, 3))
        drawn = np.zeros(m, dtype=bool)   # the chosen lobe gave a sample
        with np.errstate(divide="ignore", invalid="ignore"):
            u0 = np.where(w0 > 0, (u - w1) / np.where(w0 > 0, w0, 1.0), 0.0)
            u1 = np.where(w1 > 0, u / np.where(w1 > 0, w1, 1.0), 0.0)
        for sel, mat, uu in ((~pick1 & (w0 > 0), self.bsdf_0, u0), (pick1 & (w1 > 0), self.bsdf_1, u1)):
            if np.any(sel):
                i = np.nonzero(sel)[0]
                wi[i], _, p = _call_sample(mat, wo[i], n[i], n_raw[i], uu[i], uv[i],
                                           None if tangent is None else tangent[i])
                drawn[i] = p > 0
        pdf = np.where(drawn, self.pdf(wo, wi, n, n_raw, tangent), 0.0)
        f = self.eval(wo, wi, n, n_raw, tangent)
        ok = pdf > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            weight = np.where(ok[:, None], f / np.where(ok, pdf, 1.0)[:, None], 0.0)
        return wi, weight, pdf

    def specular(self, wo, n, entering):
        m = wo.shape[0]
        w = self._w()
        r0, t0, e0 = self.bsdf_0.specular(wo, n, entering)
        r1, t1, e1 = self.bsdf_1.specular(wo, n, entering)
        eta = np.where(np.any(t1 > 0, axis=1) & self.bsdf_1.has_transmission, e1, e0) \
            if self.bsdf_1.has_transmission else e0
        r = (1.0 - w) * r0 + w * r1
        t = (1.0 - w) * t0 + w * t1
        return np.broadcast_to(r, (m, 3)), np.broadcast_to(t, (m, 3)), eta


def _call(fn, wo, wi, n, n_raw, tangent):
    """A nested material's eval/pdf, passing ``tangent`` only to those that take it."""
    if tangent is not None and isinstance(getattr(fn, "__self__", None), (_Local, Blend)):
        return fn(wo, wi, n, n_raw, tangent=tangent)
    return fn(wo, wi, n, n_raw)


def _call_sample(mat, wo, n, n_raw, u, uv, tangent):
    """``mat.sample`` in the shading frame of ``tangent`` (Mitsuba's ``dp_du``) where one is
    given: every material's sampler takes it (a diffuse one too, whose cosine samples turn
    with the frame)."""
    if tangent is not None:
        return mat.sample(wo, n, n_raw, u, uv, tangent=tangent)
    return mat.sample(wo, n, n_raw, u, uv)



@dataclass
class PolarizedPlastic(RoughPlastic):
    """Mitsuba ``pplastic`` as its RGB variants evaluate it (``src/bsdfs/pplastic.cpp``, the
    unpolarised branch): a rough specular lobe ``F D G / (4 cos θ_i)`` (Walter et al. eq. 20,
    times cos θ_o; anisotropic roughness allowed) over a diffuse base
    ``(1 - F(cos θ_i)) ρ (1 - F(cos θ_o)) cos θ_o / π``, without roughplastic's internal
    scattering; its density and samples are roughplastic's with a constant probability
    ``s / (d + s)`` (the textures' means) of the microfacet lobe. ``alpha`` and ``nonlinear``
    are not used."""

    scalar_params = ("alpha_u", "alpha_v")

    alpha_u: object = 0.1
    alpha_v: object = None

    def __post_init__(self):
        if self.alpha_v is None:
            self.alpha_v = self.alpha_u
        self.eta = float(self.eta)
        if not (np.isfinite(self.eta) and self.eta > 0):
            raise ValueError(f"relative ior must be > 0, got {self.eta}")
        self.diffuse_reflectance = _rgb(self.diffuse_reflectance)
        self.specular_reflectance = _rgb(self.specular_reflectance)
        s_mean = _texture_mean(self.specular_reflectance)
        self.specular_sampling_weight = s_mean / (_texture_mean(self.diffuse_reflectance) + s_mean)
        mf.Microfacet(self.distribution, 0.1)

    def _distr(self):
        return mf.Microfacet(self.distribution, _scalar(self.alpha_u), _scalar(self.alpha_v),
                             self.sample_visible)

    def _prob_specular(self, cos_i):
        return np.full(np.shape(cos_i), self.specular_sampling_weight)

    def _eval(self, wi, wo):
        ok, spec = self._coat(wi, wo)
        r_i, r_o = mf.fresnel(wi[:, 2], self.eta)[0], mf.fresnel(wo[:, 2], self.eta)[0]
        diffuse = (1.0 - r_o) * (1.0 - r_i) * wo[:, 2] / math.pi
        val = (spec[:, None] * self.specular_reflectance
               + np.asarray(self.diffuse_reflectance) * diffuse[:, None])
        return np.where(ok[:, None], val, 0.0)
