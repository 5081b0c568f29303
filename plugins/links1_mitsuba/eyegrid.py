"""The eye buffer of a pinhole camera as a grid over its film: per cell of about
``CELL_PX`` x ``CELL_PX`` pixels, the BVH's quadrics a camera ray through that cell can meet,
nearest first (the first-hit speed-up of Weghorst, Hooper and Greenberg 1984 in the list form of
Haines and Greenberg's light buffer, :mod:`links1_mitsuba.lightbuffer`, whose walk
:meth:`LightBuffer.nearest` it shares: the same exact test and tie rule as the BVH walk, so the
same hit bit for bit).

A cube map around the eye (``lightbuffer.build_point``) gives the camera only the cells of the
faces it looks through, at most 64 a face side: tens of pixels a cell, whose lists hold every
quadric along the cell's cone. Here the cells are where the camera looks: in an orthonormal
frame ``(r, u, f)`` of the camera (``f`` its view axis) a direction ``d`` with ``d·f > KAPPA``
has film coordinates ``(d·r / d·f, d·u / d·f)``, and the cells tile the film's window of them;
the border cells stand for everything beyond the window (a coordinate outside it is clamped
to the border, and a bound reaching past the border is listed there). One more cell, ``BEHIND``
(the last), lists the quadrics that a direction with ``d·f <= KAPPA`` can meet.

Conservative by construction (float64 numpy, the bounds of ``lightbuffer.quadric_spheres``
inflated by the scene's margin): a film coordinate depends on two components of the direction
only, so a sphere's range of ``d·r / d·f`` is the range seen from the eye of its disc in the
``(r, f)`` plane (angles ``atan2(x, z) ± asin(ρ / |(x, z)|)``), widened by an angular margin
(``lightbuffer.ANGLE_MARGIN``: the kernel's float32 film coordinates err by far less), and the
same in ``(u, f)``. The lists are made here; ``lightbuffer.plan_eye`` makes them a
:class:`~links1_mitsuba.lightbuffer.LightBuffer` (kind ``"eye"``).
"""
from __future__ import annotations

import math

import numpy as np


#: film pixels per cell side, but at least ``MIN_SIDE`` cells along the film's longer side
#: (a small film's pixels span wide cones), at most ``MAX_CELLS`` cells in all
CELL_PX = 1
MIN_SIDE = 128
MAX_CELLS = 1 << 20
#: list entries over the film's cells at most (else the cells are made coarser, halving the sides)
MAX_ENTRIES = 1 << 24
#: directions with ``d·f`` at most this (|d| = 1) look up the ``BEHIND`` cell
KAPPA = 1e-3


def camera_frame(cam):
    """An orthonormal frame ``(r, u, f)`` (rows of a 3x3 float64 array) of the camera matrix
    ``cam`` (4x4, camera to world): ``f`` along its view axis, ``r`` and ``u`` its film's axes
    made orthogonal (Gram-Schmidt); any frame is correct, this one makes the film a rectangle."""
    m = np.asarray(cam, dtype=np.float64)[:3, :3]
    f = m[:, 2] / np.linalg.norm(m[:, 2])
    r = m[:, 0] - f * (m[:, 0] @ f)
    r /= np.linalg.norm(r)
    u = m[:, 1] - f * (m[:, 1] @ f) - r * (m[:, 1] @ r)
    u /= np.linalg.norm(u)
    return np.stack([r, u, f])


def film_window(cam, x_fov, size, R):
    """``(u0, u1, v0, v1)``: the film coordinates (in frame ``R``) of the film's corners."""
    W, H = size
    tn = math.tan(math.radians(x_fov) / 2.0)
    c = np.array([[sx * tn, sy * tn * H / W, 1.0] for sx in (-1, 1) for sy in (-1, 1)])
    d = c @ np.asarray(cam, dtype=np.float64)[:3, :3].T @ R.T
    u, v = d[:, 0] / d[:, 2], d[:, 1] / d[:, 2]
    return float(u.min()), float(u.max()), float(v.min()), float(v.max())


def _ranges(x, z, rad, angle):
    """Per sphere (centre ``(x, z)`` in a plane through the eye, radius ``rad``): the range
    ``[lo, hi]`` of ``x / z`` over its points with ``z > 0`` as seen from the eye (±inf where
    it is unbounded; ``lo > hi``: no such point), its angular range widened by the margin."""
    dist = np.hypot(x, z)
    inside = dist <= rad
    theta = np.arctan2(x, z)
    alpha = np.arcsin(np.clip(rad / np.where(inside, 1.0, dist), 0.0, 1.0)) + angle
    half = 0.5 * math.pi
    lo, hi = np.full(x.shape, np.inf), np.full(x.shape, -np.inf)
    for turn in (-2.0 * math.pi, 0.0, 2.0 * math.pi):     # the arc and its turns: the part in front
        a, b = theta - alpha + turn, theta + alpha + turn
        meets = (b > -half) & (a < half)
        lo = np.where(meets, np.minimum(lo, np.where(a <= -half, -np.inf, np.tan(np.clip(a, -half, half)))), lo)
        hi = np.where(meets, np.maximum(hi, np.where(b >= half, np.inf, np.tan(np.clip(b, -half, half)))), hi)
    return np.where(inside, -np.inf, lo), np.where(inside, np.inf, hi)


def _cells(lo, hi, w0, scale, n):
    """Cell index ranges ``[i0, i1]`` of coordinate ranges on an axis of ``n`` cells (border
    cells hold what is beyond)."""
    def idx(x):
        return np.clip(np.floor(np.clip((x - w0) * scale, -1.0, n + 1.0)), 0, n - 1).astype(np.int64)
    return idx(lo), idx(hi)


