"""The per-scene tables of ``links1_whitted`` (their one home): ``prepare`` turns a Mitsuba scene
into what the kernels read (slots in file order, ray offsets, materials, shadow transmittance,
emission, lights, camera, custom shapes, their BVH and light buffers), rebuilt only when the scene changes
(:class:`~links1_mitsuba.paramwatch.ParamWatch`: by the Dr.Jit variables of its parameters,
nothing read back). Its neighbours by job: the tables' schema (prepared.py), the parameter watch
(paramwatch.py), the camera views (views.py), which shadow rays a scene needs (shadow_plan.py),
the analytic lights' entries (lights.py), the links1 shapes (sceneshapes.py).

What a scene doesn't need is not traced (decided once per scene in ``prepare``): no
refraction code without transmissive surfaces, no reflection without reflective ones, no loop
at all without either, no custom-shape code without custom shapes, no blob solver without
blobs, no shadow ray toward a light from a hit that no shape can shadow (``shadow_plan``: a
lone convex shape, a floor below every other shape and the light, ...).

:class:`Tables` is one part of the ``Engine`` (engine.py), which hands each ``prepare`` the
frame's switches; its methods name ``mi.Float``, ``mi.Ray3f``, ... when called, so the class
serves every Mitsuba variant.
"""
from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from links1.shading.lights import ENV_LIGHT_ID, number_area_lights

import drjit as dr
import mitsuba as mi

from . import lightbuffer, proxies, views
from .bvh import QuadricBVH
from .config import Config
from .intersect import KIND_DISK, KIND_MESH, KIND_RECT, KIND_SPHERE, ROW, face_floats
from .launch import Launches, literal_key
from .lights import ConstantEnvRecord, EnvMapRecord, analytic_light, area_table, envmap_table
from .normals import held_positions, llvm, settle_moved
from .paramwatch import ParamWatch, own_param
from .prepared import LIGHT_FIELDS, PHONG_TABLES, SHAPE_FIELDS, Prepared
from .registered import plugin_class
from .sceneshapes import SceneShapes
from .shadow_plan import eye_lights, plan_occluders, shadow_split
from .tuning import Tuning
from .util import PLAIN_MESHES, checked_index, kind_of, table

#: Relative ray-origin offset on shapes whose float32 hits are accurate to a few ulps
#: (meshes, rectangles, disks, links1 quadrics): a small offset keeps shadow rays that graze
#: an object on the same side as the float64 core. Mitsuba's sphere/cylinder and links1
#: blobs (iterative roots) use Mitsuba's RayEpsilon (self-shadowing otherwise).
OFFSET_EPS = 2.0 ** -19
#: The most bytes of a scene's per-face table (:class:`MeshRecord` ``packets``): a bigger
#: table is not made, the kernel gathering each hit's face and vertices from the mesh buffers
FACE_PACKETS_MAX_BYTES = 1 << 28
#: a geometry update of the links1 shapes alone (``Tables._update_values``) keeps the launches'
#: scene input (:class:`~.launch.SceneInputs`: the update replaces none of the Mitsuba scene's
#: variables, only the integrator's) and starts from the literals' key the last update left
#: (:func:`_geometry_literals` walked once an update, not twice); False: both made anew
GEO_UPDATE_KEPT = True
_PRECISE_MITSUBA = ("Mesh", "OBJMesh", "PLYMesh", "Rectangle", "Disk", "Links1Bicubic", "SerializedMesh")


#: a Mitsuba rectangle's faces and texture coordinates (rectangle.cpp), which its row assumes
_RECT_FACES = np.array([1, 2, 0, 1, 3, 2], dtype=np.uint32)
_RECT_UV = np.array([0, 0, 1, 0, 0, 1, 1, 1], dtype=np.float32)


def _record_kind(s):
    """``s``'s kind for :class:`MeshRecord`, or None where the kernel does not make its record."""
    if s.class_name() == "Rectangle" and _rect_row(s) is not None:
        return KIND_RECT
    if s.is_mesh() and s.class_name() in PLAIN_MESHES:
        return KIND_MESH
    return {"Sphere": KIND_SPHERE, "Disk": KIND_DISK}.get(s.class_name())


def _rect_row(s):
    """Rectangle ``s``'s row (:class:`MeshRecord`): its four vertices, then the normal that all
    four carry; None where its buffers are not those the row assumes."""
    faces = np.asarray(s.faces_buffer(), dtype=np.uint32)
    uv = np.asarray(s.vertex_texcoords_buffer(), dtype=np.float32) if s.has_vertex_texcoords() else None
    n = np.asarray(s.vertex_normals_buffer(), dtype=np.float32).reshape(-1, 3) if s.has_vertex_normals() else None
    if (uv is None or n is None or not np.array_equal(faces, _RECT_FACES) or not np.array_equal(uv, _RECT_UV)
            or not (n.view(np.uint32) == n[0].view(np.uint32)).all()):
        return None
    row = np.zeros(ROW, dtype=np.float32)
    row[:12] = np.asarray(dr.detach(s.vertex_positions_buffer()), dtype=np.float32)
    row[12:15] = n[0]
    return row


@dataclasses.dataclass(eq=False)
class MeshRecord:
    """What the kernel makes the nearest hit's surface record from (``intersect.mesh_surface``)
    on the scene's Mitsuba shapes. Meshes: their buffers, one mesh's own or all of them in one
    (faces renumbered past the earlier meshes' vertices): faces (3 a face), vertex positions
    (3 a vertex), vertex normals and texture coordinates (None where no mesh has them; zeros
    for a mesh without), and per slot its first face (None: one mesh), whether it has
    normals / texture coordinates (None: every mesh or none) and whether its normals are
    flipped (None: none); ``faces`` None where the scene has no mesh. Rectangles, spheres and
    disks: a row of :data:`ROW` floats a slot (``rows``; None where there are none): a
    rectangle's four vertices (12) and the normal all four carry (3); the linear part of a
    sphere's or disk's ``to_world`` (9, row by row), then a sphere's center (3) and
    ``to_world``'s inverse (12, row by row: ``AffineTransform4f::inverse``, the transposed
    ``inverse_transpose``), a disk's normal (3: ``m_frame.n``). ``kinds``: the kinds present;
    ``kind``: each slot's (None: one kind); ``flip`` marks the meshes, rectangles and spheres
    whose normals are flipped (a sphere's: also by a negative scale). Instances of shapegroups
    (their members are slots of their own, as any shape): a row each (:func:`_instance_row`),
    ``inst_base``, ``member_of``, ``slot_reg`` (:func:`_instance_tables`; None: no instances)
    and ``inst_obj``, whether a member makes its point from the ray (a sphere, a disk: the ray
    is taken to the group's space). ``packets``: per face (the meshes' faces numbered as in
    ``faces``) what a hit on it reads, contiguous: its three vertices' positions (9 floats),
    then their normals (9) where ``normals`` is not None, their texture coordinates (6) where
    ``texcoords`` is not None, zeros up to a multiple of ``intersect.PACKET`` floats (the kernel
    reads them ``PACKET`` at a time: one packet gather each, in place of the face's index and
    its vertices' gathers); None where there are no meshes or the table would pass
    :data:`FACE_PACKETS_MAX_BYTES` (the kernel reads the buffers)."""

    faces: object
    positions: object
    normals: object = None
    texcoords: object = None
    face_off: object = None
    has_n: object = None
    has_uv: object = None
    flip: object = None
    kinds: frozenset = frozenset({KIND_MESH})
    kind: object = None
    #: where both ``kind`` and ``face_off`` are: per slot ``face_off << 2 | kind`` (UInt32)
    kind_face: object = None
    rows: object = None
    inst_base: object = None
    member_of: object = None
    slot_reg: object = None
    inst_obj: bool = False
    packets: object = None


