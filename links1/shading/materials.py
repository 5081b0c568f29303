"""Surface finishes: the paper's Phong model (eq. 3.11) and Mitsuba's BSDFs in Mitsuba's units.

The integrator asks a material three things for a batch of N hits (all directions unit,
``n`` the shading normal already turned to face the viewer, ``wo`` toward the viewer,
``wi`` toward a light):

* ``ambient`` (3,): the constant term ``dic`` of eq. (3.11);
* ``eval(wo, wi, n, n_raw)`` (N, 3): the factor that multiplies the light strength ``L_s``;
  ``n_raw`` is the shading normal before turning (Mitsuba's one-sided BSDFs need it);
* ``specular(wo, n, entering)`` → ``(r, t, eta)``: weights of the mirror ray (eq. 3.13) and
  the transmitted ray (eq. 3.16), and the relative index ``η = η_i/η_t`` of eq. (3.14/3.15);
* ``shadow_t`` (3,): the transmittance a shadow ray sees through this object (eq. 3.12 note).

A colour parameter of a Mitsuba BSDF may be a :class:`links1.shading.textures.Texture`; ``at(uv)``
returns the material with every texture evaluated at the hits' ``uv`` (``(N, 3)`` arrays in
place of ``(3,)``), which ``eval`` and ``specular`` broadcast alike.
"""
from __future__ import annotations

import copy
import warnings
from dataclasses import dataclass, field

import numpy as np

from .textures import LUMINANCE as _LUMINANCE, Texture, upper_bound
from .microfacet import square_to_cosine_hemisphere
from ..maths.vec import coordinate_system, cross, dot as _dot

# Mitsuba's named indices of refraction (src/core/... ior.h), used by dielectric/plastic.
IOR_TABLE = {
    "vacuum": 1.0, "helium": 1.000036, "hydrogen": 1.000132, "air": 1.000277,
    "carbon dioxide": 1.00045, "water": 1.3330, "acetone": 1.36, "ethanol": 1.361,
    "carbon tetrachloride": 1.461, "glycerol": 1.4729, "benzene": 1.501,
    "silicone oil": 1.52045, "bromine": 1.661, "water ice": 1.31, "fused quartz": 1.458,
    "pyrex": 1.470, "acrylic glass": 1.49, "polypropylene": 1.49, "bk7": 1.5046,
    "sodium chloride": 1.544, "amber": 1.55, "pet": 1.5750, "diamond": 2.419,
}


def _rgb(v):
    """An RGB constant (3,) float64, or a texture as it is."""
    if isinstance(v, Texture):
        return v
    return np.broadcast_to(np.asarray(v, dtype=np.float64), (3,)).copy()


def _const(v, what: str) -> np.ndarray:
    if isinstance(v, Texture):
        raise ValueError(f"'{what}' cannot be a texture here")
    return _rgb(v)


def fresnel_dielectric(cos_i: np.ndarray, eta: float | np.ndarray) -> np.ndarray:
    """Unpolarised Fresnel reflectance; ``eta = η_t/η_i`` relative to the side of ``cos_i``>0.

    ``cos_i < 0`` means the ray arrives from the inside (the index is inverted), as in
    Mitsuba's ``fresnel``. Total internal reflection gives 1.
    """
    cos_i = np.asarray(cos_i, dtype=np.float64)
    eta = np.where(cos_i >= 0, eta, 1.0 / np.asarray(eta, dtype=np.float64))
    ci = np.abs(cos_i)
    sin_t2 = (1.0 - ci * ci) / (eta * eta)
    tir = sin_t2 >= 1.0
    ct = np.sqrt(np.maximum(0.0, 1.0 - sin_t2))
    rs = (ci - eta * ct) / (ci + eta * ct)
    rp = (eta * ci - ct) / (eta * ci + ct)
    return np.where(tir, 1.0, 0.5 * (rs * rs + rp * rp))


