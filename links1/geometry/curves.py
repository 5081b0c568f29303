"""Mitsuba's ``linearcurve``: Embree's round linear curve, in float64.

A segment from control point ``p0`` (radius ``r0``) to ``p1`` (``r1``) is the convex hull of
the two balls: the cone tangent to both spheres between its two circles of tangency, and the
spheres themselves (Embree ``kernels/geometry/roundline_intersector.h``; Mitsuba 3.9.1
``src/shapes/linearcurve.cpp``: "connected by a smooth spherical joint, terminated by a
spherical endcap"). A curve is the union of its segments. As in Mitsuba, back faces are
culled: a hit counts only where the ray enters a segment (``ng · d < 0``), so a ray that
starts inside a curve does not see it from within.

The file format is Mitsuba's: one control point ``x y z radius`` per line, a blank line
between curves; ``to_world`` moves the points, the radii stay as written.
"""
from __future__ import annotations

import numpy as np

from ..maths.vec import cross, dot, normalize
from .primset import PrimitiveSet
from .shapes import _finite_or_zero, _turn


def read_curves(path, min_points: int = 2) -> list:
    """Curves of Mitsuba's text format: a list of float64 ``(K, 4)`` arrays (x, y, z,
    radius), ``K >= min_points``. ValueError ``PATH:LINE: what`` on a bad line."""
    curves, cur, start = [], [], 0
    with open(path, encoding="utf-8", errors="replace") as fh:
        lines = fh.read().split("\n")
    for i, line in enumerate(lines + [""], start=1):
        words = line.split()
        if not words:
            if cur:
                if len(cur) < min_points:
                    raise ValueError(f"{path}:{start}: a curve needs at least {min_points} control "
                                     f"points, this one has {len(cur)}")
                curves.append(np.array(cur, dtype=np.float64))
            cur = []
            continue
        try:
            vals = [float(w) for w in words[:4]]
        except ValueError:
            vals = []
        if len(vals) != 4 or not np.all(np.isfinite(vals)):
            raise ValueError(f"{path}:{i}: a control point is 4 finite numbers 'x y z radius', "
                             f"got {line.strip()!r}")
        if not cur:
            start = i
        cur.append(vals)
    if not curves:
        raise ValueError(f"{path}: no control points")
    return curves


def _sphere_front(o, d, c, r):
    """Entry distance of unit rays into the balls ``(c, r)``: ``nan`` where missed."""
    oc = o - c
    b = dot(oc, d)
    h = b * b - (dot(oc, oc) - r * r)
    with np.errstate(invalid="ignore"):
        return np.where(h >= 0.0, -b - np.sqrt(np.maximum(h, 0.0)), np.nan)


