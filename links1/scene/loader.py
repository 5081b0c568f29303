"""Mitsuba 3 XML scene → :class:`links1.scene.scene.Scene`, with Mitsuba's semantics.

:mod:`links1.scene.xmlparse` reads the XML (parameters, includes, references, transforms); this
module knows the plugins. It never imports Mitsuba.

Supported plugins (anything else: a :class:`~links1.errors.SceneError` naming file, line and
element, or a :class:`~links1.scene.xmlparse.SceneWarning` naming the approximation used)

==============  =================================================================================
element         types and parameters (Mitsuba defaults unless marked *links1*)
==============  =================================================================================
sensor          ``perspective``: ``fov`` + ``fov_axis`` (x) or ``focal_length`` (``"50mm"``: the
                diagonal field of view of a 36 x 24 mm film, as Mitsuba), ``near_clip`` (1e-2), ``far_clip`` (1e4), ``to_world`` (no scaling).
                ``thinlens``: as ``perspective`` plus ``aperture_radius`` (required) and
                ``focus_distance`` (``far_clip``): depth of field. ``orthographic``: ``near_clip``,
                ``far_clip``, ``to_world`` (its scale sizes the sensor plane, as in Mitsuba).
film            ``hdrfilm``: ``width`` (768), ``height`` (576), ``crop_offset_x/y``,
                ``crop_width/height``; ``rfilter``: ``box``, ``tent`` (radius), ``gaussian``
                (stddev; the default), ``mitchell`` (B, C), ``catmullrom``, ``lanczos`` (lobes).
sampler         any type: ``sample_count`` (4) → ``Scene.spp``.
integrator      its type → ``Scene.integrator``; ``max_depth`` (*links1*: 5; -1 → 5 with warning).
shape           ``sphere`` (center, radius), ``cylinder`` (p0, p1, radius; open), ``disk``,
                ``rectangle``, ``cube``, ``obj`` / ``ply`` / ``serialized`` (filename, face_normals;
                serialized: shape_index), all with
                ``to_world`` and ``flip_normals`` (meshes); *links1*: ``links1_quadric``,
                ``links1_blob``, ``links1_bicubic`` (see below). No bsdf → ``diffuse`` 0.5.
                ``shapegroup`` + ``instance`` (its ``to_world`` after each member's): flattened
                into copies of the group's shapes.
bsdf            ``diffuse``, ``twosided``, ``conductor`` (perfect mirror, ``eta``/``k`` or a
                ``material`` preset), ``dielectric``, ``thindielectric``, ``plastic``,
                ``roughconductor``, ``roughplastic``, ``roughdielectric``, ``blendbsdf``
                (:mod:`links1.shading.glossy`), ``principled``, ``principledthin``
                (:mod:`links1.shading.principled`),
                *links1* ``links1_phong``; other BSDFs → diffuse stand-in (warning); ``bitmap`` / ``checkerboard``
                textures (:mod:`links1.shading.textures`) and ``mesh_attribute`` (a PLY's ``vertex_*`` / ``face_*``
                properties) on their colour parameters; other textures → 0.5 grey (warning).
colours        ``rgb``, ``float``, ``spectrum`` (one value or ``wavelength:value`` pairs, converted
                as Mitsuba's RGB variants do: :mod:`links1.shading.spectra`), ``<spectrum type="uniform|
                srgb|blackbody">`` (blackbody on emitters only, warning).
emitter         ``point``, ``directional``, ``spot``, ``constant`` and ``envmap`` (filename, scale,
                to_world: background and sampled light), ``area`` in a mesh, rectangle, cube,
                sphere or disk (radiance: a colour or a ``bitmap`` / ``checkerboard`` texture at the
                shape's uv; → ``shape.emission`` and a sampled :class:`AreaLight`; on other
                shapes seen only, warning), ``projector`` (irradiance: a colour or a texture,
                scale, fov / focal_length, to_world), *links1* ``links1_point``, ``links1_spot``;
                ``sunsky`` etc. → ignored (warning).
==============  =================================================================================

links1 plugins::

    <shape type="links1_quadric">  kind = sphere | cylinder, to_world, capped (false),
        <vector name="clip_0" .../> <float name="clip_0_offset" value="h"/> ...  (keep n·y ≤ h)
    <shape type="links1_blob">     centers = "x y z w S  x y z w S ...", threshold (> 0),
        solver = exact | paper, samples (8), to_world (optional)
    <shape type="links1_bicubic">  filename (a .patch file, see links1.geometry.bezier) or
        control_points (string, 48 numbers per patch), subdivisions (8), to_world, flip_normals
    <emitter type="links1_point">  position, direction (0 0 1), L1 (1), L2 (0), falloff = none | inverse_square
    <emitter type="links1_spot">   origin, direction, radius, intensity (1)
    <bsdf type="links1_phong">     ambient (0), diffuse (0.5), specular (0), exponent (20),
        reflectance (= specular), transmittance (0), ior (1)

Public API: ``load_scene(path, **params)``, ``load_string(xml, base_dir=None, **params)`` and
``build_scene(root_node, path=None)``; ``focal_length_fov_x(mm, width, height)``.
"""
from __future__ import annotations

import math
import os
import re
import warnings

import numpy as np