def fresnel_conductor(cos_i: np.ndarray, eta: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Unpolarised Fresnel reflectance of a conductor with complex index ``eta + i k``
    (RGB: (3,) or per hit (N, 3))."""
    ci = np.clip(np.abs(cos_i), 0.0, 1.0)[:, None]
    e = eta + 1j * k
    sin2 = 1.0 - ci * ci
    ct = np.sqrt(1.0 - sin2 / (e * e))
    rs = (ci - e * ct) / (ci + e * ct)
    rp = (e * ci - ct) / (e * ci + ct)
    return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)


def fresnel_diffuse_reflectance(eta: float) -> float:
    """Mitsuba's polynomial fit of the hemispherical Fresnel reflectance (d'Eon & Irving)."""
    if eta < 1.0:
        return -1.4399 * eta * eta + 0.7099 * eta + 0.6681 + 0.0636 / eta
    ie = 1.0 / eta
    ie2, ie3 = ie * ie, ie * ie * ie
    ie4, ie5 = ie3 * ie, ie3 * ie * ie
    return (0.919317 - 3.4793 * ie + 6.75335 * ie2 - 7.80989 * ie3 + 4.98554 * ie4
            - 1.36881 * ie5)


class Material:
    """Interface shared by all finishes (see module docstring)."""

    ambient = np.zeros(3)
    shadow_t = np.zeros(3)
    has_reflection = False
    has_transmission = False
    #: Mitsuba's dielectrics scale transmitted radiance by 1/η² (radiance compression).
    scale_radiance = False
    #: the transmitted ray goes straight on (η = 1: thindielectric, a mask's see-through part)
    straight_transmission = False
    name = ""

    #: has non-delta lobes (``eval`` can be non-zero): BSDF sampling applies
    smooth = False
    #: has glossy lobes (Mitsuba's ``BSDFFlags::Glossy``): under area and environment lights
    #: the integrator adds a BSDF sample to the light samples, combined by multiple importance
    #: sampling (:mod:`links1.tracing.integrator`)
    glossy = False

    def eval(self, wo, wi, n, n_raw):
        return np.zeros((wo.shape[0], 3))

    def sample(self, wo, n, n_raw, u, uv, tangent=None):
        """A direction ``wi`` toward the light drawn from the non-delta lobes with samples ``u``
        (N,) and ``uv`` (N, 2): ``(wi, eval / pdf (N, 3), pdf (N,))``. Here: cosine-weighted
        about ``n`` (Mitsuba's ``diffuse``); the glossy BSDFs (:mod:`links1.shading.glossy`)
        draw from their microfacet lobes. ``tangent`` (N, 3): the shading frame's ``s``
        (Mitsuba's, from ``dp_du``), else ``coordinate_system(n)``'s."""
        nn = self._sampling_normal(n, n_raw)
        local = square_to_cosine_hemisphere(uv[:, 0], uv[:, 1])
        if tangent is None:
            s, t = coordinate_system(nn)
        else:   # the frame of the raw normal, its normal turned as nn (Mitsuba's twosided mirrors)
            s = tangent - n_raw * _dot(n_raw, tangent)[:, None]
            s = s / np.sqrt(_dot(s, s))[:, None]
            t = cross(n_raw, s)
        wi = local[:, 0:1] * s + local[:, 1:2] * t + local[:, 2:3] * nn
        pdf = self.pdf(wo, wi, n, n_raw)
        ok = pdf > 0
        f = self.eval(wo, wi, n, n_raw)
        return wi, np.where(ok[:, None], f / np.where(ok, pdf, 1.0)[:, None], 0.0), pdf

    def pdf(self, wo, wi, n, n_raw):
        """The density (N,) in solid angle that :meth:`sample` draws ``wi`` with (0 where the
        viewer or ``wi`` is behind a one-sided surface, as Mitsuba's ``diffuse``)."""
        nn = self._sampling_normal(n, n_raw)
        cos_l = _dot(nn, wi)
        ok = (_dot(nn, wo) > 0) & (cos_l > 0) & self.smooth
        return np.where(ok, cos_l / np.pi, 0.0)

    def _sampling_normal(self, n, n_raw):
        return n if getattr(self, "two_sided", True) else n_raw

    def specular(self, wo, n, entering):
        z = np.zeros((wo.shape[0], 3))
        return z, z, np.ones(wo.shape[0])

    @property
    def textured(self) -> tuple:
        """Names of the parameters that are textures."""
        return tuple(k for k, v in vars(self).items() if isinstance(v, Texture))

    def at(self, uv, given=None):
        """This material with its textures evaluated at ``uv (N, 2)`` (itself if it has none);
        ``given``: values already evaluated at the hits, by parameter name (mesh attributes)."""
        names = self.textured
        if not names:
            return self
        bound = copy.copy(self)
        for k in names:
            setattr(bound, k, given[k] if given and k in given else getattr(self, k).eval(uv))
        return bound


@dataclass
class Phong(Material):
    """``links1_phong``: the paper's shading, eq. (3.11), in the paper's units (no 1/π).

    ``I = dic + drc Σ L cos θ + src Σ L (cos φ)^n`` plus ``r I_r + t I_t`` (eq. 3.16).
    ``reflectance`` (r) defaults to ``specular`` (src); ``transmittance`` t also scales
    shadow rays through the object, once per object.
    At total internal reflection the transmitted weight moves to the mirror ray.
    """

    smooth = True

    ambient: np.ndarray = field(default_factory=lambda: np.zeros(3))
    diffuse: np.ndarray = field(default_factory=lambda: np.full(3, 0.5))
    specular_: np.ndarray = field(default_factory=lambda: np.zeros(3))
    exponent: float = 20.0
    reflectance: np.ndarray | None = None
    transmittance: np.ndarray = field(default_factory=lambda: np.zeros(3))
    ior: float = 1.0
    name: str = ""

    def __post_init__(self):
        self.ambient = _const(self.ambient, "ambient")
        self.diffuse = _const(self.diffuse, "diffuse")
        self.specular_ = _const(self.specular_, "specular")
        self.reflectance = (self.specular_.copy() if self.reflectance is None
                            else _const(self.reflectance, "reflectance"))
        self.transmittance = _const(self.transmittance, "transmittance")
        self.exponent = float(self.exponent)
        self.ior = float(self.ior)
        if not (np.isfinite(self.ior) and self.ior > 0):
            raise ValueError(f"ior must be > 0, got {self.ior}")
        if not (np.isfinite(self.exponent) and self.exponent >= 0):
            raise ValueError(f"exponent must be >= 0, got {self.exponent}")
        self.shadow_t = self.transmittance
        self.has_reflection = bool(np.any(self.reflectance > 0))
        self.has_transmission = bool(np.any(self.transmittance > 0))
        self.straight_transmission = self.ior == 1.0

    def eval(self, wo, wi, n, n_raw):
        cos_theta = _dot(n, wi)  # eq. (3.11), diffuse term: drc L cos θ
        lit = cos_theta > 0.0
        mirror = 2.0 * cos_theta[:, None] * n - wi  # mirror direction of the light
        cos_phi = np.maximum(_dot(mirror, wo), 0.0)  # eq. (3.11), φ: mirror vs viewer
        spec = cos_phi ** self.exponent if self.exponent > 0 else np.ones_like(cos_phi)
        f = self.diffuse * np.maximum(cos_theta, 0.0)[:, None] + self.specular_ * spec[:, None]
        return np.where(lit[:, None], f, 0.0)

    def specular(self, wo, n, entering):
        m = wo.shape[0]
        r = np.broadcast_to(self.reflectance, (m, 3))
        t = np.broadcast_to(self.transmittance, (m, 3))
        eta = np.where(entering, 1.0 / self.ior, self.ior)  # η = η_i / η_t
        return r, t, eta


@dataclass
class Diffuse(Material):
    """Mitsuba ``diffuse``: f = ρ/π, one-sided (black from behind unless wrapped by twosided)."""

    smooth = True

    reflectance: np.ndarray = field(default_factory=lambda: np.full(3, 0.5))
    two_sided: bool = False
    name: str = ""

    def __post_init__(self):
        self.reflectance = _rgb(self.reflectance)

    def eval(self, wo, wi, n, n_raw):
        nn = n if self.two_sided else n_raw
        cos_v, cos_l = _dot(nn, wo), _dot(nn, wi)
        ok = (cos_v > 0) & (cos_l > 0)
        return np.where(ok[:, None], self.reflectance / np.pi * cos_l[:, None], 0.0)


@dataclass
class Conductor(Material):
    """Mitsuba ``conductor``: a perfect mirror (``material='none'``) or a complex-index metal."""

    specular_reflectance: np.ndarray = field(default_factory=lambda: np.ones(3))
    eta: np.ndarray | None = None
    k: np.ndarray | None = None
    two_sided: bool = False
    name: str = ""

    def __post_init__(self):
        self.specular_reflectance = _rgb(self.specular_reflectance)
        if self.eta is not None:
            self.eta, self.k = _rgb(self.eta), _rgb(self.k)
        self.has_reflection = True

    def specular(self, wo, n, entering):
        m = wo.shape[0]
        if self.eta is None:
            r = np.broadcast_to(self.specular_reflectance, (m, 3)).copy()
        else:
            r = self.specular_reflectance * fresnel_conductor(_dot(wo, n), self.eta, self.k)
        if not self.two_sided:
            r = np.where(entering[:, None], r, 0.0)
        return r, np.zeros((m, 3)), np.ones(m)


@dataclass
class Dielectric(Material):
    """Mitsuba ``dielectric`` (smooth glass): Fresnel-weighted mirror and refraction rays.

    ``eta = int_ior / ext_ior``. Transmitted radiance is scaled by ``(η_i/η_t)²`` as in
    Mitsuba's radiance transport. Opaque to shadow rays (as Mitsuba's ``direct``/``path``).
    """

    eta: float = 1.5046 / 1.000277
    specular_reflectance: np.ndarray = field(default_factory=lambda: np.ones(3))
    specular_transmittance: np.ndarray = field(default_factory=lambda: np.ones(3))
    name: str = ""

    def __post_init__(self):
        self.eta = float(self.eta)
        if not (np.isfinite(self.eta) and self.eta > 0):
            raise ValueError(f"relative ior must be > 0, got {self.eta}")
        self.specular_reflectance = _rgb(self.specular_reflectance)
        self.specular_transmittance = _rgb(self.specular_transmittance)
        self.has_reflection = True
        self.has_transmission = True
        self.scale_radiance = True

    def specular(self, wo, n, entering):
        cos_i = _dot(wo, n)  # n faces the viewer: cos_i >= 0
        eta_rel = np.where(entering, self.eta, 1.0 / self.eta)  # η_t/η_i
        F = fresnel_dielectric(cos_i, eta_rel)
        r = F[:, None] * self.specular_reflectance
        t = (1.0 - F)[:, None] * self.specular_transmittance
        return r, t, 1.0 / eta_rel


@dataclass
class ThinDielectric(Dielectric):
    """Mitsuba ``thindielectric``: a thin slab; transmitted rays go straight through."""

    def __post_init__(self):
        super().__post_init__()
        self.scale_radiance = False  # in and out of the slab: no net radiance scaling
        self.straight_transmission = True

    def specular(self, wo, n, entering):
        R = fresnel_dielectric(np.abs(_dot(wo, n)), self.eta)
        T = 1.0 - R
        R = np.where(R < 1.0, R + T * T * R / (1.0 - R * R), R)
        T = 1.0 - R
        return R[:, None] * self.specular_reflectance, T[:, None] * self.specular_transmittance, np.ones(wo.shape[0])


@dataclass
class Plastic(Material):
    """Mitsuba ``plastic`` (smooth): a Fresnel-weighted mirror coating over a diffuse base."""

    smooth = True

    diffuse_reflectance: np.ndarray = field(default_factory=lambda: np.full(3, 0.5))
    specular_reflectance: np.ndarray = field(default_factory=lambda: np.ones(3))
    eta: float = 1.49 / 1.000277
    nonlinear: bool = False
    two_sided: bool = False
    name: str = ""

    def __post_init__(self):
        self.diffuse_reflectance = _rgb(self.diffuse_reflectance)
        self.specular_reflectance = _rgb(self.specular_reflectance)
        self.eta = float(self.eta)
        if not (np.isfinite(self.eta) and self.eta > 0):
            raise ValueError(f"relative ior must be > 0, got {self.eta}")
        self.fdr_int = fresnel_diffuse_reflectance(1.0 / self.eta)
        self.inv_eta2 = 1.0 / (self.eta * self.eta)
        self.has_reflection = True

    def eval(self, wo, wi, n, n_raw):
        nn = n if self.two_sided else n_raw
        cos_v, cos_l = _dot(nn, wo), _dot(nn, wi)
        ok = (cos_v > 0) & (cos_l > 0)
        f_i = fresnel_dielectric(np.abs(cos_v), self.eta)
        f_o = fresnel_dielectric(np.abs(cos_l), self.eta)
        d = self.diffuse_reflectance
        denom = 1.0 - (d * self.fdr_int if self.nonlinear else self.fdr_int)
        val = (d / denom) * (self.inv_eta2 / np.pi * cos_l * (1 - f_i) * (1 - f_o))[:, None]
        return np.where(ok[:, None], val, 0.0)

    def specular(self, wo, n, entering):
        m = wo.shape[0]
        F = fresnel_dielectric(np.abs(_dot(wo, n)), self.eta)
        r = F[:, None] * self.specular_reflectance
        if not self.two_sided:
            r = np.where(entering[:, None], r, 0.0)
        return r, np.zeros((m, 3)), np.ones(m)




@dataclass
class Mask(Material):
    """Mitsuba ``mask``: the nested finish with weight ``a`` (the opacity), a straight-through
    delta lobe with weight ``1 - a`` (Mitsuba's ``BSDFFlags::Null``).

    ``eval`` is ``a`` times the nested one; the mirror ray's weight is ``a r``; the transmitted
    ray goes straight on (η = 1) with weight ``1 - a + a t`` when the nested finish's own
    transmission is straight too (``thindielectric``, ``null``) or absent. Around a refracting
    finish (``dielectric``) only its refracted ray ``a t`` is kept (the loader warns). Opaque to
    shadow rays, as in Mitsuba's ``direct``/``path`` (their shadow tests are binary).
    """

    nested: Material = None
    opacity: np.ndarray = field(default_factory=lambda: np.full(3, 0.5))
    name: str = ""

    def __post_init__(self):
        self.opacity = _rgb(self.opacity)
        self.has_reflection = self.nested.has_reflection
        self.has_transmission = True
        self.scale_radiance = self.nested.scale_radiance
        #: the nested transmission bends the ray: the straight part cannot ride on it
        self.refracts = self.nested.has_transmission and not self.nested.straight_transmission
        self.straight_transmission = not self.refracts

    @property
    def smooth(self) -> bool:
        return self.nested.smooth

    @property
    def glossy(self) -> bool:
        return self.nested.glossy

    @property
    def textured(self) -> tuple:
        own = tuple(k for k, v in vars(self).items() if isinstance(v, Texture))
        return own + (("nested",) if self.nested.textured else ())

    def at(self, uv, given=None):
        if not self.textured:
            return self
        bound = copy.copy(self)
        if isinstance(self.opacity, Texture):   # a scalar lookup: Mitsuba's eval_1
            a = (given["opacity"] @ _LUMINANCE if given and "opacity" in given
                 else self.opacity.eval_1(uv))
            bound.opacity = np.clip(a, 0.0, 1.0)[:, None]
        bound.nested = self.nested.at(uv, given)
        return bound

    def _a(self):
        """The opacity as Mitsuba's ``eval_1`` reads it (luminance), clamped to [0, 1]: (N, 1) or (1,)."""
        a = np.asarray(self.opacity)
        if a.ndim == 2:         # bound to the hits by ``at``
            return a
        return np.clip(a @ _LUMINANCE, 0.0, 1.0).reshape(1)

    def eval(self, wo, wi, n, n_raw):
        return self._a() * self.nested.eval(wo, wi, n, n_raw)

    def specular(self, wo, n, entering):
        a = self._a()
        r, t, eta = self.nested.specular(wo, n, entering)
        if self.refracts:
            return a * r, a * t, eta
        return a * r, a * t + (1.0 - a), np.ones(wo.shape[0])


def approximate(kind: str, color=0.5, name: str = "") -> Material:
    """Stand-in for an unsupported BSDF: a Mitsuba diffuse of the given colour, with a warning."""
    warnings.warn(f"bsdf type '{kind}' is not supported by the core; approximated as diffuse",
                  stacklevel=2)
    return Diffuse(reflectance=color, name=name)
