"""Which shapes can cast a shadow toward each light: looked at once per scene, so the
integrator traces no shadow ray where no occluder can be.

Two conservative facts decide it:

* a **convex** shape (an unclipped sphere or ellipsoid, a capped quadric, a disk, a planar
  or convex closed mesh) never shadows its own points *toward a light on the outer side of
  the surface there* (``ng · wi > 0``, ``ng`` outward): that segment leaves it at once. A
  **closed** convex shape does shadow its points whose light lies on the inner side (seen
  from inside it, or reached by refraction through it): that segment crosses it;
* a **planar** shape (disk, rectangle, flat mesh) shadows nothing toward a light when the
  light and every other shape lie on one side of its plane (a floor under the scene); for an
  area light the whole emitter (its bounding box) must lie on that side;
* a convex **emitter** never hides the points sampled on it (they face the shaded point);
* a light **at a pinhole camera's eye** (a headlight) is hidden from no point the camera
  sees: the shadow ray of a camera ray's hit runs back along that camera ray, which met
  nothing before the hit (:func:`lights_at_eye`; the camera's rays only, not deeper levels').

The result per light ``j``: ``occluder[j]`` (S,) bool, the shapes a shadow ray toward ``j``
may hit, and ``need[j]`` (S,) bool, whether a point on shape ``s`` needs a shadow ray toward
``j`` at all (some occluder other than ``s``, or ``s`` itself when it is not convex).
:func:`closed_convex` names the convex shapes whose points still need a shadow ray where
``ng · wi <= 0``.
"""
from __future__ import annotations

import math

import numpy as np

from ..maths.halfspace import box_side, point_side
from ..geometry.shapes import Disk, Quadric, TriangleMesh
from ..shading.lights import AreaLight, ConeSpotLight, CylinderSpotLight, ParallelLight, PointLight, ProjectorLight

#: Relative tolerance of the side-of-plane tests (scene scale units); the rule itself is
#: :mod:`links1.maths.halfspace`'s, shared with the plugin (which has its own tolerance).
SIDE_TOL = 1e-9


def _plane_of(shape):
    """(normal, point) of a planar shape, or None."""
    if isinstance(shape, Disk):
        m = shape.to_world if hasattr(shape, "to_world") else None
        if m is None:
            return None
        n = np.linalg.inv(m[:3, :3]).T @ np.array([0.0, 0.0, 1.0])
        return n / np.linalg.norm(n), m[:3, 3].copy()
    if isinstance(shape, TriangleMesh):
        v, f = shape.vertices, shape.faces
        e1, e2 = v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]
        cr = np.cross(e1, e2)
        k = int(np.argmax(np.linalg.norm(cr, axis=1)))
        n = cr[k] / np.linalg.norm(cr[k])
        p0 = v[f[k, 0]]
        scale = 1.0 + np.max(np.abs(v))
        if np.all(np.abs((v - p0) @ n) <= SIDE_TOL * scale):
            return n, p0
    return None


def _convex(shape) -> bool:
    if isinstance(shape, Disk):
        return True
    if isinstance(shape, Quadric):
        return (shape.kind == "sphere" and not shape.clips) or shape.capped
    if isinstance(shape, TriangleMesh):
        if _plane_of(shape) is not None:
            return True
        if not shape.closed or len(shape.faces) > 256:
            return False
        v, f = shape.vertices, shape.faces
        n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        side = np.einsum("fk,fvk->fv", n, v[None, :, :] - v[f[:, 0]][:, None, :])
        return bool(np.all(side <= SIDE_TOL * (1.0 + np.max(np.abs(v))) * np.linalg.norm(n, axis=1)[:, None]))
    return False


def closed_convex(shapes) -> np.ndarray:
    """(S,) bool: the convex shapes that enclose a volume (not planar), whose points with the
    light on the inner side of the surface are shadowed by the shape itself."""
    return np.array([_convex(s) and _plane_of(s) is None and not _is_disk(s) for s in shapes], dtype=bool)


def _is_disk(shape) -> bool:
    return isinstance(shape, Disk)


def _light_side(light, n, p0):
    """+1 / -1: the side of the plane (n, p0) the light is on; 0 when it straddles it."""
    if isinstance(light, ParallelLight):
        return point_side(-float(light.direction @ n), SIDE_TOL)
    if isinstance(light, PointLight):
        pos, reach = light.position, 0.0
    elif isinstance(light, CylinderSpotLight):
        pos, reach = light.origin, light.radius
    elif isinstance(light, (ConeSpotLight, ProjectorLight)):
        pos, reach = light.position, 0.0
    elif isinstance(light, AreaLight):  # a light with extent: the whole emitter must be on one side
        return _box_side(*light.bounds(), n, p0)
    else:  # environments light from every direction
        return 0
    return point_side(float((pos - p0) @ n), reach + SIDE_TOL * (1.0 + np.max(np.abs(pos))))


