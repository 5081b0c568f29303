"""Microfacet distributions (Beckmann, GGX) in float64, as Mitsuba 3.9.1's
``MicrofacetDistribution`` (``include/mitsuba/render/microfacet.h``) defines them.

Every vector here is in the local shading frame ``(s, t, n)`` (z along the normal), in
Mitsuba's naming: ``wi`` toward the viewer, ``wo`` toward the light. The formulas are those
of Walter et al., "Microfacet Models for Refraction through Rough Surfaces" (EGSR 2007):
D (eq. 25 Beckmann, eq. 33 GGX), Smith's G1 (eq. 27 with the rational fit of the Beckmann
case, eq. 34 GGX), G = G1(wi) G1(wo) (eq. 23); visible normals are sampled after Heitz &
d'Eon, "Importance Sampling Microfacet-Based BSDFs using the Distribution of Visible
Normals" (EGSR 2014), with Jakob's numerical inversion of the Beckmann case and Heitz's
"A Simpler and Exact Sampling Routine for the GGX Distribution of Visible Normals" (2017).
"""
from __future__ import annotations

import functools
import math

import numpy as np

from ..maths.vec import dot

BECKMANN, GGX = "beckmann", "ggx"
INV_SQRT_PI = 1.0 / math.sqrt(math.pi)


# ------------------------------------------------------------------ error function
@functools.lru_cache(maxsize=1)
def _erf_grid():
    x = np.linspace(0.0, 6.0, 6001)
    return x, np.array([math.erf(v) for v in x]), 2.0 * INV_SQRT_PI * np.exp(-x * x) * (x[1] - x[0])


def erf(x) -> np.ndarray:
    """``erf`` elementwise to ~1e-14: cubic Hermite interpolation of ``math.erf`` on a grid of
    step 1e-3 with the exact derivative ``2/√π exp(-x²)``."""
    x = np.asarray(x, dtype=np.float64)
    ax = np.minimum(np.abs(x), 6.0)
    gx, gy, gd = _erf_grid()
    xs = ax * (gx.size - 1) / gx[-1]
    i = np.minimum(xs.astype(np.int64), gx.size - 2)
    t = xs - i
    y0, y1, d0, d1 = gy[i], gy[i + 1], gd[i], gd[i + 1]
    dy = y1 - y0
    y = y0 + t * (d0 + t * ((3.0 * dy - 2.0 * d0 - d1) + t * (d0 + d1 - 2.0 * dy)))   # Hermite
    return np.copysign(y, x)


def erfinv(x) -> np.ndarray:
    """Inverse error function on (-1, 1): Giles' single-precision approximation ("Approximating
    the erfinv function", GPU Computing Gems, 2011), as Dr.Jit's, polished by two Newton steps."""
    x = np.asarray(x, dtype=np.float64)
    w = -np.log(np.maximum((1.0 - x) * (1.0 + x), 1e-300))
    small = w < 5.0
    ws = w - 2.5
    p1 = 2.81022636e-08
    for c in (3.43273939e-07, -3.5233877e-06, -4.39150654e-06, 0.00021858087, -0.00125372503,
              -0.00417768164, 0.246640727, 1.50140941):
        p1 = p1 * ws + c
    wl = np.sqrt(w) - 3.0
    p2 = -0.000200214257
    for c in (0.000100950558, 0.00134934322, -0.00367342844, 0.00573950773, -0.0076224613,
              0.00943887047, 1.00167406, 2.83297682):
        p2 = p2 * wl + c
    y = np.where(small, p1, p2) * x
    for _ in range(1):
        d = 2.0 * INV_SQRT_PI * np.exp(-y * y)
        y = y - np.where(d > 0, (erf(y) - x) / np.where(d > 0, d, 1.0), 0.0)
    return y


# ------------------------------------------------------------------ helpers
def square_to_uniform_disk_concentric(u1, u2):
    """Shirley & Chiu's concentric map, as Mitsuba's ``warp::square_to_uniform_disk_concentric``."""
    x, y = 2.0 * u1 - 1.0, 2.0 * u2 - 1.0
    is_zero = (x == 0) & (y == 0)
    quad1 = np.abs(x) > np.abs(y)
    r = np.where(quad1, x, y)
    with np.errstate(divide="ignore", invalid="ignore"):
        rp = np.where(quad1, y, x)
        phi = np.where(quad1, (math.pi / 4) * rp / r, (math.pi / 2) - (math.pi / 4) * rp / r)
    phi = np.where(is_zero, 0.0, phi)
    r = np.where(is_zero, 0.0, r)
    return r * np.cos(phi), r * np.sin(phi)


