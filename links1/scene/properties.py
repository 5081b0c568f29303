"""An element's parameters, read with Mitsuba's rules (the loader's part shared by every
element): :class:`_Props`, typed access with Mitsuba's "unreferenced property" refusal
(:func:`refused_parameter`) and its report of parameters the core does not use; colours and
spectra (:mod:`links1.shading.spectra`), textures (:mod:`links1.shading.textures`), and
:func:`_construct`, which turns a core constructor's ``ValueError`` into a
:class:`~links1.errors.SceneError` naming the element.
"""
from __future__ import annotations

import os
import json
import warnings

import numpy as np

from ..errors import SceneError
from ..shading import spectra, textures
from . import params
from .xmlparse import Node, Prop, SceneWarning

_MISSING = object()
_COLOR_KINDS = ("rgb", "spectrum", "float")


class _Props:
    def __init__(self, node: Node):
        self.node = node
        self.used: set = set()
        if params.is_links1(node.type):   # all its names are known: judged before any is read
            self._refuse_unknown()

    def has(self, name: str) -> bool:
        return name in self.node.props

    def error(self, name: str, message: str) -> SceneError:
        p = self.node.props.get(name)
        if p is None:
            return self.node.error(message)
        return SceneError(message, p.file, p.line, f"{self.node.element()} {p.element()}")

    def _get(self, name: str, kinds: tuple) -> Prop | None:
        self.used.add(name)
        p = self.node.props.get(name)
        if p is not None and p.kind not in kinds:
            raise self.error(name, f"'{name}' must be given as <{'> or <'.join(kinds)}>, "
                                   f"not <{p.kind}>")
        return p

    def required(self, name: str, kinds: tuple) -> Prop:
        p = self._get(name, kinds)
        if p is None:
            raise self.node.error(f"missing required parameter '{name}' (<{kinds[0]}>)")
        return p

    def float(self, name, default=_MISSING, *, positive=False, nonneg=False) -> float:
        p = self._get(name, ("float", "integer"))
        if p is None:
            if default is _MISSING:
                raise self.node.error(f"missing required parameter '{name}' (<float>)")
            return default
        v = float(p.value)
        if positive and not v > 0:
            raise self.error(name, f"'{name}' must be > 0, got {v:g}")
        if nonneg and not v >= 0:
            raise self.error(name, f"'{name}' must be >= 0, got {v:g}")
        return v

    def int(self, name, default=_MISSING, *, minimum=None) -> int:
        p = self._get(name, ("integer",))
        if p is None:
            if default is _MISSING:
                raise self.node.error(f"missing required parameter '{name}' (<integer>)")
            return default
        if minimum is not None and p.value < minimum:
            raise self.error(name, f"'{name}' must be >= {minimum}, got {p.value}")
        return int(p.value)

    def bool(self, name, default=False) -> bool:
        p = self._get(name, ("boolean",))
        return default if p is None else bool(p.value)

    def string(self, name, default=_MISSING) -> str:
        p = self._get(name, ("string",))
        if p is None:
            if default is _MISSING:
                raise self.node.error(f"missing required parameter '{name}' (<string>)")
            return default
        return p.value

    def vec3(self, name, default=_MISSING, kinds=("point", "vector")) -> np.ndarray:
        p = self._get(name, kinds)
        if p is None:
            if default is _MISSING:
                raise self.node.error(f"missing required parameter '{name}' (<{kinds[0]}>)")
            return None if default is None else np.asarray(default, dtype=np.float64)
        return np.asarray(p.value, dtype=np.float64).copy()

    def color(self, name, default=_MISSING, *, nonneg=True, emitter=False,
              unbounded=False, reflectance=False) -> np.ndarray:
        """An RGB parameter: ``rgb``, ``float``, ``spectrum`` (converted as Mitsuba's RGB variants
        do, see :mod:`links1.shading.spectra`: ``emitter`` for emitted quantities, ``unbounded`` for
        parameters Mitsuba reads unclamped) or a ``<spectrum type=..>`` plugin; a nested
        texture → 0.5 grey."""
        tex = [n for nm, n in self.node.children if nm == name and n.tag == "texture"]
        if tex:
            self.used.add(name)
            tex[0].warn(f"textures are not supported by the core; '{name}' uses a 0.5 grey")
            return np.full(3, 0.5)
        plugin = [n for nm, n in self.node.children if nm == name and n.tag == "spectrum"]
        if plugin:
            self.used.add(name)
            return _spectrum_plugin(plugin[0], emitter)
        p = self._get(name, _COLOR_KINDS)
        if p is None:
            if default is _MISSING:
                raise self.node.error(f"missing required parameter '{name}' (<rgb>)")
            return None if default is None else np.broadcast_to(
                np.asarray(default, dtype=np.float64), (3,)).copy()
        if p.kind == "spectrum":
            v = _spectrum_rgb(p, emitter, unbounded)
        else:
            v = np.broadcast_to(np.asarray(p.value, dtype=np.float64), (3,)).copy()
        if nonneg and np.any(v < 0):
            raise self.error(name, f"'{name}' must be >= 0, got {v.tolist()}")
        if reflectance and p.kind != "spectrum":   # spectra are clamped into gamut (above)
            try:
                params.check_reflectance(name, v)
            except ValueError as exc:
                raise self.error(name, str(exc)) from None
        return v

    def texture(self, name, default=_MISSING, **kwargs):
        """A texturable BSDF parameter: a nested ``bitmap`` / ``checkerboard`` texture
        (:mod:`links1.shading.textures`), else :meth:`color`."""
        tex = [n for nm, n in self.node.children if nm == name and n.tag == "texture"]
        if tex and tex[0].type in _TEXTURES:
            self.used.add(name)
            return _texture(tex[0])
        return self.color(name, default, **kwargs)

    def transform(self, name="to_world") -> np.ndarray | None:
        p = self._get(name, ("transform",))
        return None if p is None else np.asarray(p.value, dtype=np.float64).copy()

    def ignore(self, *names) -> None:
        self.used.update(names)

    def links1(self, plugin: str, name: str):
        """A links1 plugin's parameter, read and checked by its rules in :data:`links1.scene.params.PLUGINS`
        (the same table the Mitsuba plugins read)."""
        prm = params.param(plugin, name)
        d = _MISSING if prm.default is params.REQUIRED else prm.default
        if prm.kind in ("float", "int", "string", "bool"):
            v = getattr(self, prm.kind)(name, d)
        elif prm.kind == "rgb":
            v = self.color(name, d, nonneg=False, emitter=(plugin != "links1_phong"))
        else:
            v = self.vec3(name, d, kinds=("point", "vector") if prm.kind == "point" else ("vector", "point"))
        if v is None or prm.kind == "bool":
            return v
        try:
            return prm.check(name, v)
        except ValueError as exc:
            raise self.error(name, str(exc)) from None

    def _refuse_unknown(self) -> None:
        names = [n for n in self.node.props if n not in self.used]
        found = refused_parameter(self.node.tag, self.node.type, names)
        if found is not None:
            p = self.node.props[found[0]]
            raise SceneError(found[1], p.file, p.line, f"{self.node.element()} {p.element()}")

    def finish_quietly(self) -> None:
        """Refuse a parameter the plugin does not take; the others need no word."""
        self._refuse_unknown()
        self.ignore(*self.node.props)

    def finish(self) -> None:
        """Refuse a parameter the plugin does not take (:func:`refused_parameter`), warn about
        one it takes that the core does not use."""
        self._refuse_unknown()
        for name, p in self.node.props.items():
            if name not in self.used:
                warnings.warn(str(SceneError(
                    f"parameter '{name}' is not used by the core and is ignored", p.file, p.line,
                    f"{self.node.element()} {p.element()}")), SceneWarning, stacklevel=3)


