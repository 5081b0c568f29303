"""Mitsuba's ``sdfgrid``: the zero set of a signed distance sampled on a grid, intersected as
Mitsuba 3.9.1 does (``src/shapes/sdfgrid.cpp``), in float64.

The grid's ``(Z, Y, X)`` values sit at the corners ``(i, j, k) / (res - 1)`` of the object box
``[0, 1]³``, which ``to_world`` places. Inside a voxel the distance is the trilinear
interpolation of its eight corners, so along a ray it is a cubic in ``t`` (Hansson-Söderlund,
Evans & Akenine-Möller, "Ray Tracing of Signed Distance Function Grids", JCGT 11(3), 2022);
the hit is the cubic's first root in the ray's stretch through the voxel, found between the
roots of its derivative (Marmitt et al. 2004) and refined by bisection to float64 (Mitsuba:
regula falsi to 1e-5 in float32). Only voxels whose corners do not all share one sign can hold
the surface; they are the primitives of the shape's hierarchy.

Normals: the geometric normal is the interpolant's gradient in the voxel that holds the hit
(``normals="analytic"`` uses it for shading too); ``normals="smooth"`` (Mitsuba's default)
blends the normalised gradients of the eight voxels around the nearest grid corner
trilinearly (Hansson-Söderlund et al. 2022), as Mitsuba's ``smooth_sh``. There are no
texture coordinates (``uv = 0``), as in Mitsuba.
"""
from __future__ import annotations

import numpy as np

from ..maths.vec import dot, matvec, normalize
from .primset import PrimitiveSet
from .base import _finite_or_zero, check_to_world

#: Bisection steps of the root refinement: the bracket shrinks below float64 spacing.
_BISECTIONS = 64


def read_vol(path) -> np.ndarray:
    """Mitsuba's binary grid volume (``.vol``): ``VOL``, version 3, encoding 1 (float32),
    the resolution ``x, y, z``, the channel count, a bounding box (6 float32), then the
    values with x fastest. Returns float64 ``(Z, Y, X, C)``; ValueError naming what is wrong."""
    with open(path, "rb") as fh:
        raw = fh.read()
    if len(raw) < 48 or raw[:3] != b"VOL":
        raise ValueError(f"{path}: not a Mitsuba grid volume (no 'VOL' header)")
    if raw[3] != 3:
        raise ValueError(f"{path}: grid volume version {raw[3]}, expected 3")
    enc, nx, ny, nz, nc = np.frombuffer(raw, dtype="<i4", count=5, offset=4)
    if enc != 1:
        raise ValueError(f"{path}: grid volume encoding {enc}, only 1 (float32) is supported")
    if min(nx, ny, nz, nc) < 1:
        raise ValueError(f"{path}: grid volume resolution {nx}x{ny}x{nz}x{nc} is empty")
    count = int(nx) * int(ny) * int(nz) * int(nc)
    if len(raw) < 48 + 4 * count:
        raise ValueError(f"{path}: grid volume holds {(len(raw) - 48) // 4} values, "
                         f"its header announces {count}")
    data = np.frombuffer(raw, dtype="<f4", count=count, offset=48)
    return data.astype(np.float64).reshape(int(nz), int(ny), int(nx), int(nc))


