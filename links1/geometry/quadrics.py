"""The clipped quadric's arithmetic (eq. 3.4-3.5), float64 numpy: its world box
(:func:`quadric_bounds`, the one rule of both renderers), the stable roots of its quadratic
and the interval its clip planes keep, and the first hit of both. Shared by
:class:`links1.geometry.shapes.Quadric`, the all-quadrics-at-once path of
:mod:`links1.geometry.accel` and the plugin's quadric (its box).
"""
from __future__ import annotations

import numpy as np

from .base import _row_extent


def quadric_bounds(kind: str, to_world, clips) -> tuple[np.ndarray, np.ndarray]:
    """World box of a clipped quadric (eq. 3.4; ``kind`` "sphere" or "cylinder", ``to_world``
    4x4, ``clips`` the planes ``n.y <= h`` in object space): the one rule of both renderers.

    Two boxes hold the shape, and the box is their intersection, axis by axis:

    * exact for the unclipped surface: the ellipsoid's ``m ± |L rows|``; for a cylinder, the
      unit disk swept between the ends of the ``z`` range its clip planes allow over the disk
      (any plane with a ``z`` component bounds one end);
    * the object box ``[-1, 1]² × [-1, 1]`` (cylinder: ``× [z range]``) tightened by the clip
      planes that are perpendicular to an object axis, its eight corners mapped to the world.

    A cylinder no plane bounds along its axis has an infinite box (the core refuses it; the
    plugin traces it outside its BVH)."""
    m4 = np.asarray(to_world, dtype=np.float64)
    lin, m = m4[:3, :3], m4[:3, 3]
    if kind == "sphere":
        ext = _row_extent(lin, [0, 1, 2])  # |M| rows: exact box of the ellipsoid
        lo_a, hi_a = m - ext, m + ext
        zlo, zhi = -1.0, 1.0
    else:
        zhi, zlo = np.inf, -np.inf
        for nv, h in clips:
            nv = np.asarray(nv, dtype=np.float64)
            nxy = float(np.hypot(nv[0], nv[1]))
            if nv[2] > 0:
                zhi = min(zhi, (float(h) + nxy) / nv[2])
            elif nv[2] < 0:
                zlo = max(zlo, (float(h) + nxy) / nv[2])
        if not (np.isfinite(zhi) and np.isfinite(zlo)):
            return np.full(3, -np.inf), np.full(3, np.inf)
        if zlo > zhi:
            zlo = zhi = 0.5 * (zlo + zhi)  # empty: a degenerate (but finite) box
        ext = _row_extent(lin, [0, 1])
        ends = m[None, :] + np.array([zlo, zhi])[:, None] * lin[:, 2][None, :]
        lo_a, hi_a = ends.min(axis=0) - ext, ends.max(axis=0) + ext
    # the object box, cut by the axis-perpendicular clip planes
    olo, ohi = np.array([-1.0, -1.0, zlo]), np.array([1.0, 1.0, zhi])
    for nv, h in clips:
        nv = np.asarray(nv, dtype=np.float64)
        nn = nv / np.linalg.norm(nv)
        hh = float(h) / np.linalg.norm(nv)
        for ax in range(3):
            if abs(abs(nn[ax]) - 1) < 1e-12:
                if nn[ax] > 0:
                    ohi[ax] = min(ohi[ax], hh)
                else:
                    olo[ax] = max(olo[ax], -hh)
    olo, ohi = np.minimum(olo, ohi), np.maximum(olo, ohi)   # cut away entirely: degenerate
    corners = np.array([[x, y, z] for x in (olo[0], ohi[0]) for y in (olo[1], ohi[1]) for z in (olo[2], ohi[2])])
    w = corners @ lin.T + m
    lo, hi = np.maximum(lo_a, w.min(0)), np.minimum(hi_a, w.max(0))
    mid = 0.5 * (lo + hi)
    return np.where(lo <= hi, lo, mid), np.where(lo <= hi, hi, mid)


