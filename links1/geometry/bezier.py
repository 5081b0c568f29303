"""Bicubic Bézier patches: read (``.patch`` files, inline lists) and tessellated into
triangle meshes (``(vertices, faces, normals)``, as :mod:`links1.geometry.meshes`).

Bicubic Bézier patches (docs/method.md §3.1, eq. 3.3)
---------------------------------------------
A patch has 4 × 4 control points ``P[i][j]``; the surface is
``S(u, v) = Σ_i Σ_j B_i(u) B_j(v) P[i][j]`` with the Bernstein polynomials
``B_k(t) = C(3, k) t^k (1 − t)^(3 − k)``, ``(u, v) ∈ [0, 1]²``. Tessellation samples every
patch on a ``(subdivisions + 1)²`` grid, two triangles per grid cell, and gives every vertex the
analytic normal ``n = ∂S/∂u × ∂S/∂v / |…|`` for the shading interpolation of eq. (3.3). The
triangles are wound so that their geometric normal agrees with that ``n``. Where ``∂S/∂u × ∂S/∂v``
vanishes (a collapsed patch edge, e.g. the Utah teapot's lid), the normal is taken a tiny step
toward the patch centre.

**Patch file format** (``.patch`` text, ours)::

    # comments run from '#' to the end of the line; numbers are separated by spaces,
    # tabs, newlines or commas
    2                       # the number of patches N
    x y z   x y z   ...     # then 16 control points per patch: P[0][0] P[0][1] .. P[0][3]
                            #   P[1][0] .. P[3][3] (row i follows u, column j follows v)

An inline patch list (the ``control_points`` string of ``links1_bicubic``) is the same list of
numbers *without* the leading count: ``48·N`` numbers.
"""
from __future__ import annotations

import re

import numpy as np

from ..maths import transform as tf


def _numbers(text: str, source: str) -> np.ndarray:
    out = []
    for ln, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0]
        for tok in re.split(r"[,\s]+", line.strip()):
            if not tok:
                continue
            try:
                x = float(tok)
            except ValueError:
                raise ValueError(f"{source}:{ln}: cannot parse '{tok}' as a number") from None
            if not np.isfinite(x):
                raise ValueError(f"{source}:{ln}: non-finite number '{tok}'")
            out.append(x)
    return np.array(out, dtype=np.float64)


def parse_patches(text: str, source: str = "<patches>", with_count: bool = True) -> np.ndarray:
    """Patch list text → control points ``(N, 4, 4, 3)`` (format in the module docstring)."""
    nums = _numbers(text, source)
    if with_count:
        if nums.size == 0:
            raise ValueError(f"{source}: empty patch file (expected the number of patches first)")
        count = nums[0]
        if count != int(count) or count < 1:
            raise ValueError(f"{source}: the patch count must be a positive integer, got {count:g}")
        count = int(count)
        nums = nums[1:]
        if nums.size != 48 * count:
            raise ValueError(f"{source}: {count} patch(es) need {48 * count} numbers "
                             f"(16 control points x y z each), got {nums.size}")
    else:
        if nums.size == 0 or nums.size % 48:
            raise ValueError(f"{source}: control points must be 48 numbers per patch "
                             f"(16 points x y z), got {nums.size}")
    return nums.reshape(-1, 4, 4, 3)


def read_patches(path: str) -> np.ndarray:
    """Read a ``.patch`` file → control points ``(N, 4, 4, 3)``."""
    try:
        with open(path, encoding="utf-8") as fh:
            text = fh.read()
    except OSError as exc:
        raise ValueError(f"{path}: cannot read: {exc.strerror}") from None
    return parse_patches(text, path, with_count=True)


def _bernstein(t: np.ndarray):
    """Cubic Bernstein values and derivatives at ``t`` (M,) → (M, 4), (M, 4)."""
    s = 1.0 - t
    b = np.stack([s ** 3, 3 * t * s * s, 3 * t * t * s, t ** 3], axis=-1)
    db = np.stack([-3 * s * s, 3 * s * s - 6 * t * s, 6 * t * s - 3 * t * t, 3 * t * t], axis=-1)
    return b, db