class RoundLinearCurves(PrimitiveSet):
    """Round linear segments (see the module docstring).

    Parameters
    ----------
    curves : list of (K, 4)  world-space control points and radii, one array per curve
    """

    def __init__(self, curves, name: str = ""):
        pts, starts = [], []
        n = 0
        for c in curves:
            c = np.asarray(c, dtype=np.float64)
            if c.ndim != 2 or c.shape[1] != 4 or c.shape[0] < 2:
                raise ValueError(f"linearcurve {name!r}: each curve needs (K >= 2, 4) control points, "
                                 f"got {c.shape}")
            if not np.all(np.isfinite(c)) or np.any(c[:, 3] < 0):
                raise ValueError(f"linearcurve {name!r}: control points must be finite with radii >= 0")
            pts.append(c)
            starts.extend(range(n, n + c.shape[0] - 1))
            n += c.shape[0]
        self.points = np.concatenate(pts)
        self.segments = np.array(starts, dtype=np.int64)
        a, b = self.points[self.segments], self.points[self.segments + 1]
        lo = np.minimum(a[:, :3] - a[:, 3:], b[:, :3] - b[:, 3:])
        hi = np.maximum(a[:, :3] + a[:, 3:], b[:, :3] + b[:, 3:])
        super().__init__(lo, hi, name=name)

    def _repr_extra(self) -> str:
        return f"control_points={self.points.shape[0]}, segments={self.segments.size}"

    def _ends(self, prim):
        a, b = self.points[self.segments[prim]], self.points[self.segments[prim] + 1]
        return a[:, :3], a[:, 3], b[:, :3], b[:, 3]

    def _pieces(self, prim, o, d):
        """Front hits on the segment's three pieces (sphere at p0, sphere at p1, tangent cone),
        each ``nan`` where there is none, and the cone's ``y`` and ``g`` terms (Embree's)."""
        p0, r0, p1, r1 = self._ends(prim)
        dP = p1 - p0
        dPdP = dot(dP, dP)
        dr = r1 - r0
        g = dPdP - dr * dr            # > 0 unless one ball holds the other
        O = o - p0
        OdP, dOdP = dot(O, dP), dot(d, dP)
        # the cone touching both spheres: quadratic A t^2 + B t + C = 0 (roundline_intersector.h)
        A = g - dOdP * dOdP
        B = 2.0 * (g * dot(O, d) - dOdP * (OdP + r0 * dr))
        C = g * dot(O, O) - OdP * OdP - r0 * r0 * dPdP - 2.0 * r0 * dr * OdP
        disc = B * B - 4.0 * A * C
        with np.errstate(invalid="ignore", divide="ignore"):
            sq = np.sqrt(np.maximum(disc, 0.0))
            qq = -0.5 * (B + np.where(B >= 0, sq, -sq))
            roots = [qq / A, C / qq]
        t_cone = np.full(prim.size, np.nan)
        for t in roots:
            y = OdP + r0 * dr + t * dOdP
            h = O + t[:, None] * d
            ng = g[:, None] * h - dP * y[:, None]
            ok = (disc >= 0) & (g > 0) & np.isfinite(t) & (y >= 0) & (y <= g) & (dot(ng, d) < 0)
            t_cone = np.where(ok & ~(t >= t_cone), t, t_cone)
        return _sphere_front(o, d, p0, r0), _sphere_front(o, d, p1, r1), t_cone

    def _pair_hits(self, prim, o, d, tmin, tmax):
        best = np.full(prim.size, np.inf)
        for t in self._pieces(prim, o, d):
            best = np.where((t > tmin) & (t < tmax) & (t < best), t, best)
        return best

    def _axis_point(self, prim, o, d, t):
        """Embree's ``u`` of a hit: where on ``p0 -> p1`` its normal starts, ``c = p0 + u (p1 -
        p0)`` with ``ng ∝ p - c`` (the cone: ``u = y/g``; the spheres: 0 or 1), the piece hit
        being the one whose distance is nearest ``t``."""
        p0, r0, p1, r1 = self._ends(prim)
        dP = p1 - p0
        dr = r1 - r0
        g = dot(dP, dP) - dr * dr
        p = o + t[:, None] * d
        y = dot(p - p0, dP) + r0 * dr
        with np.errstate(invalid="ignore", divide="ignore"):
            u_cone = np.clip(y / np.where(g > 0, g, 1.0), 0.0, 1.0)
        gap = np.stack([np.abs(np.nan_to_num(tp, nan=np.inf) - t) for tp in self._pieces(prim, o, d)], axis=1)
        piece = np.argmin(gap, axis=1)
        u = np.select([piece == 0, piece == 1], [0.0, 1.0], u_cone)
        return u, p0 + u[:, None] * dP, dP

    def _hit_record(self, o, d, t, prim):
        """Hit points, their normals' axis points ``c``, Embree's ``u``, segment vectors."""
        o = np.asarray(o, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(d, dtype=np.float64).reshape(-1, 3)
        prim = np.maximum(np.asarray(prim, dtype=np.int64), 0)
        t = _finite_or_zero(t)
        u_seg, c, dP = self._axis_point(prim, o, d, t)
        return o + t[:, None] * d, c, u_seg, dP, prim

    def surface(self, o, d, t, prim):
        p, c, _, _, _ = self._hit_record(o, d, t, prim)
        ng = normalize(p - c)
        return p, ng, ng.copy()

    def uv(self, o, d, t, prim):
        """Mitsuba's curve parameterisation: ``u`` the angle about the segment in a frame
        built from ``+z`` (``y`` where the segment is along ``z``), ``v = (u_seg + segment) /
        segments``."""
        p, c, u_seg, dP, prim = self._hit_record(o, d, t, prim)
        axis = normalize(dP)
        guide = np.array([0.0, 0.0, 1.0])
        rot = normalize(guide - axis * dot(axis, guide)[:, None])
        rot = np.where((np.abs(axis[:, 2]) == 1.0)[:, None], np.array([0.0, 1.0, 0.0]), rot)
        rad = cross(rot, axis)
        n = normalize(p - c)
        u = _turn(np.arctan2(dot(rot, n), dot(rad, n)))
        return np.stack([u, (u_seg + prim) / self.segments.size], axis=1)