def _analytic_row(s, kind):
    """The :data:`ROW` floats of rectangle, sphere or disk ``s`` (:class:`MeshRecord`): a
    rectangle's :func:`_rect_row`; made from a sphere's or disk's ``to_world`` (the sphere's
    center with the operations of ``Sphere::update``, ``to_world * Point3f(0)``), the disk's
    normal read from Mitsuba (``sample_position``'s, ``m_frame.n``)."""
    if kind == KIND_RECT:
        return _rect_row(s)
    tw = dr.detach(own_param(s, "to_world"))
    m = np.asarray(tw.matrix, dtype=np.float32).reshape(4, 4)
    row = np.zeros(ROW, dtype=np.float32)
    row[:9] = m[:3, :3].ravel()
    if kind == KIND_SPHERE:
        row[9:12] = np.asarray(tw @ mi.Point3f(0.0), dtype=np.float32).ravel()
        inv = np.asarray(tw.inverse_transpose, dtype=np.float32).reshape(4, 4).T
        row[12:24] = inv[:3, :].ravel()
    else:
        # (Mitsuba's own bits: Disk::update's may be folded on the host, 1 / sqrt there)
        row[9:12] = np.asarray(s.sample_position(0.0, mi.Point2f(0.5)).n, dtype=np.float32).ravel()
    return row


def _mesh_record_table(shapes, slot_list, nslots, scene, reg):
    """:class:`MeshRecord` where every Mitsuba shape of the scene is a mesh, rectangle, sphere
    or disk, or an instance of shapegroups of them, else None (the kernel reads Mitsuba's record,
    ``scene.ray_intersect``: its surface call through the shapes' callables cost ~0.1 of a
    frame, docs/benchmarks.md). ``reg``: the shapes' registry ids."""
    inst = [s.class_name() == "Instance" for s in shapes]
    kinds = [None if i else _record_kind(s) for s, i in zip(shapes, inst)]
    if not shapes or any(k is None and not i for k, i in zip(kinds, inst)) or all(inst):
        return None
    if any(inst) and not llvm():
        return None   # (the member's slot comes from Embree's shape_index: _instance_tables)

    def per_slot(flags, dtype, sl_list=slot_list):
        out = np.zeros(max(nslots, 1), dtype=dtype)
        for sl, v in zip(sl_list, flags):
            out[sl] = v
        return out

    flip = [k is not None and k != KIND_DISK and s.has_flipped_normals() for s, k in zip(shapes, kinds)]
    rec = MeshRecord(faces=None, positions=None, flip=mi.Bool(per_slot(flip, bool)) if any(flip) else None,
                     kinds=frozenset(k for k in kinds if k is not None))
    if len(rec.kinds) > 1:
        rec.kind = mi.UInt32(per_slot([k or 0 for k in kinds], np.uint32))
    analytic = [(s, k, sl) for s, k, sl in zip(shapes, kinds, slot_list) if k != KIND_MESH]
    if analytic:
        rows = np.zeros((max(nslots, 1), ROW), dtype=np.float32)
        for s, k, sl in analytic:
            rows[sl] = _analytic_row(s, k) if k is not None else _instance_row(s)
        rec.rows = table(mi.Float, rows)   # 64-byte aligned: intersect._row's packet gathers
    if any(inst):
        _instance_tables(rec, shapes, slot_list, reg, inst, nslots, scene)
    meshes = [(s, sl) for s, k, sl in zip(shapes, kinds, slot_list) if k == KIND_MESH]
    if meshes:
        _mesh_buffers(rec, meshes, per_slot)
    return rec


def _instance_row(s):
    """Instance ``s``'s row (:class:`MeshRecord`): its ``to_world`` (12, row by row), the
    ``inverse_transpose`` that transforms normals (9, row by row) and the inverse (12, row by
    row: the transposed ``inverse_transpose``, ``AffineTransform4f::inverse``)."""
    tw = dr.detach(own_param(s, "to_world"))
    m = np.asarray(tw.matrix, dtype=np.float32).reshape(4, 4)
    it = np.asarray(tw.inverse_transpose, dtype=np.float32).reshape(4, 4)
    row = np.zeros(ROW, dtype=np.float32)
    row[:12] = m[:3, :].ravel()
    row[12:21] = it[:3, :3].ravel()
    row[21:33] = it.T[:3, :].ravel()
    return row


def _instance_tables(rec, shapes, slot_list, reg, inst, nslots, scene):
    """``rec``'s tables of the hits on instances (:class:`MeshRecord`): per instance slot the
    first entry of its shapegroup's block in ``member_of`` (``inst_base``), whose entry
    ``shape_index`` (Embree's index of the hit shape in the group) is the member's slot, and
    every slot's shape (``slot_reg``: a member's registry id, which Mitsuba's record names).
    Which member an instance's ``shape_index`` names is asked of Mitsuba: a preliminary hit
    made up for each instance and index, its record's shape (``ShapeGroup::
    compute_surface_interaction`` reads the group's own table). ``reg``: the shapes' registry
    ids."""
    reg_slot = dict(zip(reg, slot_list))
    groups = group_lists(scene)
    instances = [(s, sl) for s, sl, i in zip(shapes, slot_list, inst) if i]

    def members_named(ptrs, index):
        pi = dr.zeros(mi.PreliminaryIntersection3f, len(index))
        pi.valid, pi.t, pi.prim_uv = mi.Bool(True), mi.Float(1.0), mi.Point2f(0.25)
        pi.instance = dr.gather(mi.ShapePtr, mi.ShapePtr(ptrs), mi.UInt32(np.arange(len(index))))
        pi.shape_index = mi.UInt32(index)
        si = pi.compute_surface_interaction(mi.Ray3f(mi.Point3f(0.0), mi.Vector3f(0.0, 0.0, 1.0)),
                                            +mi.RayFlags.Minimal)
        return [int(r) for r in np.asarray(dr.reinterpret_array(mi.UInt32, si.shape))]
    # each instance's group: the one whose members hold its index 0's shape
    with dr.suspend_grad():
        firsts = members_named([s for s, _ in instances], np.zeros(len(instances), np.uint32))
    first_reg = {int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(g[0]))[0]): gi for gi, g in enumerate(groups) if g}
    member_of, base_of, inst_base = [], {}, np.zeros(max(nslots, 1), np.uint32)
    for (s, sl), f in zip(instances, firsts):
        gi = first_reg[f]
        if gi not in base_of:
            base_of[gi] = len(member_of)
            with dr.suspend_grad():
                named = members_named([s] * len(groups[gi]), np.arange(len(groups[gi]), dtype=np.uint32))
            member_of += [reg_slot[r] for r in named]
        inst_base[sl] = base_of[gi]
    slot_reg = np.zeros(max(nslots, 1), np.uint32)
    for r, sl in reg_slot.items():
        slot_reg[sl] = r
    rec.inst_base, rec.member_of, rec.slot_reg = mi.UInt32(inst_base), mi.UInt32(member_of), mi.UInt32(slot_reg)
    rec.inst_obj = bool(rec.kinds & {KIND_SPHERE, KIND_DISK})