def quadric_roots(a, b, c, disc, pos):
    """Both roots of eq. (3.5) in the stable form (docs/numerics.md), as an interval ``(lo, hi)``.

    ``pos`` = ``a > 0``; where ``a = 0`` (a ray parallel to a cylinder's axis) the ray is
    inside everywhere (``c < 0``: ``(-inf, inf)``) or nowhere (an empty interval).
    Shared by :class:`links1.geometry.shapes.Quadric` and the all-quadrics-at-once path of
    :mod:`links1.geometry.accel`.
    """
    sq = np.sqrt(np.maximum(disc, 0.0))
    q = -(b + np.copysign(sq, b))
    has = pos & (disc >= 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        r1 = np.where(has & (q != 0), c / np.where(q != 0, q, 1.0), 0.0)  # eq. (3.5) roots
        r2 = np.where(has, q / np.where(pos, a, 1.0), 0.0)
    q_lo = np.minimum(r1, r2)
    q_hi = np.maximum(r1, r2)
    inside_all = ~pos & (c < 0)
    q_lo = np.where(has, q_lo, np.where(inside_all, -np.inf, np.inf))
    q_hi = np.where(has, q_hi, np.where(inside_all, np.inf, -np.inf))
    return q_lo, q_hi


def clip_interval(u, v, planes):
    """The part ``(c_in, c_out)`` of each ray ``u + t v`` (object space) where every clip
    plane ``n·y <= h`` holds, and which plane bounds each end (-1: none).

    ``planes`` yields ``(n, h)`` with ``n`` of shape (3,) or (N, 3) and ``h`` scalar or (N,).
    """
    n = u.shape[0]
    c_in = np.full(n, -np.inf)
    c_out = np.full(n, np.inf)
    j_in = np.full(n, -1, dtype=np.int64)
    j_out = np.full(n, -1, dtype=np.int64)
    for j, (nv, h) in enumerate(planes):
        den = nv[..., 0] * v[:, 0] + nv[..., 1] * v[:, 1] + nv[..., 2] * v[:, 2]
        num = h - (nv[..., 0] * u[:, 0] + nv[..., 1] * u[:, 1] + nv[..., 2] * u[:, 2])
        with np.errstate(divide="ignore", invalid="ignore"):
            tp = num / np.where(den != 0, den, 1.0)
        lower = (den > 0) & (tp < c_out)  # den > 0 lowers t_out
        c_out = np.where(lower, tp, c_out)
        j_out = np.where(lower, j, j_out)
        raise_ = (den < 0) & (tp > c_in)  # den < 0 raises t_in
        c_in = np.where(raise_, tp, c_in)
        j_in = np.where(raise_, j, j_in)
        empty = (den == 0) & (num < 0)  # parallel and outside: empty
        c_in = np.where(empty, np.inf, c_in)
        c_out = np.where(empty, -np.inf, c_out)
    return c_in, c_out, j_in, j_out


def quadric_first_hit(s, q_lo, q_hi, c_in, c_out, j_in, j_out, capped, tmin, tmax):
    """The first surface point of a clipped quadric along each ray in ``(tmin, tmax)``:
    ``(t, prim)`` (inf, -1 on a miss; prim 0 the quadric, ``1 + j`` clip plane ``j``'s cap).

    From :meth:`links1.geometry.shapes.Quadric._intervals`' inside interval ``[q_lo, q_hi]``
    and clip interval ``[c_in, c_out]`` (planes ``j_in``, ``j_out``), in the shifted frame
    whose origin is ``s`` along the ray. ``capped`` (bool or (N,) bool): a capped quadric is
    the solid ``quadric ∩ clip`` (its ends are caps where a plane sets them), an open one the
    shell points inside the clip interval. The one rule of the core's
    :class:`~links1.geometry.shapes.Quadric` and the scene accel's quadric table
    (:class:`links1.geometry.accel.Accel`)."""
    # capped solid
    lo = np.maximum(q_lo, c_in)
    hi = np.minimum(q_hi, c_out)
    solid = lo <= hi
    cp1 = np.where(c_in > q_lo, 1 + j_in, 0)
    cp2 = np.where(c_out < q_hi, 1 + j_out, 0)
    ct1 = np.where(solid, lo, np.inf)
    ct2 = np.where(solid, hi, np.inf)
    # open shell
    ok1 = (c_in <= q_lo) & (q_lo <= c_out) & (q_lo <= q_hi)
    ok2 = (c_in <= q_hi) & (q_hi <= c_out) & (q_lo <= q_hi)
    t1 = s + np.where(capped, ct1, np.where(ok1, q_lo, np.inf))
    t2 = s + np.where(capped, ct2, np.where(ok2, q_hi, np.inf))
    p1 = np.where(capped, cp1, 0)
    p2 = np.where(capped, cp2, 0)
    g1 = np.isfinite(t1) & (t1 > tmin) & (t1 < tmax)
    g2 = np.isfinite(t2) & (t2 > tmin) & (t2 < tmax)
    t = np.where(g1, t1, np.where(g2, t2, np.inf))
    prim = np.where(g1, p1, np.where(g2, p2, -1)).astype(np.int64)
    return t, prim
