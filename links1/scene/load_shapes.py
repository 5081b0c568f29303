"""The loader's shapes (:mod:`links1.scene.loader`): Mitsuba's spheres, cylinders, disks,
rectangles, cubes, mesh files, SDF grids, curves and ellipsoids, links1's quadrics, blobs and
bicubic patches, shape groups and their instances (flattened), each with its BSDF and area
emitter (a mixin of the loader's builder).
"""
from __future__ import annotations

import re

import numpy as np

from ..geometry import bezier, blob, curves, mesh_files, meshes, sdfgrid, shapes
from ..geometry import ellipsoids as ell
from ..maths import transform as tf
from ..maths.vec import coordinate_system
from ..shading import materials as mat
from ..shading import textures
from . import params
from .load_emitters import _IGNORED_EMITTERS
from .properties import _construct, _is_mesh_attribute, _Props
from .xmlparse import Node

_RECOMPUTE = object()   # a mesh's vertex normals still to be computed (ShapeLoader._mesh)
# Known Mitsuba 3 plugins the core does not support (for a clearer message than "unknown").
_MITSUBA_SHAPES = {"shapegroup", "instance", "merge"}


def _shape_class(name: str):
    """The core's shape class ``name`` (``links1.geometry.shapes`` / ``links1.geometry.blob``); the
    loader's tests put recording stubs in its place."""
    if name == "Blob":
        return blob.Blob
    return getattr(shapes, name)


def _frame(d: np.ndarray) -> np.ndarray:
    """Mitsuba's ``Frame3f(d)`` (:func:`links1.maths.vec.coordinate_system`) as a 3x3 matrix with
    columns (s, t, n)."""
    s, t = coordinate_system(np.asarray(d, dtype=np.float64))
    return np.stack([s, t, d], axis=1)


def _check_invertible(node: Node, m: np.ndarray, what: str = "to_world") -> None:
    """A shape's map must be invertible and in range (:func:`links1.scene.params.transform_problem`)."""
    problem = params.transform_problem(m, what)
    if problem is not None:
        raise node.error(problem)
    lin = m[:3, :3]
    scale = max(float(np.max(np.abs(lin))), 1e-300)
    det = float(np.linalg.det(lin / scale))
    if not (np.isfinite(det) and abs(det) > 1e-12):
        raise node.error(f"singular {what} transform (relative determinant {det:g}): "
                         "the shape would be degenerate")


