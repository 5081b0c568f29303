"""Shapes of the LINKS-1 core in float64 numpy: triangles (eq. 3.1-3.3), clipped quadrics
(eq. 3.4-3.5) and Mitsuba's disk. The weight-function surface lives in :mod:`links1.geometry.blob`.

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

from .bvh import BVH, nearest_hits
from ..maths.vec import coordinate_system, cross, dot, matvec, normalize


# ---------------------------------------------------------------------------- helpers
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


# ---------------------------------------------------------------------------- triangles
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


class TriangleMesh(HierarchyTraced):
    """A triangle mesh intersected by the paper's inverse-matrix method (eq. 3.1-3.3).

    With the vertices translated by the ray origin (``a_i = v_i - o``) and ``e`` the unit
    direction, ``[a1 a2 a3] k = e`` (eq. 3.1) is solved by Cramer's rule in undivided
    form: ``U_1 = e.(a2 x a3)``, ``U_2 = e.(a3 x a1)``, ``U_3 = e.(a1 x a2)`` (``k_i =
    U_i / det``). The same edge gives bit-equal triple products of opposite sign in the two
    triangles that share it, so a ray through an edge can never pass between them
    (watertight). The ray hits when the ``U_i`` share one sign; the distance is ``1 /
    sum(k) = (a1.N)/(e.N)`` with ``N = (v2 - v1) x (v3 - v1)`` (eq. 3.2) and the
    barycentric coordinates are ``U_i / sum(U)``. A plane through the ray origin
    (``a1.N = 0``) or parallel to the ray is a miss, never a NaN.

    Parameters
    ----------
    vertices : (V, 3)  world-space positions
    faces : (F, 3) int  vertex indices (winding gives the outward geometric normal
        ``(v1 - v0) x (v2 - v0)``, Mitsuba's convention)
    normals : (V, 3) or None  per-vertex shading normals (eq. 3.3); ``None``: ``ns = ng``
    texcoords : (V, 2) or None  per-vertex ``uv`` (``None``: a hit's ``uv`` is its
        barycentrics ``(b1, b2)``, as Mitsuba's meshes without texcoords)
    rewound : bool  the faces were rewound ``(0, 2, 1)`` by ``flip_normals`` (Mitsuba keeps the
        file's winding, so barycentric ``uv`` is then ``(b2, b1)`` of the rewound face)
    name : str
    closed : bool or None  ``None`` detects it: every edge shared by exactly two faces
    max_leaf : int  triangles per leaf of the per-mesh hierarchy
    """

    def __init__(self, vertices, faces, normals=None, name: str = "", closed=None,
                 max_leaf: int = 8, texcoords=None, rewound: bool = False, attributes=None):
        super().__init__(name)
        v = np.array(vertices, dtype=np.float64)
        f = np.array(faces)
        if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] == 0:
            raise ValueError(f"mesh {name!r}: vertices must be a non-empty (V, 3) array, got {v.shape}")
        if not np.all(np.isfinite(v)):
            raise ValueError(f"mesh {name!r}: vertices must be finite")
        if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0:
            raise ValueError(f"mesh {name!r}: faces must be a non-empty (F, 3) array, got {f.shape}")
        if not np.issubdtype(f.dtype, np.integer):
            if not np.all(f == np.round(f)):
                raise ValueError(f"mesh {name!r}: face indices must be integers")
        f = f.astype(np.int64)
        if f.min() < 0 or f.max() >= v.shape[0]:
            raise ValueError(f"mesh {name!r}: face indices must lie in [0, {v.shape[0] - 1}]")
        self.vertices = v
        self.faces = f
        if normals is not None:
            nrm = np.array(normals, dtype=np.float64)
            if nrm.shape != v.shape:
                raise ValueError(f"mesh {name!r}: normals must have the shape of vertices "
                                 f"{v.shape}, got {nrm.shape}")
            if not np.all(np.isfinite(nrm)):
                raise ValueError(f"mesh {name!r}: normals must be finite")
            self.normals = nrm
        else:
            self.normals = None
        self.texcoords = None
        self._bary_uv = [2, 1] if rewound else [1, 2]
        if texcoords is not None:
            uv = np.array(texcoords, dtype=np.float64)
            if uv.shape != (v.shape[0], 2) or not np.all(np.isfinite(uv)):
                raise ValueError(f"mesh {name!r}: texcoords must be finite with shape "
                                 f"{(v.shape[0], 2)}, got {uv.shape}")
            self.texcoords = uv
        #: Mitsuba's mesh attributes: ``vertex_<name>`` (V, k) and ``face_<name>`` (F, k)
        self.attributes = {}
        for key, a in (attributes or {}).items():
            a = np.asarray(a, dtype=np.float64)
            rows = v.shape[0] if key.startswith("vertex_") else f.shape[0] if key.startswith("face_") else -1
            if a.ndim != 2 or a.shape[0] != rows:
                raise ValueError(f"mesh {name!r}: attribute {key!r} must be vertex_* (V, k) or face_* (F, k), "
                                 f"got {a.shape}")
            self.attributes[key] = a
        self.closed = self._detect_closed() if closed is None else bool(closed)

        p0, p1, p2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        tri_lo = np.minimum(np.minimum(p0, p1), p2)
        tri_hi = np.maximum(np.maximum(p0, p1), p2)
        self.bvh = BVH(tri_lo, tri_hi, max_leaf=max_leaf)
        order = self.bvh.order
        # Triangle data in leaf order, one contiguous array per component.
        q0, q1, q2 = p0[order], p1[order], p2[order]
        nn = cross(q1 - q0, q2 - q0)  # N = (v2 - v1) x (v3 - v1), paper's numbering
        # Per vertex role, a (3, F) array (component-major) for per-ray permutation.
        self._vs = [np.ascontiguousarray(q.T) for q in (q0, q1, q2)]
        self._v0 = [np.ascontiguousarray(q0[:, k]) for k in range(3)]
        self._n = [np.ascontiguousarray(nn[:, k]) for k in range(3)]
        self._lo = v.min(axis=0)
        self._hi = v.max(axis=0)

    def _detect_closed(self) -> bool:
        f = self.faces
        e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        e = np.sort(e, axis=1)
        _, counts = np.unique(e, axis=0, return_counts=True)
        return bool(np.all(counts == 2))

    @property
    def nbytes(self) -> int:
        n = self.vertices.nbytes + self.faces.nbytes + self.bvh.nbytes
        n += sum(a.nbytes for a in self._vs) + sum(a.nbytes for a in self._n)
        if self.normals is not None:
            n += self.normals.nbytes
        return int(n)

    def _repr_extra(self) -> str:
        return (f"vertices={self.vertices.shape[0]}, faces={self.faces.shape[0]}, "
                f"normals={self.normals is not None}")

    def bounds(self):
        return self._lo.copy(), self._hi.copy()

    # ------------------------------------------------------------------ leaf test
    def _leaf(self, s, c, ray):
        """Rays (R,) x triangles [s, s+c) of the leaf order: distance (R, c), ``inf``
        where missed. ``ray`` holds the per-ray frame of :meth:`_ray_frame`."""
        kx, ky, kz, px, py, pz, sx, sy, dz, ex, ey, ez = ray
        V = self._vs
        sl = slice(s, s + c)
        # a_i = v_i - o: vertices translated by the ray origin (Choice, docs/method.md §3.1),
        # in the ray's permuted and sheared frame where e is the z axis (Woop, Benthin &
        # Wald 2013): e.(a_j x a_k) = |d_z| (a'_j x a'_k)_z. Every vertex is transformed
        # once per ray, so shared edges and vertices see the same numbers.
        out = []
        for vi in range(3):
            Vc = V[vi][:, sl]
            az = Vc[kz] - pz
            out.append((Vc[kx] - px - sx * az, Vc[ky] - py - sy * az))
        (ax, ay), (bx, by), (cx, cy) = out
        # eq. (3.1) by Cramer's rule, undivided: U_i = e.(a_j x a_k) / |d_z| (the swap of
        # x and y when d_z < 0 keeps the sign).
        u1 = bx * cy - by * cx
        u2 = cx * ay - cy * ax
        u3 = ax * by - ay * bx
        su = u1 + u2 + u3
        inside = (((u1 >= 0) & (u2 >= 0) & (u3 >= 0)) | ((u1 <= 0) & (u2 <= 0) & (u3 <= 0)))
        N = self._n
        nx, ny, nz = N[0][None, sl], N[1][None, sl], N[2][None, sl]
        V0 = self._v0
        det = ((V0[0][None, sl] - ex[1]) * nx + (V0[1][None, sl] - ey[1]) * ny
               + (V0[2][None, sl] - ez[1]) * nz)           # det[a1 a2 a3] = a1.N
        en = ex[0] * nx + ey[0] * ny + ez[0] * nz          # e.N = |d_z| sum(U)
        # det = 0: the plane contains the ray origin (Choice, docs/method.md §3.1): a miss.
        ok = inside & (su != 0) & (en * su > 0) & (det != 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = det / np.where(ok, en, 1.0)  # eq. (3.2): 1/sum(k) = (a1.N)/(e.N)
        return np.where(ok, t, np.inf)

    @staticmethod
    def _ray_frame(o, d):
        """Per ray: the permutation making |d_z| largest (winding kept), the permuted
        origin, the shear that maps d to the z axis, and the raw origin/direction."""
        n = o.shape[0]
        kz = np.argmax(np.abs(d), axis=1)
        kx = (kz + 1) % 3
        ky = (kx + 1) % 3
        rows = np.arange(n)
        dz = d[rows, kz]
        swap = dz < 0
        kx, ky = np.where(swap, ky, kx), np.where(swap, kx, ky)
        sx = d[rows, kx] / dz
        sy = d[rows, ky] / dz
        return (kx, ky, kz, o[rows, kx], o[rows, ky], o[rows, kz], sx, sy, dz,
                (d[:, 0], o[:, 0]), (d[:, 1], o[:, 1]), (d[:, 2], o[:, 2]))

    def _trace(self, o, d, tmin, tmax, cost, any_hit: bool):
        frame = self._ray_frame(o, d)

        def leaf_times(s, c, r):
            kx, ky, kz, px, py, pz, sx, sy, dz, ex, ey, ez = frame
            col = lambda a: a[r, None]
            sub = (kx[r], ky[r], kz[r], col(px), col(py), col(pz), col(sx), col(sy), col(dz),
                   (col(ex[0]), col(ex[1])), (col(ey[0]), col(ey[1])), (col(ez[0]), col(ez[1])))
            t = self._leaf(s, c, sub)
            return np.where((t > tmin[r, None]) & (t < tmax[r, None]), t, np.inf)

        return nearest_hits(self.bvh, o, d, tmin, tmax, cost, any_hit, leaf_times)


    def barycentrics(self, o, d, prim) -> np.ndarray:
        """Barycentric coordinates (N, 3) of the hits of rays ``o + t d`` on ``prim``
        (``k_i / sum(k)``, eq. 3.1-3.2)."""
        f = self.faces[prim]
        v = self.vertices
        a1, a2, a3 = v[f[:, 0]] - o, v[f[:, 1]] - o, v[f[:, 2]] - o
        u = np.stack([dot(d, cross(a2, a3)), dot(d, cross(a3, a1)), dot(d, cross(a1, a2))], axis=1)
        su = u.sum(axis=1, keepdims=True)
        with np.errstate(divide="ignore", invalid="ignore"):
            b = np.where(su != 0, u / np.where(su != 0, su, 1.0), 1.0 / 3.0)
        return b

    def surface(self, o, d, t, prim):
        o = np.asarray(o, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(d, dtype=np.float64).reshape(-1, 3)
        prim = np.asarray(prim, dtype=np.int64)
        f = self.faces[prim]
        v = self.vertices
        v0, v1, v2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        b = self.barycentrics(o, d, prim)
        # The point from the barycentrics lies on the triangle (better than o + t d
        # for a far origin).
        p = b[:, :1] * v0 + b[:, 1:2] * v1 + b[:, 2:] * v2
        ng = normalize(cross(v1 - v0, v2 - v0))
        if self.normals is None:
            ns = ng.copy()
        else:
            nv = self.normals
            # eq. (3.3): n = k1 n1 + k2 n2 + k3 n3, normalised.
            ns = b[:, :1] * nv[f[:, 0]] + b[:, 1:2] * nv[f[:, 1]] + b[:, 2:] * nv[f[:, 2]]
            ln = np.sqrt(dot(ns, ns))
            ns = np.where((ln > 0)[:, None], normalize(ns), ng)
        return p, ng, ns

    def uv(self, o, d, t, prim):
        """Texcoords interpolated by the hit's barycentrics (Mitsuba: ``(b1, b2)`` without)."""
        o = np.asarray(o, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(d, dtype=np.float64).reshape(-1, 3)
        prim = np.asarray(prim, dtype=np.int64)
        return self.uv_at(self.barycentrics(o, d, prim), prim)

    def uv_at(self, b, prim):
        """Texcoords at barycentrics ``b`` (N, 3) of triangles ``prim`` (as :meth:`uv`)."""
        if self.texcoords is None:
            return b[:, self._bary_uv]
        f = self.faces[prim]
        tc = self.texcoords
        return b[:, :1] * tc[f[:, 0]] + b[:, 1:2] * tc[f[:, 1]] + b[:, 2:] * tc[f[:, 2]]


    def tangents(self, o, d, t, prim):
        """Mitsuba's ``Mesh::compute_surface_interaction``: with texcoords, ``dp/du``, ``dp/dv``
        of the triangle's affine map from uv (its face's ``coordinate_system`` where the uv
        triangle is degenerate); without, the barycentric edges ``p1 - p0``, ``p2 - p0`` in the
        file's winding."""
        prim = np.asarray(prim, dtype=np.int64)
        f = self.faces[prim]
        v = self.vertices
        i1, i2 = self._bary_uv   # the file's second and third vertex (rewound faces: swapped)
        p0, p1, p2 = v[f[:, 0]], v[f[:, i1]], v[f[:, i2]]
        dp0, dp1 = p1 - p0, p2 - p0
        if self.texcoords is None:
            return dp0, dp1
        tc = self.texcoords
        duv0, duv1 = tc[f[:, i1]] - tc[f[:, 0]], tc[f[:, i2]] - tc[f[:, 0]]
        det = duv0[:, 0] * duv1[:, 1] - duv0[:, 1] * duv1[:, 0]
        ok = det != 0
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)[:, None]
        dp_du = (duv1[:, 1:2] * dp0 - duv0[:, 1:2] * dp1) * inv
        dp_dv = (duv0[:, 0:1] * dp1 - duv1[:, 0:1] * dp0) * inv
        if not np.all(ok):
            s, t_ = coordinate_system(normalize(cross(dp0, dp1)[~ok]))
            dp_du[~ok], dp_dv[~ok] = s, t_
        return dp_du, dp_dv

    def attribute(self, key: str, o, d, prim) -> np.ndarray:
        """Mesh attribute ``key`` at the hits (N, k): a face's value, or the vertices' values
        interpolated by the hit's barycentrics (Mitsuba's ``mesh_attribute`` texture)."""
        a = self.attributes.get(key)
        if a is None:
            raise KeyError(f"mesh {self.name!r} has no attribute {key!r} (it has {sorted(self.attributes)})")
        prim = np.asarray(prim, dtype=np.int64)
        if key.startswith("face_"):
            return a[prim]
        b = self.barycentrics(np.asarray(o, dtype=np.float64).reshape(-1, 3),
                              np.asarray(d, dtype=np.float64).reshape(-1, 3), prim)
        f = self.faces[prim]
        return b[:, :1] * a[f[:, 0]] + b[:, 1:2] * a[f[:, 1]] + b[:, 2:] * a[f[:, 2]]


# ---------------------------------------------------------------------------- quadrics
def quadric_roots(a, b, c, disc, pos):
    """Both roots of eq. (3.5) in the stable form (docs/numerics.md), as an interval ``(lo, hi)``.

    ``pos`` = ``a > 0``; where ``a = 0`` (a ray parallel to a cylinder's axis) the ray is
    inside everywhere (``c < 0``: ``(-inf, inf)``) or nowhere (an empty interval).
    Shared by :class:`Quadric` and the all-quadrics-at-once path of :mod:`links1.geometry.accel`.
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

    From :meth:`Quadric._intervals`' inside interval ``[q_lo, q_hi]`` and clip interval
    ``[c_in, c_out]`` (planes ``j_in``, ``j_out``), in the shifted frame whose origin is
    ``s`` along the ray. ``capped`` (bool or (N,) bool): a capped quadric is the solid
    ``quadric ∩ clip`` (its ends are caps where a plane sets them), an open one the shell
    points inside the clip interval. The one rule of the core's :class:`Quadric` and the
    scene accel's quadric table (:class:`links1.geometry.accel.Accel`)."""
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


class Quadric(Shape):
    """Sphere / ellipsoid or infinite elliptic cylinder ``|A(x - m)|^2 = 1`` (eq. 3.4),
    optionally cut by planes.

    Object space: the unit sphere ``|y| = 1`` or the cylinder ``y_x^2 + y_y^2 = 1``
    along the local z axis; ``to_world`` maps it to the world, so ``A`` is the inverse of
    its linear part and ``m`` its translation. Clip planes ``(n, h)`` keep ``n.y <= h``
    (object space).

    The ray's quadratic (eq. 3.5) is solved in the stable form: ``u = A(o - m)``,
    ``v = A d``, ``a = v.v``, ``b = u.v``, ``c = u.u - 1``, discriminant ``b^2 - ac =
    a - |u x v|^2`` (no cancellation), ``q = -(b + sign(b) sqrt(disc))``, roots ``c/q``
    and ``q/a``, after moving the origin to the ray's closest approach to the centre
    (``o' = o - (b/a) d``) so that far cameras lose nothing. A ray parallel to the
    cylinder's axis (``a = 0``) is inside along its whole length when ``c < 0`` (it can
    then only hit caps) and misses otherwise.

    ``capped=False`` gives an open shell: when the near root is clipped away the far root
    can still be seen (the inside of a cut sphere). ``capped=True`` gives the solid cut
    by the planes: its caps are the pieces of the planes inside the quadric, with the
    plane's normal (transformed as a normal) as outward normal. ``prim`` is 0 on the
    quadric and ``1 + j`` on the cap of plane ``j``.

    Bounds: exact for an uncut ellipsoid (a cut one keeps the uncut box); a cylinder is
    bounded along its axis by its clip planes, and one that the planes do not bound is
    rejected with ``ValueError`` (an infinite cylinder needs clip planes).

    Parameters
    ----------
    kind : "sphere" | "cylinder"
    to_world : (4, 4)  object-to-world transform (non-singular)
    clips : list of (n (3,), h)  object-space half-spaces ``n.y <= h``
    capped : bool
    name : str
    """

    KINDS = ("sphere", "cylinder")

    def __init__(self, kind: str = "sphere", to_world=None, clips=(), capped: bool = False,
                 name: str = ""):
        super().__init__(name)
        if kind not in self.KINDS:
            raise ValueError(f"quadric {name!r}: kind must be one of {self.KINDS}, got {kind!r}")
        self.kind = kind
        self.to_world = check_to_world(to_world, f"quadric {name!r}")
        self.A = np.linalg.inv(self.to_world[:3, :3])  # eq. (3.4): x = m + L y, A = L^-1
        self.m = self.to_world[:3, 3].copy()
        planes = []
        for i, cl in enumerate(clips or ()):
            try:
                nvec, h = cl
                nvec = np.asarray(nvec, dtype=np.float64).reshape(3)
                h = float(h)
            except (TypeError, ValueError):
                raise ValueError(f"quadric {name!r}: clip plane {i} must be (n (3,), h)") from None
            if not (np.all(np.isfinite(nvec)) and np.isfinite(h)) or not np.any(nvec != 0):
                raise ValueError(f"quadric {name!r}: clip plane {i} needs a finite non-zero "
                                 f"normal and a finite offset, got n={nvec.tolist()}, h={h}")
            planes.append((nvec, h))
        self.clips = planes
        self.capped = bool(capped)
        self.closed = (kind == "sphere" and not planes) or self.capped
        self._bounds = self._compute_bounds()
        # World-space outward normals of the caps: object normals transformed as normals.
        self._cap_normals = [normalize(self.A.T @ nv) for nv, _ in planes]

    def _repr_extra(self) -> str:
        return f"kind={self.kind!r}, clips={len(self.clips)}, capped={self.capped}"

    @property
    def nbytes(self) -> int:
        return int(16 * 8 + 9 * 8 + len(self.clips) * 4 * 8)

    def _compute_bounds(self):
        lo, hi = quadric_bounds(self.kind, self.to_world, self.clips)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise ValueError(f"quadric {self.name!r}: an infinite cylinder needs clip planes "
                             "that bound it along its axis (both ends)")
        return lo, hi

    def bounds(self):
        return self._bounds[0].copy(), self._bounds[1].copy()

    # ------------------------------------------------------------------ intersection
    def _quadric_terms(self, u, v):
        if self.kind == "sphere":
            a = dot(v, v)
            b = dot(u, v)
            c = dot(u, u) - 1.0
            cr = cross(u, v)
            cr2 = dot(cr, cr)
        else:
            a = v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1]
            b = u[:, 0] * v[:, 0] + u[:, 1] * v[:, 1]
            c = u[:, 0] * u[:, 0] + u[:, 1] * u[:, 1] - 1.0
            cz = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
            cr2 = cz * cz
        return a, b, c, cr2

    def _intervals(self, o, d):
        """Per ray, in world t: the quadric's inside interval [q_lo, q_hi] (empty: q_lo >
        q_hi), the clip interval [c_in, c_out] and the planes setting its ends."""
        A, m = self.A, self.m
        u = matvec(A, o - m)
        v = matvec(A, d)
        a, b, _, _ = self._quadric_terms(u, v)
        pos = a > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(pos, -b / np.where(pos, a, 1.0), 0.0)
        # Closest approach (numerics: removes the far-camera loss of c = u.u - 1).
        o2 = o + s[:, None] * d
        u = matvec(A, o2 - m)
        a, b, c, cr2 = self._quadric_terms(u, v)
        disc = a - cr2  # = b^2 - ac, eq. (3.5) discriminant without cancellation
        q_lo, q_hi = quadric_roots(a, b, c, disc, pos)
        # Clip planes n.y <= h: interval clipping along the ray (shifted frame).
        c_in, c_out, j_in, j_out = clip_interval(u, v, self.clips)
        return s, q_lo, q_hi, c_in, c_out, j_in, j_out

    def _hits(self, o, d, tmin, tmax):
        s, q_lo, q_hi, c_in, c_out, j_in, j_out = self._intervals(o, d)
        return quadric_first_hit(s, q_lo, q_hi, c_in, c_out, j_in, j_out, self.capped, tmin, tmax)

    def intersect(self, o, d, tmin, tmax, cost=None):
        o, d, tmin, tmax = _as_rays(o, d, tmin, tmax)
        _add_cost(cost)
        return self._hits(o, d, tmin, tmax)

    def surface(self, o, d, t, prim):
        o = np.asarray(o, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(d, dtype=np.float64).reshape(-1, 3)
        t = _finite_or_zero(t)
        prim = np.asarray(prim, dtype=np.int64)
        p = o + t[:, None] * d
        y = matvec(self.A, p - self.m)
        if self.kind == "cylinder":
            y = y * np.array([1.0, 1.0, 0.0])
        # Normal: grad = 2 A^T A (x - m) = 2 A^T y, normalised (outward).
        ng = normalize(matvec(self.A.T, y))
        for j, cn in enumerate(self._cap_normals):
            m = prim == 1 + j
            if m.any():
                ng[m] = cn
        return p, ng, ng.copy()

    def uv(self, o, d, t, prim):
        """Mitsuba's parameterisation in object space ``y``: sphere ``(φ/2π, θ/π)`` with
        ``φ = atan2(y_y, y_x)`` in [0, 2π) and ``θ = acos(y_z)``; cylinder ``(φ/2π, y_z)``
        (``p0`` at 0, ``p1`` at 1 for Mitsuba's ``cylinder``). Caps use the same formulas."""
        o = np.asarray(o, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(d, dtype=np.float64).reshape(-1, 3)
        y = matvec(self.A, o + _finite_or_zero(t)[:, None] * d - self.m)
        phi = _turn(np.arctan2(y[:, 1], y[:, 0]))
        if self.kind == "cylinder":
            return np.stack([phi, y[:, 2]], axis=1)
        y = normalize(y)  # Mitsuba re-projects the hit onto the sphere
        return np.stack([phi, np.arccos(np.clip(y[:, 2], -1.0, 1.0)) / np.pi], axis=1)

    def tangents(self, o, d, t, prim):
        """Mitsuba's ``dp_du``, ``dp_dv`` of :meth:`uv` (world): sphere ``2π L(-y_y, y_x, 0)`` and
        ``π L(y_z cos φ, y_z sin φ, -r)`` (``L(1, 0, 0) π`` at a pole, r = 0); cylinder
        ``2π L(-y_y, y_x, 0)`` and ``L(0, 0, 1)``; ``L`` the linear part of ``to_world``."""
        o = np.asarray(o, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(d, dtype=np.float64).reshape(-1, 3)
        y = matvec(self.A, o + _finite_or_zero(t)[:, None] * d - self.m)
        L = self.to_world[:3, :3]
        if self.kind == "sphere":
            y = normalize(y)
        zero = np.zeros(y.shape[0])
        du = 2.0 * np.pi * np.stack([-y[:, 1], y[:, 0], zero], axis=1)
        if self.kind == "cylinder":
            dv = np.tile([0.0, 0.0, 1.0], (y.shape[0], 1))
        else:
            rd = np.hypot(y[:, 0], y[:, 1])
            pole = rd == 0
            inv = np.where(pole, 0.0, 1.0 / np.where(pole, 1.0, rd))
            dv = np.stack([y[:, 2] * y[:, 0] * inv, y[:, 2] * y[:, 1] * inv, -rd], axis=1)
            dv[pole] = [1.0, 0.0, 0.0]
            dv = np.pi * dv
        return matvec(L, du), matvec(L, dv)


# ---------------------------------------------------------------------------- disk
class Disk(Shape):
    """Mitsuba's ``disk``: the unit disk in the object xy plane, normal +z, placed by
    ``to_world``. One-sided in Mitsuba's sense only for shading; intersected from both
    sides here (ng is the transformed +z, or −z with ``flip``: Mitsuba's ``flip_normals``)."""

    def __init__(self, to_world=None, name: str = "", flip: bool = False):
        super().__init__(name)
        self.to_world = check_to_world(to_world, f"disk {name!r}")
        self.A = np.linalg.inv(self.to_world[:3, :3])
        self.m = self.to_world[:3, 3].copy()
        self._normal = normalize(self.A.T @ np.array([0.0, 0.0, -1.0 if flip else 1.0]))
        ext = _row_extent(self.to_world[:3, :3], [0, 1])
        self._bounds = (self.m - ext, self.m + ext)

    def bounds(self):
        return self._bounds[0].copy(), self._bounds[1].copy()

    @property
    def nbytes(self) -> int:
        return 16 * 8 + 9 * 8

    def intersect(self, o, d, tmin, tmax, cost=None):
        o, d, tmin, tmax = _as_rays(o, d, tmin, tmax)
        _add_cost(cost)
        u = matvec(self.A, o - self.m)
        v = matvec(self.A, d)
        ok = v[:, 2] != 0
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(ok, -u[:, 2] / np.where(ok, v[:, 2], 1.0), np.inf)
        with np.errstate(invalid="ignore"):
            x = u[:, 0] + t * v[:, 0]
            y = u[:, 1] + t * v[:, 1]
            hit = ok & (x * x + y * y <= 1.0) & (t > tmin) & (t < tmax)
        t = np.where(hit, t, np.inf)
        return t, np.where(hit, 0, -1).astype(np.int64)

    def surface(self, o, d, t, prim):
        o = np.asarray(o, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(d, dtype=np.float64).reshape(-1, 3)
        t = _finite_or_zero(t)
        p = o + t[:, None] * d
        ng = np.broadcast_to(self._normal, p.shape).copy()
        return p, ng, ng.copy()

    def uv(self, o, d, t, prim):
        """Mitsuba's disk parameterisation: ``(r, φ/2π)`` of the object-space hit, φ in [0, 2π)."""
        o = np.asarray(o, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(d, dtype=np.float64).reshape(-1, 3)
        y = matvec(self.A, o + _finite_or_zero(t)[:, None] * d - self.m)
        return np.stack([np.hypot(y[:, 0], y[:, 1]), _turn(np.arctan2(y[:, 1], y[:, 0]))], axis=1)

    def tangents(self, o, d, t, prim):
        """Mitsuba's disk: ``dp_du = L(cos φ, sin φ, 0)``, ``dp_dv = 2π r L(-sin φ, cos φ, 0)``
        (``L`` the linear part of ``to_world``; both zero at the centre)."""
        o = np.asarray(o, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(d, dtype=np.float64).reshape(-1, 3)
        y = matvec(self.A, o + _finite_or_zero(t)[:, None] * d - self.m)
        r = np.hypot(y[:, 0], y[:, 1])
        inv = np.where(r > 0, 1.0 / np.where(r > 0, r, 1.0), 0.0)
        c, s = y[:, 0] * inv, y[:, 1] * inv
        zero = np.zeros(r.shape[0])
        L = self.to_world[:3, :3]
        return (matvec(L, np.stack([c, s, zero], axis=1)),
                matvec(L, 2.0 * np.pi * r[:, None] * np.stack([-s, c, zero], axis=1)))