def lists(eye, R, window, size, c, rad, angle, cell_px=CELL_PX):
    """The grid's lists over bounding spheres ``(c, rad)`` (float64) seen from ``eye`` in
    frame ``R`` (:func:`camera_frame`), the film ``window`` (:func:`film_window`) of ``size``
    pixels, angular margin ``angle``: ``(offsets, objects, keys, (R, u0, v0, su, sv, nu, nv,
    KAPPA))``, CSR over the ``nu * nv`` film cells (row-major, v then u) and ``BEHIND``, each
    list ordered by key (the nearest distance to the eye a bound can come) then object."""
    W, H = size
    px = min(float(cell_px), max(W, H) / MIN_SIDE)
    nu = max(1, int(math.ceil(W / px)))
    nv = max(1, int(math.ceil(H / px)))
    while nu * nv > MAX_CELLS:
        nu, nv = max(1, nu // 2), max(1, nv // 2)
    u0, u1, v0, v1 = window
    if not (np.all(np.isfinite(window)) and u1 > u0 and v1 > v0):
        u0, u1, v0, v1 = -1.0, 1.0, -1.0, 1.0     # a degenerate camera: any window is correct
    eye = np.asarray(eye, dtype=np.float64)
    q = (c - eye) @ R.T                                        # centres in the camera frame
    ulo, uhi = _ranges(q[:, 0], q[:, 2], rad, angle)
    vlo, vhi = _ranges(q[:, 1], q[:, 2], rad, angle)
    nb = np.nonzero((ulo <= uhi) & (vlo <= vhi))[0]
    while True:         # coarser cells while the lists would pass MAX_ENTRIES (bounds filling the film)
        su, sv = nu / (u1 - u0), nv / (v1 - v0)
        iu0, iu1 = _cells(ulo[nb], uhi[nb], u0, su, nu)
        iv0, iv1 = _cells(vlo[nb], vhi[nb], v0, sv, nv)
        cu = iu1 - iu0 + 1
        per = cu * (iv1 - iv0 + 1)
        if int(per.sum()) <= MAX_ENTRIES or nu * nv == 1:
            break
        nu, nv = max(1, nu // 2), max(1, nv // 2)
    objs = np.repeat(nb, per)
    k = np.arange(objs.size) - np.repeat(np.cumsum(per) - per, per)     # index within its rectangle
    cu_r = np.repeat(cu, per)
    cells = (np.repeat(iv0, per) + k // cu_r) * nu + np.repeat(iu0, per) + k % cu_r
    # BEHIND: a direction at angle >= acos(KAPPA) from f meets the bounds reaching that far
    dist = np.linalg.norm(q, axis=1)
    ang = np.arccos(np.clip(q[:, 2] / np.maximum(dist, 1e-300), -1.0, 1.0))
    reach = ang + np.arcsin(np.clip(rad / np.maximum(dist, 1e-300), 0.0, 1.0)) + angle
    back = np.nonzero((dist <= rad) | (reach >= math.acos(KAPPA)))[0]
    cells = np.concatenate([cells, np.full(back.size, nu * nv, dtype=np.int64)])
    objs = np.concatenate([objs, back])
    keys = np.linalg.norm(c - eye, axis=1) - rad
    order = np.lexsort((objs, keys[objs], cells))
    cells, objs = cells[order], objs[order]
    off = np.zeros(nu * nv + 2, dtype=np.int64)
    np.add.at(off, cells + 1, 1)
    return np.cumsum(off), objs, keys[objs], (R, u0, v0, su, sv, nu, nv, KAPPA)


def line_lists(eye, R, window, size, c, rad, angle, cell_px=CELL_PX):
    """:func:`lists` for lines through ``eye``: per film cell the spheres ``(c, rad)`` that the
    whole line through the eye along a direction of the cell (both ways) can meet, each list in
    increasing sphere index, ``(offsets, objects, frame)``. The line's part behind the eye meets
    a sphere where the ray meets its mirror image through the eye (``2 eye - c``), so the lists
    are :func:`lists` over the spheres and their mirror images, merged."""
    n = len(c)
    eye = np.asarray(eye, dtype=np.float64)
    off, objs, _, frame = lists(eye, R, window, size, np.concatenate([c, 2.0 * eye - c]),
                                np.concatenate([rad, rad]), angle, cell_px)
    cells = np.repeat(np.arange(len(off) - 1), np.diff(off))
    key = np.sort(cells * n + objs % n)
    key = key[np.r_[True, key[1:] != key[:-1]]] if key.size else key   # (cell, sphere) pairs once each
    cells, objs = key // n, key % n
    out = np.zeros(len(off), dtype=np.int64)
    np.add.at(out, cells + 1, 1)
    return np.cumsum(out), objs, frame


def film_cell(g, v):
    """The cell (UInt32) of directions ``v`` in the grid ``g`` (its ``frame`` rows, ``u0``,
    ``v0``, ``su``, ``sv``, ``nu``, ``nv`` and ``kappa``, Python floats): :func:`lists`' cell
    of the film coordinates, ``BEHIND`` where ``v·f <= kappa |v|``."""
    import drjit as dr
    import mitsuba as mi
    x, y, z = (row[0] * v.x + row[1] * v.y + row[2] * v.z for row in g.frame)
    front = z > g.kappa * dr.norm(v)
    zs = dr.select(front, z, 1.0)
    iu = dr.clip(dr.floor((x / zs - g.u0) * g.su), 0.0, g.nu - 1.0)
    iv = dr.clip(dr.floor((y / zs - g.v0) * g.sv), 0.0, g.nv - 1.0)
    return dr.select(front, mi.UInt32(iv) * g.nu + mi.UInt32(iu), g.nu * g.nv)