def bezier_eval(ctrl: np.ndarray, u, v):
    """Evaluate one patch ``ctrl (4, 4, 3)`` at ``(u, v)`` (arrays of equal shape (M,)).

    Returns ``(S, S_u, S_v)``, each (M, 3): the point and its two partial derivatives.
    """
    u = np.atleast_1d(np.asarray(u, dtype=np.float64))
    v = np.atleast_1d(np.asarray(v, dtype=np.float64))
    bu, dbu = _bernstein(u)
    bv, dbv = _bernstein(v)
    p = np.einsum("mi,mj,ijk->mk", bu, bv, ctrl)
    pu = np.einsum("mi,mj,ijk->mk", dbu, bv, ctrl)
    pv = np.einsum("mi,mj,ijk->mk", bu, dbv, ctrl)
    return p, pu, pv


def bezier_normal(ctrl: np.ndarray, u, v) -> np.ndarray:
    """Unit normal ``S_u × S_v`` of a patch, nudged toward the centre where it vanishes."""
    u = np.atleast_1d(np.asarray(u, dtype=np.float64))
    v = np.atleast_1d(np.asarray(v, dtype=np.float64))
    _, pu, pv = bezier_eval(ctrl, u, v)
    n = np.cross(pu, pv)
    size = float(np.max(np.ptp(ctrl.reshape(-1, 3), axis=0))) or 1.0
    tiny = np.linalg.norm(n, axis=1) <= 1e-12 * size * size
    for eps in (1e-6, 1e-4, 1e-2):
        if not np.any(tiny):
            break
        uu = u[tiny] + (0.5 - u[tiny]) * eps
        vv = v[tiny] + (0.5 - v[tiny]) * eps
        _, qu, qv = bezier_eval(ctrl, uu, vv)
        n[tiny] = np.cross(qu, qv)
        tiny = np.linalg.norm(n, axis=1) <= 1e-12 * size * size * eps * eps
    return tf.normalize(n)


def tessellate_patches(patches: np.ndarray, subdivisions: int = 8):
    """Bicubic Bézier patches ``(N, 4, 4, 3)`` → ``(vertices, faces, normals)``.

    Each patch becomes a ``(subdivisions + 1)²`` grid of vertices carrying the analytic unit
    normals of eq. (3.3), and ``2 · subdivisions²`` triangles wound like ``S_u × S_v``.
    """
    patches = np.asarray(patches, dtype=np.float64)
    if patches.ndim != 4 or patches.shape[1:] != (4, 4, 3) or len(patches) == 0:
        raise ValueError(f"patches must have shape (N, 4, 4, 3), got {patches.shape}")
    if not np.all(np.isfinite(patches)):
        raise ValueError("patch control points must be finite")
    m = int(subdivisions)
    if m < 1:
        raise ValueError(f"subdivisions must be >= 1, got {subdivisions}")
    t = np.linspace(0.0, 1.0, m + 1)
    uu, vv = np.meshgrid(t, t, indexing="ij")  # vertex (i, j) at u = t[i], v = t[j]
    uu, vv = uu.ravel(), vv.ravel()
    i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    a = (i * (m + 1) + j).ravel()
    b = a + (m + 1)        # (i + 1, j)
    c = b + 1              # (i + 1, j + 1)
    d = a + 1              # (i, j + 1)
    local = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    verts, norms, faces = [], [], []
    per = (m + 1) ** 2
    for k, ctrl in enumerate(patches):
        p, _, _ = bezier_eval(ctrl, uu, vv)
        verts.append(p)
        norms.append(bezier_normal(ctrl, uu, vv))
        faces.append(local + k * per)
    return np.concatenate(verts), np.concatenate(faces).astype(np.int64), np.concatenate(norms)