class ShapeLoader:
    """Shapes (methods of the loader's builder)."""

    def _shapegroup(self, node: Node) -> list:
        """The shapes of a ``shapegroup`` (checked once per use; Mitsuba's rules: shapes only,
        no nested groups or instances, no area emitters)."""
        _Props(node).finish()
        members = []
        for _, child in node.children:
            if child.tag != "shape":
                raise child.error(f"<{child.tag}> is not allowed in a shapegroup (only shapes)")
            if child.type in ("shapegroup", "instance"):
                raise child.error("nested instancing is not supported (as in Mitsuba)")
            if child.objects("emitter"):
                raise child.error("a shape in a shapegroup cannot be an emitter (as in Mitsuba)")
            members.append(child)
        return members

    def _instance(self, node: Node) -> list:
        """An ``instance`` of a ``shapegroup``: copies of the group's shapes, each mapped by the
        instance's ``to_world`` after its own (the core flattens instances; Mitsuba shares
        them, which renders the same image)."""
        props = _Props(node)
        outer = props.transform()
        outer = np.eye(4) if outer is None else outer
        groups = [child for _, child in node.children if child.tag == "shape" and child.type == "shapegroup"]
        for _, child in node.children:
            if not (child.tag == "shape" and child.type == "shapegroup"):
                raise child.error(f"<{child.tag}> is not allowed in an instance (only a <ref> to a shapegroup)")
        if len(groups) != 1:
            raise node.error("an instance needs exactly one shapegroup (<ref id=\"...\"/>)")
        _check_invertible(node, outer)
        props.finish()
        return [self.shape(member, outer=outer) for member in self._shapegroup(groups[0])]

    def shape(self, node: Node, outer: np.ndarray | None = None):
        """One shape; ``outer``: the transformation of the instance it is drawn through."""
        t = node.type
        props = _Props(node)
        name = node.id or ""
        to_world = props.transform()
        if outer is not None:
            to_world = outer if to_world is None else outer @ to_world
        m = np.eye(4) if to_world is None else to_world
        if t == "sphere":
            center = props.vec3("center", (0.0, 0.0, 0.0))
            radius = props.float("radius", 1.0, positive=True)
            self._no_flip(props)
            full = m @ tf.translate(center) @ tf.scale(radius)
            _check_invertible(node, full)
            shape = _construct(node, _shape_class("Quadric"), "sphere", full, clips=[], capped=False,
                               name=name)
        elif t == "cylinder":
            p0 = props.vec3("p0", (0.0, 0.0, 0.0))
            p1 = props.vec3("p1", (0.0, 0.0, 1.0))
            radius = props.float("radius", 1.0, positive=True)
            self._no_flip(props)
            axis = p1 - p0
            length = float(np.linalg.norm(axis))
            if not length > 0:
                raise node.error("cylinder: p0 and p1 coincide")
            frame = np.eye(4)
            frame[:3, :3] = _frame(axis / length)
            full = m @ tf.translate(p0) @ frame @ tf.scale([radius, radius, length])
            _check_invertible(node, full)
            clips = [(np.array([0.0, 0.0, -1.0]), 0.0), (np.array([0.0, 0.0, 1.0]), 1.0)]
            shape = _construct(node, _shape_class("Quadric"), "cylinder", full, clips=clips,
                               capped=False, name=name)
        elif t == "disk":
            flip = props.bool("flip_normals", False)
            m = params.planar_to_world(m)   # zero thickness is still a disk
            _check_invertible(node, m)
            shape = _construct(node, _shape_class("Disk"), m, name=name, flip=flip)
        elif t in ("rectangle", "cube"):
            if t == "rectangle":
                m = params.planar_to_world(m)   # zero thickness is still a rectangle
            v, f, n, uv = (meshes.rectangle_mesh if t == "rectangle" else meshes.cube_mesh)(uv=True)
            shape = self._mesh(node, props, v, f, n, m, closed=(t == "cube"), uv=uv)
        elif t in ("obj", "ply", "serialized"):
            fn = props.string("filename")
            path = node.resolve(fn)
            index = props.int("shape_index", 0, minimum=0) if t == "serialized" else 0
            try:
                if t == "obj":
                    (v, f, n, uv), attrs = mesh_files.read_obj(path, uv=True), {}
                elif t == "ply":
                    v, f, n, uv, attrs = mesh_files.read_ply(path, uv=True, attributes=True)
                else:
                    (v, f, n, uv), attrs = mesh_files.read_serialized(path, index), {}
            except ValueError as exc:
                raise props.error("filename", str(exc)) from None
            if props.bool("face_normals", False):
                n = None
            elif n is None:
                n = _RECOMPUTE
            if t != "serialized" and uv is not None and props.bool("flip_tex_coords", t == "obj"):
                uv = uv * np.array([1.0, -1.0]) + np.array([0.0, 1.0])  # Mitsuba: v -> 1 - v
            if t != "serialized":
                props.ignore("mesh_attributes", "flip_tex_coords")
            shape = self._mesh(node, props, v, f, n, m, closed=None, uv=uv, attributes=attrs)
        elif t == "links1_quadric":
            shape = self._quadric(node, props, m, name)
        elif t == "links1_blob":
            shape = self._blob(node, props, to_world, name)
        elif t == "links1_bicubic":
            shape = self._bicubic(node, props, m)
        elif t == "sdfgrid":
            shape = self._sdfgrid(node, props, m, name)
        elif t in ("linearcurve", "bsplinecurve"):
            shape = self._curves(node, props, m, name)
        elif t in ("ellipsoids", "ellipsoidsmesh"):
            if outer is not None:
                raise node.error(f"{t} in an instance is not supported by the core")
            shape = self._ellipsoids(node, props, m, name)
        elif t in _MITSUBA_SHAPES:
            raise node.error(f"shape type '{t}' is not supported by the core")
        else:
            raise node.error(f"unknown plugin '{t}' (shape)")

        # nested objects: bsdf, area emitter
        material, emission = None, None
        for cname, child in node.children:
            if child.tag == "bsdf":
                if material is not None:
                    raise child.error("a shape can have only one bsdf")
                material = self.bsdf(child)
            elif child.tag == "emitter":
                if child.type in _IGNORED_EMITTERS:   # directionalarea: an area emitter of its own kind
                    child.warn(f"emitter '{child.type}' is not supported by the core and is ignored")
                    _Props(child).ignore(*child.props)
                    continue
                if child.type != "area":
                    raise child.error(f"emitter '{child.type}' cannot be nested in a shape "
                                      "(only 'area')")
                if emission is not None:
                    raise child.error("a shape can have only one area emitter")
                ep = _Props(child)
                emission = (ep.color if _is_mesh_attribute(child, "radiance") else ep.texture)(
                    "radiance", 1.0, emitter=True)
                ep.finish()
                emitter_node = child
            elif child.tag in ("medium",):
                child.warn("media are not supported by the core and are ignored")
            elif child.tag == "shape" and cname == "shell" and t in ("ellipsoids", "ellipsoidsmesh"):
                continue   # an ellipsoidsmesh's shell template (read by _ellipsoids)
            else:
                raise child.error(f"<{child.tag}> is not allowed inside a shape")
        if material is None:
            # Mitsuba's default BSDF: diffuse 0.5, black on an emitting shape (its Shape does so)
            material = mat.Diffuse(reflectance=np.full(3, 0.0 if emission is not None else 0.5))
        props.finish()
        for k, tex in vars(material).items():   # a mesh_attribute must name one of the mesh's
            if isinstance(tex, textures.MeshAttribute) and tex.attribute not in getattr(shape, "attributes", {}):
                raise node.error(f"the bsdf's '{k}' reads mesh attribute '{tex.attribute}', which this "
                                 f"{t} does not have (it has: {', '.join(sorted(getattr(shape, 'attributes', {}))) or 'none'})")
        shape.material = material
        shape.emission = emission
        if emission is not None:
            shape._emitter_node = emitter_node
        return shape

    def _sdfgrid(self, node, props, m, name):
        """Mitsuba's ``sdfgrid``: a ``.vol`` grid over [0, 1]³ placed by ``to_world``."""
        path = node.resolve(props.string("filename"))
        normals = props.string("normals", "smooth")
        if normals not in ("smooth", "analytic"):
            raise props.error("normals", f"normals must be 'analytic' or 'smooth', got {normals!r}")
        try:
            grid = sdfgrid.read_vol(path)
        except (OSError, ValueError) as exc:
            raise props.error("filename", str(exc)) from None
        if grid.shape[3] != 1:
            raise props.error("filename", f"{path}: an SDF grid has 1 channel, this one {grid.shape[3]}")
        _check_invertible(node, m)
        return _construct(node, sdfgrid.SDFGrid, grid, m, normals=normals, name=name)

    def _curves(self, node, props, m, name):
        """Mitsuba's ``linearcurve`` / ``bsplinecurve``: control points moved by ``to_world``,
        radii as written."""
        linear = node.type == "linearcurve"
        path = node.resolve(props.string("filename"))
        props.ignore("silhouette_sampling_weight")
        try:
            cs = curves.read_curves(path, min_points=2 if linear else 4)
        except (OSError, ValueError) as exc:
            raise props.error("filename", str(exc)) from None
        placed = [np.concatenate([c[:, :3] @ m[:3, :3].T + m[:3, 3], c[:, 3:]], axis=1) for c in cs]
        return _construct(node, curves.RoundLinearCurves if linear else curves.RoundBSplineCurves,
                          placed, name=name)

    def _ellipsoids(self, node, props, m, name):
        """Mitsuba's ``ellipsoids`` / ``ellipsoidsmesh`` from a PLY file (a scene file cannot
        hold their tensors), placed by ``to_world`` as Mitsuba places them."""
        for key in ("data", "centers", "scales", "quaternions"):
            if props.has(key):
                raise props.error(key, f"'{key}' is a tensor, which a scene file cannot give; "
                                       "give 'filename' (a PLY file)")
        if node.objects("emitter"):
            raise node.error(f"an area emitter on {node.type} cannot be sampled (Mitsuba 3.9.1 "
                             "has no sampling for it)")
        path = node.resolve(props.string("filename"))
        scale_factor = props.float("scale_factor", 1.0, positive=True)
        extent = props.float("extent", ell.DEFAULT_EXTENT, positive=True)
        adaptive = props.bool("extent_adaptive_clamping", False)
        props.ignore("silhouette_sampling_weight")
        _check_invertible(node, m)
        try:
            centers, rotations, scales, opacities = ell.read_ellipsoids(path, m, scale_factor)
        except (OSError, ValueError) as exc:
            raise props.error("filename", str(exc)) from None
        if adaptive and opacities is None:
            node.warn("extent_adaptive_clamping needs an 'opacities' attribute; ignored (as Mitsuba)")
        try:
            ext = ell.extents(len(centers), extent, opacities if adaptive else None)
        except ValueError as exc:
            raise props.error("extent_adaptive_clamping", f"{path}: {exc}") from None
        scales = scales * ext[:, None]
        nested = [child for cname, child in node.children if child.tag == "shape" and cname == "shell"]
        if node.type == "ellipsoids":
            props.ignore("shell")   # Mitsuba skips it there
            return _construct(node, ell.Ellipsoids, centers, rotations, scales, name=name)
        props.ignore("face_normals")   # no vertex normals: always face normals
        if nested:
            mesh = self.shape(nested[0])
            if not hasattr(mesh, "faces"):
                raise nested[0].error("an ellipsoidsmesh shell must be a triangle mesh")
            template = (mesh.vertices, mesh.faces)
        else:
            template = props.string("shell", "ico_sphere")
        try:
            template = ell.shell(template)
        except ValueError as exc:
            raise (props.error("shell", str(exc)) if not nested else nested[0].error(str(exc))) from None
        return _construct(node, ell.EllipsoidsMesh, centers, rotations, scales, template,
                          flip=props.bool("flip_normals", False), name=name)

    def _no_flip(self, props: _Props) -> None:
        if props.bool("flip_normals", False):
            props.node.warn("flip_normals is not supported on analytic shapes by the core; ignored")

    def _mesh(self, node, props, v, f, n, m, closed, uv=None, attributes=None):
        """A triangle mesh placed by ``m``; ``n``: vertex normals, None (face normals) or
        ``_RECOMPUTE`` (Mitsuba's angle-weighted normals of the placed mesh, as it computes them
        after ``to_world``)."""
        recompute = n is _RECOMPUTE
        n = None if recompute else n
        rewound = props.bool("flip_normals", False)
        if rewound:
            f, n = meshes.flip(f, n)
        _check_invertible(node, m)   # normals map by its inverse transpose
        if n is not None and np.linalg.det(m[:3, :3]) < 0:
            # a mirroring to_world turns the winding but not the given normals: Mitsuba's
            # BSDFs and area emitters follow the normals, so the faces are turned back
            f, rewound = f[:, [0, 2, 1]], not rewound
        v, n = meshes.transform_mesh(m, v, n)
        if not np.all(np.isfinite(v)):
            raise node.error("non-finite vertex positions after to_world")
        if recompute:
            n = meshes.angle_weighted_normals(v, f)
        return _construct(node, _shape_class("TriangleMesh"), v, f, normals=n, name=node.id or "",
                          closed=closed, texcoords=uv, rewound=rewound, attributes=attributes)

    def _quadric(self, node, props, m, name):
        kind = props.links1("links1_quadric", "kind")
        _check_invertible(node, m)
        clips = []
        k = 0
        while props.has(f"clip_{k}"):
            try:
                nrm, h = params.clip_plane(k, props.vec3(f"clip_{k}", kinds=("vector", "point")),
                                           props.float(f"clip_{k}_offset", params.default("links1_quadric", "clip_offset")))
            except ValueError as exc:
                raise props.error(f"clip_{k}", str(exc)) from None
            clips.append((nrm, h))
            k += 1
        for pname in node.props:
            if re.fullmatch(r"clip_\d+(_offset)?", pname) and pname not in props.used:
                raise props.error(pname, f"'{pname}' without the planes before it "
                                         f"(clip planes are numbered clip_0, clip_1, ...)")
        capped = props.links1("links1_quadric", "capped")
        return _construct(node, _shape_class("Quadric"), kind, m, clips=clips, capped=capped,
                          name=name)

    def _blob(self, node, props, to_world, name):
        try:
            c = params.blob_centers(props.string("centers"))
        except ValueError as exc:
            raise props.error("centers", str(exc)) from None
        threshold = props.links1("links1_blob", "threshold")
        solver = props.links1("links1_blob", "solver")
        samples = props.links1("links1_blob", "samples")
        if to_world is not None:
            _check_invertible(node, to_world)
        return _construct(node, _shape_class("Blob"), c, threshold, solver=solver, samples=samples,
                          to_world=to_world, name=name)

    def _bicubic(self, node, props, m):
        has_file, has_inline = props.has("filename"), props.has("control_points")
        if has_file == has_inline:
            raise node.error("links1_bicubic needs exactly one of 'filename' and 'control_points'")
        try:
            if has_file:
                patches = bezier.read_patches(node.resolve(props.string("filename")))
            else:
                p = props.required("control_points", ("string",))
                patches = bezier.parse_patches(p.value, f"{p.file}:{p.line}", with_count=False)
        except ValueError as exc:
            raise props.error("filename" if has_file else "control_points", str(exc)) from None
        sub = props.links1("links1_bicubic", "subdivisions")
        v, f, n = bezier.tessellate_patches(patches, sub)
        if props.bool("face_normals", False):
            n = None
        return self._mesh(node, props, v, f, n, m, closed=None)
