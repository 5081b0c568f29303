"""Which side of a plane a point or a box lies on: the one home of the side rule that plans
shadow rays in both renderers (:mod:`links1.tracing.occluders`, the plugin's
``tables.Tables._occluders``): a planar shape shadows nothing toward a light when the light and
every other shape lie on one side of its plane.

The rule is one; the plane's form and the tolerance are the caller's, so that each renderer
keeps the decisions it made before the rule had one home (the images stay the same bits):

- the core measures ``(x - p0) · n`` with ``links1.tracing.occluders.SIDE_TOL`` (1e-9) relative
  to the box's or the point's own magnitude;
- the plugin measures ``x · n - c`` with ``1e-6`` times the scene's scale (one tolerance for the
  scene, ``tables.Tables._occluder_shapes``), and 0 for a direction.

Backend-neutral: numpy on the host, run once per scene (no Dr.Jit, no Mitsuba).
"""
from __future__ import annotations

import numpy as np


def point_side(s: float, tol: float) -> int:
    """+1 / -1: the sign of the signed distance ``s`` of a point (or direction) from a plane
    when it is beyond ``tol``; 0 (on the plane, or NaN) otherwise."""
    return 1 if s > tol else (-1 if s < -tol else 0)


def box_side(lo, hi, distance, tol) -> int:
    """+1 / -1 when the whole box ``lo``-``hi`` lies in the closed half-space ``distance >= -tol``
    / ``distance <= tol`` (touching the plane allowed), else 0; an unbounded box: 0.

    ``distance``: the signed distances of an (8, 3) array of corners from the plane;
    ``tol``: a number, or a function of the corners giving one."""
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    if not np.all(np.isfinite(corners)):
        return 0
    s = distance(corners)
    t = tol(corners) if callable(tol) else tol
    if np.all(s >= -t):
        return 1
    if np.all(s <= t):
        return -1
    return 0
