"""A shape made of many small primitives in a per-shape :class:`~links1.geometry.bvh.BVH`
(the SDF grid's voxels, a curve's segments): the traversal of :class:`TriangleMesh` for any
primitive that answers ``_pair_hits``."""
from __future__ import annotations

import numpy as np

from .bvh import BVH, nearest_hits
from .base import HierarchyTraced


class PrimitiveSet(HierarchyTraced):
    """Base class: primitives with world boxes ``lo, hi`` (P, 3) in a hierarchy.

    A subclass gives ``_pair_hits(prim (K,), o (K,3), d (K,3), tmin (K,), tmax (K,)) -> t
    (K,)``: the nearest hit of each (ray, primitive) pair in ``(tmin, tmax)``, ``inf`` where
    there is none. Equal distances go to the lower primitive index, as in the meshes."""

    def __init__(self, lo, hi, name: str = "", max_leaf: int = 4):
        super().__init__(name)
        lo = np.asarray(lo, dtype=np.float64).reshape(-1, 3)
        hi = np.asarray(hi, dtype=np.float64).reshape(-1, 3)
        self.bvh = BVH(lo, hi, max_leaf=max_leaf)
        self._lo, self._hi = lo.min(axis=0), hi.max(axis=0)

    def bounds(self):
        return self._lo.copy(), self._hi.copy()

    @property
    def nbytes(self) -> int:
        return int(self.bvh.nbytes)

    def _pair_hits(self, prim, o, d, tmin, tmax):  # pragma: no cover - interface
        raise NotImplementedError

    def _trace(self, o, d, tmin, tmax, cost, any_hit: bool):
        def leaf_times(s, c, r):
            rr = np.repeat(r, c)
            prims = np.tile(self.bvh.order[s:s + c], r.size)
            return self._pair_hits(prims, o[rr], d[rr], tmin[rr], tmax[rr]).reshape(r.size, c)

        return nearest_hits(self.bvh, o, d, tmin, tmax, cost, any_hit, leaf_times)

