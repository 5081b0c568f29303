"""Mitsuba's ``ellipsoids`` and ``ellipsoidsmesh``: point clouds of anisotropic ellipsoids,
in float64, as Mitsuba 3.9.1 builds and intersects them.

What Mitsuba 3.9.1 does (``src/shapes/ellipsoids.h``, the ``EllipsoidsData`` both plugins
share; ``src/shapes/ellipsoids.cpp``; ``src/shapes/ellipsoidsmesh.cpp``;
``src/render/scene_embree.inl`` for the mesh's culling):

* **Data.** Ten floats per ellipsoid: centre (3), scale (3), rotation quaternion (4, stored
  ``x y z w``). A scene *file* can give them only as ``filename``, a PLY file (``data``,
  ``centers``/``scales``/``quaternions`` are tensors, which only ``mi.load_dict`` passes).
  The PLY's first element must start with the properties ``x y z nx ny nz`` and end with
  ``scale_0 scale_1 scale_2 rot_0 rot_1 rot_2 rot_3``; Mitsuba reads every property of a
  record as a float32 (binary little-endian or ASCII). Per ellipsoid: ``centre = to_world ·
  (x, y, z)``; ``scale = max(exp(scale_k), 1e-6) · scale_factor · mean(diag S)`` with ``S``
  the stretch of ``to_world``'s polar decomposition ``Q S``; quaternion ``normalize(Q ·
  (rot_1, rot_2, rot_3, rot_0))`` (``rot_0`` is the real part). A mirroring map has its own
  twist (:func:`world_rotation`): negative semi-axes and another rotation. The properties between (``nx ... ``) are attributes for
  volumetric integrators; of them only ``opacities`` matters here (below): a property
  ``opacities``, or, in a 3D Gaussian splatting file (``f_dc_0`` seventh, ``opacity``
  eighth from last), ``clip(sigmoid(opacity), 1e-8, 1 - 1e-8)``.
* **Extent.** The surface is the ellipsoid of semi-axes ``extent · scale`` (``extent``,
  default 3: the support of a kernel whose standard deviations are the scales). With
  ``extent_adaptive_clamping`` the extent of each is ``extent / 3 · sqrt(2 log(opacity /
  0.01))``; without an ``opacities`` attribute Mitsuba warns and drops the option.
* **``ellipsoids``** (a custom Embree shape): the ray moved into the frame where the
  ellipsoid is the unit sphere (``diag(1/s) Rᵀ (o - c)``), the quadratic solved from the
  point of the ray's plane through the centre; **back faces culled**: a hit only where the
  near root lies in ``[0, maxt]``, so a ray that starts inside an ellipsoid does not see it.
  The normal (geometric and shading) is ``normalize(R · (local / s²))``, outward; ``uv = (0,
  0)``, ``dp/du = dp/dv = 0``.
* **``ellipsoidsmesh``**: a triangle mesh, one copy of a shell per ellipsoid mapped by
  ``translate(c) · R · scale(s · extent)``. ``shell``: ``ico_sphere`` (the default: 12
  vertices, 20 faces), ``uv_sphere`` (38, 72), ``box`` (24, 12) or a nested mesh; its
  vertices are first divided by the smallest distance from the origin of a vertex or a face
  centroid (so the shell's vertices and face centres lie on or outside the unit sphere; the
  box ends up inside it). Triangles are **culled when seen from behind** (Embree's filter:
  ``d · Ng > 0``, ``Ng = (v1 - v0) × (v2 - v0)``). Mitsuba's plain mesh surface otherwise:
  face normals, barycentric ``uv``; ``flip_normals`` negates the normal, not the culling.
  Mitsuba does not build the mesh's area tables (no area emitter on it).

The core reads the PLY as Mitsuba does (:func:`read_ellipsoids`) and refuses what Mitsuba
would read as garbage (non-float32 properties, big-endian data) in one line.
"""
from __future__ import annotations

import numpy as np

from ..maths.vec import cross, dot, normalize
from .base import _finite_or_zero
from .mesh_files import _read_binary_element, ply_file
from .primset import PrimitiveSet
from .quadrics import quadric_roots
from .shapes import TriangleMesh

#: Mitsuba's default ``extent``.
DEFAULT_EXTENT = 3.0
#: The PLY properties Mitsuba requires at the start and at the end of an ellipsoid record.
PLY_HEAD = ("x", "y", "z", "nx", "ny", "nz")
PLY_TAIL = ("scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")


