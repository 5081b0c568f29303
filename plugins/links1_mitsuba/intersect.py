"""Intersection in ``links1_whitted`` (its one home): the nearest hit of each ray over Mitsuba's
shapes (``scene.ray_intersect``) and the links1 quadrics and blobs in Dr.Jit, nearest wins, ties
to the lower slot (:func:`nearest`); the transmittance of shadow rays (3-3-3) through the links1
shapes (:func:`shadow_custom`) and Mitsuba's (:func:`shadow_mitsuba`), each shape counted once;
the uv of hits on textured links1 quadrics (:func:`custom_uv`); a derivative pass's hits on
links1 shapes moving with their parameters (:func:`moving_hits`). Many links1 quadrics go under
a BVH (:mod:`links1_mitsuba.bvh`).

Plain functions of the prepared tables (``tables``: a :class:`~.prepared.Prepared` or camera
view) and of the switches they are given (:class:`~.tuning.Tuning`'s, from the ray tree): no
state. They name ``mi.Float``, ``mi.Ray3f``, ... when called, so they serve every Mitsuba
variant.
"""
from __future__ import annotations

import dataclasses

import drjit as dr
import mitsuba as mi

from . import geometry
from .shapes import quadric_uv
from .util import INF, color3, gather3, next_up

#: the kinds of Mitsuba shape whose nearest hit's surface record the kernel makes
#: (:func:`mesh_surface`, ``tables.MeshRecord.kind``): ``Mesh`` (triangle meshes, cubes:
#: ``Mesh::compute_surface_interaction``, Mitsuba 3.9.1's mesh.cpp), rectangles (a ``Mesh`` of
#: two faces, its record made from a row of the rectangle's own: rectangle.cpp), spheres
#: (sphere.cpp), disks (disk.cpp)
KIND_MESH, KIND_RECT, KIND_SPHERE, KIND_DISK = 0, 1, 2, 3
#: floats a rectangle's, sphere's, disk's or instance's row of ``tables.MeshRecord.rows``
ROW = 36
#: floats a packet gather of the per-face table reads (``tables.MeshRecord.packets``)
PACKET = 4
#: how :func:`mesh_surface` picks each lane's kind where a scene has several: one symbolic
#: branch a kind present ("if": a packet runs the kinds it holds), or every kind's operations
#: on every lane and a select ("select"), or Dr.Jit's symbolic switch ("switch")
DISPATCH = "if"
#: a fresh preliminary hit's slot from Embree's geometry id (:func:`record_slots`; False: from
#: the shape's registry id, as a hit remade from kept arrays): the same slots
GEOM_SLOTS = True
#: a hit's kind and its mesh's first face read as one word (``MeshRecord.kind_face``; False:
#: two gathers): the same values
KIND_FACE = True
#: a rectangle's, sphere's, disk's or instance's row read :data:`PACKET` floats a packet gather
#: (:func:`_row`; False: one gather a float): the same values
ROW_PACKETS = True

# the switches read here (preliminary, box_cull, eye_buffer, split) are fields of
# tuning.Tuning, handed over while tracing: a frozen launch is keyed on them (launch.py)


# -------------------------------------------------------------- geometry
def nearest(tables, scene, o, d, tmin, tmax, active, cost, eye=False, coherent=False, ad=False, pi=None,
            keep=None):
    """Nearest hit over Mitsuba shapes and custom shapes: (t, slot, si, prim).
    ``eye``: the rays start at a pinhole camera's eye and its buffer replaces the BVH
    (``Tuning.eye_buffer``).
    ``ad``: a derivative pass's rays (the links1 shapes' hits found on primal values).
    ``coherent``: the camera's rays, neighbours in the lanes (Embree's coherent mode, as
    Mitsuba's own integrators trace their camera rays: ~1.2-2x faster for spp 16 eye rays;
    a ray that meets an edge shared by two triangles at the same distance may get the other
    one, as in Mitsuba).
    ``pi``: where the kernel makes the record (:func:`remakes`), the preliminary hits of these
    rays found before (:func:`kept_hit`): the record made from them, no query. ``keep``: a list
    that takes the preliminary hits the query found there."""
    rec = getattr(tables, "mesh_record", None)
    if tables.any_mitsuba_shapes:
        ray = mi.Ray3f(o + d * tmin, d, tmax - tmin)
        if rec is not None and not ad:
            # every Mitsuba shape a mesh, rectangle, sphere or disk, or an instance of them:
            # Embree's preliminary hit, the record made here
            fresh = pi is None
            if fresh:
                pi = scene.ray_intersect_preliminary(ray, bool(coherent), active)
            if keep is not None:
                keep.append(pi)
            valid = active & pi.is_valid()
            t = dr.select(valid, pi.t + tmin, INF)
            slot, inst, islot = record_slots(tables, rec, pi, valid, fresh)
            si = mesh_surface(rec, ray, pi, slot, valid, inst, islot)
        else:
            si = scene.ray_intersect(ray, mi.RayFlags.All, bool(coherent), active)
            valid = active & si.is_valid()
            t = dr.select(valid, si.t + tmin, INF)
            slot = _shape_slot(tables, si.shape, valid)
        cost += dr.select(active, mi.UInt32(1), 0)
    else:
        si = dr.zeros(mi.SurfaceInteraction3f, dr.width(o))
        t = dr.full(mi.Float, INF, dr.width(o))
        slot = dr.full(mi.Int32, -1, dr.width(o))
    prim = dr.zeros(mi.UInt32, dr.width(o))
    if ad:
        # a derivative pass: the links1 shapes' hits on primal values (re-attached by
        # moving_hits: implicit differentiation, not through the solvers)
        with dr.suspend_grad():
            t, slot, prim = _nearest_custom(tables, o, d, tmin, tmax, active, cost, eye, t, slot, prim)
        return t, slot, si, prim
    t, slot, prim = _nearest_custom(tables, o, d, tmin, tmax, active, cost, eye, t, slot, prim)
    return t, slot, si, prim