def square_to_cosine_hemisphere(u1, u2):
    """Mitsuba's ``warp::square_to_cosine_hemisphere`` (Malley's method), local (N, 3)."""
    x, y = square_to_uniform_disk_concentric(u1, u2)
    z = np.sqrt(np.maximum(0.0, 1.0 - x * x - y * y))
    return np.stack([x, y, z], axis=-1)


def cosine_hemisphere_pdf(v):
    return np.maximum(v[..., 2], 0.0) / math.pi


def fresnel(cos_i, eta):
    """Mitsuba's ``fresnel(cos_theta_i, eta)``: ``(F, cos_theta_t, eta_it, eta_ti)`` of a dielectric
    interface of relative index ``eta`` (inside over outside); ``cos_i < 0``: from the inside."""
    cos_i = np.asarray(cos_i, dtype=np.float64)
    eta = np.asarray(eta, dtype=np.float64)
    outside = cos_i >= 0.0
    eta_it = np.where(outside, eta, 1.0 / eta)
    eta_ti = np.where(outside, 1.0 / eta, eta)
    cos_t_sqr = 1.0 - (1.0 - cos_i * cos_i) * eta_ti * eta_ti
    ci = np.abs(cos_i)
    ct = np.sqrt(np.maximum(cos_t_sqr, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        a_s = (ci - eta_it * ct) / (ci + eta_it * ct)
        a_p = (ct - eta_it * ci) / (ct + eta_it * ci)
        r = 0.5 * (a_s * a_s + a_p * a_p)
    matched = eta == 1.0
    r = np.where(matched | (ci == 0.0), np.where(matched, 0.0, 1.0), r)
    cos_t = np.where(cos_i >= 0.0, -ct, ct)
    return r, cos_t, eta_it, eta_ti


def fresnel_conductor(cos_i, eta, k):
    """Unpolarised reflectance of a conductor ``eta + i k`` (Mitsuba's ``fresnel_conductor``):
    ``cos_i`` (N,), ``eta``/``k`` (3,) or (N, 3) → (N, 3)."""
    c = np.asarray(cos_i, dtype=np.float64)[:, None]
    c2 = c * c
    s2 = 1.0 - c2
    s4 = s2 * s2
    temp1 = eta * eta - k * k - s2
    a2pb2 = np.sqrt(np.maximum(temp1 * temp1 + 4.0 * k * k * eta * eta, 0.0))
    a = np.sqrt(np.maximum(0.5 * (a2pb2 + temp1), 0.0))
    term1, term2 = a2pb2 + c2, 2.0 * c * a
    r_s = (term1 - term2) / (term1 + term2)
    term3, term4 = a2pb2 * c2 + s4, term2 * s2
    r_p = r_s * (term3 - term4) / (term3 + term4)
    return 0.5 * (r_s + r_p)


def reflect(wi, m):
    """Mirror ``wi`` about ``m`` (Mitsuba's ``reflect(wi, m)``)."""
    return 2.0 * dot(wi, m)[..., None] * m - wi


def refract(wi, m, cos_t, eta_ti):
    """Mitsuba's ``refract(wi, m, cos_theta_t, eta_ti)``."""
    return m * (dot(wi, m) * eta_ti + cos_t)[..., None] - wi * np.asarray(eta_ti)[..., None]


def _normalize(v):
    return v / np.sqrt(dot(v, v))[..., None]


# ------------------------------------------------------------------ the distribution
class Microfacet:
    """A Beckmann or GGX distribution of roughness ``alpha_u``, ``alpha_v`` (scalars or (N,)),
    clamped to 1e-4 as Mitsuba clamps them."""

    def __init__(self, kind: str, alpha_u, alpha_v=None, sample_visible: bool = True):
        if kind not in (BECKMANN, GGX):
            raise ValueError(f"distribution must be 'beckmann' or 'ggx', got {kind!r}")
        self.kind = kind
        self.alpha_u = np.maximum(np.asarray(alpha_u, dtype=np.float64), 1e-4)
        self.alpha_v = (self.alpha_u if alpha_v is None
                        else np.maximum(np.asarray(alpha_v, dtype=np.float64), 1e-4))
        self.sample_visible = bool(sample_visible)

    def scaled(self, factor) -> "Microfacet":
        return Microfacet(self.kind, self.alpha_u * factor, self.alpha_v * factor, self.sample_visible)

    def eval(self, m):
        """D(m), Walter et al. eq. (25) (Beckmann) / eq. (33) (GGX), anisotropic form."""
        au, av = self.alpha_u, self.alpha_v
        ct = m[..., 2]
        ct2 = ct * ct
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            if self.kind == BECKMANN:
                d = np.exp(-((m[..., 0] / au) ** 2 + (m[..., 1] / av) ** 2) / ct2) / (
                    math.pi * au * av * ct2 * ct2)
            else:
                d = 1.0 / (math.pi * au * av * ((m[..., 0] / au) ** 2 + (m[..., 1] / av) ** 2 + ct2) ** 2)
        d = np.nan_to_num(d, nan=0.0, posinf=0.0)
        return np.where(d * ct > 1e-20, d, 0.0)

    def smith_g1(self, v, m):
        """Smith's G1(v, m), Walter et al. eq. (27) with its rational fit / eq. (34)."""
        xy = (self.alpha_u * v[..., 0]) ** 2 + (self.alpha_v * v[..., 1]) ** 2
        with np.errstate(divide="ignore", invalid="ignore"):
            tan2 = xy / (v[..., 2] ** 2)
            if self.kind == BECKMANN:
                a = 1.0 / np.sqrt(tan2)
                g = np.where(a >= 1.6, 1.0, (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a))
            else:
                g = 2.0 / (1.0 + np.sqrt(1.0 + tan2))
        g = np.where(xy == 0.0, 1.0, g)
        return np.where(dot(v, m) * v[..., 2] <= 0.0, 0.0, g)

    def G(self, wi, wo, m):
        """Walter et al. eq. (23): the separable shadowing-masking term."""
        return self.smith_g1(wi, m) * self.smith_g1(wo, m)

    def pdf(self, wi, m):
        d = self.eval(m)
        if self.sample_visible:
            return d * self.smith_g1(wi, m) * np.abs(dot(wi, m)) / wi[..., 2]
        return d * m[..., 2]

    def sample(self, wi, u1, u2):
        """A microfacet normal for ``wi`` and its density ``(m (N, 3), pdf (N,))``."""
        au, av = self.alpha_u, self.alpha_v
        if not self.sample_visible:
            isotropic = np.all(au == av)
            if isotropic:
                phi = 2.0 * math.pi * u2
                sin_phi, cos_phi = np.sin(phi), np.cos(phi)
                alpha2 = au * au
            else:
                tmp = (av / au) * np.tan(2.0 * math.pi * u2)
                cos_phi = 1.0 / np.sqrt(tmp * tmp + 1.0)
                cos_phi = np.copysign(cos_phi, np.abs(u2 - 0.5) - 0.25)
                sin_phi = cos_phi * tmp
                alpha2 = 1.0 / ((cos_phi / au) ** 2 + (sin_phi / av) ** 2)
            with np.errstate(divide="ignore", invalid="ignore"):
                if self.kind == BECKMANN:
                    ct = 1.0 / np.sqrt(1.0 - alpha2 * np.log(1.0 - u1))
                    ct2 = ct * ct
                    pdf = (1.0 - u1) / (math.pi * au * av * np.maximum(ct2 * ct, 1e-20))
                else:
                    tan2 = alpha2 * u1 / (1.0 - u1)
                    ct = 1.0 / np.sqrt(1.0 + tan2)
                    ct2 = ct * ct
                    temp = 1.0 + tan2 / alpha2
                    pdf = 1.0 / (math.pi * au * av * np.maximum(ct2 * ct, 1e-20) * temp * temp)
            st = np.sqrt(np.maximum(1.0 - ct2, 0.0))
            return np.stack([cos_phi * st, sin_phi * st, ct], axis=-1), pdf
        # visible normals: stretch, sample the alpha = 1 slopes, rotate, unstretch (Heitz & d'Eon)
        wi_p = _normalize(np.stack([au * wi[..., 0], av * wi[..., 1], wi[..., 2]], axis=-1))
        sin_t = np.sqrt(np.maximum(1.0 - wi_p[..., 2] ** 2, 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            cos_phi = np.where(sin_t > 0, wi_p[..., 0] / np.where(sin_t > 0, sin_t, 1.0), 1.0)
            sin_phi = np.where(sin_t > 0, wi_p[..., 1] / np.where(sin_t > 0, sin_t, 1.0), 0.0)
        cos_phi, sin_phi = np.clip(cos_phi, -1.0, 1.0), np.clip(sin_phi, -1.0, 1.0)
        sx, sy = self._sample_visible_11(wi_p[..., 2], u1, u2)
        sx, sy = (cos_phi * sx - sin_phi * sy) * au, (sin_phi * sx + cos_phi * sy) * av
        m = _normalize(np.stack([-sx, -sy, np.ones_like(sx)], axis=-1))
        return m, self.eval(m) * self.smith_g1(wi, m) * np.abs(dot(wi, m)) / wi[..., 2]

    def _sample_visible_11(self, cos_i, u1, u2):
        if self.kind == BECKMANN:
            with np.errstate(divide="ignore", invalid="ignore"):
                tan_i = np.sqrt(np.maximum(1.0 - cos_i * cos_i, 0.0)) / cos_i
                cot_i = 1.0 / tan_i
            maxval = erf(cot_i)
            u1 = np.clip(u1, 1e-6, 1.0 - 1e-6)
            u2 = np.clip(u2, 1e-6, 1.0 - 1e-6)
            x = maxval - (maxval + 1.0) * erf(np.sqrt(-np.log(u1)))
            with np.errstate(over="ignore", invalid="ignore"):
                u1 = u1 * (1.0 + maxval + INV_SQRT_PI * tan_i * np.exp(-cot_i * cot_i))
            u1 = np.nan_to_num(u1, nan=0.0)
            for _ in range(3):   # Jakob's Newton iterations in the erf domain
                slope = erfinv(x)
                value = 1.0 + x + INV_SQRT_PI * tan_i * np.exp(-slope * slope) - u1
                x = x - value / (1.0 - slope * tan_i)
            return erfinv(x), erfinv(2.0 * u2 - 1.0)
        px, py = square_to_uniform_disk_concentric(u1, u2)
        s = 0.5 * (1.0 + cos_i)
        py = np.sqrt(np.maximum(1.0 - px * px, 0.0)) * (1.0 - s) + py * s
        z = np.sqrt(np.maximum(1.0 - px * px - py * py, 0.0))
        sin_i = np.sqrt(np.maximum(1.0 - cos_i * cos_i, 0.0))
        norm = 1.0 / (sin_i * py + cos_i * z)
        return (cos_i * py - sin_i * z) * norm, px * norm


# ------------------------------------------------------------------ roughplastic's tables
ROUGH_TRANSMITTANCE_RES = 64   # Mitsuba's MI_ROUGH_TRANSMITTANCE_RES


def _gauss_legendre_grid(res):
    nodes, weights = np.polynomial.legendre.leggauss(res)
    nx, ny = np.meshgrid(nodes, nodes, indexing="xy")
    wx, wy = np.meshgrid(weights, weights, indexing="xy")
    return 0.5 * nx.ravel() + 0.5, 0.5 * ny.ravel() + 0.5, (wx * wy).ravel() * 0.25


def _quadrature(distr: Microfacet, wi, eta: float, transmit: bool):
    """Mitsuba's ``eval_reflectance`` / ``eval_transmittance``: the energy a rough dielectric
    interface reflects / transmits for each direction ``wi`` (N, 3), by Gauss-Legendre
    quadrature over visible normals."""
    u1, u2, w = _gauss_legendre_grid(32 if eta > 1 else 128)
    k = u1.size
    v = np.repeat(wi, k, axis=0)
    m, _ = distr.sample(v, np.tile(u1, wi.shape[0]), np.tile(u2, wi.shape[0]))
    f, cos_t, _, eta_ti = fresnel(dot(v, m), eta)
    if transmit:
        wo = refract(v, m, cos_t, eta_ti)
        g = distr.smith_g1(wo, m) * (1.0 - f)
        g = np.where(wo[:, 2] * v[:, 2] >= 0.0, 0.0, g)
    else:
        wo = reflect(v, m)
        g = distr.smith_g1(wo, m) * f
        g = np.where((wo[:, 2] <= 0.0) | (v[:, 2] <= 0.0), 0.0, g)
    return np.sum(g.reshape(-1, k) * w, axis=1)


@functools.lru_cache(maxsize=64)
def rough_plastic_tables(kind: str, alpha: float, eta: float):
    """``(external_transmittance (64,), internal_reflectance)`` of a rough dielectric coating,
    as Mitsuba's ``roughplastic`` precomputes them (``parameters_changed``)."""
    distr = Microfacet(kind, alpha)
    mu = np.maximum(1e-6, np.linspace(0.0, 1.0, ROUGH_TRANSMITTANCE_RES))
    wi = np.stack([np.sqrt(1.0 - mu * mu), np.zeros_like(mu), mu], axis=-1)
    external = _quadrature(distr, wi, eta, transmit=True)
    internal = float(np.mean(_quadrature(distr, wi, 1.0 / eta, transmit=False) * mu) * 2.0)
    external.setflags(write=False)
    return external, internal


def lerp_table(data, x):
    """Mitsuba's ``lerp_gather`` on a table over [0, 1]."""
    n = data.size
    x = np.asarray(x, dtype=np.float64) * (n - 1)
    idx = np.minimum(np.maximum(x, 0.0).astype(np.int64), n - 2)
    t = x - idx
    return data[idx] * (1.0 - t) + data[idx + 1] * t
