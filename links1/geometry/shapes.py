"""Shapes of the LINKS-1 core in float64 numpy: triangles (eq. 3.1-3.3), clipped quadrics
(eq. 3.4-3.5) and Mitsuba's disk. The contract they answer is :mod:`links1.geometry.base`;
the quadric's arithmetic :mod:`links1.geometry.quadrics`; the weight-function surface lives
in :mod:`links1.geometry.blob`.
"""
from __future__ import annotations

import numpy as np

from .base import HierarchyTraced, Shape, _add_cost, _as_rays, _finite_or_zero, _row_extent, _turn, check_to_world
from .bvh import BVH, nearest_hits
from .quadrics import clip_interval, quadric_bounds, quadric_first_hit, quadric_roots
from ..maths.vec import coordinate_system, cross, dot, matvec, normalize


# ---------------------------------------------------------------------------- triangles
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
