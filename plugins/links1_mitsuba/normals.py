"""The vertex normals Mitsuba computes, the same bits every time (LLVM variants).

Mitsuba computes a mesh's smooth vertex normals (``Mesh::recompute_vertex_normals``:
angle-weighted face normals, summed per vertex, then normalised) at load for a mesh file that
stores none, and again at each ``params.update()`` that moves the mesh's vertices without
setting its ``vertex_normals`` (an update that sets them keeps them). On an LLVM variant the
sums are float32 atomic scatter-adds over Dr.Jit's threads: each vertex's sum is added in the
order the threads reach it, so its last bits, and a few pixels of the image, change from run
to run (a 50k-face mesh: 7 different normal buffers in 30 identical updates, up to 2.4e-7
apart). :func:`recompute` does Mitsuba's own computation on one thread (face order: the same
bits every time). The loader calls it for the meshes whose file stores no normals
(``loader._settle_normals``); ``links1_whitted``'s tables call :func:`settle_moved` for the
meshes an update moved, before a frame reads them (``tables.Tables._settle_normals``).

What is left as Mitsuba makes it: the normals of a scene from plain ``mi.load_file`` until
its first frame (the plugin sees no file, and a file's normals can equal the computed ones
to a few ulps: mitsuba-data's ``cbox_largebox.obj``, 1.8e-7 apart), those of attached
vertices (:func:`settle_moved`), and every variant but LLVM's: a CUDA variant's atomics keep
their order whatever Dr.Jit's thread count (its normals vary as Mitsuba's do), and a scalar
variant sums in face order already.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from .paramwatch import own_param, set_own_param

#: The most two computations of the same normals may differ by in any component when only the
#: order of each vertex's float32 sum differs (Mitsuba's threads against one thread): measured
#: up to 2.4e-7 on the 50k-face bumpy sphere of tests/plugins/test_loaded_normals.py and on
#: mitsuba-data's bunny.ply, that is a few float32 ulps of a unit vector's components.
SUM_ORDER = 1e-6


def llvm() -> bool:
    """Whether the current Mitsuba variant is an LLVM one (whose normals this module settles)."""
    return mi.variant().startswith("llvm")


def recompute(meshes) -> None:
    """Mitsuba's ``recompute_vertex_normals`` of each of ``meshes`` on one thread of Dr.Jit's
    pool, evaluated there (each vertex's sum in face order: the same bits every time). The
    pool's thread count goes back at once: one thread stalls Mitsuba's EXR reads, and
    instantiating a scene under it hangs, so nothing else runs inside."""
    if not meshes:
        return
    threads = dr.thread_count()
    # Dr.Jit's LLVM launches are asynchronous: the work queued before (Mitsuba's own parallel
    # recompute at load) ends before the pool shrinks, and the recompute ends before it grows
    # back, or the pool's new threads take the rest of its blocks (under load: other bits)
    dr.sync_thread()
    dr.set_thread_count(1)
    try:
        for s in meshes:
            s.recompute_vertex_normals()
            dr.eval(own_param(s, "vertex_normals"))
        dr.sync_thread()
    finally:
        dr.set_thread_count(threads)


def held_positions(shape):
    """The vertex positions of a ``shape`` with vertex normals, held (another reference to their
    variables, the AD one too: ``own_param`` gives a view of the field, which the next
    ``params.update()`` overwrites, and a copy under ``dr.suspend_grad`` would drop it): what
    tells later whether an update moved them. None for a shape without vertex normals or
    without a ``vertex_positions`` parameter (Mitsuba's ``rectangle``: a mesh made from its
    ``to_world``)."""
    if not (shape.is_mesh() and shape.has_vertex_normals()):
        return None
    try:
        value = own_param(shape, "vertex_positions")
    except KeyError:
        return None
    with dr.resume_grad():
        return type(value)(value)


def attached(mesh) -> bool:
    """Whether ``mesh``'s vertex positions or normals have gradients enabled (an AD index in
    the upper 32 bits of their variables: read so under ``dr.suspend_grad`` too)."""
    return any(i >> 32 for k in ("vertex_positions", "vertex_normals")
               for i in dr.detail.collect_indices(own_param(mesh, k)))


def settle_moved(meshes) -> int:
    """After a ``params.update()`` that moved the vertices of ``meshes`` (those with vertex
    normals; LLVM variants only): the normals Mitsuba computed again, on its threads, replaced
    by :func:`recompute`'s, as a fresh ``links1_mitsuba.load_file`` of the moved mesh has
    them; how many were.

    Which normals Mitsuba computed is told by their values, the update's keys being the
    caller's alone: normals within :data:`SUM_ORDER` of the one-thread result in every
    component are Mitsuba's sums in another order; any others are the ones the update set
    (Mitsuba keeps them) and are put back, bit for bit, attached or not. Normals set by an
    update that equal the mesh's computed normals to float32 rounding (say, the same
    weighting done in float64) cannot be told from Mitsuba's: they become the one-thread
    result, which differs from them by a few ulps.

    A mesh whose vertices or normals are attached (inverse rendering's update) keeps
    Mitsuba's normals, and their derivative path: a frame runs inside ``mi.render``'s
    ``dr.custom`` operation, where the recompute can only make detached normals (Dr.Jit
    aborts, ``ad_add_special(): internal error``, when it records an attached one there under
    ``dr.resume_grad``)."""
    if not llvm():
        return 0
    meshes = [s for s in meshes if s.is_mesh() and s.has_vertex_normals() and not attached(s)]
    # (held: Mitsuba's recompute scatters into the buffer the mesh holds, which with another
    # reference it copies first, so that the values put back are the ones the update left)
    before = [own_param(s, "vertex_normals") for s in meshes]
    recompute(meshes)
    settled = 0
    for s, old in zip(meshes, before):
        a = np.asarray(dr.detach(old), dtype=np.float32)
        b = np.asarray(dr.detach(own_param(s, "vertex_normals")), dtype=np.float32)
        if a.shape == b.shape and np.all((np.abs(a - b) <= SUM_ORDER) | (np.isnan(a) & np.isnan(b))):
            settled += 1
        else:
            set_own_param(s, "vertex_normals", old)
    return settled