def remakes(tables):
    """Whether a nearest hit's record can be made again from its preliminary hit alone
    (:func:`kept_hit`, :func:`nearest`'s ``pi``): every shape of the scene a Mitsuba one whose
    record the kernel makes (:func:`mesh_surface`) outside instances, no links1 shape."""
    rec = getattr(tables, "mesh_record", None)
    return (bool(tables.any_mitsuba_shapes) and rec is not None and rec.member_of is None
            and not tables.custom_unrolled and tables.bvh is None)


def kept_hit(pi):
    """What a kernel stores of the preliminary hits ``pi`` for :func:`remade_hit` (whether
    there is one, the hit shape's registry id, ``t``, the primitive and its uv): six arrays."""
    return (pi.valid, dr.reinterpret_array(mi.UInt32, pi.shape), pi.t, pi.prim_index, pi.prim_uv.x, pi.prim_uv.y)


def remade_hit(kept):
    """The preliminary hits of :func:`kept_hit`'s arrays ``kept`` (gathered for other lanes)."""
    valid, shape, t, prim_index, u, v = kept
    pi = dr.zeros(mi.PreliminaryIntersection3f, dr.width(t))
    pi.valid, pi.shape = mi.Bool(valid), dr.reinterpret_array(mi.ShapePtr, shape)
    pi.t, pi.prim_index, pi.prim_uv = mi.Float(t), mi.UInt32(prim_index), mi.Point2f(u, v)
    return pi


def _shape_slot(tables, shape, valid):
    """The slot of the Mitsuba shapes ``shape`` (``ShapePtr``, a hit's) where ``valid``, else -1."""
    reg = dr.reinterpret_array(mi.UInt32, shape)
    return dr.select(valid, dr.gather(mi.Int32, tables.reg_to_slot, reg, valid), -1)


def record_slots(tables, rec, pi, valid, fresh=False):
    """``(slot, inst, islot)`` of the preliminary hits ``pi`` (``valid``: the lanes with a
    hit): the slot of the shape hit (on an instance: the shapegroup's member, which Mitsuba's
    record names: ``rec.member_of``), the lanes on an instance (None: the scene has none) and
    the instance's slot. ``fresh``: ``pi`` is Embree's answer in this kernel (not one remade
    from :func:`kept_hit`'s arrays), so where the scene has no instance (:data:`GEOM_SLOTS`) the
    slot comes from its geometry id, ``shape_index``, the index itself where the slots are the
    shapes' indices: no gather of the registry id (``pi.shape``, a gather after Embree's call)
    and of its slot, each waiting on the one before."""
    if fresh and GEOM_SLOTS and rec.member_of is None and tables.geom_to_slot is not None:
        g = pi.shape_index
        slot = mi.Int32(g) if tables.geom_slot_identity else dr.gather(mi.Int32, tables.geom_to_slot, g, valid)
        return dr.select(valid, slot, -1), None, None
    slot = _shape_slot(tables, pi.shape, valid)
    if rec.member_of is None:
        return slot, None, None
    ireg = dr.reinterpret_array(mi.UInt32, pi.instance)
    inst = valid & (ireg != 0)
    islot = mi.UInt32(dr.gather(mi.Int32, tables.reg_to_slot, ireg, inst))
    member = dr.gather(mi.UInt32, rec.member_of, dr.gather(mi.UInt32, rec.inst_base, islot, inst) + pi.shape_index,
                       inst)
    return dr.select(inst, mi.Int32(member), slot), inst, islot


def _affine(r, v, point):
    """``AffineTransform4f * Point3f`` (``point``) or ``* Vector3f`` (Mitsuba 3.9.1's
    transform.h) of the rows ``r`` (3 rows of 4 floats, the translation last): a point's
    ``r[i][3]``, then ``fma(r[i][j], v_j, .)``; a vector's ``r[i][0] v0``, then the fmas."""
    out = []
    for row in r:
        acc = dr.fma(row[0], v[0], row[3]) if point else row[0] * v[0]
        out.append(dr.fma(row[2], v[2], dr.fma(row[1], v[1], acc)))
    return (mi.Point3f if point else mi.Vector3f)(*out)


