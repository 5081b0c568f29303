"""The shape contract of the LINKS-1 core (float64 numpy): :class:`Shape`, the base every shape
derives from, :class:`HierarchyTraced`, and the helpers shapes share (ray batches, cost,
``to_world`` checks). The shapes themselves: :mod:`links1.geometry.shapes` (triangles, quadrics,
disk), :mod:`links1.geometry.blob`, :mod:`links1.geometry.primset` and its subclasses.

Every shape answers the contract of docs/architecture.md for batches of ``N`` rays
(``o (N,3)``, unit ``d (N,3)``, ``tmin (N,)``, ``tmax (N,)``, all float64):

* ``bounds() -> (lo (3,), hi (3,))``: world-space box;
* ``intersect(o, d, tmin, tmax, cost=None) -> (t (N,), prim (N,) int64)``: the nearest
  distance in the open interval ``(tmin, tmax)``, ``t = inf`` and ``prim = -1`` on a miss;
* ``any_hit(o, d, tmin, tmax, cost=None) -> (N,) bool``;
* ``surface(o, d, t, prim) -> (p, ng, ns)``: hit point, geometric normal and shading
  normal, both unit and outward (never turned toward the ray);
* ``uv(o, d, t, prim) -> (N, 2)``: Mitsuba's surface coordinates of the hits (what textures
  are evaluated at, :mod:`links1.shading.textures`): mesh texcoords interpolated by barycentrics
  (``(b1, b2)`` without texcoords), Mitsuba's sphere / cylinder / disk parameterisations.

``cost`` (``(N,)`` int64) gets +1 per ray-primitive test (box tests are free). No output
is ever NaN; degenerate configurations (a triangle plane through the ray origin, a ray
parallel to a cylinder's axis) are misses or handled explicitly.
"""
from __future__ import annotations

import numpy as np


def _as_rays(o, d, tmin, tmax):
    o = np.asarray(o, dtype=np.float64).reshape(-1, 3)
    d = np.asarray(d, dtype=np.float64).reshape(-1, 3)
    n = o.shape[0]
    tmin = np.broadcast_to(np.asarray(tmin, dtype=np.float64), (n,))
    tmax = np.broadcast_to(np.asarray(tmax, dtype=np.float64), (n,))
    return o, d, tmin, tmax


def _add_cost(cost, amount=1, where=None):
    if cost is None:
        return
    if where is None:
        cost += amount
    else:
        cost[where] += amount


def _finite_or_zero(t) -> np.ndarray:
    """``t`` with non-finite entries (misses passed to ``surface``) replaced by 0."""
    t = np.asarray(t, dtype=np.float64)
    return np.where(np.isfinite(t), t, 0.0)


def _turn(phi: np.ndarray) -> np.ndarray:
    """An angle from ``atan2`` as a fraction of a full turn in [0, 1) (Mitsuba's ``u``/``v``)."""
    return np.where(phi < 0.0, phi + 2.0 * np.pi, phi) / (2.0 * np.pi)


def check_to_world(to_world, what: str) -> np.ndarray:
    """Validate a 4x4 object-to-world transform; return it as float64 (4, 4).

    Raises ``ValueError`` when it is not finite or its linear part is singular (or so
    badly conditioned that its inverse means nothing in float64).
    """
    m = np.eye(4) if to_world is None else np.array(to_world, dtype=np.float64)
    if m.shape != (4, 4):
        raise ValueError(f"{what}: to_world must be a 4x4 matrix, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise ValueError(f"{what}: to_world has non-finite entries")
    lin = m[:3, :3]
    sv = np.linalg.svd(lin, compute_uv=False)
    if not (sv[-1] > 0 and sv[0] / sv[-1] < 1e14):
        raise ValueError(f"{what}: to_world's linear part is singular "
                         f"(singular values {sv.tolist()})")
    return m



def _row_extent(lin: np.ndarray, cols) -> np.ndarray:
    """Half-extent along each world axis of the image of a unit ball in ``cols``."""
    return np.sqrt(np.sum(lin[:, cols] ** 2, axis=1))


class Shape:
    """Base class: the attributes the scene and integrator read, and the interface."""

    material = None
    emission = None
    index = -1
    name = ""
    closed = False

    def __init__(self, name: str = ""):
        self.material = None
        self.emission = None
        self.index = -1
        self.name = str(name)
        self.closed = False

    def bounds(self):  # pragma: no cover - interface
        raise NotImplementedError

    def intersect(self, o, d, tmin, tmax, cost=None):  # pragma: no cover - interface
        raise NotImplementedError

    def any_hit(self, o, d, tmin, tmax, cost=None):
        """Whether each segment hits the shape (default: via :meth:`intersect`)."""
        t, _ = self.intersect(o, d, tmin, tmax, cost)
        return np.isfinite(t)

    def surface(self, o, d, t, prim):  # pragma: no cover - interface
        raise NotImplementedError

    def uv(self, o, d, t, prim):
        """Surface coordinates (N, 2) of the hits (default: none, zeros)."""
        return np.zeros((np.asarray(prim).shape[0], 2))

    def tangents(self, o, d, t, prim):
        """``(dp_du, dp_dv)`` (N, 3) each: the world derivatives of the hit point along the
        shape's ``uv`` (Mitsuba's ``si.dp_du``, ``si.dp_dv``; default: none, zeros, whose
        shading frame Mitsuba then builds with ``coordinate_system(n)``)."""
        z = np.zeros((np.asarray(prim).shape[0], 3))
        return z, z.copy()

    @property
    def nbytes(self) -> int:
        return 0

    def _repr_extra(self) -> str:
        return ""

    def __repr__(self) -> str:
        extra = self._repr_extra()
        return (f"{type(self).__name__}(name={self.name!r}, index={self.index}"
                f"{', ' + extra if extra else ''}, closed={self.closed})")


class HierarchyTraced(Shape):
    """A shape whose rays walk a per-shape hierarchy of its primitives: ``_trace(o, d, tmin,
    tmax, cost, any_hit) -> (t, prim)`` (:func:`links1.geometry.bvh.nearest_hits`) gives both
    queries (meshes, :class:`links1.geometry.primset.PrimitiveSet`)."""

    def _trace(self, o, d, tmin, tmax, cost, any_hit: bool):  # pragma: no cover - interface
        raise NotImplementedError

    def intersect(self, o, d, tmin, tmax, cost=None):
        o, d, tmin, tmax = _as_rays(o, d, tmin, tmax)
        return self._trace(o, d, tmin, tmax, cost, any_hit=False)

    def any_hit(self, o, d, tmin, tmax, cost=None):
        o, d, tmin, tmax = _as_rays(o, d, tmin, tmax)
        t, _ = self._trace(o, d, tmin, tmax, cost, any_hit=True)
        return np.isfinite(t)