# ---------------------------------------------------------------------------- the data
def quat_matrix(q) -> np.ndarray:
    """Rotation matrices (N, 3, 3) of quaternions ``q`` (N, 4) stored ``x y z w``
    (Dr.Jit's ``quat_to_matrix``)."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, 4)
    x, y, z, w = (q[:, k] for k in range(4))
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=1)], axis=1)


def matrix_quat(m) -> np.ndarray:
    """Dr.Jit's ``matrix_to_quat`` of a 3x3 matrix (Mike Day's branches), ``x y z w``: a unit
    quaternion for a rotation; for another matrix whatever the chosen branch gives (NaN where
    its ``t`` is negative)."""
    m = np.asarray(m, dtype=np.float64)
    t0, t1 = 1 + m[0, 0] - m[1, 1] - m[2, 2], 1 - m[0, 0] + m[1, 1] - m[2, 2]
    t2, t3 = 1 - m[0, 0] - m[1, 1] + m[2, 2], 1 + m[0, 0] + m[1, 1] + m[2, 2]
    q0 = (t0, m[1, 0] + m[0, 1], m[0, 2] + m[2, 0], m[2, 1] - m[1, 2])
    q1 = (m[1, 0] + m[0, 1], t1, m[2, 1] + m[1, 2], m[0, 2] - m[2, 0])
    q2 = (m[0, 2] + m[2, 0], m[2, 1] + m[1, 2], t2, m[1, 0] - m[0, 1])
    q3 = (m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1], t3)
    t, q = ((t0, q0) if m[0, 0] > m[1, 1] else (t1, q1)) if m[2, 2] < 0 else \
        ((t2, q2) if m[0, 0] < -m[1, 1] else (t3, q3))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.array(q) * (0.5 / np.sqrt(t))


def world_rotation(lin) -> tuple[np.ndarray, float]:
    """What Mitsuba's ``EllipsoidsData`` takes from ``to_world``'s linear part ``lin`` (3, 3):
    the rotation its ellipsoids turn by and the factor their semi-axes scale by, ``mean(diag
    S)`` of the polar decomposition ``lin = Q S`` (Dr.Jit's ``transform_decompose``). For a
    mirroring map Dr.Jit's ``mulsign(Q, det Q)`` negates the *diagonals* of ``Q`` and ``S``
    only (a scalar broadcast to a matrix is a multiple of the identity): the scale factor is
    then ``-mean(diag S)`` and the rotation that of ``matrix_to_quat`` of that matrix,
    normalised. ValueError where that quaternion is undefined."""
    lin = np.asarray(lin, dtype=np.float64)
    u, _, vt = np.linalg.svd(lin)
    q = u @ vt
    scale = float(np.mean(np.diag(q.T @ lin)))
    if np.linalg.det(q) < 0:
        q[np.diag_indices(3)] *= -1.0
        scale = -scale
    quat = matrix_quat(q)
    norm = float(np.linalg.norm(quat))
    if not (np.all(np.isfinite(quat)) and norm > 0):
        raise ValueError("to_world: Mitsuba's rotation of this mirroring map is undefined (NaN)")
    return quat_matrix(quat / norm)[0], scale


def read_ellipsoids(path, to_world=None, scale_factor: float = 1.0):
    """The ellipsoids of Mitsuba's PLY format (see the module docstring) placed by
    ``to_world``: ``(centers (N, 3), rotations (N, 3, 3), scales (N, 3), opacities (N,) or
    None)``. ValueError naming the file (and the header line) on what Mitsuba cannot read."""
    raw, fmt, elements, off = ply_file(path)
    if not elements:
        raise ValueError(f"{path}: PLY file has no element")
    name, count, props, line = elements[0]
    names = [p for p, _ in props]
    if len(names) < len(PLY_HEAD) + len(PLY_TAIL) or tuple(names[:6]) != PLY_HEAD \
            or tuple(names[-7:]) != PLY_TAIL:
        raise ValueError(f"{path}:{line}: element '{name}' must start with the properties "
                         f"{' '.join(PLY_HEAD)} and end with {' '.join(PLY_TAIL)} (Mitsuba's "
                         f"ellipsoids), got {' '.join(names)}")
    bad = [p for p, t in props if t != "f4"]
    if bad:
        raise ValueError(f"{path}:{line}: property '{bad[0]}' of element '{name}' is not a float: "
                         "Mitsuba reads every property of an ellipsoid as a float32")
    if fmt == "binary_big_endian":
        raise ValueError(f"{path}: binary_big_endian ellipsoids: Mitsuba reads them as "
                         "little-endian floats")
    if count < 1:
        raise ValueError(f"{path}:{line}: element '{name}' holds no ellipsoid")
    k = len(names)
    if fmt == "ascii":
        toks = raw[off:].split()
        if len(toks) < k * count:
            raise ValueError(f"{path}: truncated PLY data in element '{name}'")
        try:
            rec = np.array(toks[:k * count], dtype=np.float32).reshape(count, k)
        except ValueError:
            raise ValueError(f"{path}: a value of element '{name}' is not a number") from None
    else:
        cols, _ = _read_binary_element(raw, off, count, props, "<", path, name)
        rec = np.stack([np.asarray(cols[p], dtype=np.float32) for p in names], axis=1)
    rec = rec.astype(np.float64)
    if not np.all(np.isfinite(rec[:, list(range(3)) + list(range(k - 7, k))])):
        raise ValueError(f"{path}: an ellipsoid's position, scale or rotation is not finite")
    m = np.eye(4) if to_world is None else np.asarray(to_world, dtype=np.float64)
    q_world, world_scale = world_rotation(m[:3, :3])
    centers = rec[:, :3] @ m[:3, :3].T + m[:3, 3]
    scales = np.maximum(np.exp(rec[:, k - 7:k - 4]), 1e-6) * scale_factor * world_scale
    quats = rec[:, [k - 3, k - 2, k - 1, k - 4]]          # (rot_1, rot_2, rot_3, rot_0): x y z w
    norm = np.linalg.norm(quats, axis=1)
    if not np.all(norm > 0):
        raise ValueError(f"{path}: ellipsoid {int(np.argmin(norm))} has a zero rotation quaternion")
    rotations = q_world[None] @ quat_matrix(quats / norm[:, None])
    opacities = None
    if names[6] == "f_dc_0" and names[k - 8] == "opacity":   # a 3D Gaussian splatting file
        opacities = np.clip(1.0 / (1.0 + np.exp(-rec[:, k - 8])), 1e-8, 1.0 - 1e-8)
    elif "opacities" in names[6:k - 7]:
        opacities = rec[:, names.index("opacities")]
    return centers, rotations, scales, opacities


def extents(count: int, extent: float = DEFAULT_EXTENT, opacities=None) -> np.ndarray:
    """Mitsuba's per-ellipsoid extent: ``extent``, or with ``opacities`` (adaptive clamping)
    ``extent / 3 · sqrt(2 log(opacity / 0.01))``; ValueError where an opacity is at most
    0.01 (Mitsuba's extent is then NaN)."""
    if opacities is None:
        return np.full(count, float(extent))
    op = np.asarray(opacities, dtype=np.float64).reshape(count)
    if not np.all(op > 0.01):
        raise ValueError(f"extent_adaptive_clamping: ellipsoid {int(np.argmin(op))} has opacity "
                         f"{float(np.min(op)):g} <= 0.01, whose extent Mitsuba makes NaN")
    return np.sqrt(2.0 * np.log(op / 0.01)) * float(extent) / 3.0


def _check(centers, rotations, scales, what: str):
    c = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
    r = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    s = np.asarray(scales, dtype=np.float64).reshape(-1, 3)
    if not (c.shape[0] == r.shape[0] == s.shape[0] > 0):
        raise ValueError(f"{what}: centers, rotations and scales need one row per ellipsoid, "
                         f"got {c.shape[0]}, {r.shape[0]}, {s.shape[0]}")
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(r)) and np.all(np.isfinite(s))):
        raise ValueError(f"{what}: ellipsoid data must be finite")
    a = np.abs(s)
    if not (np.all(a > 0) and np.all(a.max(axis=1) <= 1e12 * a.min(axis=1))):
        raise ValueError(f"{what}: every semi-axis must be non-zero (ratio <= 1e12)")
    if not np.allclose(r @ np.transpose(r, (0, 2, 1)), np.eye(3), atol=1e-9):
        raise ValueError(f"{what}: rotations must be orthonormal")
    return c, r, s