from ..shading import glossy, principled
from ..shading import materials as mat
from ..shading import normalmaps
from . import params
from ..geometry import bezier, mesh_files, meshes
from ..shading import textures
from ..shading import spectra
from ..maths import transform as tf
from ..sensor.camera import FOV_AXES, Camera, fov_x_from
from ..errors import SceneError
from ..sensor.filters import FILTERS, Filter
from ..shading.lights import (ENV_LIGHT_ID, AreaLight, ConeSpotLight, ConstantEnvironment, CylinderSpotLight,
                     EnvironmentMap, ParallelLight, PointLight, ProjectorLight, number_area_lights)
from ..maths.vec import coordinate_system
from .scene import Scene
from .xmlparse import Node, Prop, SceneWarning, parse_file, parse_string

__all__ = ["load_scene", "load_string", "build_scene", "focal_length_fov_x"]

DEFAULT_MAX_DEPTH = params.default("links1_whitted", "max_depth")
DEFAULT_SPP = 4  # Mitsuba's independent sampler

# Known Mitsuba 3 plugins the core does not support (for a clearer message than "unknown").
_MITSUBA_SHAPES = {"shapegroup", "instance", "merge"}
_APPROX_BSDFS = {"hair", "measured", "pplastic", "polarizer",
                 "retarder", "circular", "measured_polarized", "bumpmap",
                 "normalmap"}
_IGNORED_EMITTERS = {"sunsky", "directionalarea"}
_FILMS = {"hdrfilm", "specfilm"}
_SAMPLERS = {"independent", "stratified", "multijitter", "orthogonal", "ldsampler"}
_SENSORS = {"perspective", "thinlens", "orthographic", "radiancemeter", "irradiancemeter",
            "distant", "batch"}


# --------------------------------------------------------------------------------------------
# public entry points
# --------------------------------------------------------------------------------------------

def load_scene(path, /, **params) -> Scene:
    """Load a Mitsuba 3 XML scene file; ``params`` fill ``$name`` references (``-D name=value``)."""
    root = parse_file(path, params)
    return build_scene(root, os.fspath(path))


def load_string(xml: str, /, base_dir=None, **params) -> Scene:
    """Load a scene from XML text; relative file names are looked up in ``base_dir`` (cwd)."""
    root = parse_string(xml, base_dir=base_dir, params=params)
    return build_scene(root, None)


def build_scene(root: Node, path: str | None = None) -> Scene:
    """Turn the parsed ``<scene>`` node into a :class:`Scene`; each warning once (an element
    referenced twice, a BSDF shared by shapes, is read twice but named once)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = _Builder().scene(root, path)
    seen = set()
    for w in caught:
        key = (str(w.message), w.category)
        if key not in seen:
            seen.add(key)
            warnings.warn(w.message if isinstance(w.message, Warning) else str(w.message),
                          w.category, stacklevel=2)
    return scene


# --------------------------------------------------------------------------------------------
# property access with type checks and Mitsuba's "unused property" report
# --------------------------------------------------------------------------------------------

_MISSING = object()
_RECOMPUTE = object()   # a mesh's vertex normals still to be computed (_Builder._mesh)
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
        import json
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
# helpers
# --------------------------------------------------------------------------------------------

def _shape_class(name: str):
    """The core's shape classes, imported on first use (``links1.geometry.shapes`` / ``links1.geometry.blob``)."""
    if name == "Blob":
        from ..geometry.blob import Blob
        return Blob
    from ..geometry import shapes
    return getattr(shapes, name)


def _construct(node: Node, factory, *args, **kwargs):
    """Call a core constructor; its ValueError becomes a SceneError naming the element."""
    try:
        return factory(*args, **kwargs)
    except SceneError:
        raise
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise node.error(str(exc)) from None


def _frame(d: np.ndarray) -> np.ndarray:
    """Mitsuba's ``Frame3f(d)`` (:func:`links1.maths.vec.coordinate_system`) as a 3x3 matrix with
    columns (s, t, n)."""
    s, t = coordinate_system(np.asarray(d, dtype=np.float64))
    return np.stack([s, t, d], axis=1)


def focal_length_fov_x(focal_length_mm: float, width: int, height: int) -> float:
    """Mitsuba's ``focal_length``: the diagonal field of view of a 36 x 24 mm film, as ``fov_x``."""
    diag_fov = math.degrees(2.0 * math.atan(math.hypot(36.0, 24.0) / (2.0 * focal_length_mm)))
    return fov_x_from(diag_fov, "diagonal", width, height)


def _fov_x(node, props, width: int, height: int) -> float:
    """The horizontal field of view (degrees) of a perspective sensor or a projector on a
    ``width`` x ``height`` image: ``fov`` along ``fov_axis``, else ``focal_length`` (Mitsuba's
    ``parse_fov``)."""
    if props.has("fov") and props.has("focal_length"):
        raise node.error("give either 'fov' or 'focal_length', not both")
    if props.has("fov"):
        fov = props.float("fov")
        if not 0 < fov < 180:
            raise props.error("fov", f"'fov' must be in (0, 180) degrees, got {fov:g}")
        axis = props.string("fov_axis", "x").strip().lower()
        if axis not in FOV_AXES:
            raise props.error("fov_axis", f"'fov_axis' must be one of {', '.join(FOV_AXES)}, got '{axis}'")
        return fov_x_from(fov, axis, width, height)
    text = props.string("focal_length", "50mm").strip()
    m = re.fullmatch(r"([0-9.eE+-]+)\s*(mm)?", text)
    try:
        f = float(m.group(1)) if m else float("nan")
    except ValueError:
        f = float("nan")
    if not (math.isfinite(f) and f > 0):
        raise props.error("focal_length", f"'focal_length' must be a positive length such "
                                          f"as '50mm', got '{text}'")
    props.ignore("fov_axis")  # Mitsuba ignores it with a focal length too
    return focal_length_fov_x(f, width, height)


