"""The loader's BSDFs (:mod:`links1.scene.loader`): Mitsuba's diffuse, conductors,
dielectrics, plastics, their rough forms, principled, blends, masks, normal and bump maps,
links1's Phong, and stand-ins for the rest (a mixin of the loader's builder).
"""
from __future__ import annotations

import warnings

import numpy as np

from ..shading import glossy, normalmaps, principled
from ..shading import materials as mat
from ..shading import textures
from . import params
from .properties import _MISSING, _construct, _Props, _texture
from .xmlparse import Node

# Known Mitsuba 3 plugins the core does not support (for a clearer message than "unknown").
_APPROX_BSDFS = {"hair", "measured", "pplastic", "polarizer",
                 "retarder", "circular", "measured_polarized", "bumpmap",
                 "normalmap"}


def _roughness(props: _Props, name: str, default=_MISSING):
    """A microfacet roughness: a float, or a texture (read as its luminance, Mitsuba's ``eval_1``)."""
    v = props.texture(name, default, unbounded=True)
    if isinstance(v, textures.Texture):
        return v
    v = np.asarray(v, dtype=np.float64)
    return float(v[0]) if np.all(v == v[0]) else float(v @ textures.LUMINANCE)


def _conductor_preset(props: _Props, material: str):
    """Mitsuba's RGB ``(eta, k)`` of a conductor ``material`` name (:data:`glossy.CONDUCTORS`)."""
    table = glossy.conductors()
    if material not in table:
        raise props.error("material", f"unknown conductor material '{material}' "
                                      f"(known: none, {', '.join(table)})")
    return table[material]


def _ior(props: _Props, name: str, default: str) -> float:
    p = props._get(name, ("float", "string", "integer"))
    if p is None:
        return mat.IOR_TABLE[default]
    if p.kind == "string":
        key = p.value.strip().lower()
        if key not in mat.IOR_TABLE:
            raise props.error(name, f"unknown index of refraction '{p.value}' "
                                    f"(known: {', '.join(sorted(mat.IOR_TABLE))})")
        return mat.IOR_TABLE[key]
    v = float(p.value)
    if not v > 0:
        raise props.error(name, f"'{name}' must be > 0, got {v:g}")
    return v


def _warn_turned_delta(node, t: str, *nested) -> None:
    """Warn where a ``normalmap``/``bumpmap`` with mirror or refraction rays sits inside ``t``
    (a blend or a mask): the integrator turns the delta rays of a map it meets at the top only."""
    if any(getattr(m, "delta_frame", None) and (m.has_reflection or m.has_transmission) for m in nested):
        node.warn(f"{t}: the mirror and refraction rays of a normalmap or bumpmap nested in it leave "
                  "about the unturned normal in the core")