def refused_parameter(tag: str, plugin: str | None, names) -> tuple | None:
    """``(name, message)`` for the first of ``names`` that plugin ``plugin`` of element ``tag``
    does not take (Mitsuba refuses such a property: "unreferenced property"), else None. links1's
    plugins are judged by :mod:`links1.scene.params`, Mitsuba's by :func:`mitsuba_parameters`
    (a plugin in neither table is not judged). The rule of both renderers and every loader."""
    if params.is_links1(plugin):
        return params.unknown_in(tag, plugin, names)
    known = mitsuba_parameters(tag, plugin)
    bad = [n for n in names if known is not None and n not in known]
    return (bad[0], params.unknown_parameter(tag, plugin, bad[0], known)) if bad else None


_MITSUBA_PARAMETERS = None


def mitsuba_parameters(tag: str, plugin: str | None):
    """The parameter names Mitsuba 3.9.1's plugin ``plugin`` of element ``tag`` may query
    (``links1/data/mitsuba_properties.json``, made by tools/make_mitsuba_properties.py from
    Mitsuba's sources), or None for a plugin not listed (links1's own, unknown ones)."""
    global _MITSUBA_PARAMETERS
    if _MITSUBA_PARAMETERS is None:
        path = os.path.join(os.path.dirname(os.path.dirname(__file__)), "data", "mitsuba_properties.json")
        with open(path, encoding="utf-8") as f:
            _MITSUBA_PARAMETERS = json.load(f)["plugins"]
    names = _MITSUBA_PARAMETERS.get(tag, {}).get(plugin or tag)
    return None if names is None else frozenset(names)


# --------------------------------------------------------------------------------------------
# textures (links1.shading.textures)
# --------------------------------------------------------------------------------------------