def _check_invertible(node: Node, m: np.ndarray, what: str = "to_world") -> None:
    """A shape's map must be invertible and in range (:func:`links1.scene.params.transform_problem`)."""
    problem = params.transform_problem(m, what)
    if problem is not None:
        raise node.error(problem)
    lin = m[:3, :3]
    scale = max(float(np.max(np.abs(lin))), 1e-300)
    det = float(np.linalg.det(lin / scale))
    if not (np.isfinite(det) and abs(det) > 1e-12):
        raise node.error(f"singular {what} transform (relative determinant {det:g}): "
                         "the shape would be degenerate")


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


# --------------------------------------------------------------------------------------------
# the builder
# --------------------------------------------------------------------------------------------

class _Builder:
    def scene(self, root: Node, path: str | None) -> Scene:
        props = _Props(root)
        props.finish()
        camera, spp = None, None
        sensors = []    # (camera, spp) of each sensor, in file order (Scene.use_sensor)
        shapes, lights, environments = [], [], []
        background = np.zeros(3)
        integrator, max_depth, integrator_params = None, DEFAULT_MAX_DEPTH, {}
        for name, node in root.children:
            if node.tag == "sensor":
                if sensors:
                    # another view of the scene (mi.render(scene, sensor=k), links1 render
                    # --sensor k): one the core cannot render is an error only when chosen
                    try:
                        sensors.append(self.sensor(node))
                    except SceneError as exc:
                        sensors.append(exc)
                    continue
                camera, spp = self.sensor(node)
                sensors.append((camera, spp))
            elif node.tag == "shape":
                if node.type == "shapegroup":
                    self._shapegroup(node)   # drawn only through its instances
                elif node.type == "instance":
                    shapes.extend(self._instance(node))
                else:
                    shapes.append(self.shape(node))
            elif node.tag == "emitter":
                if node.type == "area" and node.id is not None:
                    continue  # a declaration, used where a shape references it (as Mitsuba)
                light = self.emitter(node)
                if isinstance(light, (ConstantEnvironment, EnvironmentMap)):
                    light.light_id = ENV_LIGHT_ID + len(environments)
                    environments.append(light)
                    if isinstance(light, ConstantEnvironment):
                        background = background + light.radiance
                if light is not None:
                    lights.append(light)
            elif node.tag == "integrator":
                if integrator is not None:
                    node.warn("more than one integrator: the first one is used")
                    continue
                integrator, max_depth, integrator_params = self.integrator(node)
            elif node.tag in ("bsdf", "texture", "medium", "phase", "volume"):
                if node.tag == "bsdf":
                    self.bsdf(node)  # validate declarations that are only referenced
            else:
                raise node.error(f"<{node.tag}> is not allowed at the top level of a scene")
        if camera is None:
            root.warn("the scene has no sensor: using Mitsuba's default perspective camera "
                      "(50mm, 768x576, at the origin looking along +z)")
            camera = Camera(fov_x=focal_length_fov_x(50.0, 768, 576), width=768, height=576)
            spp = DEFAULT_SPP
            sensors.append((camera, spp))
        for k, shape in enumerate(shapes):      # area emitters light the scene (after file-order lights)
            if shape.emission is not None:
                shape.index = k
                enode = shape.__dict__.pop("_emitter_node", None)
                try:
                    lights.append(AreaLight(shape, shape.emission))
                except ValueError as exc:
                    (enode or root).warn(f"{exc}: it is seen but lights nothing in the core")
        # sample streams by place (the same whichever order a loader gives the shapes), and the
        # area lights in that order, as the plugin orders them
        lights = [light for light in lights if not isinstance(light, AreaLight)] + \
            [lights[i] for i in number_area_lights(lights)]
        kwargs = dict(camera=camera, sensors=sensors, shapes=shapes, lights=lights, spp=spp, max_depth=max_depth,
                      background=background, path=path,
                      environments=[e for e in environments if isinstance(e, EnvironmentMap)])
        if integrator is not None:
            kwargs["integrator"] = integrator
        kwargs.update(integrator_params)
        return Scene(**kwargs)

    # -- integrator ------------------------------------------------------------------------
    def integrator(self, node: Node):
        # links1 replaces whatever integrator the file names (the Mitsuba renderer too, with
        # --integrator links1): one it does not know (a Bitterli scene's 'mat') is no error
        props = _Props(node)
        inner = node.objects("integrator")
        depth_node = node
        if inner and not props.has("max_depth"):
            depth_node = inner[0]
        dp = _Props(depth_node)
        max_depth = dp.int("max_depth", DEFAULT_MAX_DEPTH)
        if max_depth > params.MAX_MAX_DEPTH:
            raise dp.error("max_depth", f"'max_depth' must be <= {params.MAX_MAX_DEPTH} (or -1), got {max_depth}")
        if max_depth == -1:
            depth_node.warn(f"max_depth=-1 (unlimited) is capped at {DEFAULT_MAX_DEPTH} by the core")
            max_depth = DEFAULT_MAX_DEPTH
        elif max_depth < 1:
            raise dp.error("max_depth", f"'max_depth' must be >= 1 or -1, got {max_depth}")
        extra = {}
        if node.type == "links1_whitted":   # its parameters that change the image
            extra["light_samples"] = props.links1(node.type, "light_samples")
            extra["min_weight"] = props.links1(node.type, "min_weight")
        for p in (props, dp):
            # other parameters do not apply to the core; one the integrator does not take is
            # refused all the same (the file is judged as Mitsuba judges it, whichever renderer)
            p.finish_quietly()
        return node.type, max_depth, extra

    # -- sensor ----------------------------------------------------------------------------
    def sensor(self, node: Node):
        if node.type not in _SENSORS:
            raise node.error(f"unknown plugin '{node.type}' (sensor)")
        if node.type not in ("perspective", "thinlens", "orthographic"):
            raise node.error(f"sensor type '{node.type}' is not supported by the core "
                             "(only 'perspective', 'thinlens' and 'orthographic')")
        props = _Props(node)
        props.ignore("srf")
        # film first: fov_axis conversions need the film's aspect ratio
        films = node.objects("film")
        width, height, crop_offset, crop_size, rfilter = (self.film(films[0]) if films
                                                          else (768, 576, (0, 0), None, Filter()))
        if len(films) > 1:
            films[1].warn("more than one film: the first one is used")
        samplers = node.objects("sampler")
        spp = self.sampler(samplers[0]) if samplers else DEFAULT_SPP
        for child in node.objects():
            if child.tag not in ("film", "sampler"):
                child.warn(f"<{child.tag}> inside a sensor is ignored by the core")

        if node.type == "orthographic":
            fov_x = None   # the sensor plane's size comes from to_world (below)
        else:
            fov_x = _fov_x(node, props, width, height)
        near = props.float("near_clip", 1e-2, positive=True)
        far = props.float("far_clip", 1e4, positive=True)
        if not near < far:
            raise node.error(f"near_clip ({near:g}) must be smaller than far_clip ({far:g})")
        for k in ("principal_point_offset_x", "principal_point_offset_y"):
            if props.has(k) and props.float(k) != 0.0:
                node.warn(f"'{k}' is not supported by the core and is ignored")
        to_world = props.transform()
        if to_world is None:
            to_world = np.eye(4)
        lin = to_world[:3, :3]
        if node.type != "orthographic" and not np.allclose(np.linalg.norm(lin, axis=0), 1.0, rtol=0, atol=1e-4):
            raise props.error("to_world", "scale factors in the camera-to-world transformation "
                                          "are not allowed (as in Mitsuba)")
        if abs(np.linalg.det(lin)) < 1e-300:
            raise props.error("to_world", "the camera-to-world transformation is singular")
        extra = {"projection": "orthographic"} if fov_x is None else {"fov_x": fov_x}
        if node.type == "thinlens":   # Mitsuba: a zero aperture becomes float32's epsilon
            extra["aperture_radius"] = props.float("aperture_radius") or 2.0 ** -24
            extra["focus_distance"] = props.float("focus_distance", far, positive=True)
            for k in ("aperture_radius", "focus_distance"):
                if abs(extra[k]) > params.MAX_EXTENT:
                    raise props.error(k, f"'{k}' must be <= {params.MAX_EXTENT:g} in magnitude, got {extra[k]:g}")
        props.finish()
        cam = _construct(node, Camera, to_world=to_world, near_clip=near,
                         far_clip=far, width=width, height=height, crop_offset=crop_offset,
                         crop_size=crop_size, rfilter=rfilter, **extra)
        return cam, spp

    def film(self, node: Node):
        if node.type not in _FILMS:
            raise node.error(f"unknown plugin '{node.type}' (film)")
        if node.type != "hdrfilm":
            node.warn(f"film '{node.type}' is treated as an RGB hdrfilm")
        props = _Props(node)
        props.ignore("file_format", "pixel_format", "component_format", "banner", "sample_border",
                     "compensate", "srf")
        width = props.int("width", 768)
        height = props.int("height", 576)
        for k, v in (("width", width), ("height", height)):
            if v < 1:
                raise props.error(k, f"film '{k}' must be >= 1, got {v}")
        ox = props.int("crop_offset_x", 0, minimum=0)
        oy = props.int("crop_offset_y", 0, minimum=0)
        cw = props.int("crop_width", width - ox)
        ch = props.int("crop_height", height - oy)
        if cw < 1 or ch < 1:
            raise node.error(f"crop window size must be >= 1, got {cw}x{ch}")
        if ox + cw > width or oy + ch > height:
            raise node.error(f"crop window {cw}x{ch}+{ox}+{oy} exceeds the film {width}x{height}")
        rfilters = node.objects("rfilter")
        if len(rfilters) > 1:
            rfilters[1].warn("more than one rfilter: the first one is used")
        rfilter = self.rfilter(rfilters[0]) if rfilters else Filter()
        props.finish()
        crop = None if (ox, oy, cw, ch) == (0, 0, width, height) else (cw, ch)
        return width, height, (ox, oy), crop, rfilter

    def rfilter(self, node: Node) -> Filter:
        if node.type not in FILTERS:
            raise node.error(f"unknown plugin '{node.type}' (rfilter)")
        props = _Props(node)
        params = {}
        for k, default in FILTERS[node.type].items():
            if props.has(k):
                params[k] = props.int(k) if k == "lobes" else props.float(k)
        props.finish()
        try:
            return Filter(node.type, params)
        except ValueError as e:
            raise node.error(str(e)) from None

    def sampler(self, node: Node) -> int:
        if node.type not in _SAMPLERS:
            raise node.error(f"unknown plugin '{node.type}' (sampler)")
        props = _Props(node)
        props.ignore("seed", "jitter", "scramble")
        spp = props.int("sample_count", DEFAULT_SPP)
        if spp < 1:
            raise props.error("sample_count", f"'sample_count' must be >= 1, got {spp}")
        props.finish()
        return spp

    # -- shapes ----------------------------------------------------------------------------
    def _shapegroup(self, node: Node) -> list:
        """The shapes of a ``shapegroup`` (checked once per use; Mitsuba's rules: shapes only,
        no nested groups or instances, no area emitters)."""
        _Props(node).finish()
        members = []
        for _, child in node.children:
            if child.tag != "shape":
                raise child.error(f"<{child.tag}> is not allowed in a shapegroup (only shapes)")
            if child.type in ("shapegroup", "instance"):
                raise child.error("nested instancing is not supported (as in Mitsuba)")
            if child.objects("emitter"):
                raise child.error("a shape in a shapegroup cannot be an emitter (as in Mitsuba)")
            members.append(child)
        return members

    def _instance(self, node: Node) -> list:
        """An ``instance`` of a ``shapegroup``: copies of the group's shapes, each mapped by the
        instance's ``to_world`` after its own (the core flattens instances; Mitsuba shares
        them, which renders the same image)."""
        props = _Props(node)
        outer = props.transform()
        outer = np.eye(4) if outer is None else outer
        groups = [child for _, child in node.children if child.tag == "shape" and child.type == "shapegroup"]
        for _, child in node.children:
            if not (child.tag == "shape" and child.type == "shapegroup"):
                raise child.error(f"<{child.tag}> is not allowed in an instance (only a <ref> to a shapegroup)")
        if len(groups) != 1:
            raise node.error("an instance needs exactly one shapegroup (<ref id=\"...\"/>)")
        _check_invertible(node, outer)
        props.finish()
        return [self.shape(member, outer=outer) for member in self._shapegroup(groups[0])]

    def shape(self, node: Node, outer: np.ndarray | None = None):
        """One shape; ``outer``: the transformation of the instance it is drawn through."""
        t = node.type
        props = _Props(node)
        name = node.id or ""
        to_world = props.transform()
        if outer is not None:
            to_world = outer if to_world is None else outer @ to_world
        m = np.eye(4) if to_world is None else to_world
        if t == "sphere":
            center = props.vec3("center", (0.0, 0.0, 0.0))
            radius = props.float("radius", 1.0, positive=True)
            self._no_flip(props)
            full = m @ tf.translate(center) @ tf.scale(radius)
            _check_invertible(node, full)
            shape = _construct(node, _shape_class("Quadric"), "sphere", full, clips=[], capped=False,
                               name=name)
        elif t == "cylinder":
            p0 = props.vec3("p0", (0.0, 0.0, 0.0))
            p1 = props.vec3("p1", (0.0, 0.0, 1.0))
            radius = props.float("radius", 1.0, positive=True)
            self._no_flip(props)
            axis = p1 - p0
            length = float(np.linalg.norm(axis))
            if not length > 0:
                raise node.error("cylinder: p0 and p1 coincide")
            frame = np.eye(4)
            frame[:3, :3] = _frame(axis / length)
            full = m @ tf.translate(p0) @ frame @ tf.scale([radius, radius, length])
            _check_invertible(node, full)
            clips = [(np.array([0.0, 0.0, -1.0]), 0.0), (np.array([0.0, 0.0, 1.0]), 1.0)]
            shape = _construct(node, _shape_class("Quadric"), "cylinder", full, clips=clips,
                               capped=False, name=name)
        elif t == "disk":
            flip = props.bool("flip_normals", False)
            m = params.planar_to_world(m)   # zero thickness is still a disk
            _check_invertible(node, m)
            shape = _construct(node, _shape_class("Disk"), m, name=name, flip=flip)
        elif t in ("rectangle", "cube"):
            if t == "rectangle":
                m = params.planar_to_world(m)   # zero thickness is still a rectangle
            v, f, n, uv = (meshes.rectangle_mesh if t == "rectangle" else meshes.cube_mesh)(uv=True)
            shape = self._mesh(node, props, v, f, n, m, closed=(t == "cube"), uv=uv)
        elif t in ("obj", "ply", "serialized"):
            fn = props.string("filename")
            path = node.resolve(fn)
            index = props.int("shape_index", 0, minimum=0) if t == "serialized" else 0
            try:
                if t == "obj":
                    (v, f, n, uv), attrs = mesh_files.read_obj(path, uv=True), {}
                elif t == "ply":
                    v, f, n, uv, attrs = mesh_files.read_ply(path, uv=True, attributes=True)
                else:
                    (v, f, n, uv), attrs = mesh_files.read_serialized(path, index), {}
            except ValueError as exc:
                raise props.error("filename", str(exc)) from None
            if props.bool("face_normals", False):
                n = None
            elif n is None:
                n = _RECOMPUTE
            if t != "serialized" and uv is not None and props.bool("flip_tex_coords", t == "obj"):
                uv = uv * np.array([1.0, -1.0]) + np.array([0.0, 1.0])  # Mitsuba: v -> 1 - v
            if t != "serialized":
                props.ignore("mesh_attributes", "flip_tex_coords")
            shape = self._mesh(node, props, v, f, n, m, closed=None, uv=uv, attributes=attrs)
        elif t == "links1_quadric":
            shape = self._quadric(node, props, m, name)
        elif t == "links1_blob":
            shape = self._blob(node, props, to_world, name)
        elif t == "links1_bicubic":
            shape = self._bicubic(node, props, m)
        elif t == "sdfgrid":
            shape = self._sdfgrid(node, props, m, name)
        elif t in ("linearcurve", "bsplinecurve"):
            shape = self._curves(node, props, m, name)
        elif t in ("ellipsoids", "ellipsoidsmesh"):
            if outer is not None:
                raise node.error(f"{t} in an instance is not supported by the core")
            shape = self._ellipsoids(node, props, m, name)
        elif t in _MITSUBA_SHAPES:
            raise node.error(f"shape type '{t}' is not supported by the core")
        else:
            raise node.error(f"unknown plugin '{t}' (shape)")

        # nested objects: bsdf, area emitter
        material, emission = None, None
        for cname, child in node.children:
            if child.tag == "bsdf":
                if material is not None:
                    raise child.error("a shape can have only one bsdf")
                material = self.bsdf(child)
            elif child.tag == "emitter":
                if child.type in _IGNORED_EMITTERS:   # directionalarea: an area emitter of its own kind
                    child.warn(f"emitter '{child.type}' is not supported by the core and is ignored")
                    _Props(child).ignore(*child.props)
                    continue
                if child.type != "area":
                    raise child.error(f"emitter '{child.type}' cannot be nested in a shape "
                                      "(only 'area')")
                if emission is not None:
                    raise child.error("a shape can have only one area emitter")
                ep = _Props(child)
                emission = (ep.color if _is_mesh_attribute(child, "radiance") else ep.texture)(
                    "radiance", 1.0, emitter=True)
                ep.finish()
                emitter_node = child
            elif child.tag in ("medium",):
                child.warn("media are not supported by the core and are ignored")
            elif child.tag == "shape" and cname == "shell" and t in ("ellipsoids", "ellipsoidsmesh"):
                continue   # an ellipsoidsmesh's shell template (read by _ellipsoids)
            else:
                raise child.error(f"<{child.tag}> is not allowed inside a shape")
        if material is None:
            # Mitsuba's default BSDF: diffuse 0.5, black on an emitting shape (its Shape does so)
            material = mat.Diffuse(reflectance=np.full(3, 0.0 if emission is not None else 0.5))
        props.finish()
        for k, tex in vars(material).items():   # a mesh_attribute must name one of the mesh's
            if isinstance(tex, textures.MeshAttribute) and tex.attribute not in getattr(shape, "attributes", {}):
                raise node.error(f"the bsdf's '{k}' reads mesh attribute '{tex.attribute}', which this "
                                 f"{t} does not have (it has: {', '.join(sorted(getattr(shape, 'attributes', {}))) or 'none'})")
        shape.material = material
        shape.emission = emission
        if emission is not None:
            shape._emitter_node = emitter_node
        return shape

    def _sdfgrid(self, node, props, m, name):
        """Mitsuba's ``sdfgrid``: a ``.vol`` grid over [0, 1]³ placed by ``to_world``."""
        from ..geometry import sdfgrid
        path = node.resolve(props.string("filename"))
        normals = props.string("normals", "smooth")
        if normals not in ("smooth", "analytic"):
            raise props.error("normals", f"normals must be 'analytic' or 'smooth', got {normals!r}")
        try:
            grid = sdfgrid.read_vol(path)
        except (OSError, ValueError) as exc:
            raise props.error("filename", str(exc)) from None
        if grid.shape[3] != 1:
            raise props.error("filename", f"{path}: an SDF grid has 1 channel, this one {grid.shape[3]}")
        _check_invertible(node, m)
        return _construct(node, sdfgrid.SDFGrid, grid, m, normals=normals, name=name)

    def _curves(self, node, props, m, name):
        """Mitsuba's ``linearcurve`` / ``bsplinecurve``: control points moved by ``to_world``,
        radii as written."""
        from ..geometry import curves
        linear = node.type == "linearcurve"
        path = node.resolve(props.string("filename"))
        props.ignore("silhouette_sampling_weight")
        try:
            cs = curves.read_curves(path, min_points=2 if linear else 4)
        except (OSError, ValueError) as exc:
            raise props.error("filename", str(exc)) from None
        placed = [np.concatenate([c[:, :3] @ m[:3, :3].T + m[:3, 3], c[:, 3:]], axis=1) for c in cs]
        return _construct(node, curves.RoundLinearCurves if linear else curves.RoundBSplineCurves,
                          placed, name=name)

    def _ellipsoids(self, node, props, m, name):
        """Mitsuba's ``ellipsoids`` / ``ellipsoidsmesh`` from a PLY file (a scene file cannot
        hold their tensors), placed by ``to_world`` as Mitsuba places them."""
        from ..geometry import ellipsoids as ell
        for key in ("data", "centers", "scales", "quaternions"):
            if props.has(key):
                raise props.error(key, f"'{key}' is a tensor, which a scene file cannot give; "
                                       "give 'filename' (a PLY file)")
        if node.objects("emitter"):
            raise node.error(f"an area emitter on {node.type} cannot be sampled (Mitsuba 3.9.1 "
                             "has no sampling for it)")
        path = node.resolve(props.string("filename"))
        scale_factor = props.float("scale_factor", 1.0, positive=True)
        extent = props.float("extent", ell.DEFAULT_EXTENT, positive=True)
        adaptive = props.bool("extent_adaptive_clamping", False)
        props.ignore("silhouette_sampling_weight")
        _check_invertible(node, m)
        try:
            centers, rotations, scales, opacities = ell.read_ellipsoids(path, m, scale_factor)
        except (OSError, ValueError) as exc:
            raise props.error("filename", str(exc)) from None
        if adaptive and opacities is None:
            node.warn("extent_adaptive_clamping needs an 'opacities' attribute; ignored (as Mitsuba)")
        try:
            ext = ell.extents(len(centers), extent, opacities if adaptive else None)
        except ValueError as exc:
            raise props.error("extent_adaptive_clamping", f"{path}: {exc}") from None
        scales = scales * ext[:, None]
        nested = [child for cname, child in node.children if child.tag == "shape" and cname == "shell"]
        if node.type == "ellipsoids":
            props.ignore("shell")   # Mitsuba skips it there
            return _construct(node, ell.Ellipsoids, centers, rotations, scales, name=name)
        props.ignore("face_normals")   # no vertex normals: always face normals
        if nested:
            mesh = self.shape(nested[0])
            if not hasattr(mesh, "faces"):
                raise nested[0].error("an ellipsoidsmesh shell must be a triangle mesh")
            template = (mesh.vertices, mesh.faces)
        else:
            template = props.string("shell", "ico_sphere")
        try:
            template = ell.shell(template)
        except ValueError as exc:
            raise (props.error("shell", str(exc)) if not nested else nested[0].error(str(exc))) from None
        return _construct(node, ell.EllipsoidsMesh, centers, rotations, scales, template,
                          flip=props.bool("flip_normals", False), name=name)

    def _no_flip(self, props: _Props) -> None:
        if props.bool("flip_normals", False):
            props.node.warn("flip_normals is not supported on analytic shapes by the core; ignored")

    def _mesh(self, node, props, v, f, n, m, closed, uv=None, attributes=None):
        """A triangle mesh placed by ``m``; ``n``: vertex normals, None (face normals) or
        ``_RECOMPUTE`` (Mitsuba's angle-weighted normals of the placed mesh, as it computes them
        after ``to_world``)."""
        recompute = n is _RECOMPUTE
        n = None if recompute else n
        rewound = props.bool("flip_normals", False)
        if rewound:
            f, n = meshes.flip(f, n)
        _check_invertible(node, m)   # normals map by its inverse transpose
        if n is not None and np.linalg.det(m[:3, :3]) < 0:
            # a mirroring to_world turns the winding but not the given normals: Mitsuba's
            # BSDFs and area emitters follow the normals, so the faces are turned back
            f, rewound = f[:, [0, 2, 1]], not rewound
        v, n = meshes.transform_mesh(m, v, n)
        if not np.all(np.isfinite(v)):
            raise node.error("non-finite vertex positions after to_world")
        if recompute:
            n = meshes.angle_weighted_normals(v, f)
        return _construct(node, _shape_class("TriangleMesh"), v, f, normals=n, name=node.id or "",
                          closed=closed, texcoords=uv, rewound=rewound, attributes=attributes)

    def _quadric(self, node, props, m, name):
        kind = props.links1("links1_quadric", "kind")
        _check_invertible(node, m)
        clips = []
        k = 0
        while props.has(f"clip_{k}"):
            try:
                nrm, h = params.clip_plane(k, props.vec3(f"clip_{k}", kinds=("vector", "point")),
                                           props.float(f"clip_{k}_offset", params.default("links1_quadric", "clip_offset")))
            except ValueError as exc:
                raise props.error(f"clip_{k}", str(exc)) from None
            clips.append((nrm, h))
            k += 1
        for pname in node.props:
            if re.fullmatch(r"clip_\d+(_offset)?", pname) and pname not in props.used:
                raise props.error(pname, f"'{pname}' without the planes before it "
                                         f"(clip planes are numbered clip_0, clip_1, ...)")
        capped = props.links1("links1_quadric", "capped")
        return _construct(node, _shape_class("Quadric"), kind, m, clips=clips, capped=capped,
                          name=name)

    def _blob(self, node, props, to_world, name):
        try:
            c = params.blob_centers(props.string("centers"))
        except ValueError as exc:
            raise props.error("centers", str(exc)) from None
        threshold = props.links1("links1_blob", "threshold")
        solver = props.links1("links1_blob", "solver")
        samples = props.links1("links1_blob", "samples")
        if to_world is not None:
            _check_invertible(node, to_world)
        return _construct(node, _shape_class("Blob"), c, threshold, solver=solver, samples=samples,
                          to_world=to_world, name=name)

    def _bicubic(self, node, props, m):
        has_file, has_inline = props.has("filename"), props.has("control_points")
        if has_file == has_inline:
            raise node.error("links1_bicubic needs exactly one of 'filename' and 'control_points'")
        try:
            if has_file:
                patches = bezier.read_patches(node.resolve(props.string("filename")))
            else:
                p = props.required("control_points", ("string",))
                patches = bezier.parse_patches(p.value, f"{p.file}:{p.line}", with_count=False)
        except ValueError as exc:
            raise props.error("filename" if has_file else "control_points", str(exc)) from None
        sub = props.links1("links1_bicubic", "subdivisions")
        v, f, n = bezier.tessellate_patches(patches, sub)
        if props.bool("face_normals", False):
            n = None
        return self._mesh(node, props, v, f, n, m, closed=None)

    # -- BSDFs -----------------------------------------------------------------------------
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
        if nested.has_reflection or nested.has_transmission:
            node.warn(f"{t}: the mirror and refraction rays of the nested bsdf leave about the "
                      "unperturbed normal in the core")
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

    # -- emitters --------------------------------------------------------------------------
    def emitter(self, node: Node):
        t = node.type
        props = _Props(node)
        name = node.id or ""
        to_world = props.transform()
        light = None
        if t == "point":
            if props.has("position") and to_world is not None:
                raise node.error("point: give either 'position' or 'to_world', not both")
            pos = props.vec3("position", None)
            if pos is None:
                pos = np.zeros(3) if to_world is None else to_world[:3, 3]
            light = _construct(node, PointLight, position=pos, L1=props.color("intensity", 1.0, emitter=True),
                               L2=np.zeros(3), falloff="inverse_square", name=name)
        elif t == "links1_point":
            falloff = props.links1(t, "falloff")
            pos = props.links1(t, "position") if props.has("position") else None
            direction = props.links1(t, "direction")
            if to_world is not None:
                pos = tf.apply_point(to_world, np.zeros(3) if pos is None else pos)
                direction = tf.apply_vector(to_world, direction)
            light = _construct(node, PointLight, position=np.zeros(3) if pos is None else pos,
                               direction=direction, L1=props.links1(t, "L1"),
                               L2=props.links1(t, "L2"), falloff=falloff, name=name)
        elif t == "directional":
            if props.has("direction") and to_world is not None:
                raise node.error("directional: give either 'direction' or 'to_world', not both")
            d = props.vec3("direction", None, kinds=("vector", "point"))
            if d is None:
                d = np.array([0.0, 0.0, 1.0]) if to_world is None else to_world[:3, 2]
            light = _construct(node, ParallelLight, direction=d,
                               irradiance=props.color("irradiance", 1.0, emitter=True), name=name)
        elif t == "spot":
            cutoff = props.float("cutoff_angle", 20.0, positive=True)
            beam = props.float("beam_width", None, positive=True) if props.has("beam_width") else None
            if cutoff > 90:
                raise props.error("cutoff_angle", f"'cutoff_angle' must be <= 90, got {cutoff:g}")
            if beam is not None and beam > cutoff:
                raise props.error("beam_width", f"'beam_width' ({beam:g}) must not exceed cutoff_angle ({cutoff:g})")
            texture = props.texture("texture", None)   # a projector's image (or a constant factor)
            intensity = props.color("intensity", 1.0, emitter=True)
            if texture is not None and not textures.is_texture(texture):
                intensity, texture = intensity * texture, None
            light = _construct(node, ConeSpotLight, to_world=np.eye(4) if to_world is None else to_world,
                               intensity=intensity, cutoff_angle=cutoff, beam_width=beam, name=name,
                               texture=texture)
        elif t == "projector":
            irradiance = props.texture("irradiance", 1.0, unbounded=True)
            w, h = irradiance.resolution if isinstance(irradiance, textures.Bitmap) else (1, 1)
            light = _construct(node, ProjectorLight, to_world=np.eye(4) if to_world is None else to_world,
                               irradiance=irradiance, x_fov=_fov_x(node, props, w, h), aspect=w / h,
                               scale=props.float("scale", 1.0), name=name)
        elif t == "links1_spot":
            origin = props.links1(t, "origin")
            direction = props.links1(t, "direction")
            radius = props.links1(t, "radius")
            if to_world is not None:
                origin = tf.apply_point(to_world, origin)
                direction = tf.apply_vector(to_world, direction)
            light = _construct(node, CylinderSpotLight, origin=origin, direction=direction,
                               radius=radius, intensity=props.links1(t, "intensity"), name=name)
        elif t == "constant":
            light = ConstantEnvironment(props.color("radiance", 1.0, emitter=True), name=name)
        elif t == "envmap":
            fn = props.string("filename")
            from ..errors import Links1Error
            from ..imaging.image import read_image
            try:
                data = read_image(node.resolve(fn))
            except (Links1Error, OSError, ValueError) as exc:
                raise props.error("filename", f"envmap: cannot read '{fn}': {exc}") from None
            light = _construct(node, EnvironmentMap, data, to_world=to_world,
                               scale=props.float("scale", 1.0, nonneg=True), name=name)
            props.ignore("mis_compensation")
        elif t == "area":
            raise node.error("an area emitter must be nested in a shape")
        elif t in _IGNORED_EMITTERS:
            node.warn(f"emitter '{t}' is not supported by the core and is ignored")
            props.ignore(*node.props)
        else:
            raise node.error(f"unknown plugin '{t}' (emitter)")
        for cname, child in node.children:
            if not (child.tag in ("spectrum", "texture") and cname in props.used):
                child.warn(f"<{child.tag}> inside an emitter is ignored by the core")
        props.ignore("sampling_weight")
        props.finish()
        return light
