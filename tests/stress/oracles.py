"""float64 analytic references for the numerical stress cases (docs/numerics.md)."""
from __future__ import annotations

import math

import numpy as np


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def perpendicular(d):
    """A unit vector perpendicular to each row of ``d``."""
    d = np.atleast_2d(d)
    a = np.where(np.abs(d[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    return unit(np.cross(d, a))


def rays_with_impact(centre, d, b, dist):
    """Rays of direction ``d`` passing at distance ``b`` from ``centre``, starting ``dist``
    before the closest approach: ``o = centre + b u - dist d`` (u ⟂ d)."""
    d = unit(np.atleast_2d(d))
    u = perpendicular(d)
    return np.asarray(centre) + b[:, None] * u - dist[:, None] * d, d


def sphere_t(b, dist, radius):
    """Entry distance of those rays into a sphere of ``radius``: ``dist − sqrt(R² − b²)``
    (``inf`` where b > R); computed as ``dist − (R−b)(R+b)`` square-rooted, no cancellation."""
    b = np.asarray(b, dtype=np.float64)
    inside = b <= radius
    with np.errstate(invalid="ignore"):
        half = np.sqrt(np.maximum((radius - b) * (radius + b), 0.0))
    return np.where(inside, dist - half, np.inf)


def blob_radius(w, S, T):
    """Single-centre blob (w > 0, threshold T): the surface is a sphere of this radius."""
    q = T / w
    if q > 2.0 / 3.0:
        return S * math.sqrt(3.0 * (1.0 - q))
    return S * (3.0 - math.sqrt(6.0 * q))


def kernel(r, S):
    """LINKS-1 kernel P(r), eq. (3.9), float64."""
    r = np.asarray(r, dtype=np.float64)
    return np.where(r < S, 1.0 - r * r / (3 * S * S),
                    np.where(r < 3 * S, (r - 3 * S) ** 2 / (6 * S * S), 0.0))


def blob_field(x, centres):
    """W(x) = Σ w_i P(|x − P_i|) for rows ``x y z w S``."""
    x = np.atleast_2d(x)
    W = np.zeros(x.shape[0])
    for cx, cy, cz, w, S in np.asarray(centres, dtype=np.float64):
        r = np.linalg.norm(x - [cx, cy, cz], axis=1)
        W += w * kernel(r, S)
    return W


def blob_first_hit(o, d, centres, T, t_max, step=1e-3, iters=80):
    """First t in (0, t_max) where W crosses T along each ray: dense march + bisection.

    Reference only (slow): features thinner than ``step`` may be missed.
    """
    o = np.atleast_2d(o)
    d = unit(np.atleast_2d(d))
    ts = np.arange(step, t_max, step)
    out = np.full(o.shape[0], np.inf)
    for i in range(o.shape[0]):
        W = blob_field(o[i] + ts[:, None] * d[i], centres) - T
        inside0 = blob_field(o[i][None], centres)[0] > T
        s = np.nonzero((W <= 0) if inside0 else (W > 0))[0]
        if s.size == 0:
            continue
        hi = ts[s[0]]
        lo = ts[s[0] - 1] if s[0] > 0 else 0.0
        for _ in range(iters):
            mid = 0.5 * (lo + hi)
            v = blob_field(o[i] + mid * d[i], centres)[0] - T
            if (v > 0) != inside0:
                hi = mid
            else:
                lo = mid
        out[i] = 0.5 * (lo + hi)
    return out


def cube_mesh(half=1.0, centre=(0.0, 0.0, 0.0)):
    """A closed cube, outward winding, 12 triangles."""
    c = np.asarray(centre, dtype=np.float64)
    v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * half + c
    # vertex index = 4*(x>0) + 2*(y>0) + (z>0)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    f = []
    for a, b, c_, d_ in quads:
        f += [(a, b, c_), (a, c_, d_)]
    f = np.array(f)
    # orient outward
    for i, (a, b, c_) in enumerate(f):
        n = np.cross(v[b] - v[a], v[c_] - v[a])
        if np.dot(n, (v[a] + v[b] + v[c_]) / 3 - c) < 0:
            f[i] = (a, c_, b)
    return v, f


def f32_ulp(t):
    """Spacing of float32 at |t|."""
    return np.spacing(np.abs(np.asarray(t, dtype=np.float32))).astype(np.float64)