def mesh_surface(rec, ray, pi, slot, valid, inst=None, islot=None):
    """Mitsuba's surface record (``scene.ray_intersect``'s, ``RayFlags.All``) of the
    preliminary hits ``pi`` of ``ray`` on the meshes, rectangles, spheres and disks of ``rec``
    (``tables.MeshRecord``; ``slot``: the hit's slot, ``valid``: the lanes with a hit), made
    with the float operations of Mitsuba 3.9.1's ``compute_surface_interaction`` of each
    (:func:`_mesh_part`, :func:`_rect_part`, :func:`_sphere_part`, :func:`_disk_part`; the
    lane's kind from ``rec.kind``, each kind present in the kernel, picked as
    :data:`DISPATCH` says) and ``SurfaceInteraction::finalize_surface_interaction``
    (interaction.h): the same bits. On an instance (``inst``: those lanes, ``islot``: its
    slot; :func:`record_slots`), as ``Instance::compute_surface_interaction`` (instance.cpp):
    the member's record of the ray in the group's space, its point, normals and dp/du, dp/dv
    transformed back by the instance's ``to_world`` (normals normalized). Lanes without a hit
    hold what Mitsuba's shape call leaves there (zeros, ``t`` infinite, ``wi = -d``)."""
    sl = mi.UInt32(dr.maximum(slot, 0))
    face_off = ()
    if rec.kind_face is not None and KIND_FACE:
        # the kind and the meshes' first face in one word (tables.MeshRecord.kind_face): one
        # gather, the first face handed to the branch
        kf = dr.gather(mi.UInt32, rec.kind_face, sl, valid)
        kind, face_off = kf & 3, (kf >> 2,)
    else:
        kind = None if rec.kind is None else dr.gather(mi.UInt32, rec.kind, sl, valid)
    part = {KIND_MESH: _mesh_part, KIND_RECT: _rect_part, KIND_SPHERE: _sphere_part, KIND_DISK: _disk_part}
    kinds = sorted(rec.kinds)
    o, d = ray.o, ray.d
    if inst is not None:
        # the instance's to_world (rows), inverse_transpose (normals) and, where a member
        # makes its point from the ray, the inverse: the ray in the group's space
        row = _row(rec, islot, inst, 33 if rec.inst_obj else 21)
        tw, it = [row[4 * i:4 * i + 4] for i in range(3)], [row[12 + 3 * i:15 + 3 * i] for i in range(3)]
        if rec.inst_obj:
            to = [row[21 + 4 * i:25 + 4 * i] for i in range(3)]
            o, d = dr.select(inst, _affine(to, o, True), o), dr.select(inst, _affine(to, d, False), d)
    args = (o, d, pi.t, pi.prim_uv, pi.prim_index, sl, *face_off)

    def run(k, m, o, d, t, prim_uv, prim_index, sl, *face_off):
        # (the hit's fields as arguments: a symbolic call or branch takes no wide array it reads)
        hit = _Hit(o, d, t, prim_uv, prim_index, *face_off)
        p, n, ns, uv, du, dv = part[k](rec, hit, sl, m)
        return mi.Point3f(p), mi.Vector3f(n), mi.Vector3f(ns), mi.Point2f(uv), mi.Vector3f(du), mi.Vector3f(dv)

    if kind is None:
        out = run(kinds[0], valid, *args)
    elif DISPATCH == "select":
        out = run(kinds[-1], valid & (kind == kinds[-1]), *args)
        for k in kinds[:-1]:
            m = valid & (kind == k)
            out = tuple(dr.select(m, a, b) for a, b in zip(run(k, m, *args), out))
    elif DISPATCH == "switch":
        idx = dr.zeros(mi.UInt32, dr.width(valid))
        for k in kinds[:-1]:
            idx += dr.select(kind > k, mi.UInt32(1), 0)
        out = dr.switch(idx, [lambda *a, k=k: run(k, *a) for k in kinds], valid, *args, mode="symbolic",
                        label="links1_record")
    else:
        def branch(ks, m, *a):
            if len(ks) == 1:
                return run(ks[0], m, *a)
            return dr.if_stmt((m, *a), kind == ks[0], lambda *b: run(ks[0], *b), lambda *b: branch(ks[1:], *b),
                              mode="symbolic", label="links1_record")
        out = branch(kinds, valid, *args)
    p, n, ns, uv, dp_du, dp_dv = out
    if rec.flip is not None:
        fl = dr.gather(mi.Bool, rec.flip, sl, valid)
        n, ns = dr.select(fl, -n, n), dr.select(fl, -ns, ns)
    if inst is not None:
        def normal(v):
            return dr.normalize(_affine(it, v, False))
        p = dr.select(inst, _affine(tw, p, True), p)
        n, ns = dr.select(inst, normal(n), n), dr.select(inst, normal(ns), ns)
        dp_du, dp_dv = (dr.select(inst, _affine(tw, v, False), v) for v in (dp_du, dp_dv))
    si = dr.zeros(mi.SurfaceInteraction3f, dr.width(valid))
    si.t = dr.select(valid, pi.t, INF)
    si.p = dr.select(valid, p, 0.0)
    si.n = dr.select(valid, n, 0.0)
    si.uv = dr.select(valid, uv, 0.0)
    dp_du = dr.select(valid, dp_du, 0.0)
    si.dp_du, si.dp_dv = dp_du, dr.select(valid, dp_dv, 0.0)
    si.prim_index = dr.select(valid, pi.prim_index, 0)
    si.shape = dr.select(valid, pi.shape, mi.ShapePtr(None))
    if inst is not None:
        member = dr.reinterpret_array(mi.ShapePtr, dr.gather(mi.UInt32, rec.slot_reg, sl, inst))
        si.shape = dr.select(inst, member, si.shape)
        si.instance = dr.select(inst, pi.instance, mi.ShapePtr(None))
    si.time = ray.time
    si.wavelengths = ray.wavelengths
    # SurfaceInteraction::initialize_sh_frame
    ns = dr.select(valid, ns, 0.0)
    s = dr.normalize(dr.fma(ns, -dr.dot(ns, dp_du), dp_du))
    s = dr.select(dr.all(dp_du == 0.0), mi.coordinate_system(ns)[0], s)
    si.sh_frame = mi.Frame3f(s, dr.cross(ns, s), ns)
    si.wi = dr.select(valid, si.to_local(-ray.d), -ray.d)
    return si