def _box_side(lo, hi, n, p0):
    """+1 / -1 when the whole box is on one side of the plane (touching allowed), else 0
    (:func:`links1.maths.halfspace.box_side` with the core's plane form and tolerance)."""
    return box_side(lo, hi, lambda c: (c - p0) @ n, lambda c: SIDE_TOL * (1.0 + np.max(np.abs(c))))


def shadow_plan(shapes, lights):
    """``(occluder, need)``: lists over lights of (S,) bool arrays (see the module docstring)."""
    S = len(shapes)
    convex = np.array([_convex(s) for s in shapes], dtype=bool)
    planes = [_plane_of(s) for s in shapes]
    boxes = [s.bounds() for s in shapes]
    occluder, need = [], []
    for light in lights:
        occ = np.ones(S, dtype=bool)
        for k, pl in enumerate(planes):
            if pl is None:
                continue
            n, p0 = pl
            side = _light_side(light, n, p0)
            if side == 0:
                continue
            if all(_box_side(*boxes[j], n, p0) == side for j in range(S) if j != k):
                occ[k] = False  # the light and every other shape are on one side: a floor
        own = [k for k, s in enumerate(shapes) if s is getattr(light, "shape", None)]
        if own and convex[own[0]]:
            occ[own[0]] = False  # a convex emitter never hides its own sampled (facing) points
        total = int(occ.sum())
        nd = np.array([(total - int(occ[s])) > 0 or (occ[s] and not convex[s]) for s in range(S)], dtype=bool)
        occluder.append(occ)
        need.append(nd)
    return occluder, need


#: Margin of :func:`lights_at_eye`'s near-plane reach (relative), for the float32 rays' rounding
EYE_REACH_MARGIN = 2.0 ** -16


def near_reach(near_clip: float, tan_x: float, tan_y: float) -> float:
    """How far from a pinhole camera's eye its rays start at most: the near plane's corner,
    ``near_clip`` away along the view axis, ``tan_x`` and ``tan_y`` the half-angles' tangents."""
    return float(near_clip) * math.sqrt(1.0 + tan_x * tan_x + tan_y * tan_y)


def lights_at_eye(eye, reach: float, positions, boxes) -> list[bool]:
    """Per light, whether the shadow rays of a pinhole camera's hits toward it need no test:
    the light sits at the eye (its position equal to the eye's in float32, the precision the
    plugin's rays are traced in), so each shadow ray runs back along the camera ray that found
    its hit, which met nothing before it. The camera rays start on the near plane, up to
    ``reach`` (:func:`near_reach`) from the eye, so every shape's bounding box must keep
    farther than that: a shape nearer would be unseen yet cast a shadow (and an unbounded one
    may be anywhere). ``positions``: per light its position, or None for a light without one;
    ``boxes``: ``(lo, hi)`` per shape. Conservative: False where unsure."""
    eye = np.asarray(eye, dtype=np.float64).reshape(3)
    e32 = eye.astype(np.float32)
    at = [p is not None and bool(np.array_equal(np.asarray(p, dtype=np.float64).reshape(3).astype(np.float32), e32))
          for p in positions]
    if not any(at) or not np.all(np.isfinite(eye)):
        return [False] * len(at)
    boxes = list(boxes)
    if boxes:
        lo = np.array([b[0] for b in boxes], dtype=np.float64).reshape(-1, 3)
        hi = np.array([b[1] for b in boxes], dtype=np.float64).reshape(-1, 3)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            return [False] * len(at)
        gap = np.maximum(np.maximum(lo - eye, eye - hi), 0.0)     # the eye's distance to each box
        r = reach * (1.0 + EYE_REACH_MARGIN) + EYE_REACH_MARGIN * (1.0 + float(np.max(np.abs(eye))))
        if float(np.min(np.sqrt(np.sum(gap * gap, axis=1)))) <= r:
            return [False] * len(at)
    return at


def camera_lights_at_eye(camera, shapes, lights) -> list[bool]:
    """:func:`lights_at_eye` of the core's camera (``links1.sensor.camera.Camera``: a pinhole
    perspective one, else none), shapes and lights (point, cone spot and projector lights
    have a position)."""
    if camera is None or camera.projection != "perspective" or camera.thin_lens:
        return [False] * len(lights)
    t = math.tan(math.radians(camera.fov_x) / 2.0)
    reach = near_reach(camera.near_clip, t, t * camera.height / camera.width)
    positions = [lt.position if isinstance(lt, (PointLight, ConeSpotLight, ProjectorLight)) else None
                 for lt in lights]
    return lights_at_eye(camera.origin, reach, positions, (s.bounds() for s in shapes))   # (boxes only if needed)
