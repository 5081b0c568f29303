"""Mitsuba's ``linearcurve`` and ``bsplinecurve``: Embree's round linear and round cubic
B-spline curves, in float64 (the B-spline: :class:`RoundBSplineCurves`).

A segment from control point ``p0`` (radius ``r0``) to ``p1`` (``r1``) is the convex hull of
the two balls: the cone tangent to both spheres between its two circles of tangency, and the
spheres themselves (Embree ``kernels/geometry/roundline_intersector.h``; Mitsuba 3.9.1
``src/shapes/linearcurve.cpp``: "connected by a smooth spherical joint, terminated by a
spherical endcap"). A curve is the union of its segments. As in Mitsuba, back faces are
culled: a hit counts only where the ray enters a segment (``ng · d < 0``), so a ray that
starts inside a curve does not see it from within.

The cubic B-spline, as Mitsuba 3.9.1 renders it (``src/shapes/bsplinecurve.cpp`` gives Embree
its segments as ``RTC_GEOMETRY_TYPE_ROUND_BSPLINE_CURVE``; its Embree 3.13 fork is built with
``EMBREE_BACKFACE_CULLING_CURVES`` on, ``ext/CMakeLists.txt``):

* The surface. Embree's sweep intersector (``kernels/geometry/curve_intersector_sweep.h``,
  ``intersect_bezier_iterative_jacobian``) solves ``f = (q - c(u))·T(u) = 0`` and ``g =
  sqrt(|q - c(u)|² - f²) - r(u) = 0`` for ``(u, t)``, ``q = o + t d``, ``T = c'/|c'|``,
  keeping ``u`` in [0, 1] and ``t`` in [tnear, tfar]: the sweep of the circle of radius
  ``r(u)`` about ``c(u)`` in the plane normal to ``T``, not of a sphere (a varying radius
  tilts the normal, not the circle). Each segment is open at both ends; consecutive
  segments share their end circle (the spline is C2); a curve's first and last ends are
  open (Mitsuba's documentation: "hollow cylindrical tubes [...] open-ended"). Premise,
  Embree's and the core's: ``r κ < 1`` (``κ`` the centre line's curvature), the sweep does
  not fold onto itself; where it does, Embree misses entries at the folded turns (measured:
  a zigzag with ``r κ = 4`` lit from below, 0.8 % of the core's hits, all at its turns).
* Which hits. Embree cuts a segment into pieces, each bounded by a cylinder and by the
  planes normal to ``c'`` at its ends; with back-face culling, Newton starts only where the
  ray enters a piece's outer bounding cylinder outside its inner one, and the root it
  converges to is reported whichever way it faces. From outside, that is the entry. A ray
  that starts inside a tube mostly finds nothing there (the tube is transparent from within:
  the ray goes on to the next entry), but from just inside the wall, between a piece's two
  bounding cylinders, Newton can converge to the exit. Mitsuba drops a hit whose own normal
  faces along the ray (``Shape::cull_backface`` in ``compute_surface_interaction``: ``si.t =
  inf``, a miss, not the next hit), while ``ray_test`` keeps it (``src/render/scene_embree.inl``
  sets no filter function on curves): occluded. The core counts entries only, never an exit
  (measured: 1 of 18000 rays from random points inside the tests' two tubes differs so).
* Mitsuba's normal (Embree's ``Ng`` is not used): ``(|c'|² - (p - c)·c'') (p - c) - r r' c'``,
  the sweep's exact normal. ``uv``: ``u`` the angle about ``c'`` from Mitsuba's
  ``local_frame`` (guide +z), ``v = (v_local + segment) / segments``. ``dp_du``, ``dp_dv``:
  Mitsuba's ``partials`` (Frenet frame); ``dp_du = 2π r T × ρ`` is the tangent of Mitsuba's
  shading frame (``initialize_sh_frame`` in ``include/mitsuba/render/interaction.h``).
* Not reproduced: Embree's float32 Newton iteration (5 steps) near a silhouette, which misses
  some grazing hits and, at a tangent graze, can step to a point off the surface that
  Mitsuba then culls. Measured (tests/core/test_bspline_curves.py): under 0.1 % of random
  rays, each within 1 % of the radius of a silhouette.

The file format is Mitsuba's: one control point ``x y z radius`` per line, a blank line
between curves; ``to_world`` moves the points, the radii stay as written.
"""
from __future__ import annotations