def _mesh_part(rec, pi, sl, valid):
    """``(p, n, ns, uv, dp_du, dp_dv)`` of the hits ``valid`` on meshes, normals not yet
    flipped: the face's vertices, texture coordinates and normals read from the per-face
    table (``rec.packets``, :func:`_face_values`) or gathered from the meshes' buffers, then
    :func:`_triangle`."""
    face = pi.prim_index
    if pi.face_off is not None:
        face = face + pi.face_off
    elif rec.face_off is not None:
        face = face + dr.gather(mi.UInt32, rec.face_off, sl, valid)
    uvs = nrm = has_uv = has_n = None
    if rec.texcoords is not None:
        has_uv = valid if rec.has_uv is None else valid & dr.gather(mi.Bool, rec.has_uv, sl, valid)
    if rec.normals is not None:
        has_n = valid if rec.has_n is None else valid & dr.gather(mi.Bool, rec.has_n, sl, valid)
    if rec.packets is not None:
        pos, nrm, uvs = _face_values(rec, face, valid)
    else:
        fi = [dr.gather(mi.UInt32, rec.faces, face * 3 + k, valid) for k in range(3)]
        pos = [dr.gather(mi.Point3f, rec.positions, f, valid) for f in fi]
        if rec.texcoords is not None:
            uvs = [dr.gather(mi.Point2f, rec.texcoords, f, has_uv) for f in fi]
        if rec.normals is not None:
            nrm = [dr.gather(mi.Vector3f, rec.normals, f, has_n) for f in fi]
    return _triangle(pi, pos, uvs, has_uv, nrm, has_n)