def _mesh_buffers(rec, meshes, per_slot):
    """``rec``'s mesh buffers (:class:`MeshRecord`) of ``meshes`` (``[(mesh, slot)]``)."""
    # (detached: the launches read primal values; attached vertices stay the derivative pass's)
    bufs = [dict(faces=dr.detach(s.faces_buffer()), positions=dr.detach(s.vertex_positions_buffer()),
                 normals=dr.detach(s.vertex_normals_buffer()) if s.has_vertex_normals() else None,
                 texcoords=dr.detach(s.vertex_texcoords_buffer()) if s.has_vertex_texcoords() else None)
            for s, _ in meshes]
    slots = [sl for _, sl in meshes]
    has_n = [b["normals"] is not None for b in bufs]
    has_uv = [b["texcoords"] is not None for b in bufs]

    def mixed(flags):
        return mi.Bool(per_slot(flags, bool, slots)) if any(flags) and not all(flags) else None

    rec.has_n, rec.has_uv = mixed(has_n), mixed(has_uv)
    if len(meshes) == 1:
        b = bufs[0]
        rec.faces, rec.positions, rec.normals, rec.texcoords = b["faces"], b["positions"], b["normals"], b["texcoords"]
        rec.packets = _face_packets(rec)
        return
    nv = [dr.width(b["positions"]) // 3 for b in bufs]
    nf = [dr.width(b["faces"]) // 3 for b in bufs]
    voff, foff = np.cumsum([0] + nv[:-1]), np.cumsum([0] + nf[:-1])
    rec.faces = mi.UInt32(np.concatenate([np.asarray(b["faces"], dtype=np.uint32) + np.uint32(o)
                                          for b, o in zip(bufs, voff)]))
    rec.positions = mi.Float(np.concatenate([np.asarray(b["positions"], dtype=np.float32) for b in bufs]))
    if any(has_n):
        rec.normals = mi.Float(np.concatenate([np.asarray(b["normals"], dtype=np.float32) if h
                                               else np.zeros(3 * k, np.float32) for b, h, k in zip(bufs, has_n, nv)]))
    if any(has_uv):
        rec.texcoords = mi.Float(np.concatenate([np.asarray(b["texcoords"], dtype=np.float32) if h
                                                 else np.zeros(2 * k, np.float32) for b, h, k in zip(bufs, has_uv, nv)]))
    rec.face_off = mi.UInt32(per_slot(foff, np.uint32, slots))
    if rec.kind is not None and int(foff[-1]) < 2 ** 30:
        rec.kind_face = mi.UInt32((np.asarray(rec.face_off, dtype=np.uint32) << np.uint32(2))
                                  | np.asarray(rec.kind, dtype=np.uint32))
    rec.packets = _face_packets(rec)


def _face_packets(rec):
    """``rec``'s per-face table (:class:`MeshRecord` ``packets``) made from its mesh buffers, in
    64-byte aligned memory (``util.table``: numpy's 16-byte aligned one made the kernel 1.1x
    slower on ``cbox_point``), or None where it would pass :data:`FACE_PACKETS_MAX_BYTES`."""
    nf = dr.width(rec.faces) // 3
    k = face_floats(rec)
    if nf * k * 4 > FACE_PACKETS_MAX_BYTES:
        return None
    f = np.asarray(rec.faces, dtype=np.int64).reshape(-1, 3)
    cols = [np.asarray(rec.positions, dtype=np.float32).reshape(-1, 3)[f].reshape(nf, 9)]
    if rec.normals is not None:
        cols.append(np.asarray(rec.normals, dtype=np.float32).reshape(-1, 3)[f].reshape(nf, 9))
    if rec.texcoords is not None:
        cols.append(np.asarray(rec.texcoords, dtype=np.float32).reshape(-1, 2)[f].reshape(nf, 6))
    t = np.zeros((nf, k), dtype=np.float32)
    t[:, :sum(c.shape[1] for c in cols)] = np.concatenate(cols, axis=1)
    return table(mi.Float, t)


def _textured(bsdf) -> bool:
    """Whether a Mitsuba BSDF has a texture (bitmap and checkerboard expose ``to_uv``)."""
    import mitsuba as mi
    return bsdf is not None and any(k.endswith("to_uv") for k in mi.traverse(bsdf).keys())


#: Mitsuba's spectra of one value (``rgb``, a float): a ``diffuse`` BSDF's reflectance that
#: the kernel reads from a table (:func:`_uniform_diffuse`)
_UNIFORM_SPECTRA = ("SRGBReflectanceSpectrum", "UniformSpectrum")


def _uniform_diffuse(b):
    """``(spectrum, twosided)`` of a Mitsuba ``diffuse`` BSDF whose reflectance is one value
    (``rgb`` or a float, no texture), alone or as the one BSDF of a ``twosided`` (its front and
    back, Mitsuba 3.9.1's twosided.cpp: ``m_brdf[0] == m_brdf[1]``); None for any other BSDF."""
    if b is None or b.class_name() not in ("SmoothDiffuse", "TwoSidedBRDF"):
        return None
    two = b.class_name() == "TwoSidedBRDF"
    params = mi.traverse(b)
    key = "brdf_0.reflectance.value" if two else "reflectance.value"
    if list(params.keys()) != [key]:    # (two: brdf_1 is another BSDF)
        return None
    node = params.properties[key][2]
    parent = params.hierarchy[node][0] if node in params.hierarchy else None
    if node.class_name() not in _UNIFORM_SPECTRA or parent is None or \
            parent.class_name() != "SmoothDiffuse":
        return None
    return node, two


def _spectrum_rgb(node):
    """The value of a spectrum of one value (:data:`_UNIFORM_SPECTRA`) as 3 float32 (a float
    spread over RGB, as its ``eval``), or None when it holds another number of values."""
    v = np.array(own_param(node, "value"), dtype=np.float32).ravel()
    return np.repeat(v, 3) if v.size == 1 else v if v.size == 3 else None


def _spawn_table(is_phong, refl, trans, mitsuba_delta):
    """Per slot, whether a hit there can spawn a child (``Prepared.spawns``): a links1_phong
    slot whose reflectance or transmittance is not zero, a Mitsuba BSDF with a delta or Null
    lobe (``mitsuba_delta``)."""
    return mi.Bool(mitsuba_delta | (is_phong & ((refl.max(1) > 0) | (trans.max(1) > 0))))


def _unmask(mi, b):
    """The BSDF a Mitsuba ``mask`` (nested masks too) wraps; ``b`` itself if it is no mask."""
    while kind_of(b) == "Mask":
        kids = [k for k, (parent, depth) in mi.traverse(b).hierarchy.items()
                if depth == 1 and isinstance(k, mi.BSDF)]
        if len(kids) != 1:
            break
        b = kids[0]
    return b


def group_lists(scene) -> list:
    """The shapes inside each of the scene's ``shapegroup``s, group by group in the scene's
    order, each shape once (:func:`group_members`)."""
    found, seen = [], set()

    class Collect(mi.TraversalCallback):
        def put(self, name, value, flags, cpptype=None):
            if isinstance(value, mi.Shape) and id(value) not in seen:
                seen.add(id(value))
                found.append(value)

    scene.traverse(Collect())
    groups = [s for s in found if s.class_name() == "ShapeGroupPlugin"]
    lists = []
    for g in groups:
        found.clear()
        g.traverse(Collect())
        lists.append([s for s in found if s.class_name() not in ("ShapeGroupPlugin", "Instance")])
    return lists


def group_members(scene) -> list:
    """The shapes inside the scene's ``shapegroup``s (drawn by its ``instance``s: a hit on one
    names the member, ``si.instance`` the instance), each once, in the scene's order."""
    return [s for g in group_lists(scene) for s in g]


def _geometry_literals(base):
    """What the frozen launches' kernels take as literals from the tables a geometry update
    makes anew (``launch.literal_key``): the shapes' tables (:data:`SHAPE_FIELDS`), the
    tables planned from the lights and the shapes' bounds (:data:`LIGHT_FIELDS`, without the
    planning's own host data ``occ_shapes``) and each camera view's eye buffer and lights at
    its eye (``shadow_plan.eye_lights``: a shape moved near the eye takes that rule away)."""
    return literal_key([getattr(base, f, None) for f in SHAPE_FIELDS + LIGHT_FIELDS if f != "occ_shapes"]
                       + [view.eye_buf for view in base.views.values()]
                       + [eye_lights(view) for view in base.views.values()])


def scene_identity(scene):
    """The scene's shapes, emitters and sensors as object identities (cheap: no parameters).
    Prepared tables keep those objects alive, so another scene's objects cannot take the
    same identities while the tables are kept."""
    ids = []
    for objs in (scene.shapes(), scene.emitters(), scene.sensors()):
        ids.append(len(objs))
        ids += [id(o) for o in objs]
    return tuple(ids)


class Tables:
    """``prepare``: the per-scene tables, brought up to changes in place where it can, and
    their camera views. Given the integrator's parameters ``config`` (``verify_scene``), its
    links1 shapes ``shapes`` (:class:`~.sceneshapes.SceneShapes`) and its launches
    (:class:`~.launch.Launches`: their recordings start anew when the tables they read are
    replaced or a constant of their kernels changes)."""

    __slots__ = (
        "config", "shapes", "launches",
        "last",            # the last prepared camera view (prepared.CameraView), or None
        "vertices",        # id(mesh) -> (mesh, its vertex positions when last seen): whether an
        #                    update moved them since (_settle_normals), for meshes with normals
        # -- counters (tests and benchmarks read them through Engine.info())
        "n_scene_builds", "n_camera_views", "n_value_updates",
        "geo_key",         # (tables, their views' keys, _geometry_literals of them) as the last
        #                    geometry update left them
    )

    def __init__(self, config: Config, shapes: SceneShapes, launches: Launches):
        self.config = config
        self.shapes = shapes
        self.launches = launches
        self.last = None
        self.vertices = {}
        self.n_scene_builds = self.n_camera_views = self.n_value_updates = 0
        self.geo_key = None

    def forget(self):
        """The next :meth:`prepare` checks nothing against the last tables: it builds them."""
        self.last = None

    def loaded(self, shapes):
        """Called by the loader: the vertex positions of the scene's meshes as loaded, their
        normals settled (``loader._settle_normals``): the first frame's
        :meth:`_settle_normals` tells which meshes an update moved since."""
        self.vertices = {id(s): (s, v) for s in shapes if (v := held_positions(s)) is not None}

    def prepare(self, scene, sensor, tuning: Tuning):
        """The tables of ``scene`` seen from ``sensor`` (a sensor object, an index into
        ``scene.sensors()``, or None: the scene's first sensor), rebuilt when the scene is
        another one or was changed; ``tuning``: the frame's switches (:class:`~.tuning.Tuning`).

        The scene's tables (shapes, materials, lights, shadow rays) are keyed on what they
        are built from, never on ``id(scene)``: the registry ids of the scene's shapes,
        emitters and sensors (the tables keep those objects alive, so no other scene can reuse the
        ids), the part of the tuning they are built from (``tuning.Tuning.tables_key``: light
        buffers, BVH), and, while ``verify_scene``, every parameter ``mi.traverse`` exposes, watched
        by its Dr.Jit variables (:class:`ParamWatch`: a ``params.update()`` after a render
        is seen, and nothing is read back from the device). ``n_scene_builds`` and
        ``n_camera_views`` count the tables built. Each sensor gets its own
        view of them (``views.camera_view``: camera, film, filter, eye buffer) as a distinct
        object, so a frozen launch recorded for one sensor's camera (``cfg`` holds the
        view's id) is never replayed for another."""
        if self.shapes.adopt(scene):     # another plainly loaded scene: its links1 shapes
            self.last = None
        ident = scene_identity(scene)
        base = getattr(self.last, "base", None)
        known = base is not None and base.ident == ident
        same = known and base.tuning.tables_key() == tuning.tables_key()
        if same and (not self.config.verify_scene or base.watch.unchanged(scene)):
            pass
        else:
            if self.config.verify_scene:
                self._settle_normals(scene, base if known else None)
            if not (same and self._update_values(base, scene)):
                # (after _update_values, the base's watch knows which parameters changed: the
                # new watch reads only those again)
                base = self._prepare_scene(scene, ident, tuning, base.watch if same else None)
        view, made = views.camera_view(base, scene, views.sensor_of(scene, sensor), self.config.verify_scene,
                                       self.shapes.place)
        self.n_camera_views += made
        self.last = view
        return view

    def _settle_normals(self, scene, base) -> None:
        """The vertex normals Mitsuba computed again, on its threads, for the meshes whose
        vertices a ``params.update()`` moved, computed once more on one thread before any table
        reads them (:func:`.normals.settle_moved`: the same bits at every update, those of a
        fresh ``links1_mitsuba.load_file``; normals the update set are kept). Moved since
        ``base``, as its watch saw; without one (the scene's first frame, or the tables
        forgotten), since the positions :attr:`vertices` holds: the loader's or those the last
        frame saw. A scene from plain ``mi.load_file`` has no record before its first frame:
        its meshes keep the normals Mitsuba made until then (which a file's could not be told
        from)."""
        if not llvm():
            return
        if base is not None:
            moved = [node for name, node in base.watch.changed(scene) or ()
                     if name == "vertex_positions" and isinstance(node, mi.Mesh)]
        else:
            ids = dr.detail.collect_indices
            now = {id(s): (s, v) for s in scene.shapes() if (v := held_positions(s)) is not None}
            moved = [s for k, (s, v) in now.items() if k in self.vertices and ids(self.vertices[k][1]) != ids(v)]
            self.vertices = now     # (this scene's meshes alone: another scene's are let go)
        settle_moved(moved)
        if base is not None:
            self.vertices.update({id(s): (s, v) for s in moved if (v := held_positions(s)) is not None})

    def _update_values(self, base, scene) -> bool:
        """The tables ``base`` brought up to a change of ``links1_phong`` coefficients, analytic
        lights or links1 shapes' geometry only (``params.update()``
        re-prepares what the change touches), in place:

        - coefficients: the material rows re-read from the BSDFs; the frozen launch is kept
          (the rows are its inputs); so is a ``diffuse`` reflectance's value that the kernel
          reads from its table (:meth:`_lambert_tables`);
        - a light's values (a ``links1_point``'s or ``links1_spot``'s, a Mitsuba point, spot or
          directional emitter's own parameters): its ``base.lights`` entry and the tables planned
          from the lights' places (:meth:`_shadow_tables`: shadow rays, light buffers); the
          frozen launches start anew (the lights are constants in their kernels);
        - a sensor's values (its ``to_world``, its film's size and crop): its camera view only
          (:meth:`_refresh_cameras`: camera, film, eye buffer, the launch's gathered inputs);
          the frozen launches start anew where the camera changed (a constant of their
          kernels), not for a crop window alone;
        - the links1 shapes' geometry (the integrator's parameters: a quadric's ``to_world``
          or clip offsets, a blob's centres, weights, radii, threshold; their specs already
          made anew by ``parameters_changed``): the shapes' tables (:meth:`_shape_tables`: the
          BVH built again over the same quadrics, the blob and quadric tables), the light
          tables (planned from the shapes' bounds too) and each camera view's eye buffer; the
          frozen launches are kept (the tables are their inputs) unless a value their kernels
          take as a literal changed (:func:`_geometry_literals`: a BVH's root box, the shadow
          rays' plan, a table's size, ...), then they start anew.

        Every other table (Mitsuba shapes, materials, emission, area and environment lights)
        is kept. False (the caller rebuilds all) for another scene or tuning, or any other
        change: a Mitsuba shape's or other object's (a light's texture, a sensor's sampler or filter too), a quadric that
        leaves or joins the BVH (its bounds become infinite or finite), or a Phong change that
        alters what the other tables are built from (the transmittance: shadow rays; which
        slots reflect or have ambient light: the kernels traced). ``n_value_updates`` counts
        the updates. Called by :meth:`prepare` only for tables of this scene and
        tuning, while ``verify_scene``, whose watch saw a change."""
        changed = base.watch.changed(scene)
        Phong = plugin_class("links1_phong")
        point_class, spot_class = plugin_class("links1_point"), plugin_class("links1_spot")
        if not changed:
            return False
        phong = any(isinstance(node, Phong) for _, node in changed)
        light = geo = lam = False
        lam_nodes = {id(v) for v in base.lam_src.values()}
        cams = []      # the scene's sensors whose own or film's values changed
        for _, node in changed:
            if isinstance(node, Phong):
                continue
            if id(node) in lam_nodes:         # a diffuse BSDF's reflectance (_lambert_tables)
                lam = True
                continue
            if node is scene.integrator():    # the links1 shapes' geometry (integrator.traverse)
                geo = True
                continue
            owner = views.sensor_owning(base, node)
            if owner is not None:
                if not any(owner is c for c in cams):
                    cams.append(owner)
                continue
            if not (isinstance(node, (point_class, spot_class)) or isinstance(node, mi.Emitter)
                    and kind_of(node) in ("PointLight", "SpotLight", "DirectionalEmitter")):
                return False
            light = True
        quad = None
        if geo:
            quad = self._bvh_quadrics(base)
            if frozenset(sp.slot for sp in quad) != base.bvh_slots:
                return False      # another split of the quadrics (one became unbounded)
        new, now = {}, None
        if phong:
            names = {k: PHONG_TABLES[k][0] for k in base.phong_np}   # (the transmittance: below)
            now = {k: np.zeros_like(v) for k, v in base.phong_np.items()}
            trans = np.zeros((base.nslots, 3))
            for sl, b in enumerate(base.keep_alive[3]):
                if isinstance(b, Phong):
                    p = b.params
                    for k, name in names.items():
                        now[k][sl] = p[name]
                    trans[sl] = p["transmittance"]
            if not (np.array_equal(trans, base.shadow_t_np) and bool(np.any(now["amb"] > 0)) == base.any_ambient
                    and bool(np.any(now["refl"].max(1) > 0)) == base.any_phong_r):
                return False
            # the tables whose values changed, made as _prepare_scene makes them (the same bits)
            new = {k: table(mi.Float, v) for k, v in now.items() if not np.array_equal(v, base.phong_np[k])}
            if not np.array_equal(now["refl"].max(1) > 0, base.phong_np["refl"].max(1) > 0):
                new["spawns"] = _spawn_table(base.is_phong_np, now["refl"], trans, base.mitsuba_delta_np)
        lam_now = None
        if lam:
            lam_now = base.lam_np.copy()
            for sl, node in base.lam_src.items():
                v = _spectrum_rgb(node)
                if v is None:       # no longer one value
                    return False
                lam_now[sl] = v
            if not np.array_equal(lam_now, base.lam_np):
                new["lam_rgb"] = table(mi.Float, lam_now)
        if light:
            lights = [L for e in scene.emitters()
                      for L in [analytic_light(e, kind_of(e), point_class, spot_class, base, self.shapes.place)]
                      if L is not None]
            if len(lights) != len(base.lights):
                return False
            base.lights = lights
        # (a geometry update replays the frozen launches unless it changed a literal of their kernels)
        kept = self.geo_key[2] if GEO_UPDATE_KEPT and self.geo_key is not None and self.geo_key[0] is base \
            and self.geo_key[1] == tuple(base.views) else None     # (a camera view made since: walked)
        self.geo_key = None
        literals = (kept if kept is not None else _geometry_literals(base)) if geo and not light else None
        if geo:
            self._shape_tables(base, quad)
        if light or geo:
            self._shadow_tables(base, scene, base.shape_list, base.slot_list, reuse=not geo)
        if light:
            self.launches.forget()   # (the lights are constants of their kernels)
        for k, v in new.items():
            setattr(base, k, v)
        if now is not None:
            base.phong_np = now
        if lam_now is not None:
            base.lam_np = lam_now
        if cams and views.refresh_cameras(base, scene, cams, geo, self.shapes.place):
            self.launches.forget()   # (the camera is a constant of their kernels)
        # the camera views read the new tables through base; of their own fields, the eye's
        # buffer follows the geometry and the launch's inputs are gathered again
        for view in (base, *base.views.values()) if phong or lam or light or geo else ():
            if geo and view is not base:   # the camera rays' buffer around the eye (views.camera_view)
                view.eye_buf = lightbuffer.plan_eye(view, scene) if base.tuning.light_buffer else None
            view.frozen_inputs = None       # gathered again: the new arrays are the launch's inputs
            if light or (geo and not GEO_UPDATE_KEPT) or not base.all_phong or base.any_mitsuba_emission:
                view.scene_input = None     # the scene's variables (the BSDFs' new values) too
            # (all links1_phong: the launch's scene input leaves them out, launch._unread_bsdfs)
        if literals is not None:
            now_key = _geometry_literals(base)
            if now_key != literals:
                self.launches.forget()   # (a literal of their kernels changed: another structure)
            self.geo_key = (base, tuple(base.views), now_key)
        base.watch = base.watch.renewed(scene)
        self.n_value_updates += 1
        return True

    def _prepare_scene(self, scene, ident, tuning, watch=None):
        """The tables of ``scene`` that do not depend on the sensor (:meth:`prepare`), built with
        ``tuning``; ``watch``: the last tables' (:meth:`ParamWatch.renewed`), or None."""
        base = Prepared()
        base.ident = ident
        base.tuning = tuning     # what the tables are built with (tables_key)
        # before the tables read the parameters
        base.watch = ParamWatch(scene) if watch is None else watch.renewed(scene)
        self.n_scene_builds += 1
        base.keep_alive = (list(scene.shapes()), list(scene.emitters()), list(scene.sensors()))  # see scene_identity
        base.views, base.obj_params = {}, {}
        # recordings hold the previous tables, and their key names the tables by id(base): a new
        # base may get a dead one's id, so both frozen launches start anew
        self.launches.forget()
        shapes, slot_list, nslots, base.member_slots = self._mitsuba_shapes(scene)
        base.shape_list, base.slot_list = shapes, slot_list
        base.nslots = nslots
        base.custom = self.shapes.custom
        # registry id -> slot
        reg = [int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(s))[0]) for s in shapes]
        reg_slot = np.full(max(reg + [0]) + 1, -1, dtype=np.int32)
        for r, sl in zip(reg, slot_list):
            reg_slot[r] = sl
        base.reg_to_slot = mi.Int32(checked_index(reg_slot, nslots, "reg_to_slot", sentinel=-1))
        # Embree's geometry ids: the shapes' indices in scene.shapes() (Mitsuba attaches them in
        # that order; on an instance the id is the member's in its group: none then; OptiX's
        # preliminary hits untried: none there)
        every = list(scene.shapes())
        if shapes and llvm() and not any(s.class_name() in ("Instance", "ShapeGroup") for s in every):
            by_reg = dict(zip(reg, slot_list))
            g2s = np.array([by_reg.get(int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(s))[0]), -1) for s in every],
                           dtype=np.int32)
            base.geom_to_slot = mi.Int32(checked_index(g2s, nslots, "geom_to_slot", sentinel=-1))
            base.geom_slot_identity = bool(np.array_equal(g2s, np.arange(len(every))))
        base.any_mitsuba_shapes = len(shapes) > 0
        base.mesh_record = _mesh_record_table(shapes, slot_list, nslots, scene, reg)
        eps_np = np.full(max(nslots, 1), float(mi.math.RayEpsilon), dtype=np.float32)
        for s_, sl in zip(shapes, slot_list):
            if s_.is_mesh() or kind_of(s_) in _PRECISE_MITSUBA:
                eps_np[sl] = OFFSET_EPS
        for spec in self.shapes.custom:
            if spec.__class__.__name__ == "QuadricSpec":
                eps_np[spec.slot] = OFFSET_EPS
        base.eps_table = mi.Float(eps_np)
        # materials
        default_bsdf = None
        bsdfs = [None] * nslots
        for s, sl in zip(shapes, slot_list):
            bsdfs[sl] = s.bsdf()
        for spec in self.shapes.custom:
            b = self.shapes.custom_bsdfs.get(spec.slot)
            if b is None:
                if default_bsdf is None:
                    default_bsdf = mi.load_dict({"type": "diffuse"})
                b = default_bsdf
            bsdfs[spec.slot] = b
        Phong = plugin_class("links1_phong")
        is_phong = np.zeros(nslots, dtype=bool)
        amb = np.zeros((nslots, 3)); dif = np.zeros((nslots, 3)); spe = np.zeros((nslots, 3))
        refl = np.zeros((nslots, 3)); trans = np.zeros((nslots, 3))
        expo = np.zeros(nslots); ior = np.ones(nslots)
        has_dr = np.zeros(nslots, dtype=bool); has_dt = np.zeros(nslots, dtype=bool)
        has_null = np.zeros(nslots, dtype=bool)
        glossy = np.zeros(nslots, dtype=bool)
        inner = list(bsdfs)   # the BSDF whose delta lobes a slot samples (a mask's nested one)
        warned = set()
        for sl, b in enumerate(bsdfs):
            if b is None:
                continue
            if isinstance(b, Phong):
                p = b.params
                is_phong[sl] = True
                amb[sl], dif[sl], spe[sl] = p["ambient"], p["diffuse"], p["specular"]
                refl[sl], trans[sl] = p["reflectance"], p["transmittance"]
                expo[sl], ior[sl] = p["exponent"], p["ior"]
            else:
                fl = int(b.flags())
                has_dr[sl] = bool(fl & int(mi.BSDFFlags.DeltaReflection))
                has_dt[sl] = bool(fl & int(mi.BSDFFlags.DeltaTransmission))
                # Null: a straight-through delta lobe (thindielectric's transmission, mask's
                # transparency, null); its weight is eval_null_transmission
                has_null[sl] = bool(fl & int(mi.BSDFFlags.Null))
                inner[sl] = _unmask(mi, b)
                if has_null[sl] and has_dt[sl]:
                    name = kind_of(b)
                    if ("null+dt", name) not in warned:
                        warned.add(("null+dt", name))
                        warnings.warn(f"links1_whitted: BSDF {name} has both a refracted and a "
                                      "straight-through transmission (a mask around a "
                                      "dielectric); the straight-through part is dropped",
                                      stacklevel=2)
                    has_null[sl] = False
                if fl & int(mi.BSDFFlags.Diffuse):
                    glossy[sl] = True    # (a BSDF sample as for glossy lobes: Mitsuba's direct)
                if fl & int(mi.BSDFFlags.Glossy):
                    glossy[sl] = True
                    name = kind_of(b)
                    where = self.shapes.place(b)
                    if (where, name) not in warned:     # once per element
                        warned.add((where, name))
                        warnings.warn(f"{where}: BSDF {name} has glossy lobes; it gets direct "
                                      "light only (its glossy interreflections are not Whitted's light paths)",
                                      stacklevel=2)
        base.is_phong_np = is_phong
        base.all_phong = bool(is_phong.all())
        base.any_phong = bool(is_phong.any())
        base.is_phong = mi.Bool(is_phong)
        base.amb, base.dif, base.spe = (table(mi.Float, a) for a in (amb, dif, spe))
        base.refl, base.trans = table(mi.Float, refl), table(mi.Float, trans)
        base.expo, base.ior = mi.Float(expo), mi.Float(ior)
        base.phong_np = dict(amb=amb, dif=dif, spe=spe, refl=refl, expo=expo, ior=ior)
        base.any_ambient = bool(np.any(amb > 0))
        base.has_dr, base.has_dt, base.has_null = mi.Bool(has_dr), mi.Bool(has_dt), mi.Bool(has_null)
        base.any_mitsuba_dr, base.any_mitsuba_dt = bool(has_dr.any()), bool(has_dt.any())
        base.any_mitsuba_null = bool(has_null.any())
        base.any_mitsuba_delta = bool(np.any(has_dr | has_dt | has_null))
        base.mitsuba_delta_np = has_dr | has_dt | has_null
        # masks: their delta lobes are sampled on the nested BSDF and scaled by the opacity
        # (Mitsuba's mask.sample cannot sample one lobe alone: it returns its null lobe)
        # the delta lobes by component: each component of a slot's sampler (a mask's nested BSDF)
        # with a delta lobe is sampled on its own (BSDFContext.component): a blendbsdf weighs its
        # nested components by its weight there, where sampling the whole BSDF would pick one
        # nested BSDF by the sample; every smooth reflection has one direction, so the
        # components' weights add up (delta_components: lobe -> [(component, Bool per slot)])
        comp = {"r": {}, "t": {}}
        for sl, b in enumerate(bsdfs):
            if b is None or is_phong[sl] or not (has_dr[sl] or has_dt[sl]):
                continue
            s = inner[sl]
            for c in range(s.component_count()):
                fc = int(s.flags(c))
                for which, flag in (("r", mi.BSDFFlags.DeltaReflection), ("t", mi.BSDFFlags.DeltaTransmission)):
                    if fc & int(flag):
                        comp[which].setdefault(c, np.zeros(nslots, dtype=bool))[sl] = True
        base.delta_components = {k: [(c, mi.Bool(v)) for c, v in sorted(d.items())] for k, d in comp.items()}
        is_mask = np.array([b is not None and i is not b for b, i in zip(bsdfs, inner)], dtype=bool)
        base.any_mask = bool(is_mask.any())
        base.inner_ptr = mi.BSDFPtr([i if i is not None else default_bsdf for i in inner]) \
            if base.any_mask else None
        base.any_phong_r = bool(np.any(refl.max(1) > 0))
        base.any_phong_t = bool(np.any(trans.max(1) > 0))
        base.any_specular = base.any_mitsuba_delta or base.any_phong_r or base.any_phong_t
        base.spawns = _spawn_table(is_phong, refl, trans, has_dr | has_dt | has_null)
        base.glossy = mi.Bool(glossy)
        # links1_quadric shapes whose Mitsuba BSDF has a texture get the core's uv
        base.uv_slots = {sp.slot for sp in self.shapes.custom if sp.__class__.__name__ == "QuadricSpec"
                      and not is_phong[sp.slot] and _textured(bsdfs[sp.slot])}
        if default_bsdf is None and any(b is None for b in bsdfs):
            default_bsdf = mi.load_dict({"type": "diffuse"})
        bsdfs = [b if b is not None else default_bsdf for b in bsdfs]
        # a BSDFPtr array holds registry ids, not references: the BSDF objects (the default
        # made here above all) must live as long as the tables, or a vcall through a freed
        # id crashes the process
        base.keep_alive = base.keep_alive + (bsdfs,)
        if len(bsdfs) != nslots or any(b is None for b in bsdfs):
            raise RuntimeError("links1_whitted: the BSDF table has a hole (an internal inconsistency)")
        for spec in self.shapes.custom:
            checked_index([spec.slot], nslots, "custom shape slot")
        base.bsdf_ptr = mi.BSDFPtr(bsdfs) if not base.all_phong else None
        shaded = is_phong | np.array([bool(int(b.flags()) & int(mi.BSDFFlags.Smooth)) for b in bsdfs])
        base.shaded, base.all_shaded = mi.Bool(shaded), bool(shaded.all())
        self._lambert_tables(base, bsdfs, is_phong)
        # shadow transmittance (3-3-3): Phong t; Mitsuba BSDFs are opaque
        base.shadow_t_np = trans.copy()
        self._shape_tables(base, self._bvh_quadrics(base))
        base.shadow_t = mi.Float(trans.ravel())
        # transparent Mitsuba shapes, each counted once per shadow segment (3-3-3): shape j
        # owns bit j % 32 of word j // 32 of a per-lane "seen" set (as many words as needed)
        transparent_mitsuba = [(s, sl) for s, sl in zip(shapes, slot_list) if trans[sl].max() > 0]
        bits = np.zeros(nslots, dtype=np.uint32)
        words = np.zeros(nslots, dtype=np.uint32)
        for j, (_, sl) in enumerate(transparent_mitsuba):
            bits[sl], words[sl] = np.uint32(1 << (j % 32)), np.uint32(j // 32)
        base.trans_bits, base.trans_words = mi.UInt32(bits), mi.UInt32(words)
        base.trans_nwords = max(1, -(-len(transparent_mitsuba) // 32))
        # a segment crosses each triangle at most once and an analytic shape at most twice,
        # and stops at the first opaque one: no arbitrary cap on crossings
        base.max_crossings = 1 + sum(int(s.face_count()) if s.is_mesh() else 2 for s, _ in transparent_mitsuba)
        base.any_transparent_mitsuba = bool(transparent_mitsuba)
        # (sub-scenes hold top-level shapes: a transparent shape inside an instance walks its crossings)
        base.shadow_split = shadow_split(mi, shapes, slot_list, trans) \
            if transparent_mitsuba and not any(sl in base.member_slots for _, sl in transparent_mitsuba) else None
        # emission
        emis = np.zeros((nslots, 3))
        for spec in self.shapes.custom:
            if spec.emission is not None:
                emis[spec.slot] = spec.emission
        base.custom_emission = mi.Float(emis.ravel())
        base.any_custom_emission = bool(np.any(emis > 0))
        # Mitsuba shapes that emit: area emitters only (a directionalarea is ignored, as the
        # emitter loop below says, so its shape shows no emission either)
        emits = np.zeros(max(nslots, 1), dtype=bool)
        for s, sl in zip(shapes, slot_list):
            if s.emitter() is not None and kind_of(s.emitter()) == "AreaLight":
                emits[sl] = True
        base.any_mitsuba_emission = bool(emits.any())
        base.mitsuba_emits = mi.Bool(emits)
        for s in shapes:
            if s.interior_medium() is not None or s.exterior_medium() is not None:
                warnings.warn(f"{self.shapes.place(s)}: its medium is not supported by links1_whitted and "
                              "is ignored", stacklevel=2)
        # lights
        base.lights, base.area, base.env, base.consts, base.area_tab = [], [], None, [], []
        n_env = 0
        point_class, spot_class = plugin_class("links1_point"), plugin_class("links1_spot")
        for e in scene.emitters():
            kind = kind_of(e)
            L = analytic_light(e, kind, point_class, spot_class, base, self.shapes.place)
            if L is not None:
                base.lights.append(L)
            elif kind == "ConstantBackgroundEmitter":
                rad = np.array(mi.traverse(e)["radiance.value"], dtype=np.float64).ravel()
                base.consts.append(ConstantEnvRecord(np.broadcast_to(rad, (3,)).copy(), ENV_LIGHT_ID + n_env))
                n_env += 1
                base.env = e
            elif kind == "EnvironmentMapEmitter":
                base.consts.append(EnvMapRecord(envmap_table(e), ENV_LIGHT_ID + n_env))
                n_env += 1
                base.env = e
            elif e.is_environment() or (int(e.flags()) & int(mi.EmitterFlags.Infinite)):
                warnings.warn(f"{self.shapes.place(e)}: emitter {kind} is seen as the background but "
                              "lights nothing", stacklevel=2)
                n_env += 1
                base.env = e
            elif kind == "AreaLight":   # a directionalarea (also Surface) is ignored, as in the core
                tab = area_table(e, shapes, slot_list, self.shapes.place)
                if tab is not None:
                    base.area.append(e)
                    base.area_tab.append(tab)
            else:
                warnings.warn(f"{self.shapes.place(e)}: emitter {kind} is not supported and is ignored",
                              stacklevel=2)
        # sample streams by place (as the core numbers them, whichever order Mitsuba gives the
        # shapes), and the area lights in that order
        order = number_area_lights([tab["light"] for tab in base.area_tab])
        base.area, base.area_tab = [base.area[i] for i in order], [base.area_tab[i] for i in order]
        for tab in base.area_tab:
            tab["id"] = tab["light"].light_id
        base.any_mis = bool(np.any(glossy)) and bool(base.area_tab or base.consts)
        self._shadow_tables(base, scene, shapes, slot_list)
        return base

    @staticmethod
    def _lambert_tables(base, bsdfs, is_phong):
        """The tables of the slots whose BSDF is a ``diffuse`` of one reflectance value
        (:func:`_uniform_diffuse`; the kernel evaluates them without a BSDF call)."""
        nslots = len(bsdfs)
        lam = np.zeros(nslots, dtype=bool)
        two = np.zeros(nslots, dtype=bool)
        rgb = np.zeros((nslots, 3), dtype=np.float32)
        src = {}
        for sl, b in enumerate(bsdfs):
            found = None if is_phong[sl] else _uniform_diffuse(b)
            v = None if found is None else _spectrum_rgb(found[0])
            if v is not None:
                lam[sl], two[sl], rgb[sl], src[sl] = True, found[1], v, found[0]
        base.lam, base.lam_two, base.lam_rgb = mi.Bool(lam), mi.Bool(two), table(mi.Float, rgb)
        base.lam_np, base.lam_src = rgb, src
        base.any_lam, base.any_lam_two = bool(lam.any()), bool(two.any())
        base.all_lam = bool(np.all(lam | is_phong))

    def _bvh_quadrics(self, base):
        """The links1 quadrics to put under a BVH (bvh.py) instead of one code block each:
        the bounded ones, when there are ``bvh_min`` of them; else none."""
        quad = [sp for sp in self.shapes.custom if sp.__class__.__name__ == "QuadricSpec"
                and np.all(np.isfinite(np.concatenate(sp.bounds())))]
        return quad if len(quad) >= base.tuning.bvh_min else []

    def _shape_tables(self, base, quad):
        """The tables made from the links1 shapes' geometry (what a ``params.update()`` of it
        redoes, :meth:`_update_values`): the quadrics ``quad`` under a BVH (its slots, the
        tree, each slot's place in it), the others traced in their own code
        (``custom_unrolled``) with their tables (shapes.py ``tables()``: their constants, a
        blob's candidate search), built before any trace (frozen inputs)."""
        in_bvh = {id(sp) for sp in quad}
        base.custom = self.shapes.custom
        base.custom_unrolled = [sp for sp in self.shapes.custom if id(sp) not in in_bvh]
        base.bvh_slots = frozenset(sp.slot for sp in quad)
        base.bvh = None
        if quad:
            base.bvh = QuadricBVH(quad, base.shadow_t_np)
            s2q = np.full(max(base.nslots, 1), -1, dtype=np.int32)
            for i, sp in enumerate(base.bvh.specs):
                s2q[sp.slot] = i
            base.bvh.slot_to_q = mi.Int32(checked_index(s2q, base.bvh.n, "slot_to_q", sentinel=-1))
        base.blob_tables = [sp.tables() for sp in base.custom_unrolled]

    def _shadow_tables(self, base, scene, shapes, slot_list, reuse=False):
        """The tables planned from the analytic lights' places (:data:`LIGHT_FIELDS`): what
        each light's shadow rays test (:func:`~links1_mitsuba.shadow_plan.plan_occluders`, ``reuse``: of the shapes' part
        made before) and the light buffers."""
        plan_occluders(base, self.shapes.custom, shapes, slot_list, reuse)
        # light buffers for the quadric shadow rays toward analytic lights (where they pay)
        base.lbuf = lightbuffer.plan(base, scene) if base.tuning.light_buffer else [None] * len(base.lights)

    def _mitsuba_shapes(self, scene):
        """``(shapes, slot_list, nslots, member_slots)``: Mitsuba's own shapes of ``scene``
        (links1 proxies left out) with their slots (``SceneShapes.slots``), then the shapes inside its
        shapegroups (:func:`group_members`), each a slot of its own after all others: a hit
        on an instance names the member, whose BSDF it takes (shared by every instance)."""
        shapes = [s for s in scene.shapes() if not proxies.is_proxy(s)]
        slot_list, nslots = self.shapes.slots(shapes)
        members = group_members(scene) if any(s.class_name() == "Instance" for s in shapes) else []
        member_slots = frozenset(range(nslots, nslots + len(members)))
        return shapes + members, slot_list + sorted(member_slots), nslots + len(members), member_slots