import numpy as np

from ..maths.vec import coordinate_system, cross, dot, normalize
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


def _segments(curves, what: str, order: int):
    """All curves' control points (P, 4) stacked, and the index of each segment's first point
    (a curve of ``K`` points has ``K - order + 1`` segments of ``order`` points)."""
    pts, starts = [], []
    n = 0
    for c in curves:
        c = np.asarray(c, dtype=np.float64)
        if c.ndim != 2 or c.shape[1] != 4 or c.shape[0] < order:
            raise ValueError(f"{what}: each curve needs (K >= {order}, 4) control points, got {c.shape}")
        if not np.all(np.isfinite(c)) or np.any(c[:, 3] < 0):
            raise ValueError(f"{what}: control points must be finite with radii >= 0")
        pts.append(c)
        starts.extend(range(n, n + c.shape[0] - order + 1))
        n += c.shape[0]
    return np.concatenate(pts), np.array(starts, dtype=np.int64)


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
        self.points, self.segments = _segments(curves, f"linearcurve {name!r}", 2)
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
        p, c, u_seg, dP, prim = self._hit_record(o, d, t, prim)
        return _curve_uv(p - c, dP, u_seg, prim, self.segments.size)


def _curve_uv(rad, tangent, v_local, prim, segments):
    """Mitsuba's curve parameterisation: ``u`` the angle of ``rad`` about ``tangent`` in a
    frame built from ``+z`` (``y`` where the tangent is along ``z``), ``v = (v_local +
    segment) / segments``."""
    axis = normalize(tangent)
    guide = np.array([0.0, 0.0, 1.0])
    rot = normalize(guide - axis * dot(axis, guide)[:, None])
    rot = np.where((np.abs(axis[:, 2]) == 1.0)[:, None], np.array([0.0, 1.0, 0.0]), rot)
    n = normalize(rad)
    u = _turn(np.arctan2(dot(rot, n), dot(cross(rot, axis), n)))
    return np.stack([u, (v_local + prim) / segments], axis=1)


# ---------------------------------------------------------------------------- cubic B-splines
#: Initial samples of a ray's stretch through a segment's box, and the refinement rounds.
BSPLINE_SAMPLES = 16
_REFINE_ROUNDS = 40
_BISECTIONS_T = 52
#: Lipschitz constant assumed for the distance along the ray (1 for a constant radius).
_LIPSCHITZ = 1.5
_CHUNK = 4096


def _bspline_basis(v):
    """Uniform cubic B-spline basis at ``v`` (...,): values, first and second derivatives,
    each (..., 4) (Mitsuba's ``cubic_interpolation``)."""
    v2, v3 = v * v, v * v * v
    b = np.stack([-v3 + 3 * v2 - 3 * v + 1, 3 * v3 - 6 * v2 + 4, -3 * v3 + 3 * v2 + 3 * v + 1, v3], -1) / 6.0
    db = np.stack([-3 * v2 + 6 * v - 3, 9 * v2 - 12 * v, -9 * v2 + 6 * v + 3, 3 * v2], -1) / 6.0
    ddb = np.stack([1 - v, 3 * v - 2, 1 - 3 * v, v], -1)
    return b, db, ddb


def _eval(ctrl, v):
    """Centre, first and second derivatives, radius and its derivative of the segments
    ``ctrl`` (N, 4, 4) at ``v`` (N,)."""
    b, db, ddb = _bspline_basis(v)
    c = np.einsum("nj,njd->nd", b, ctrl)
    dc = np.einsum("nj,njd->nd", db, ctrl)
    ddc = np.einsum("nj,njd->nd", ddb, ctrl[:, :, :3])
    return c[:, :3], dc[:, :3], ddc, c[:, 3], dc[:, 3]


