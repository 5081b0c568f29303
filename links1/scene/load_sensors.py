"""The loader's sensors (:mod:`links1.scene.loader`): ``perspective``, ``thinlens`` and
``orthographic`` sensors with their film, reconstruction filter and sampler, as
:class:`links1.sensor.camera.Camera` (a mixin of the loader's builder); Mitsuba's field of view
(``fov`` / ``fov_axis`` / ``focal_length``), which projectors read too.
"""
from __future__ import annotations

import math
import re

import numpy as np

from ..sensor.camera import FOV_AXES, Camera, fov_x_from
from ..sensor.filters import FILTERS, Filter
from . import params
from .properties import _construct, _Props
from .xmlparse import Node

DEFAULT_SPP = 4  # Mitsuba's independent sampler

# Known Mitsuba 3 plugins the core does not support (for a clearer message than "unknown").
_FILMS = {"hdrfilm", "specfilm"}
_SAMPLERS = {"independent", "stratified", "multijitter", "orthogonal", "ldsampler"}
_SENSORS = {"perspective", "thinlens", "orthographic", "radiancemeter", "irradiancemeter",
            "distant", "batch"}


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


class SensorLoader:
    """Sensors, films, filters and samplers (methods of the loader's builder)."""

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