class SDFGrid(PrimitiveSet):
    """Mitsuba's ``sdfgrid`` (see the module docstring).

    Parameters
    ----------
    grid : (Z, Y, X) or (Z, Y, X, 1)  distance values at the grid corners, each axis >= 2
    to_world : 4x4  object ([0, 1]³) to world
    normals : "smooth" (default) or "analytic"  shading normals
    """

    def __init__(self, grid, to_world=None, normals: str = "smooth", name: str = ""):
        g = np.asarray(grid, dtype=np.float64)
        if g.ndim == 4 and g.shape[3] == 1:
            g = g[..., 0]
        if g.ndim != 3 or min(g.shape) < 2:
            raise ValueError(f"sdfgrid {name!r}: the grid must be (Z, Y, X) with every axis >= 2, "
                             f"got shape {np.shape(grid)}")
        if not np.all(np.isfinite(g)):
            raise ValueError(f"sdfgrid {name!r}: grid values must be finite")
        if normals not in ("smooth", "analytic"):
            raise ValueError(f"sdfgrid {name!r}: normals must be 'analytic' or 'smooth', got {normals!r}")
        m = check_to_world(to_world, f"sdfgrid {name!r}")
        self.grid, self.to_world, self.normals = g, m, normals
        self.A = np.linalg.inv(m[:3, :3])
        self.m = m[:3, 3].copy()
        self.res = np.array([g.shape[2] - 1, g.shape[1] - 1, g.shape[0] - 1], dtype=np.float64)  # voxels x, y, z
        # the voxels whose corners do not all share one sign (Mitsuba's occupied voxels)
        c = np.stack([g[z:g.shape[0] - 1 + z, y:g.shape[1] - 1 + y, x:g.shape[2] - 1 + x]
                      for z in (0, 1) for y in (0, 1) for x in (0, 1)])
        occupied = ~(np.all(c > 0, axis=0) | np.all(c < 0, axis=0))
        vz, vy, vx = np.nonzero(occupied)
        if vz.size == 0:
            raise ValueError(f"sdfgrid {name!r}: no voxel holds the surface (every voxel's corners "
                             "share one sign)")
        self.voxels = np.stack([vx, vy, vz], axis=1).astype(np.int64)   # (V, 3) x, y, z
        #: the eight corner values of each voxel, corner index x + 2y + 4z
        self.corners = np.stack([g[vz + z, vy + y, vx + x] for z in (0, 1) for y in (0, 1) for x in (0, 1)],
                                axis=1)
        h = 0.5 / self.res
        centre = (self.voxels + 0.5) / self.res
        wc = centre @ m[:3, :3].T + self.m
        we = h @ np.abs(m[:3, :3]).T
        super().__init__(wc - we, wc + we, name=name)

    def _repr_extra(self) -> str:
        return f"grid={tuple(self.grid.shape)}, voxels={self.voxels.shape[0]}, normals={self.normals!r}"

    # ------------------------------------------------------------------ intersection
    def _pair_hits(self, prim, o, d, tmin, tmax):
        vox = self.voxels[prim].astype(np.float64)
        # ray in voxel coordinates: the voxel is [0, 1]³ (t is the world distance throughout)
        q = matvec(self.A, o - self.m) * self.res - vox
        e = matvec(self.A, d) * self.res
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / np.where(e == 0, 1e-300, e)
            ta = (0.0 - q) * inv
            tb = (1.0 - q) * inv
        t0 = np.minimum(ta, tb).max(axis=1)
        t1 = np.maximum(ta, tb).min(axis=1)
        t0 = np.maximum(t0, tmin)
        t1 = np.minimum(t1, tmax)
        ok = t0 <= t1
        # f(t) = sum_corners s * Lx * Ly * Lz with L1 = q + t e, L0 = 1 - L1: a cubic in t
        s = self.corners[prim]
        c = np.zeros((prim.size, 4))
        for corner in range(8):
            bits = (corner & 1, (corner >> 1) & 1, (corner >> 2) & 1)
            poly = np.ones((prim.size, 1))
            for ax, b in enumerate(bits):
                a0 = q[:, ax] if b else 1.0 - q[:, ax]
                a1 = e[:, ax] if b else -e[:, ax]
                poly = np.concatenate([poly * a0[:, None], np.zeros((prim.size, 1))], axis=1) \
                    + np.concatenate([np.zeros((prim.size, 1)), poly * a1[:, None]], axis=1)
            c += s[:, corner, None] * poly
        t = _first_root(c, np.where(ok, t0, 0.0), np.where(ok, t1, 0.0))
        return np.where(ok & (t > tmin) & (t < tmax), t, np.inf)

    # ------------------------------------------------------------------ surface
    def _value(self, p):
        """The grid's trilinear interpolant at object points ``p`` (N, 3), held constant
        outside [0, 1]³ (Mitsuba's clamped texture lookup)."""
        g = self.grid
        pos = np.clip(p * self.res, 0.0, self.res)
        i = np.minimum(np.floor(pos), self.res - 1).astype(np.int64)
        f = pos - i
        out = np.zeros(p.shape[0])
        for z in (0, 1):
            for y in (0, 1):
                for x in (0, 1):
                    w = ((f[:, 0] if x else 1 - f[:, 0]) * (f[:, 1] if y else 1 - f[:, 1])
                         * (f[:, 2] if z else 1 - f[:, 2]))
                    out += w * g[i[:, 2] + z, i[:, 1] + y, i[:, 0] + x]
        return out

    def _voxel_grad(self, p, v):
        """Mitsuba's ``voxel_grad``: the difference quotient of the interpolant across voxel
        ``v`` (N, 3) through ``p``: the gradient of that voxel's trilinear function at ``p``."""
        vs = 1.0 / self.res
        lo = v * vs
        grad = np.empty_like(p)
        for ax in range(3):
            a, b = p.copy(), p.copy()
            a[:, ax] = lo[:, ax] + vs[ax]
            b[:, ax] = lo[:, ax]
            grad[:, ax] = (self._value(a) - self._value(b)) / vs[ax]
        return grad

    def _smooth(self, p):
        """Mitsuba's ``smooth_sh``: normalised gradients of the 8 voxels around the nearest
        grid corner, blended trilinearly; voxels below the grid's origin are left out."""
        scaled = p * self.res
        corner = np.floor(scaled + 0.5)
        v000 = corner - 1.0
        w = scaled - corner + 0.5
        n = {}
        valid = {}
        for z in (0, 1):
            for y in (0, 1):
                for x in (0, 1):
                    v = v000 + np.array([x, y, z], dtype=np.float64)
                    ok = np.all(v >= 0, axis=1)
                    n[x, y, z] = np.where(ok[:, None], normalize(self._voxel_grad(p, v)), 0.0)
                    valid[x, y, z] = ok
        for ax in range(3):
            side = [[k for k in valid if k[ax] == b] for b in (0, 1)]
            none0 = ~np.any([valid[k] for k in side[0]], axis=0)
            none1 = ~np.any([valid[k] for k in side[1]], axis=0)
            w[:, ax] = np.where(none0, 1.0, w[:, ax])
            w[:, ax] = np.where(none1, 0.0, w[:, ax])
        out = np.zeros_like(p)
        for (x, y, z), nk in n.items():
            wk = ((w[:, 0] if x else 1 - w[:, 0]) * (w[:, 1] if y else 1 - w[:, 1])
                  * (w[:, 2] if z else 1 - w[:, 2]))
            out += wk[:, None] * nk
        return out

    def surface(self, o, d, t, prim):
        o = np.asarray(o, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(d, dtype=np.float64).reshape(-1, 3)
        p = o + _finite_or_zero(t)[:, None] * d
        local = matvec(self.A, p - self.m)
        grad = self._voxel_grad(local, np.floor(local * self.res))   # the voxel holding the hit
        ng = normalize(matvec(self.A.T, grad))          # normals map by the inverse transpose
        if self.normals == "analytic":
            return p, ng, ng.copy()
        ns = normalize(matvec(self.A.T, self._smooth(local)))
        return p, ng, np.where((dot(ns, ns) > 0)[:, None], ns, ng)


def _first_root(c, ta, tb):
    """First root in ``[ta, tb]`` of the cubics ``c0 + c1 t + c2 t² + c3 t³`` (rows of ``c``):
    the interval is cut at the derivative's roots into monotone pieces, the first piece whose
    ends differ in sign (or touch zero) is bisected. ``inf`` where there is none."""
    def f(t):
        return ((c[:, 3] * t + c[:, 2]) * t + c[:, 1]) * t + c[:, 0]

    # derivative 3 c3 t² + 2 c2 t + c1
    a, b, k = 3.0 * c[:, 3], 2.0 * c[:, 2], c[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        disc = b * b - 4.0 * a * k
        sq = np.sqrt(np.maximum(disc, 0.0))
        q = -0.5 * (b + np.where(b >= 0, sq, -sq))
        quad = a != 0
        r0 = np.where(quad, q / np.where(quad, a, 1.0), np.where(b != 0, -k / np.where(b != 0, b, 1.0), np.nan))
        r1 = np.where(quad, k / np.where(q != 0, q, np.nan), np.nan)
        r0 = np.where(quad & (disc < 0), np.nan, r0)
        r1 = np.where(quad & (disc < 0), np.nan, r1)
    cuts = []
    for r in (r0, r1):
        inside = np.isfinite(r) & (r > ta) & (r < tb)
        cuts.append(np.where(inside, r, ta))
    pts = np.sort(np.stack([ta, cuts[0], cuts[1], tb], axis=1), axis=1)
    fv = np.stack([f(pts[:, i]) for i in range(4)], axis=1)
    lo = np.full(ta.shape, np.nan)
    hi = np.full(ta.shape, np.nan)
    for i in range(3):
        change = np.isnan(lo) & (fv[:, i] * fv[:, i + 1] <= 0.0)
        lo = np.where(change, pts[:, i], lo)
        hi = np.where(change, pts[:, i + 1], hi)
    found = np.isfinite(lo)
    lo, hi = np.where(found, lo, 0.0), np.where(found, hi, 0.0)
    flo = f(lo)
    exact = flo == 0.0
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        fm = f(mid)
        same = (fm * flo) > 0.0
        lo = np.where(same, mid, lo)
        flo = np.where(same, fm, flo)
        hi = np.where(same, hi, mid)
    t = np.where(exact, lo, hi)
    return np.where(found, t, np.inf)