# ---------------------------------------------------------------------------- ellipsoids
class Ellipsoids(PrimitiveSet):
    """Mitsuba's ``ellipsoids`` (module docstring): ellipsoid ``i`` is ``{c_i + R_i diag(s_i)
    y : |y| = 1}``, entered only from outside (back faces culled).

    Parameters
    ----------
    centers : (N, 3); rotations : (N, 3, 3) orthonormal; scales : (N, 3) semi-axes, the
        extent already applied (non-zero; a negative one, from a mirroring ``to_world``,
        is the same surface)
    """

    def __init__(self, centers, rotations, scales, name: str = ""):
        c, r, s = _check(centers, rotations, scales, f"ellipsoids {name!r}")
        self.centers, self.rotations, self.scales = c, r, s
        #: object (unit sphere) from world: diag(1/s) Rᵀ
        self._inv = np.transpose(r, (0, 2, 1)) / s[:, :, None]
        half = np.sqrt(np.sum((r * s[:, None, :]) ** 2, axis=2))   # |rows of R diag(s)|: exact box
        super().__init__(c - half, c + half, name=name)

    def _repr_extra(self) -> str:
        return f"ellipsoids={self.centers.shape[0]}"

    def _pair_hits(self, prim, o, d, tmin, tmax):
        A, c = self._inv[prim], self.centers[prim]
        v = np.einsum("kij,kj->ki", A, d)
        a = dot(v, v)
        # origin moved to the ray's closest approach to the centre (in the sphere's frame), as
        # Mitsuba does and as the quadrics do (docs/numerics.md): no far-origin cancellation
        shift = -dot(np.einsum("kij,kj->ki", A, o - c), v) / a
        u = np.einsum("kij,kj->ki", A, o + shift[:, None] * d - c)
        b = dot(u, v)
        cc = dot(u, u) - 1.0
        cr = cross(u, v)
        q_lo, q_hi = quadric_roots(a, b, cc, a - dot(cr, cr), a > 0)
        t = shift + q_lo
        # back faces culled: only the entry (near root) counts
        return np.where(np.isfinite(q_lo) & (q_lo <= q_hi) & (t > tmin) & (t < tmax), t, np.inf)

    def surface(self, o, d, t, prim):
        o = np.asarray(o, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(d, dtype=np.float64).reshape(-1, 3)
        prim = np.asarray(prim, dtype=np.int64)
        p = o + _finite_or_zero(t)[:, None] * d
        A = self._inv[prim]
        u = np.einsum("kij,kj->ki", A, p - self.centers[prim])
        n = normalize(np.einsum("kji,kj->ki", A, u))            # Aᵀ A (p - c) = R (local / s²)
        return p, n, n.copy()


# ---------------------------------------------------------------------------- the mesh
#: Mitsuba 3.9.1's shell templates (``ellipsoidsmesh.cpp``), float32 as there.
_ICO_V = [(0.0, -1.0, 0.0), (0.7236, -0.447215, 0.52572), (-0.276385, -0.447215, 0.85064),
          (-0.894425, -0.447215, 0.0), (-0.276385, -0.447215, -0.85064), (0.7236, -0.447215, -0.52572),
          (0.276385, 0.447215, 0.85064), (-0.7236, 0.447215, 0.52572), (-0.7236, 0.447215, -0.52572),
          (0.276385, 0.447215, -0.85064), (0.894425, 0.447215, 0.0), (0.0, 1.0, 0.0)]
_ICO_F = [(0, 1, 2), (1, 0, 5), (0, 2, 3), (0, 3, 4), (0, 4, 5), (1, 5, 10), (2, 1, 6), (3, 2, 7),
          (4, 3, 8), (5, 4, 9), (1, 10, 6), (2, 6, 7), (3, 7, 8), (4, 8, 9), (5, 9, 10),
          (6, 10, 11), (7, 6, 11), (8, 7, 11), (9, 8, 11), (10, 9, 11)]
_BOX_V = [(1, -1, -1), (1, -1, 1), (-1, -1, 1), (-1, -1, -1), (1, 1, -1), (-1, 1, -1), (-1, 1, 1),
          (1, 1, 1), (1, -1, -1), (1, 1, -1), (1, 1, 1), (1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1),
          (-1, -1, 1), (-1, -1, 1), (-1, 1, 1), (-1, 1, -1), (-1, -1, -1), (1, 1, -1), (1, -1, -1),
          (-1, -1, -1), (-1, 1, -1)]
_BOX_F = [(4 * k + a, 4 * k + b, 4 * k + c) for k in range(6) for a, b, c in ((0, 1, 2), (3, 0, 2))]
_UV_V = [(0.377821, 0.809017, -0.450270), (0.611327, 0.309017, -0.728552), (0.611327, -0.309017, -0.728552),
         (0.377821, -0.809017, -0.450270), (0.578855, 0.809017, -0.102068), (0.936608, 0.309017, -0.165149),
         (0.936608, -0.309017, -0.165149), (0.578855, -0.809017, -0.102068), (0.509037, 0.809017, 0.293893),
         (0.823639, 0.309017, 0.475528), (0.823639, -0.309017, 0.475528), (0.509037, -0.809017, 0.293893),
         (0.201034, 0.809017, 0.552337), (0.325280, 0.309017, 0.893701), (0.325280, -0.309017, 0.893701),
         (0.201034, -0.809017, 0.552337), (-0.201034, 0.809017, 0.552337), (-0.325280, 0.309017, 0.893701),
         (-0.325280, -0.309017, 0.893701), (-0.201034, -0.809017, 0.552337), (0.0, 1.0, 0.0),
         (-0.509037, 0.809017, 0.293893), (-0.823639, 0.309017, 0.475528), (-0.823639, -0.309017, 0.475528),
         (-0.509037, -0.809017, 0.293893), (-0.578855, 0.809017, -0.102068), (-0.936608, 0.309017, -0.165149),
         (-0.936608, -0.309017, -0.165149), (-0.578855, -0.809017, -0.102068), (-0.377821, 0.809017, -0.450269),
         (-0.611327, 0.309017, -0.728551), (-0.611327, -0.309017, -0.728551), (-0.377821, -0.809017, -0.450269),
         (0.0, 0.809017, -0.587785), (0.0, 0.309017, -0.951056), (0.0, -0.309017, -0.951056),
         (0.0, -0.809017, -0.587785), (0.0, -1.0, 0.0)]
_UV_F = [(35, 3, 36), (34, 0, 1), (37, 36, 3), (34, 2, 35), (33, 20, 0), (37, 3, 7), (1, 6, 2), (0, 20, 4),
         (2, 7, 3), (1, 4, 5), (37, 7, 11), (5, 10, 6), (4, 20, 8), (6, 11, 7), (4, 9, 5), (37, 11, 15),
         (9, 14, 10), (8, 20, 12), (11, 14, 15), (8, 13, 9), (37, 15, 19), (13, 18, 14), (12, 20, 16),
         (14, 19, 15), (13, 16, 17), (37, 19, 24), (17, 23, 18), (16, 20, 21), (18, 24, 19), (17, 21, 22),
         (37, 24, 28), (22, 27, 23), (21, 20, 25), (23, 28, 24), (22, 25, 26), (37, 28, 32), (26, 31, 27),
         (25, 20, 29), (27, 32, 28), (26, 29, 30), (37, 32, 36), (30, 35, 31), (29, 20, 33), (32, 35, 36),
         (29, 34, 30), (35, 2, 3), (34, 33, 0), (34, 1, 2), (1, 5, 6), (2, 6, 7), (1, 0, 4), (5, 9, 10),
         (6, 10, 11), (4, 8, 9), (9, 13, 14), (11, 10, 14), (8, 12, 13), (13, 17, 18), (14, 18, 19),
         (13, 12, 16), (17, 22, 23), (18, 23, 24), (17, 16, 21), (22, 26, 27), (23, 27, 28), (22, 21, 25),
         (26, 30, 31), (27, 31, 32), (26, 25, 29), (30, 34, 35), (32, 31, 35), (29, 33, 34)]
SHELLS = {"ico_sphere": (_ICO_V, _ICO_F), "default": (_ICO_V, _ICO_F), "uv_sphere": (_UV_V, _UV_F),
          "box": (_BOX_V, _BOX_F)}


def shell(kind="ico_sphere"):
    """A shell template ``(vertices (V, 3), faces (F, 3))``: one of :data:`SHELLS` by name, or
    a mesh's ``(vertices, faces)``; scaled as Mitsuba scales it (divided by the smallest norm
    of a vertex or face centroid)."""
    if isinstance(kind, str):
        if kind not in SHELLS:
            raise ValueError(f"shell '{kind}' is not one of {', '.join(sorted(SHELLS))}")
        v, f = SHELLS[kind]
        v = np.array(v, dtype=np.float32).astype(np.float64)
    else:
        v, f = kind
        v = np.asarray(v, dtype=np.float64)
    f = np.asarray(f, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or f.size == 0 \
            or f.min() < 0 or f.max() >= v.shape[0]:
        raise ValueError("an ellipsoid shell needs vertices (V, 3) and faces (F, 3) indexing them")
    used = v[f]                                   # (F, 3, 3): each face's corners
    near = min(float(np.min(np.linalg.norm(used, axis=2))),
               float(np.min(np.linalg.norm(used.mean(axis=1), axis=1))))
    if not near > 0:
        raise ValueError("an ellipsoid shell must keep the origin off its vertices and face centres")
    return v / near, f


class EllipsoidsMesh(TriangleMesh):
    """Mitsuba's ``ellipsoidsmesh`` (module docstring): a copy of ``shell`` (from
    :func:`shell`) per ellipsoid, mapped by ``translate(c) · R · scale(s)``, its triangles
    culled from behind (``d · Ng > 0``, whatever ``flip``); ``flip`` (``flip_normals``) negates
    the reported normals."""

    def __init__(self, centers, rotations, scales, shell_mesh=None, flip: bool = False, name: str = ""):
        c, r, s = _check(centers, rotations, scales, f"ellipsoidsmesh {name!r}")
        sv, sf = shell() if shell_mesh is None else shell_mesh
        lin = r * s[:, None, :]                                   # R diag(s)
        v = (np.einsum("kij,vj->kvi", lin, sv) + c[:, None, :]).reshape(-1, 3)
        f = (sf[None] + (np.arange(c.shape[0]) * sv.shape[0])[:, None, None]).reshape(-1, 3)
        super().__init__(v, f, name=name, closed=None)
        self.flip = bool(flip)
        self.faces_per_ellipsoid = int(sf.shape[0])

    def _leaf(self, s, c, ray):
        t = super()._leaf(s, c, ray)
        ex, ey, ez = ray[9:]
        sl = slice(s, s + c)
        en = ex[0] * self._n[0][None, sl] + ey[0] * self._n[1][None, sl] + ez[0] * self._n[2][None, sl]
        return np.where(en > 0, np.inf, t)                        # seen from behind: culled

    def surface(self, o, d, t, prim):
        p, ng, ns = super().surface(o, d, t, prim)
        return (p, -ng, -ns) if self.flip else (p, ng, ns)


def write_ellipsoids(path, centers, scales, quats, extra=None, binary: bool = True) -> None:
    """Write ellipsoids in Mitsuba's PLY format (:func:`read_ellipsoids` reads them back):
    ``centers`` (N, 3), ``scales`` (N, 3) semi-axes (written as their logarithms), ``quats``
    (N, 4) stored ``x y z w``; ``extra``: ``{name: (N,) values}`` written between the normals
    and the scales (``opacities`` for adaptive clamping). Float32, little-endian or ASCII."""
    c = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
    q = np.asarray(quats, dtype=np.float64).reshape(-1, 4)
    cols = [c, np.zeros_like(c)] + [np.asarray(v, dtype=np.float64).reshape(-1, 1) for v in (extra or {}).values()]
    cols += [np.log(np.asarray(scales, dtype=np.float64).reshape(-1, 3)), q[:, [3, 0, 1, 2]]]
    names = list(PLY_HEAD) + list(extra or {}) + list(PLY_TAIL)
    rec = np.concatenate(cols, axis=1).astype("<f4")
    head = (f"ply\nformat {'binary_little_endian' if binary else 'ascii'} 1.0\nelement vertex {len(c)}\n"
            + "".join(f"property float {n}\n" for n in names) + "end_header\n").encode("ascii")
    body = rec.tobytes() if binary else "".join(" ".join(repr(float(x)) for x in row) + "\n"
                                                for row in rec).encode("ascii")
    with open(path, "wb") as fh:
        fh.write(head + body)
