"""``links1_bicubic`` for Mitsuba: bicubic Bézier patches tessellated (with
``links1.geometry.bezier``, eq. 3.3) into a real :class:`mitsuba.Mesh`.
"""
from __future__ import annotations

import os

import numpy as np

from links1.geometry import bezier, meshes
from links1.scene.params import read, transform_problem

from .registered import check_properties
from .shapes import _matrix


def tessellate_bicubic(props, base_dir=None):
    """Vertices, faces and normals of a ``links1_bicubic`` node, with ``links1.geometry.bezier``."""
    check_properties("shape", "links1_bicubic", props)
    has_file = ("filename" in props)
    has_inline = ("control_points" in props)
    if has_file == has_inline:
        raise ValueError("links1_bicubic needs exactly one of 'filename' and 'control_points'")
    if has_file:
        fn = str(props["filename"])
        if not os.path.isabs(fn) and base_dir:
            fn = os.path.join(base_dir, fn)
        elif not os.path.isabs(fn):
            # mi.load_file / load_string: Mitsuba's file resolver holds the scene's folder
            import mitsuba as mi
            fn = str(mi.file_resolver().resolve(fn))
        patches = bezier.read_patches(fn)
    else:
        patches = bezier.parse_patches(str(props["control_points"]), "<control_points>", with_count=False)
    sub = read("links1_bicubic", "subdivisions", int(props["subdivisions"]) if ("subdivisions" in props) else None)
    v, f, n = bezier.tessellate_patches(patches, sub)
    if ("flip_normals" in props) and bool(props["flip_normals"]):
        f, n = meshes.flip(f, n)
    m = _matrix(props)
    if m is not None:
        if (problem := transform_problem(m)) is not None:
            raise ValueError(f"links1_bicubic: {problem}")
        v, n = meshes.transform_mesh(m, v, n)
    if ("face_normals" in props) and bool(props["face_normals"]):
        n = None
    return v, f, n


def define_bicubic():
    """``Links1Bicubic`` for the variant in use: a subclass of its ``mi.Mesh``, made per variant."""
    import drjit as dr
    import mitsuba as mi

    class Links1Bicubic(mi.Mesh):
        r"""Bicubic Bézier patches (``links1_bicubic``) tessellated into a Mitsuba mesh (eq. 3.3).

        ==============  =======  ==========================================  =========
        Parameter       Type     Meaning                                     Default
        ==============  =======  ==========================================  =========
        filename        string   a ``.patch`` file (see ``links1.geometry.bezier``)   —
        control_points  string   inline: 48 numbers per patch                —
        subdivisions    integer  grid cells per patch side                   8
        to_world        trafo    object → world                              identity
        flip_normals    boolean  reverse the winding and normals             false
        face_normals    boolean  flat shading (no vertex normals)            false
        ==============  =======  ==========================================  =========
        """

        def __init__(self, props):
            base = props["_links1_base_dir"] if ("_links1_base_dir" in props) else None
            v, f, n = tessellate_bicubic(props, base)
            for key in ("subdivisions", "flip_normals", "face_normals", "filename", "control_points"):
                if (key in props):
                    props.mark_queried(key) if hasattr(props, "mark_queried") else None
            super().__init__(props.id() or "links1_bicubic", len(v), len(f), props,
                             has_vertex_normals=n is not None)
            prm = mi.traverse(self)
            prm["vertex_positions"] = mi.Float(np.asarray(v, dtype=np.float32).ravel())
            prm["faces"] = mi.UInt32(np.asarray(f, dtype=np.uint32).ravel())
            if n is not None:
                prm["vertex_normals"] = mi.Float(np.asarray(n, dtype=np.float32).ravel())
            prm.update()
            self._nbytes = int(v.nbytes // 2 + f.nbytes // 2 + (0 if n is None else n.nbytes // 2))

        def to_string(self):
            return f"Links1Bicubic[id={self.id()!r}, vertices={self.vertex_count()}, faces={self.face_count()}]"

    return Links1Bicubic