def face_floats(rec):
    """Floats a face of ``rec``'s per-face table (``tables.MeshRecord.packets``): 9, 9 more
    with normals, 6 more with texture coordinates, rounded up to a multiple of :data:`PACKET`."""
    k = 9 + (9 if rec.normals is not None else 0) + (6 if rec.texcoords is not None else 0)
    return -(-k // PACKET) * PACKET


def _face_values(rec, face, valid):
    """``(positions, normals, texture coordinates)`` of the vertices of faces ``face`` (lanes
    ``valid``) from the per-face table ``rec.packets`` (``tables.MeshRecord``), :data:`PACKET`
    floats a packet gather: the same values as the buffers' (normals, texture coordinates None
    where the record has none; a mesh without holds zeros there, as the buffers do)."""
    n = face_floats(rec) // PACKET
    vals = _packets(rec.packets, face * n, n, valid)
    pos = [mi.Point3f(*vals[3 * i:3 * i + 3]) for i in range(3)]
    nrm = uvs = None
    at = 9
    if rec.normals is not None:
        nrm = [mi.Vector3f(*vals[at + 3 * i:at + 3 * i + 3]) for i in range(3)]
        at += 9
    if rec.texcoords is not None:
        uvs = [mi.Point2f(*vals[at + 2 * i:at + 2 * i + 2]) for i in range(3)]
    return pos, nrm, uvs


def _rect_part(rec, pi, sl, valid):
    """:func:`_mesh_part` on rectangles from their rows (``tables.MeshRecord``: the four
    vertices, the normal all four carry): Mitsuba's rectangle is a ``Mesh`` whose faces are
    (1, 2, 0) and (1, 3, 2) and whose vertex i has the texture coordinates (i & 1, i >> 1)
    (rectangle.cpp), so that the face's vertices are gathered from the row without an index
    and its texture coordinates are constants."""
    first = pi.prim_index == 0
    if ROW_PACKETS:   # the four vertices and the normal (15 floats) read whole, the face's picked
        row = _row(rec, sl, valid, 15)
        vert = [mi.Point3f(*row[3 * i:3 * i + 3]) for i in range(4)]
        pos = [vert[1], dr.select(first, vert[2], vert[3]), dr.select(first, vert[0], vert[2])]
        n = mi.Vector3f(*row[12:15])
    else:
        at = sl * ROW

        def vertex(i):
            return mi.Point3f(*[dr.gather(mi.Float, rec.rows, at + i * 3 + k, valid) for k in range(3)])
        pos = [vertex(1), vertex(dr.select(first, mi.UInt32(2), 3)), vertex(dr.select(first, mi.UInt32(0), 2))]
        n = mi.Vector3f(*[dr.gather(mi.Float, rec.rows, at + 12 + k, valid) for k in range(3)])
    uvs = [mi.Point2f(1.0, 0.0), dr.select(first, mi.Point2f(0.0, 1.0), mi.Point2f(1.0, 1.0)),
           dr.select(first, mi.Point2f(0.0, 0.0), mi.Point2f(0.0, 1.0))]
    return _triangle(pi, pos, uvs, valid, [n, n, n], valid)


def _triangle(pi, pos, uvs, has_uv, nrm, has_n):
    """``(p, n, ns, uv, dp_du, dp_dv)`` of hits on triangles (vertices ``pos``, texture
    coordinates ``uvs`` where ``has_uv``, vertex normals ``nrm`` where ``has_n``; None: none),
    normals not yet flipped, as Mitsuba 3.9.1's ``Mesh::compute_surface_interaction``
    (mesh.cpp) makes them: the point interpolated from the vertices with the barycentrics (not
    ``o + t d``), the geometric normal ``Mesh::face_normal``, the shading normal the
    normalized interpolated vertex normal (without: the face normal), uv and dp/du, dp/dv from
    the texture coordinates (without: the barycentrics and the edges)."""
    p0, p1, p2 = pos
    b1, b2 = pi.prim_uv.x, pi.prim_uv.y
    b0 = 1.0 - b1 - b2
    p = dr.fma(p0, b0, dr.fma(p1, b1, p2 * b2))
    dp0, dp1 = p1 - p0, p2 - p0
    n = dr.normalize(dr.cross(dp0, dp1))      # Mesh::face_normal
    uv = mi.Point2f(b1, b2)
    dp_du, dp_dv = mi.Vector3f(dp0), mi.Vector3f(dp1)
    if uvs is not None:
        uv0, uv1, uv2 = uvs
        uv = dr.select(has_uv, dr.fma(uv2, b2, dr.fma(uv1, b1, uv0 * b0)), uv)
        # an arbitrary basis for degenerate parameterizations
        cs, ct = mi.coordinate_system(mi.Vector3f(n))
        duv0, duv1 = uv1 - uv0, uv2 - uv0
        det = dr.fma(duv0.x, duv1.y, -(duv0.y * duv1.x))
        inv_det = dr.rcp(det)
        ok = det != 0.0
        du = dr.select(ok, dr.fma(duv1.y, dp0, -(duv0.y * dp1)) * inv_det, cs)
        dv = dr.select(ok, dr.fma(-duv1.x, dp0, duv0.x * dp1) * inv_det, ct)
        dp_du, dp_dv = dr.select(has_uv, du, dp_du), dr.select(has_uv, dv, dp_dv)
    ns = mi.Vector3f(n)
    if nrm is not None:
        n0, n1, n2 = nrm
        ni = dr.fma(n2, b2, dr.fma(n1, b1, n0 * b0))
        ns = dr.select(has_n, ni * dr.rsqrt(dr.squared_norm(ni)), ns)
    return p, n, ns, uv, dp_du, dp_dv


@dataclasses.dataclass
class _Hit:
    """A preliminary hit's fields that :func:`mesh_surface`'s parts read: its ray's origin and
    direction, ``t``, ``prim_uv``, ``prim_index``, and its mesh's first face (None: gathered
    from ``MeshRecord.face_off``)."""
    o: object
    d: object
    t: object
    prim_uv: object
    prim_index: object
    face_off: object = None


def _linear(m, v):
    """``AffineTransform4f * Vector3f`` (Mitsuba 3.9.1's transform.h) of the rows ``m`` (9
    floats, row by row): :func:`_affine` of a vector."""
    return _affine([m[3 * i:3 * i + 3] for i in range(3)], v, False)


def _row(rec, sl, valid, n):
    """The first ``n`` floats of the rows ``sl`` of ``rec.rows``: :data:`PACKET` floats a
    packet gather (:data:`ROW_PACKETS`; the rows 64-byte aligned, ``ROW`` a multiple of
    ``PACKET``), else one gather a float; the same values."""
    if not ROW_PACKETS:
        return [dr.gather(mi.Float, rec.rows, sl * ROW + k, valid) for k in range(n)]
    return _packets(rec.rows, sl * (ROW // PACKET), -(-n // PACKET), valid)[:n]


def _packets(table, first, count, valid):
    """The floats of ``count`` consecutive packets of :data:`PACKET` floats of ``table`` from
    packet ``first`` (lane by lane) on, one packet gather each (the table 64-byte aligned)."""
    vals = []
    for j in range(count):
        v = dr.gather(mi.ArrayXf, table, first + j, valid, shape=(PACKET, max(dr.width(first), dr.width(valid))))
        vals += [v[i] for i in range(PACKET)]
    return vals


def _sphere_part(rec, pi, sl, valid):
    """``(p, n, ns, uv, dp_du, dp_dv)`` of the hits ``valid`` on spheres, normals not yet
    flipped, as Mitsuba 3.9.1's ``Sphere::compute_surface_interaction`` (sphere.cpp) makes them
    in a differentiable variant without ``FollowShape``: the point ``ray(t)``, the normal
    ``normalize(p - center)``, uv from the spherical angles of ``p`` in object space
    (``to_world``'s stored inverse), dp/du and dp/dv the parameterization's (``(1, 0, 0)`` on
    the axis) through ``to_world``, times 2 pi and pi."""
    row = _row(rec, sl, valid, 24)
    lin, c = row[:9], mi.Vector3f(*row[9:12])
    p = dr.fma(pi.d, pi.t, pi.o)                        # Ray::operator()
    n = dr.normalize(p - c)
    # to_object * p (transform.h)
    loc = mi.Vector3f(_affine([row[12 + 4 * i:16 + 4 * i] for i in range(3)], p, True))
    theta, phi = mi.dir_to_sph(loc)                     # dr::unit_angle_z, atan2
    phi = dr.select(phi < 0.0, phi + mi.Float(2.0 * dr.pi), phi)
    uv = mi.Point2f(phi * dr.inv_two_pi, theta * dr.inv_pi)
    rd = dr.sqrt(dr.square(loc.x) + dr.square(loc.y))
    inv_rd = dr.rcp(rd)
    dv = mi.Vector3f(loc.z * (loc.x * inv_rd), loc.z * (loc.y * inv_rd), -rd)
    dv = dr.select(valid & (rd == 0.0), mi.Vector3f(1.0, 0.0, 0.0), dv)
    du = _linear(lin, mi.Vector3f(-loc.y, loc.x, 0.0)) * mi.Float(2.0 * dr.pi)
    return p, n, n, uv, du, _linear(lin, dv) * mi.Float(dr.pi)


def _disk_part(rec, pi, sl, valid):
    """``(p, n, ns, uv, dp_du, dp_dv)`` of the hits ``valid`` on disks as Mitsuba 3.9.1's
    ``Disk::compute_surface_interaction`` (disk.cpp) makes them in a differentiable variant
    without ``FollowShape``: the point ``ray(t)``, the normal the disk's frame's, uv
    ``(r, phi / 2 pi)`` from Embree's local hit (``pi.prim_uv``), dp/du the radial direction
    and dp/dv the tangent times 2 pi r through ``to_world``."""
    row = _row(rec, sl, valid, 12)
    lin, n = row[:9], mi.Vector3f(*row[9:12])
    p = dr.fma(pi.d, pi.t, pi.o)                        # Ray::operator()
    q = pi.prim_uv
    r_2 = dr.squared_norm(q)
    inv_r = dr.select(r_2 != 0.0, dr.rsqrt(r_2), 0.0)
    r = r_2 * inv_r
    v = dr.atan2(q.y, q.x) * dr.inv_two_pi
    uv = mi.Point2f(r, dr.select(v < 0.0, v + 1.0, v))
    cos_phi, sin_phi = q.x * inv_r, q.y * inv_r
    du = _linear(lin, mi.Vector3f(cos_phi, sin_phi, 0.0))
    dv = _linear(lin, mi.Vector3f(-sin_phi, cos_phi, 0.0)) * (mi.Float(2.0 * dr.pi) * r)
    return p, n, n, uv, du, dv


def _nearest_custom(tables, o, d, tmin, tmax, active, cost, eye, t, slot, prim):
    """:func:`nearest` over the links1 shapes, from the Mitsuba hit ``(t, slot, prim)``."""
    # ties at the same distance go to the lower slot (file order), as in the core
    # (links1.geometry.accel): a shape after the current best may not tie, one before it may
    buf = tables.eye_buf if eye else None
    films = getattr(buf, "blobs", {})     # the blobs' candidates per film cell (lightbuffer.plan_eye)
    for spec in tables.custom_unrolled:
        tt = dr.minimum(t, tmax)
        tt = dr.select(slot > spec.slot, next_up(tt), tt)
        if spec.__class__.__name__ == "BlobSpec":
            tc, pc = spec.intersect(o, d, tmin, tt, active, cost, film=films.get(spec.slot))
        else:
            tc, pc = spec.intersect(o, d, tmin, tt, active)
            cost += dr.select(active, mi.UInt32(1), 0)
        better = (tc < t) | ((tc == t) & (slot > spec.slot))
        t = dr.select(better, tc, t)
        slot = dr.select(better, spec.slot, slot)
        prim = dr.select(better, pc, prim)
    if tables.bvh is not None:
        buf = buf if getattr(buf, "bvh", None) is not None else None    # (EyeBlobs: blobs only)
        tq, q, part, found = (buf or tables.bvh).nearest(o, d, tmin, next_up(dr.minimum(t, tmax)), active, cost)
        sq = mi.Int32(dr.gather(mi.UInt32, tables.bvh.slot, q, found))
        better = found & ((tq < t) | ((tq == t) & ((slot < 0) | (sq < slot))))
        t = dr.select(better, tq, t)
        slot = dr.select(better, sq, slot)
        prim = dr.select(better, part, prim)
    return t, slot, prim


def shadow_custom(tables, o, d, smax, active, cost, specs=None, light=None):
    """Transmittance (3-3-3) through the links1 shapes: product of shadow_t over the
    shapes the segment hits, once per shape. The BVH's quadrics through the light
    buffer of analytic light ``light`` where it has one (lightbuffer.py), else the BVH."""
    T = dr.select(active, mi.Color3f(1.0), mi.Color3f(0.0))
    specs = tables.custom if specs is None else specs
    lb = tables.lbuf[light] if light is not None and light < len(tables.lbuf) else None
    grids = getattr(lb, "blobs", {})      # the blobs' candidates per cell (lightbuffer.plan)
    if tables.bvh is not None:
        if any(sp.slot in tables.bvh_slots for sp in specs):
            if getattr(lb, "bvh", None) is not None:     # (EyeBlobs: blobs only)
                T = lb.transmittance(o, d, smax, active, cost)
            else:
                T = tables.bvh.transmittance(o, d, smax, active, cost)
        specs = [sp for sp in specs if sp.slot not in tables.bvh_slots]
    for spec in specs:
        st = tables.shadow_t_np[spec.slot]
        act = active & (dr.max(T) > 0)
        if spec.__class__.__name__ == "BlobSpec":
            tc, _ = spec.intersect(o, d, 0.0, smax, act, cost, any_hit=True, film=grids.get(spec.slot))
        else:
            tc, _ = spec.intersect(o, d, 0.0, smax, act)
            cost += dr.select(act, mi.UInt32(1), 0)
        hit = act & (tc < INF)
        T = dr.select(hit, T * color3(st), T)
    return T


def meets_boxes(o, d, smax, boxes, own):
    """Lanes whose segment ``o + t d``, 0 <= t <= smax, can meet one of ``boxes``
    (``shadow_plan.occluder_boxes``): a slab test made conservative in float32 (Ize 2013: the
    far distance widened by 1 + 2 gamma_3; the segment's end by 2^-16); a zero
    direction component is replaced by 1e-30 (no 0 * inf). A convex shape's box is skipped where the ray leaves that shape
    on its outer side (``own``: the hit's slot there, else -1; the rule of
    ``shadow_plan.plan_occluders``)."""
    widen = 1.0 + 2.0 * (3.0 * 2.0 ** -24) / (1.0 - 3.0 * 2.0 ** -24)
    inv = [1.0 / dr.select(d[k] == 0, 1e-30, d[k]) for k in range(3)]
    far_max = smax * (1.0 + 2.0 ** -16)   # Mitsuba's t at a segment's end: its own rounding
    meet = dr.zeros(mi.Bool, dr.width(o))
    for lo, hi, sl, convex in boxes:
        near, far = mi.Float(0.0), far_max
        for k in range(3):
            t0 = (lo[k] - o[k]) * inv[k]
            t1 = (hi[k] - o[k]) * inv[k]
            near = dr.maximum(near, dr.minimum(t0, t1))
            far = dr.minimum(far, dr.maximum(t0, t1) * widen)
        m = near <= far
        if convex:
            m &= own != sl
        meet |= m
    return meet


def shadow_mitsuba(tables, scene, o, d, smax, active, T, cost, tuning, light=None, own=None, coherent=False):
    """Continue the transmittance ``T`` through Mitsuba's shapes (once per shape): per
    group of shapes (:func:`_shadow_groups`) its query, which a packet whose segments
    meet none of the group's occluder boxes of ``light`` skips (``tables.occ_boxes``;
    ``own``: see :func:`meets_boxes`; ``tuning``: the
    switches box_cull, split and preliminary of :class:`~.tuning.Tuning`). ``coherent``: the
    segments start at the camera rays' hits (neighbours in the lanes), their any-hit queries in
    Embree's coherent mode where ``tuning.coherent_shadows`` (the same answers)."""
    if not tables.any_mitsuba_shapes:
        return T
    boxes = tables.occ_boxes[light] if tuning.box_cull and light is not None else None
    occ = tables.occ_mslots[light] if light is not None else None
    inc = dr.zeros(mi.UInt32, dr.width(o))
    for slots, query in _shadow_groups(tables, scene, o, d, smax, occ, tuning, coherent and tuning.coherent_shadows):
        mine = None if boxes is None else [b for b in boxes if slots is None or b[2] in slots]
        if mine is not None and not mine:
            continue                       # none of these shapes can shadow this light
        run = active & (dr.max(T) > 0)
        if mine is None:
            T, inc = query(T, inc, run)
        else:
            run &= meets_boxes(o, d, smax, mine, own)
            T, inc = dr.if_stmt((T, inc), run, lambda T, inc, q=query, r=run: q(T, inc, r),
                                lambda T, inc: (T, inc), mode="symbolic", label="links1_shadow_boxes")
    cost += inc
    return T


def _shadow_groups(tables, scene, o, d, smax, occ, tuning, coherent):
    """``[(slots, query)]``: the Mitsuba shapes a shadow segment is tested against, by
    group (``slots`` None: all of them), ``query(T, tests, lanes) -> (T, tests)``. With
    ``tables.shadow_split`` (``shadow_plan.shadow_split``) an any-hit query on the opaque shapes'
    sub-scene (T = 0) and one on each transparent shape's (T times its transmittance),
    skipping groups that cannot occlude (``occ``: the light's occluder slots); else the
    scene with :func:`_shadow_embree` (in Embree's coherent mode where ``coherent``)."""
    split = tables.shadow_split if tuning.split else None
    if split is None:
        return [(None, lambda T, inc, run: _shadow_embree(tables, scene, o, d, smax, run, T, inc, tuning.preliminary,
                                                          coherent))]
    ray = mi.Ray3f(o, d, smax, 0.0, mi.Color0f())

    def any_hit(sub, st):
        def query(T, inc, run):
            hit = sub.ray_test(ray, active=run)
            return (dr.select(hit, 0.0 if st is None else T * color3(st), T),
                    inc + dr.select(run, mi.UInt32(1), 0))
        return query
    groups = []
    if split["opaque"] is not None and (occ is None or occ & split["opaque_slots"]):
        groups.append((split["opaque_slots"], any_hit(split["opaque"], None)))
    groups += [(frozenset([sl]), any_hit(sub, st)) for sub, sl, st in split["trans"] if occ is None or sl in occ]
    return groups


def _shadow_embree(tables, scene, o, d, smax, act, T, inc, preliminary, coherent=False):
    """Shadow segments of the lanes ``act`` through the whole scene: one any-hit test (in
    Embree's coherent mode where ``coherent``), or with transparent shapes the walk over the
    crossings, nearest first -> (T, tests)."""
    if not tables.any_transparent_mitsuba:
        # (o, d, x) would set time, not maxt
        occluded = scene.ray_test(mi.Ray3f(o, d, smax, 0.0, mi.Color0f()), coherent, act)
        return dr.select(occluded, 0.0, T), inc + dr.select(act, mi.UInt32(1), 0)
    reg_to_slot, bits_t, words_t, sh_t = tables.reg_to_slot, tables.trans_bits, tables.trans_words, tables.shadow_t
    nwords, max_crossings = tables.trans_nwords, tables.max_crossings

    def cond(o, tleft, T, seen, run, it, cost):
        return run

    def body(o, tleft, T, seen, run, it, cost):
        ray = mi.Ray3f(o, d, tleft, 0.0, mi.Color0f())
        if preliminary:
            # the full surface record only where the ray goes on (a transparent hit):
            # scene.ray_intersect is this preliminary test plus compute_surface_interaction
            pi = scene.ray_intersect_preliminary(ray, active=run)
            hit = run & pi.is_valid()
            shape = pi.shape
        else:
            si = scene.ray_intersect(ray, active=run)
            hit = run & si.is_valid()
            shape = si.shape
        cost += dr.select(run, mi.UInt32(1), 0)
        reg = dr.reinterpret_array(mi.UInt32, shape)
        slot = dr.gather(mi.Int32, reg_to_slot, reg, hit)
        bit = dr.gather(mi.UInt32, bits_t, mi.UInt32(slot), hit)
        word = dr.gather(mi.UInt32, words_t, mi.UInt32(slot), hit)
        opaque = hit & (bit == 0)
        if preliminary:
            si = pi.compute_surface_interaction(ray, mi.RayFlags.All, hit & ~opaque)
        mine = [hit & (bit != 0) & (word == k) for k in range(nwords)]
        new = hit & mi.Bool(False)
        for k in range(nwords):
            new = new | (mine[k] & ((seen[k] & bit) == 0))
        T = dr.select(opaque, 0.0, T)
        T = dr.select(new, T * gather3(sh_t, mi.UInt32(slot), new), T)
        seen = [dr.select(new & mine[k], seen[k] | bit, seen[k]) for k in range(nwords)]
        nxt = si.spawn_ray(d)
        tleft = dr.select(hit, tleft - si.t, tleft)
        o = dr.select(hit, nxt.o, o)
        it += 1
        run = hit & ~opaque & (it < max_crossings) & (tleft > 0)
        return o, tleft, T, seen, run, it, cost

    n = dr.width(o)
    state = (mi.Point3f(o), mi.Float(smax), T, [dr.zeros(mi.UInt32, n) for _ in range(nwords)], mi.Bool(act),
             dr.zeros(mi.UInt32, n), dr.zeros(mi.UInt32, n))
    o, tleft, T, seen, run, it, c_loop = dr.while_loop(state, cond, body)
    return T, inc + c_loop


def custom_uv(tables, o, d, t, prim, slot, uslot, hit):
    """uv of the hits on links1_quadric shapes with textured BSDFs (0 elsewhere)."""
    uv = mi.Point2f(0.0)
    if not tables.uv_slots:
        return uv
    for spec in tables.custom_unrolled:
        if spec.slot in tables.uv_slots:
            uv = dr.select(slot == spec.slot, spec.uv(o, d, t, prim), uv)
    if tables.bvh is not None and tables.uv_slots & tables.bvh_slots:
        qi = dr.gather(mi.Int32, tables.bvh.slot_to_q, uslot, hit)
        m = hit & (qi >= 0)
        uv = dr.select(m, quadric_uv(*tables.bvh.object_point(mi.UInt32(dr.maximum(qi, 0)), o, d, t, m)), uv)
    return uv


def moving_hits(tables, o, d, t, slot, prim, p, ng, ns):
    """The hits on links1 shapes moving with their parameters and with the ray (``o``,
    ``d`` are attached below a moving surface), in a derivative pass (``tables.geo_ad``:
    gradients.py): ``(t, p, ng, ns)`` with the interior derivative
    (:func:`geometry.surface_ad`: implicit differentiation of the surface equation at the
    primal hit)."""
    moving_ray = dr.grad_enabled(o) or dr.grad_enabled(d)
    custom = False
    for sp in tables.custom_unrolled:
        held = tables.geo_ad.get(sp.slot)
        if held is None and not moving_ray:
            continue
        m = slot == sp.slot
        tn, nn = geometry.surface_ad(mi, dr, sp, held[1] if held else {}, o, d, t, prim, m, tables.ad_memo)
        t = dr.select(m, tn, t)
        ng = dr.select(m, nn, ng)
        ns = dr.select(m, nn, ns)
        custom = True
    if custom:
        p = dr.select(_custom_slot(tables, slot), o + d * t, p)
    return t, p, ng, ns


def _custom_slot(tables, slot):
    m = dr.zeros(mi.Bool, dr.width(slot))
    for sp in tables.custom_unrolled:
        m |= slot == sp.slot
    return m