def _closest(ctrl, q):
    """The centre line's point nearest ``q`` (N, 3): ``v`` in [0, 1] (17 samples, then Newton
    on ``(c - q)·c' = 0``) and the distance ``|q - c(v)| - r(v)`` to the swept circle there
    (a surface point only where ``v`` is not an end: the tube is open)."""
    vs = np.linspace(0.0, 1.0, 17)
    b, _, _ = _bspline_basis(vs)
    c = np.einsum("mj,njd->nmd", b, ctrl[:, :, :3])
    v = vs[np.argmin(np.sum((c - q[:, None]) ** 2, axis=2), axis=1)]
    for _ in range(6):
        c, dc, ddc, _, _ = _eval(ctrl, v)
        g = dot(c - q, dc)
        dg = dot(dc, dc) + dot(c - q, ddc)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.where(dg > 0, g / np.where(dg > 0, dg, 1.0), 0.0)
        v = np.clip(v - step, 0.0, 1.0)
    c, dc, _, r, _ = _eval(ctrl, v)
    return v, np.sqrt(dot(q - c, q - c)) - r


class RoundBSplineCurves(PrimitiveSet):
    """Mitsuba's ``bsplinecurve``: Embree's round cubic B-spline curve, the sweep of a circle
    of radius ``r(v)`` centred on the uniform cubic B-spline ``c(v)`` in the plane normal to
    ``c'(v)``, open at the ends (``v`` in [0, 1] per segment; Embree
    ``kernels/geometry/curve_intersector_sweep.h``: ``dot(R, T) = 0``, ``|R| = r``).

    Intersection (the module docstring says which surface and which hits): along the ray,
    the distance to the tube ``φ(t) = |q - c(v*)| - r(v*)`` with ``c(v*)`` the centre line's
    point nearest ``q = o + t d`` (where ``(q - c)·c' = 0``: the swept circle through ``q``'s
    normal plane); an entry is a change of ``φ`` from + to - with ``v*`` inside (0, 1) (the
    tube is open at its ends). The ray's stretch through the segment's box is sampled; a piece
    whose ends have one sign (both outside, or both inside: a ray grazing out of the wall from
    within) but could hide a root between them (``φ`` changes by at most :data:`_LIPSCHITZ`
    per unit of ``t``) is split, each entry is bisected to float64. This assumes the radius
    below the centre line's radius of curvature (Embree's premise too); roots closer than
    1e-12 relative are not separated. Normals as Mitsuba's.
    """

    def __init__(self, curves, name: str = ""):
        self.points, self.segments = _segments(curves, f"bsplinecurve {name!r}", 4)
        super().__init__(*self.bvh_boxes(np.arange(self.segments.size)), name=name)

    def _repr_extra(self) -> str:
        return f"control_points={self.points.shape[0]}, segments={self.segments.size}"

    def _ctrl(self, prim):
        return self.points[self.segments[prim][:, None] + np.arange(4)]

    def _normal(self, prim, p, v):
        """Mitsuba's normal: ``(|c'|² - (p - c)·c'') (p - c) - r r' c'``, normalised."""
        c, dc, ddc, r, dr = _eval(self._ctrl(prim), v)
        rad = p - c
        return normalize((dot(dc, dc) - dot(rad, ddc))[:, None] * rad - (dr * r)[:, None] * dc), c, dc

    def _phi(self, prim, o, d, t):
        """Distance to the tube at ``o + t d``, ``v``, and whether ``v`` is inside (0, 1)."""
        v = np.empty(prim.size)
        phi = np.empty(prim.size)
        for s in range(0, prim.size, _CHUNK):
            sl = slice(s, s + _CHUNK)
            v[sl], phi[sl] = _closest(self._ctrl(prim[sl]), o[sl] + t[sl, None] * d[sl])
        return phi, v, (v > 0.0) & (v < 1.0)

    def _nearest(self, prim, o, d, tmin, tmax):
        """Nearest front-facing hit of each pair in ``(tmin, tmax)``: ``(t, v)``, inf/nan.

        The ray's stretch through the segment's box is cut into :data:`BSPLINE_SAMPLES`
        pieces; a piece whose ends' distances go from + to - holds an entry (bisected to
        float64); one whose ends are both outside but closer together than the distance can
        change along it (Lipschitz bound) is split into four, up to :data:`_REFINE_ROUNDS`
        times, so that no entry is skipped between samples."""
        k = prim.size
        lo_b, hi_b = self.bvh_boxes(prim)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            inv = 1.0 / np.where(d == 0, 1e-300, d)
            ta, tb = (lo_b - o) * inv, (hi_b - o) * inv
        t0 = np.maximum(np.minimum(ta, tb).max(axis=1), tmin)
        t1 = np.minimum(np.maximum(ta, tb).min(axis=1), tmax)
        best_t, best_v = np.full(k, np.inf), np.full(k, np.nan)
        live = np.nonzero(t0 < t1)[0]
        if live.size == 0:
            return best_t, best_v
        n = BSPLINE_SAMPLES
        pair = np.repeat(live, n + 1)
        ts = (t0[live, None] + (t1 - t0)[live, None] * np.linspace(0.0, 1.0, n + 1)).ravel()
        phi, _, inner = self._phi(prim[pair], o[pair], d[pair], ts)
        # pieces: pair, t at its ends, distances at its ends, whether each end is off the open ends
        j = np.arange(pair.size).reshape(live.size, n + 1)
        lo_i, hi_i = j[:, :-1].ravel(), j[:, 1:].ravel()
        P, TL, TH, FL, FH = pair[lo_i], ts[lo_i], ts[hi_i], phi[lo_i], phi[hi_i]
        IL, IH = inner[lo_i], inner[hi_i]
        brackets = []
        for _ in range(_REFINE_ROUNDS):
            wide = TH - TL > 1e-12 * (1.0 + np.abs(TH))
            entry = (FL > 0) & (FH <= 0) & IL & IH
            # a root hides between two ends of one sign (outside: an entry and an exit; inside:
            # an exit and a re-entry, a ray grazing the wall from within) only where the
            # distance can go to 0 and back between them
            same = (FL > 0) == (FH > 0)
            suspect = wide & ((same & (np.abs(FL) + np.abs(FH) < _LIPSCHITZ * (TH - TL)))
                              | ~same & ~(IL & IH))
            brackets.append((P[entry], TL[entry], TH[entry]))
            if not suspect.any():
                break
            P, TL, TH = P[suspect], TL[suspect], TH[suspect]
            FL, FH, IL, IH = FL[suspect], FH[suspect], IL[suspect], IH[suspect]
            m = 4
            tm = (TL[:, None] + (TH - TL)[:, None] * (np.arange(1, m) / m)).ravel()
            pm = np.repeat(P, m - 1)
            fm, _, im = self._phi(prim[pm], o[pm], d[pm], tm)
            tt = np.concatenate([TL[:, None], tm.reshape(-1, m - 1), TH[:, None]], axis=1)
            ff = np.concatenate([FL[:, None], fm.reshape(-1, m - 1), FH[:, None]], axis=1)
            ii = np.concatenate([IL[:, None], im.reshape(-1, m - 1), IH[:, None]], axis=1)
            P = np.repeat(P, m)
            TL, TH, FL, FH = tt[:, :-1].ravel(), tt[:, 1:].ravel(), ff[:, :-1].ravel(), ff[:, 1:].ravel()
            IL, IH = ii[:, :-1].ravel(), ii[:, 1:].ravel()
        P = np.concatenate([b[0] for b in brackets])
        if P.size == 0:
            return best_t, best_v
        TL = np.concatenate([b[1] for b in brackets])
        TH = np.concatenate([b[2] for b in brackets])
        # only each pair's first bracket matters
        order = np.lexsort((TL, P))
        first = np.ones(order.size, dtype=bool)
        first[1:] = P[order][1:] != P[order][:-1]
        sel = order[first]
        P, TL, TH = P[sel], TL[sel], TH[sel]
        sp, so, sd = prim[P], o[P], d[P]
        for _ in range(_BISECTIONS_T):
            mid = 0.5 * (TL + TH)
            fm, _, _ = self._phi(sp, so, sd, mid)
            out = fm > 0
            TL, TH = np.where(out, mid, TL), np.where(out, TH, mid)
        _, v, _ = self._phi(sp, so, sd, TH)
        best_t[P] = TH
        best_v[P] = v
        return best_t, best_v

    def bvh_boxes(self, prim):
        """The world boxes of segments ``prim``."""
        ctrl = self._ctrl(prim)
        rmax = ctrl[:, :, 3].max(axis=1, keepdims=True)
        return ctrl[:, :, :3].min(axis=1) - rmax, ctrl[:, :, :3].max(axis=1) + rmax

    def _pair_hits(self, prim, o, d, tmin, tmax):
        return self._nearest(prim, o, d, tmin, tmax)[0]

    def _hit_record(self, o, d, t, prim):
        o = np.asarray(o, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(d, dtype=np.float64).reshape(-1, 3)
        prim = np.maximum(np.asarray(prim, dtype=np.int64), 0)
        t = _finite_or_zero(t)
        _, v, _ = self._phi(prim, o, d, t)      # the hit's circle: the one :meth:`_nearest` gives
        p = o + t[:, None] * d
        n, c, dc = self._normal(prim, p, v)
        return p, n, c, dc, v, prim

    def surface(self, o, d, t, prim):
        p, n, _, _, _, _ = self._hit_record(o, d, t, prim)
        return p, n, n.copy()

    def uv(self, o, d, t, prim):
        """Mitsuba's parameterisation, as :meth:`RoundLinearCurves.uv` about ``c'(v)``."""
        p, _, c, dc, v, prim = self._hit_record(o, d, t, prim)
        return _curve_uv(p - c, dc, v, prim, self.segments.size)

    def tangents(self, o, d, t, prim):
        """Mitsuba's ``partials``: ``dp_du = 2π r (B cos θ - N sin θ)`` and ``dp_dv = S (c' +
        r' ρ + r ρ_v)``, ``ρ = N cos θ + B sin θ`` the unit radial direction of the hit in the
        Frenet frame ``(T, N, B)`` of the centre line (curvature ``κ``, torsion ``τ``; ``ρ_v =
        |c'| (cos θ (τ B - κ T) - sin θ τ N)``; ``S`` segments). Mitsuba's shading frame takes
        its tangent from ``dp_du``: the direction around the tube, ``T × ρ``."""
        p, _, c, dc, v, prim = self._hit_record(o, d, t, prim)
        ctrl = self._ctrl(prim)
        _, _, ddc, r, dr = _eval(ctrl, v)
        dddc = np.einsum("j,njd->nd", np.array([-1.0, 3.0, -3.0, 1.0]), ctrl[:, :, :3])
        ldc = np.sqrt(dot(dc, dc))
        T = dc / ldc[:, None]
        b = cross(dc, ddc)
        lb = np.sqrt(dot(b, b))
        with np.errstate(divide="ignore", invalid="ignore"):
            kappa = lb / (ldc * ldc * ldc)
            tau = np.where((lb < 1e-6) | (np.sqrt(dot(dddc, dddc)) < 1e-6), 0.0, dot(dddc, b) / (lb * lb))
        N = normalize(cross(b, dc))
        B = normalize(cross(T, N))
        flat = ~(kappa >= np.finfo(np.float32).eps / 2)     # Mitsuba: κ < Epsilon, a degenerate frame
        if flat.any():
            s_, t_ = coordinate_system(T[flat])
            N[flat], B[flat], kappa[flat], tau[flat] = s_, t_, 0.0, 0.0
        rho = normalize(cross(cross(T, p - c), T))
        cos_t, sin_t = dot(N, rho), dot(B, rho)
        rho_v = ldc[:, None] * (cos_t[:, None] * (tau[:, None] * B - kappa[:, None] * T)
                                - (sin_t * tau)[:, None] * N)
        dp_du = (2.0 * np.pi * r)[:, None] * (cos_t[:, None] * B - sin_t[:, None] * N)
        dp_dv = self.segments.size * (dc + dr[:, None] * rho + r[:, None] * rho_v)
        return dp_du, dp_dv
