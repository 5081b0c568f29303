"""Small elementwise vector helpers on (N, 3) float64 arrays.

Written component by component on purpose: BLAS-backed ``@`` / ``einsum`` may round a
row differently depending on the batch size, and a window of the film must render the
same bits as the full frame (determinism whatever the tiling).
"""
from __future__ import annotations

import numpy as np


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def length(a: np.ndarray) -> np.ndarray:
    return np.sqrt(dot(a, a))


def normalize(a: np.ndarray) -> np.ndarray:
    n = length(a)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where((n > 0)[..., None], a / np.where(n > 0, n, 1.0)[..., None], a)


def matvec(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``m[:3,:3] @ v`` for each row of ``v`` (N, 3), elementwise."""
    return np.stack([m[r, 0] * v[..., 0] + m[r, 1] * v[..., 1] + m[r, 2] * v[..., 2]
                     for r in range(3)], axis=-1)


def max_abs(a: np.ndarray) -> np.ndarray:
    return np.maximum(np.maximum(np.abs(a[..., 0]), np.abs(a[..., 1])), np.abs(a[..., 2]))


def coordinate_system(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mitsuba's ``coordinate_system(n)`` (Duff et al. 2017): tangents ``(s, t)`` with ``(s, t, n)``
    orthonormal, for unit ``n`` (..., 3). Mitsuba's ``mulsign(x, y)`` is ``x`` times the sign
    bit of ``y`` (``-0.0`` counts as negative there), unlike ``sign`` below (``>= 0``)."""
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    sign = np.where(z >= 0, 1.0, -1.0)
    zs = np.copysign(1.0, z)
    a = -1.0 / (sign + z)
    b = x * y * a
    s = np.stack([x * x * a * zs + 1.0, b * zs, -x * zs], axis=-1)
    t = np.stack([b, sign + y * y * a, -y], axis=-1)
    return s, t
