"""The loader's emitters (:mod:`links1.scene.loader`): Mitsuba's point, directional, spot,
projector, constant and envmap emitters and links1's ``links1_point`` and ``links1_spot`` (a
mixin of the loader's builder; area emitters are read with their shape,
:mod:`links1.scene.load_shapes`).
"""
from __future__ import annotations

import numpy as np

from ..errors import Links1Error
from ..imaging.image import read_image
from ..maths import transform as tf
from ..shading import textures
from ..shading.lights import (ConeSpotLight, ConstantEnvironment, CylinderSpotLight, EnvironmentMap,
                              ParallelLight, PointLight, ProjectorLight)
from .load_sensors import _fov_x
from .properties import _construct, _Props
from .xmlparse import Node

# Known Mitsuba 3 plugins the core does not support (for a clearer message than "unknown").
_IGNORED_EMITTERS = {"sunsky", "directionalarea"}


class EmitterLoader:
    """Emitters (methods of the loader's builder)."""

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