class BsdfLoader:
    """BSDFs (methods of the loader's builder)."""

    def bsdf(self, node: Node):
        t = node.type
        props = _Props(node)
        name = node.id or ""
        if t == "diffuse":
            m = mat.Diffuse(reflectance=props.texture("reflectance", 0.5, reflectance=True), name=name)
        elif t == "twosided":
            inner = node.objects("bsdf")
            if not inner:
                raise node.error("twosided needs a nested bsdf")
            if len(inner) > 1:
                node.warn("twosided with two different BSDFs: the core uses the first on both sides")
            m = self.bsdf(inner[0])
            if hasattr(m, "two_sided"):
                m.two_sided = True
            if name:
                m.name = name
        elif t == "conductor":
            refl = props.texture("specular_reflectance", 1.0, reflectance=True)
            material = props.string("material", "none").strip()
            eta = props.texture("eta", None, unbounded=True)
            k = props.texture("k", None, unbounded=True)
            if (eta is None) != (k is None):
                raise node.error("conductor: give both 'eta' and 'k', or neither")
            if eta is not None:
                m = mat.Conductor(specular_reflectance=refl, eta=eta, k=k, name=name)
            elif material != "none":
                eta, k = _conductor_preset(props, material)
                m = mat.Conductor(specular_reflectance=refl, eta=eta, k=k, name=name)
            else:
                m = mat.Conductor(specular_reflectance=refl, name=name)
        elif t in ("roughconductor", "roughdielectric", "roughplastic"):
            m = self._rough_bsdf(node, props, t, name)
        elif t in ("principled", "principledthin"):
            m = self._principled(node, props, t, name)
        elif t == "blendbsdf":
            inner = node.objects("bsdf")
            if len(inner) != 2:
                raise node.error("blendbsdf needs exactly two nested bsdfs")
            a, b = self.bsdf(inner[0]), self.bsdf(inner[1])
            if (a.has_transmission and b.has_transmission and not a.straight_transmission
                    and getattr(a, "eta", None) != getattr(b, "eta", None)):
                raise node.error("blendbsdf of two refracting bsdfs of different index: a Whitted "
                                 "node has one refracted ray (not supported by the core)")
            m = _construct(node, glossy.Blend, bsdf_0=a, bsdf_1=b,
                           weight=props.texture("weight", unbounded=True), name=name)
            _warn_turned_delta(node, t, a, b)
        elif t in ("dielectric", "thindielectric"):
            int_ior = _ior(props, "int_ior", "bk7")
            ext_ior = _ior(props, "ext_ior", "air")
            cls = mat.Dielectric if t == "dielectric" else mat.ThinDielectric
            m = _construct(node, cls, eta=int_ior / ext_ior,
                           specular_reflectance=props.texture("specular_reflectance", 1.0, reflectance=True),
                           specular_transmittance=props.texture("specular_transmittance", 1.0, reflectance=True),
                           name=name)
        elif t == "plastic":
            int_ior = _ior(props, "int_ior", "polypropylene")
            ext_ior = _ior(props, "ext_ior", "air")
            m = _construct(node, mat.Plastic,
                           diffuse_reflectance=props.texture("diffuse_reflectance", 0.5, reflectance=True),
                           specular_reflectance=props.texture("specular_reflectance", 1.0, reflectance=True),
                           eta=int_ior / ext_ior, nonlinear=props.bool("nonlinear", False),
                           name=name)
        elif t == "links1_phong":
            v = {k: props.links1(t, k) for k in params.PLUGINS[("bsdf", t)]}
            m = _construct(node, mat.Phong, ambient=v["ambient"], diffuse=v["diffuse"],
                           specular_=v["specular"], exponent=v["exponent"], reflectance=v["reflectance"],
                           transmittance=v["transmittance"], ior=v["ior"], name=name)
        elif t == "mask":
            inner = node.objects("bsdf")
            if len(inner) != 1:
                raise node.error("mask needs exactly one nested bsdf")
            nested = self.bsdf(inner[0])
            m = _construct(node, mat.Mask, nested=nested, opacity=props.texture("opacity", 0.5),
                           name=name)
            _warn_turned_delta(node, t, nested)
            if m.refracts:
                node.warn("mask around a refracting bsdf: its straight-through part (1 - opacity) "
                          "is dropped (a Whitted node has one transmitted ray)")
        elif t == "null":   # Mitsuba's null: every ray goes straight through (BSDFFlags::Null)
            m = mat.Mask(nested=mat.Material(), opacity=0.0, name=name)
        elif t in ("bumpmap", "normalmap"):
            m = self._perturbed(node, props, t, name)
        elif t == "pplastic":
            m = self._pplastic(node, props, name)
        elif t in _APPROX_BSDFS:
            color = 0.5
            for key in ("reflectance", "diffuse_reflectance", "base_color", "specular_reflectance"):
                if props.has(key) or any(nm == key for nm, _ in node.children):
                    color = props.texture(key, reflectance=True)
                    break
            props.ignore(*node.props)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                m = mat.approximate(t, color=color, name=name)
            what = ("its texture" if textures.is_texture(m.reflectance)
                    else np.round(m.reflectance, 4).tolist())
            node.warn(f"bsdf type '{t}' is not supported by the core; approximated as a diffuse "
                      f"surface of reflectance {what}")
        else:
            raise node.error(f"unknown plugin '{t}' (bsdf)")
        props.finish()
        return m

    def _principled(self, node: Node, props: _Props, t: str, name: str):
        """``principled``, ``principledthin`` (:mod:`links1.shading.principled`): their weights
        are floats or textures."""
        thin = t == "principledthin"
        cls = principled.PrincipledThin if thin else principled.Principled
        defaults = {"roughness": 0.5, "eta": 1.5}
        weights = {k: _roughness(props, k, defaults.get(k, 0.0)) for k in cls.scalar_params}
        rates = ("specular_reflectance_sampling_rate", "specular_transmittance_sampling_rate",
                 "diffuse_reflectance_sampling_rate", "diffuse_transmittance_sampling_rate") if thin else (
            "main_specular_sampling_rate", "clearcoat_sampling_rate", "diffuse_reflectance_sampling_rate")
        rates = {k: props.float(k, 1.0, nonneg=True) for k in rates}
        if not thin:
            rates.update(eta=props.float("eta", None), specular=props.float("specular", None))
        return _construct(node, cls, base_color=props.texture("base_color", 0.5, reflectance=True),
                          name=name, **weights, **rates)

    def _perturbed(self, node: Node, props: _Props, t: str, name: str):
        """``normalmap`` / ``bumpmap`` around their nested bsdf (:mod:`links1.shading.normalmaps`)."""
        inner = node.objects("bsdf")
        if len(inner) != 1:
            raise node.error(f"{t} needs exactly one nested bsdf")
        nested = self.bsdf(inner[0])
        common = dict(nested=nested, flip_invalid_normals=props.bool("flip_invalid_normals", True),
                      use_shadowing_function=props.bool("use_shadowing_function", True), name=name)
        if t == "normalmap":
            m = _construct(node, normalmaps.NormalMap,
                           normalmap=props.texture("normalmap", nonneg=False, unbounded=True), **common)
        else:
            tex = node.objects("texture")
            if len(tex) != 1:
                raise node.error("bumpmap needs exactly one nested texture (the height)")
            if tex[0].type != "bitmap":
                raise tex[0].error(f"bumpmap: Mitsuba takes the gradient of a bitmap height texture "
                                   f"only, not of a '{tex[0].type}'")
            props.ignore(*[nm for nm, c in node.children if c is tex[0] and nm])
            m = _construct(node, normalmaps.BumpMap, texture=_texture(tex[0]),
                           scale=props.float("scale", 1.0), **common)
        return m

    def _pplastic(self, node: Node, props: _Props, name: str):
        """``pplastic`` as Mitsuba's RGB variants evaluate it (:class:`links1.shading.glossy.PolarizedPlastic`)."""
        distribution = props.string("distribution", "beckmann").strip().lower()
        if distribution not in ("beckmann", "ggx"):
            raise props.error("distribution", f"invalid distribution '{distribution}', must be "
                                              "'beckmann' or 'ggx'")
        if props.has("eta"):
            if props.has("int_ior"):
                raise props.error("eta", "give either 'eta' or 'int_ior' and 'ext_ior', not both")
            eta = props.float("eta", positive=True)
        else:
            int_ior, ext_ior = _ior(props, "int_ior", "polypropylene"), _ior(props, "ext_ior", "air")
            if int_ior == ext_ior:
                raise node.error("the interior and exterior indices of refraction must differ")
            eta = int_ior / ext_ior
        if props.has("alpha_u") or props.has("alpha_v"):
            if props.has("alpha"):
                raise props.error("alpha", "give either 'alpha' or 'alpha_u'/'alpha_v'")
            if not (props.has("alpha_u") and props.has("alpha_v")):
                raise node.error("both 'alpha_u' and 'alpha_v' must be given")
            alpha = (_roughness(props, "alpha_u"), _roughness(props, "alpha_v"))
        else:
            alpha = (_roughness(props, "alpha", 0.1),) * 2
        return _construct(node, glossy.PolarizedPlastic, distribution=distribution,
                          alpha_u=alpha[0], alpha_v=alpha[1], eta=eta,
                          diffuse_reflectance=props.texture("diffuse_reflectance", 0.5, reflectance=True),
                          specular_reflectance=props.texture("specular_reflectance", 1.0, reflectance=True),
                          sample_visible=props.bool("sample_visible", True), name=name)

    def _rough_bsdf(self, node: Node, props: _Props, t: str, name: str):
        """``roughconductor``, ``roughdielectric``, ``roughplastic`` (:mod:`links1.shading.glossy`)."""
        distribution = props.string("distribution", "beckmann").strip().lower()
        if distribution not in ("beckmann", "ggx"):
            raise props.error("distribution", f"invalid distribution '{distribution}', must be "
                                              "'beckmann' or 'ggx'")
        common = dict(distribution=distribution, sample_visible=props.bool("sample_visible", True),
                      name=name)
        anisotropic = props.has("alpha_u") or props.has("alpha_v")
        if anisotropic:
            if props.has("alpha"):
                raise props.error("alpha", "give either 'alpha' or 'alpha_u'/'alpha_v'")
            if not (props.has("alpha_u") and props.has("alpha_v")):
                raise node.error("both 'alpha_u' and 'alpha_v' must be given")
            if t == "roughplastic":
                raise node.error("roughplastic does not support anisotropic roughness (Mitsuba "
                                 "refuses it too)")
            alpha = (_roughness(props, "alpha_u"), _roughness(props, "alpha_v"))
        else:
            alpha = (_roughness(props, "alpha", 0.1),) * 2
        if t == "roughplastic":
            int_ior, ext_ior = _ior(props, "int_ior", "polypropylene"), _ior(props, "ext_ior", "air")
            if int_ior == ext_ior:
                raise node.error("the interior and exterior indices of refraction must differ")
            if isinstance(alpha[0], textures.Texture):
                raise props.error("alpha", "roughplastic's 'alpha' cannot be a texture (Mitsuba "
                                           "precomputes its tables for one roughness)")
            return _construct(node, glossy.RoughPlastic, alpha=alpha[0], eta=int_ior / ext_ior,
                              diffuse_reflectance=props.texture("diffuse_reflectance", 0.5, reflectance=True),
                              specular_reflectance=props.texture("specular_reflectance", 1.0, reflectance=True),
                              nonlinear=props.bool("nonlinear", False), **common)
        if t == "roughdielectric":
            int_ior, ext_ior = _ior(props, "int_ior", "bk7"), _ior(props, "ext_ior", "air")
            if int_ior == ext_ior:
                raise node.error("the interior and exterior indices of refraction must differ")
            return _construct(node, glossy.RoughDielectric, alpha_u=alpha[0], alpha_v=alpha[1],
                              eta=int_ior / ext_ior,
                              specular_reflectance=props.texture("specular_reflectance", 1.0, reflectance=True),
                              specular_transmittance=props.texture("specular_transmittance", 1.0, reflectance=True),
                              **common)
        material = props.string("material", "none").strip()
        if props.has("eta") or material == "none":
            if material != "none":
                raise node.error("give either 'eta'/'k' or 'material', not both")
            eta = props.texture("eta", 0.0, unbounded=True)
            k = props.texture("k", 1.0, unbounded=True)
        else:
            eta, k = _conductor_preset(props, material)
        return _construct(node, glossy.RoughConductor, alpha_u=alpha[0], alpha_v=alpha[1], eta=eta, k=k,
                          specular_reflectance=props.texture("specular_reflectance", 1.0, reflectance=True),
                          **common)
