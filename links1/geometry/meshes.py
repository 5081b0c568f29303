"""Triangle meshes from their sources: what every source shares (Mitsuba's vertex normals, a
transform, ``flip_normals``) and Mitsuba's built-in rectangle and cube. The files (OBJ, PLY,
Mitsuba ``serialized``) are read by :mod:`links1.geometry.mesh_files`, bicubic Bézier patches
tessellated by :mod:`links1.geometry.bezier`.

Every function returns plain arrays ``(vertices (V, 3) float64, faces (F, 3) int64,
normals (V, 3) float64 or None)``; :mod:`links1.scene.loader` hands them to
``links1.geometry.shapes.TriangleMesh``. Bad input raises ``ValueError`` whose message names the
file and line (the loader re-raises it as a ``SceneError`` naming the XML element too).

Mitsuba semantics kept here
---------------------------
* A mesh without normals gets Mitsuba's smooth vertex normals
  (:func:`angle_weighted_normals`, ``Mesh::recompute_vertex_normals``) unless the caller asks
  for face normals.
* :func:`rectangle_mesh`: ``[-1, 1]²`` in ``z = 0``, normal ``+z``, ``uv = ((x+1)/2, (y+1)/2)``
  (Mitsuba's ``rectangle``). :func:`cube_mesh`: ``[-1, 1]³``, outward winding, flat faces: the
  same 24 vertices, texcoords and 12 triangles as Mitsuba's ``cube``.
"""
from __future__ import annotations

import os

import numpy as np

from ..maths import transform as tf

# --------------------------------------------------------------------------------------------
# helpers shared by every mesh source
# --------------------------------------------------------------------------------------------

def angle_weighted_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Mitsuba's ``recompute_vertex_normals``: face normals weighted by the corner angle."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    normals = np.zeros_like(v)
    if len(f) == 0:
        return normals
    p = v[f]  # (F, 3, 3)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    n = tf.normalize(n)
    for i in range(3):
        d0 = tf.normalize(p[:, (i + 1) % 3] - p[:, i])
        d1 = tf.normalize(p[:, (i + 2) % 3] - p[:, i])
        angle = np.arccos(np.clip(np.einsum("ij,ij->i", d0, d1), -1.0, 1.0))
        np.add.at(normals, f[:, i], n * angle[:, None])
    length = np.linalg.norm(normals, axis=1)
    bad = ~(length > 0)
    normals = normals / np.where(bad, 1.0, length)[:, None]
    normals[bad] = (1.0, 0.0, 0.0)  # Mitsuba's fallback for isolated / degenerate vertices
    return normals


def transform_mesh(to_world: np.ndarray, vertices: np.ndarray, normals: np.ndarray | None):
    """Apply ``to_world`` to positions and (by the inverse transpose) to normals, renormalised."""
    m = np.asarray(to_world, dtype=np.float64)
    v = tf.apply_point(m, vertices)
    n = None if normals is None else tf.normalize(tf.apply_normal(m, normals))
    return v, n


def flip(faces: np.ndarray, normals: np.ndarray | None):
    """Mitsuba's ``flip_normals``: reverse the winding and the vertex normals."""
    f = np.asarray(faces)[:, [0, 2, 1]].copy()
    return f, (None if normals is None else -normals)


# --------------------------------------------------------------------------------------------
# Mitsuba's built-in meshes
# --------------------------------------------------------------------------------------------

def rectangle_mesh(uv: bool = False):
    """Mitsuba's ``rectangle``: ``[-1, 1]²`` in the plane ``z = 0``, normal ``+z``; with
    ``uv=True`` also its texcoords ``((x + 1)/2, (y + 1)/2)``."""
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=np.float64)
    f = np.array([[0, 1, 2], [2, 3, 0]], dtype=np.int64)
    n = np.tile([0.0, 0.0, 1.0], (4, 1))
    return (v, f, n, 0.5 * (v[:, :2] + 1.0)) if uv else (v, f, n)


_CUBE_V = [[1, -1, -1], [1, -1, 1], [-1, -1, 1], [-1, -1, -1], [1, 1, -1], [-1, 1, -1],
           [-1, 1, 1], [1, 1, 1], [1, -1, -1], [1, 1, -1], [1, 1, 1], [1, -1, 1],
           [1, -1, 1], [1, 1, 1], [-1, 1, 1], [-1, -1, 1], [-1, -1, 1], [-1, 1, 1],
           [-1, 1, -1], [-1, -1, -1], [1, 1, -1], [1, -1, -1], [-1, -1, -1], [-1, 1, -1]]
_CUBE_N = [[0, -1, 0], [0, 1, 0], [1, 0, 0], [0, 0, 1], [-1, 0, 0], [0, 0, -1]]


def cube_mesh(uv: bool = False):
    """Mitsuba's ``cube``: ``[-1, 1]³``, 24 vertices (flat faces), 12 outward-wound triangles;
    with ``uv=True`` also Mitsuba's texcoords (each face (0,1), (1,1), (1,0), (0,0))."""
    v = np.array(_CUBE_V, dtype=np.float64)
    f = np.array([tri for k in range(6) for tri in ([4 * k, 4 * k + 1, 4 * k + 2],
                                                    [4 * k + 3, 4 * k, 4 * k + 2])], dtype=np.int64)
    n = np.repeat(np.array(_CUBE_N, dtype=np.float64), 4, axis=0)
    if not uv:
        return v, f, n
    return v, f, n, np.tile(np.array([[0, 1], [1, 1], [1, 0], [0, 0]], dtype=np.float64), (6, 1))


def find_mesh_format(filename: str) -> str:
    """``'obj'`` or ``'ply'`` from a file name's extension (ValueError otherwise)."""
    ext = os.path.splitext(filename)[1].lower()
    if ext not in (".obj", ".ply"):
        raise ValueError(f"unknown mesh file extension '{ext}'")
    return ext[1:]