_TEXTURES = ("bitmap", "checkerboard", "mesh_attribute")


def _is_mesh_attribute(node: Node, name: str) -> bool:
    """Whether parameter ``name`` of ``node`` is a ``mesh_attribute`` texture (which an
    emitter's radiance cannot be in the core: it then becomes a 0.5 grey, warned)."""
    return any(nm == name and c.tag == "texture" and c.type == "mesh_attribute" for nm, c in node.children)


def _texture(node: Node):
    """A ``<texture type="bitmap | checkerboard">`` element → :class:`links1.shading.textures.Texture`."""
    props = _Props(node)
    to_uv = props.transform("to_uv")
    if node.type == "mesh_attribute":
        tex = _construct(node, textures.MeshAttribute, props.string("name"), props.float("scale", 1.0),
                         texname=node.id or "")
    elif node.type == "checkerboard":
        tex = _construct(node, textures.Checkerboard, props.texture("color0", 0.4),
                         props.texture("color1", 0.2), to_uv=to_uv, name=node.id or "")
    else:
        filter_type = props.string("filter_type", "bilinear").strip()
        wrap_mode = props.string("wrap_mode", "repeat").strip()
        for key, value, allowed in (("filter_type", filter_type, textures.FILTER_TYPES),
                                    ("wrap_mode", wrap_mode, textures.WRAP_MODES)):
            if value not in allowed:
                raise props.error(key, f"'{key}' must be one of {', '.join(allowed)}, got '{value}'")
        raw = props.bool("raw", False)
        if props.has("data") or props.has("bitmap"):
            raise node.error("bitmap: only 'filename' can be given in a scene file")
        fn = props.string("filename")
        try:
            data = textures.read_bitmap(node.resolve(fn), raw)
        except ValueError as exc:
            raise props.error("filename", str(exc)) from None
        props.ignore("format", "accel")  # storage precision and GPU lookups: same values here
        tex = _construct(node, textures.Bitmap, data, filter_type, wrap_mode, to_uv=to_uv,
                         name=node.id or "")
    props.finish()
    return tex


# --------------------------------------------------------------------------------------------
# constructors, spectra
# --------------------------------------------------------------------------------------------

def _construct(node: Node, factory, *args, **kwargs):
    """Call a core constructor; its ValueError becomes a SceneError naming the element."""
    try:
        return factory(*args, **kwargs)
    except SceneError:
        raise
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise node.error(str(exc)) from None


def _spectrum_rgb(p: Prop, emitter: bool, unbounded: bool) -> np.ndarray:
    """A ``<spectrum value=..>`` as Mitsuba's RGB variants read it (warns where it clamps)."""
    rgb, raw = spectra.to_rgb(p.value.wavelengths, p.value.values, emitter=emitter,
                              unbounded=unbounded)
    if raw is not None:
        warnings.warn(str(p.error(f"clamping out-of-gamut colour {np.round(raw, 6).tolist()} to "
                                  f"{np.round(rgb, 6).tolist()} (as Mitsuba)")),
                      SceneWarning, stacklevel=4)
    return rgb


def _spectrum_plugin(node: Node, emitter: bool) -> np.ndarray:
    """``<spectrum type=..>`` in an RGB variant: ``uniform``, ``srgb`` and ``blackbody``."""
    props = _Props(node)
    t = node.type
    if t == "uniform":
        props.ignore("wavelength_min", "wavelength_max")
        rgb = np.full(3, props.float("value"))
    elif t == "srgb":
        rgb = props.color("color")
        if not emitter and np.any(rgb > 1):
            raise props.error("color", f"invalid RGB reflectance {rgb.tolist()}: must be in "
                                       "[0, 1] (as Mitsuba)")
    elif t == "blackbody":
        if not emitter:
            raise node.error("a blackbody spectrum only makes sense for emission")
        temperature = props.float("temperature", positive=True)
        lo = props.float("wavelength_min", spectra.CIE_MIN, positive=True)
        hi = props.float("wavelength_max", spectra.CIE_MAX, positive=True)
        rgb = _construct(node, spectra.blackbody_to_rgb, temperature, lo, hi)
        node.warn(f"blackbody ({temperature:g} K): Mitsuba's RGB variants cannot evaluate it; "
                  f"the core uses the colour its spectral variants integrate to, "
                  f"{np.round(rgb, 6).tolist()}")
    elif t in ("regular", "irregular", "d65", "rawconstant"):
        raise node.error(f"spectrum plugin '{t}' is not supported by the core; give the "
                         "spectrum as <spectrum name=.. value=\"wavelength:value, ...\"/>")
    else:
        raise node.error(f"unknown plugin '{t}' (spectrum)")
    props.finish()
    return rgb
