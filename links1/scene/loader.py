"""Mitsuba 3 XML scene → :class:`links1.scene.scene.Scene`, with Mitsuba's semantics.

:mod:`links1.scene.xmlparse` reads the XML (parameters, includes, references, transforms); this
module knows the plugins: it reads the scene and its integrator, and its builder takes the rest
from one module per kind of element (:mod:`~links1.scene.load_sensors`,
:mod:`~links1.scene.load_shapes`, :mod:`~links1.scene.load_bsdfs`,
:mod:`~links1.scene.load_emitters`), all reading parameters through
:mod:`links1.scene.properties`. It never imports Mitsuba.

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

import os
import warnings

import numpy as np

from ..errors import SceneError
from ..sensor.camera import Camera
from ..shading.lights import (ENV_LIGHT_ID, AreaLight, ConstantEnvironment, EnvironmentMap,
                              number_area_lights)
from . import params
from .load_bsdfs import BsdfLoader
from .load_emitters import EmitterLoader
from .load_sensors import DEFAULT_SPP, SensorLoader, focal_length_fov_x
from .load_shapes import ShapeLoader
from .properties import _Props
from .scene import Scene
from .xmlparse import Node, parse_file, parse_string

__all__ = ["load_scene", "load_string", "build_scene", "focal_length_fov_x"]

DEFAULT_MAX_DEPTH = params.default("links1_whitted", "max_depth")


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


def build_scene(root: Node, path: str | None = None, kept: dict | None = None) -> Scene:
    """Turn the parsed ``<scene>`` node into a :class:`Scene`; each warning once (an element
    referenced twice, a BSDF shared by shapes, is read twice but named once).

    ``kept``: top-level element index -> what that element made in an earlier build, taken
    instead of building it again (:class:`links1.scene.scenefile.SceneFile`: elements whose
    parameters did not change); the dict is then filled with what this build made."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = _Builder(kept).scene(root, path)
    seen = set()
    for w in caught:
        key = (str(w.message), w.category)
        if key not in seen:
            seen.add(key)
            warnings.warn(w.message if isinstance(w.message, Warning) else str(w.message),
                          w.category, stacklevel=2)
    return scene


# --------------------------------------------------------------------------------------------
# the builder
# --------------------------------------------------------------------------------------------

class _Builder(SensorLoader, ShapeLoader, BsdfLoader, EmitterLoader):
    """The scene and its integrator; each kind of element is read by a mixin above.

    ``kept`` (:func:`build_scene`): what top-level elements made before, by index."""

    def __init__(self, kept: dict | None = None):
        self.kept = {} if kept is None else kept
        self.made: dict = {}

    def once(self, i: int, build):
        """What top-level element ``i`` makes: the kept one, else ``build()``."""
        value = self.kept[i] if i in self.kept else build()
        self.made[i] = value
        return value

    def _other_sensor(self, node: Node):
        # another view of the scene (mi.render(scene, sensor=k), links1 render --sensor k):
        # one the core cannot render is an error only when chosen
        try:
            return self.sensor(node)
        except SceneError as exc:
            return exc

    def scene(self, root: Node, path: str | None) -> Scene:
        props = _Props(root)
        props.finish()
        camera, spp = None, None
        sensors = []    # (camera, spp) of each sensor, in file order (Scene.use_sensor)
        shapes, lights, environments = [], [], []
        background = np.zeros(3)
        integrator, max_depth, integrator_params = None, DEFAULT_MAX_DEPTH, {}
        for i, (name, node) in enumerate(root.children):
            if node.tag == "sensor":
                if sensors:
                    sensors.append(self.once(i, lambda: self._other_sensor(node)))
                    continue
                camera, spp = self.once(i, lambda: self.sensor(node))
                sensors.append((camera, spp))
            elif node.tag == "shape":
                if node.type == "shapegroup":
                    self._shapegroup(node)   # drawn only through its instances
                elif node.type == "instance":
                    shapes.extend(self.once(i, lambda: self._instance(node)))
                else:
                    shapes.append(self.once(i, lambda: self.shape(node)))
            elif node.tag == "emitter":
                if node.type == "area" and node.id is not None:
                    continue  # a declaration, used where a shape references it (as Mitsuba)
                light = self.once(i, lambda: self.emitter(node))
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
                    self.once(i, lambda: self.bsdf(node))  # validate declarations that are only referenced
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
        self.kept.clear()
        self.kept.update(self.made)
        return Scene(**kwargs)

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
