"""4×4 homogeneous transforms with Mitsuba's conventions (column vectors, degrees).

Names follow destination-from-source: a shape's ``to_world`` maps object space to world space.
"""
from __future__ import annotations

import numpy as np


def identity() -> np.ndarray:
    return np.eye(4)


def translate(v) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = np.asarray(v, dtype=np.float64)
    return m


def scale(v) -> np.ndarray:
    v = np.broadcast_to(np.asarray(v, dtype=np.float64), (3,))
    return np.diag([v[0], v[1], v[2], 1.0])


def rotate(axis, angle_deg: float, normalize_axis: bool = True) -> np.ndarray:
    """Rotation about ``axis`` by ``angle_deg`` degrees (right-handed), Rodrigues' matrix.

    ``normalize_axis=False`` keeps the axis as given, as Mitsuba 3.9.1's ``Transform4f::rotate``
    does (not a rotation unless the axis is a unit vector).
    """
    a = np.asarray(axis, dtype=np.float64)
    n = np.linalg.norm(a)
    if not n > 0:
        raise ValueError("rotation axis must be non-zero")
    x, y, z = a / n if normalize_axis else a
    th = np.deg2rad(angle_deg)
    c, s = np.cos(th), np.sin(th)
    C = 1.0 - c
    m = np.eye(4)
    m[:3, :3] = [[x * x * C + c, x * y * C - z * s, x * z * C + y * s],
                 [y * x * C + z * s, y * y * C + c, y * z * C - x * s],
                 [z * x * C - y * s, z * y * C + x * s, z * z * C + c]]
    return m


def look_at(origin, target, up) -> np.ndarray:
    """Mitsuba's ``Transform4f::look_at``: columns (left, up', dir, origin); camera looks along +z."""
    o = np.asarray(origin, dtype=np.float64)
    d = np.asarray(target, dtype=np.float64) - o
    nd = np.linalg.norm(d)
    if not nd > 0:
        raise ValueError("lookat: origin and target coincide")
    d = d / nd
    left = np.cross(np.asarray(up, dtype=np.float64), d)
    nl = np.linalg.norm(left)
    if not nl > 0:
        raise ValueError("lookat: 'up' is parallel to the viewing direction")
    left = left / nl
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, d, o
    return m


def apply_point(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Transform points ``p`` (..., 3) by ``m`` (affine part; no projective divide)."""
    return p @ m[:3, :3].T + m[:3, 3]


def apply_vector(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    return v @ m[:3, :3].T


def apply_normal(m: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Transform normals by the inverse transpose of the linear part (not normalised)."""
    return n @ np.linalg.inv(m[:3, :3])


def normalize(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, v / np.where(n > 0, n, 1.0), v)
