"""Where every Mitsuba shape of a scene is a mesh (triangle meshes, rectangles, cubes), a sphere or
a disk, or an instance of shapegroups of them, links1_whitted makes the nearest hit's surface
record itself from Embree's preliminary hit and the shapes' buffers and transforms
(``tables.MeshRecord``, ``intersect.mesh_surface``) with the operations of Mitsuba's
``compute_surface_interaction`` of each (an instance's: its member's, transformed back),
instead of ``scene.ray_intersect``'s record.

The reference is Mitsuba's record itself: on rays aimed at every shape (texture coordinates or
not, vertex normals or face normals, flipped normals; spheres, rectangles and disks under
rotations, non-uniform and negative scales, rays from inside and segments that end before a
hit; instances under rotations, non-uniform and negative scales) each field is equal bit for
bit, and the slot and shape hit, and the frame with the record taken away (Mitsuba's) is the
frame with it; a scene with another shape keeps Mitsuba's record."""
from __future__ import annotations

import numpy as np
import pytest

from tests.scenes import perspective, scene

pytestmark = pytest.mark.mitsuba

LAMP = '<emitter type="point"><point name="position" x="1" y="5" z="2"/><rgb name="intensity" value="20"/></emitter>'
CHECKER = ('<bsdf type="diffuse"><texture type="checkerboard" name="reflectance">'
           '<transform name="to_uv"><scale x="5" y="5"/></transform></texture></bsdf>')
PLASTIC = '<bsdf type="plastic"/>'
MIRROR = '<bsdf type="conductor"/>'
SPHERE = '<shape type="sphere"><point name="center" x="1.2" y="0.5" z="0.5"/><float name="radius" value="0.4"/></shape>'
CYLINDER = '<shape type="cylinder"><point name="p0" x="1.2" y="0" z="0.5"/><point name="p1" x="1.2" y="0.8" z="0.5"/></shape>'
#: spheres (a flipped one under a non-uniform scale, one mirrored by a negative scale), rectangles
#: and disks (flipped ones, non-uniform scales, rotations off the axes) and a cube
ANALYTIC = [
    '<shape type="sphere"><transform name="to_world"><scale x="0.3" y="0.6" z="0.45"/><rotate x="1" y="1" angle="37"/>'
    '<translate x="-1.5" y="0.8" z="0.2"/></transform><boolean name="flip_normals" value="true"/>{bsdf}</shape>',
    '<shape type="sphere"><transform name="to_world"><scale x="-0.5" y="0.5" z="0.5"/><translate y="1.9" z="-1"/>'
    '</transform>{bsdf}</shape>',
    '<shape type="rectangle"><transform name="to_world"><scale x="0.6" y="0.3"/><rotate y="1" angle="30"/>'
    '<translate x="0.3" y="0.8" z="-1.5"/></transform><boolean name="flip_normals" value="true"/>{bsdf}</shape>',
    '<shape type="rectangle"><transform name="to_world"><scale x="0.4" y="0.7"/><rotate x="1" z="0.5" angle="70"/>'
    '<translate x="1.6" y="1.2" z="1"/></transform>{bsdf}</shape>',
    '<shape type="disk"><transform name="to_world"><scale x="0.5" y="0.8"/><rotate x="1" y="0.3" angle="-60"/>'
    '<translate x="-0.4" y="0.5" z="1.2"/></transform>{bsdf}</shape>',
    '<shape type="disk"><transform name="to_world"><scale value="0.4"/><rotate y="1" angle="120"/>'
    '<translate x="2" y="0.6" z="-0.5"/></transform><boolean name="flip_normals" value="true"/>{bsdf}</shape>',
    '<shape type="cube"><transform name="to_world"><scale x="0.2" y="0.3" z="0.25"/><rotate z="1" angle="20"/>'
    '<translate x="-0.6" y="1.5" z="-0.8"/></transform>{bsdf}</shape>',
]

#: a floor with texture coordinates (its BSDF a checkerboard)
FLOOR = """v -3 0 -3
v 3 0 -3
v 3 0 3
v -3 0 3
vt 0 0
vt 1 0
vt 1 1
vt 0 1
f 1/1 3/3 2/2
f 1/1 4/4 3/3
"""
#: a tetrahedron with vertex normals of its own (smooth shading over flat faces)
TETRA = """v -0.2 1.6 0.2
v -0.8 0.4 0.8
v -0.8 1.2 -0.4
v 0.4 0.6 -0.2
vn 0.1 1 0.1
vn -0.6 -0.3 0.7
vn -0.7 0.2 -0.6
vn 0.8 -0.2 -0.3
f 1//1 2//2 3//3
f 1//1 4//4 2//2
f 1//1 3//3 4//4
f 2//2 4//4 3//3
"""


def _shape(path, bsdf, extra=""):
    return f'<shape type="obj"><string name="filename" value="{path}"/>{extra}{bsdf}</shape>'


def _load(tmp_path, extra=(), meshes=True):
    """The floor, the tetrahedron (a mirror: its reflections are level 2's hits) and the
    tetrahedron again shifted, flat shaded (``face_normals``) with flipped normals (without
    ``meshes``: none of them), then the shapes ``extra``."""
    import links1_mitsuba as lm
    floor, tetra = tmp_path / "floor.obj", tmp_path / "tetra.obj"
    floor.write_text(FLOOR)
    tetra.write_text(TETRA)
    moved = ('<transform name="to_world"><translate x="1.4" z="0.3"/></transform>'
             '<boolean name="face_normals" value="true"/><boolean name="flip_normals" value="true"/>')
    mesh = [_shape(floor, CHECKER), _shape(tetra, MIRROR), _shape(tetra, PLASTIC, moved)] if meshes else []
    return lm.load_string(scene(perspective("0, 3, 6", "0, 0.5, 0", fov=45, width=24, height=20, spp=2),
                                '<integrator type="links1_whitted"><integer name="max_depth" value="3"/></integrator>',
                                LAMP, *mesh, *extra))


def _frame(s, own):
    """A frame of ``s`` with its tables' mesh record (``own``) or Mitsuba's record, and
    whether the tables have one (the launches recorded anew)."""
    import mitsuba as mi
    engine = s.integrator().engine
    mi.render(s, seed=1)                       # the tables
    base = engine.tables.last.base or engine.tables.last
    rec = base.mesh_record
    base.mesh_record = rec if own else None
    engine.launches.forget()
    try:
        return np.array(mi.render(s, seed=1)), rec is not None
    finally:
        base.mesh_record = rec
        engine.launches.forget()


def _analytic(bsdfs=(PLASTIC, MIRROR, CHECKER)):
    """The shapes of :data:`ANALYTIC` and a sphere, their BSDFs in turn from ``bsdfs``."""
    return [SPHERE] + [a.format(bsdf=bsdfs[i % len(bsdfs)]) for i, a in enumerate(ANALYTIC)]


@pytest.mark.parametrize("extra, made", [((), True), ("analytic", True), ((CYLINDER,), False)],
                         ids=["meshes", "with spheres, rectangles, disks", "with a cylinder"])
def test_mesh_record_renders_mitsubas(variant, tmp_path, extra, made):
    s = _load(tmp_path, _analytic() if extra == "analytic" else extra)
    own, has = _frame(s, True)
    mitsuba, _ = _frame(s, False)
    assert has == made
    assert np.count_nonzero(own) > own.size // 3
    np.testing.assert_array_equal(own, mitsuba)


def _record_fields_equal(s, n_rays, inside=0.0, short=0.0, box=False):
    """Mitsuba's record (``scene.ray_intersect``) and the kernel's (``mesh_surface``) of rays
    from around ``s`` to points sampled on every shape (``n_rays`` a shape; a share ``inside``
    of them from near the shape's box center, a share ``short`` of segments ending at 2; with
    ``box``: ``n_rays`` rays between random points of the scene's box grown by 1): every field
    equal bit for bit, and the slot of the shape hit. Returns the tables' record and the
    slots hit."""
    import drjit as dr
    import mitsuba as mi

    from links1_mitsuba.intersect import mesh_surface, record_slots
    mi.render(s, spp=1)
    tables = s.integrator().engine.tables.last
    base = tables.base or tables
    rec = base.mesh_record
    rng = np.random.default_rng(3)
    targets, origins = [], []
    for sh in ([] if box else s.shapes()):
        u = rng.random((2, n_rays)).astype(np.float32)
        tg = np.array(sh.sample_position(0.0, mi.Point2f(u[0], u[1])).p)
        o = rng.random(tg.shape) * [[6], [3], [6]] - [[3], [-0.2], [3]]
        center = np.array(sh.bbox().center()).reshape(3, 1)
        near = rng.random(n_rays) < inside
        o[:, near] = center + (rng.random((3, near.sum())) - 0.5) * 0.05
        targets.append(tg)
        origins.append(o.astype(np.float32))
    if box:
        lo, hi = np.array(s.bbox().min).reshape(3, 1), np.array(s.bbox().max).reshape(3, 1)
        targets.append(lo + rng.random((3, n_rays)) * (hi - lo))
        origins.append(lo - 1 + rng.random((3, n_rays)) * (hi - lo + 2))
    tg, o = np.concatenate(targets, axis=1), np.concatenate(origins, axis=1).astype(np.float32)
    ray = mi.Ray3f(mi.Point3f(o), dr.normalize(mi.Vector3f((tg - o).astype(np.float32))))
    ray.maxt = mi.Float(np.where(rng.random(tg.shape[1]) < short, 2.0, np.inf).astype(np.float32))
    si = s.ray_intersect(ray)
    pi = s.ray_intersect_preliminary(ray)
    valid = pi.is_valid()
    slot, inst, islot = record_slots(base, rec, pi, valid)
    mine = mesh_surface(rec, ray, pi, slot, valid, inst, islot)
    for name in ("t", "p", "n", "uv", "dp_du", "dp_dv", "dn_du", "dn_dv", "wi", "prim_index",
                 "sh_frame.s", "sh_frame.t", "sh_frame.n", "time"):
        a, b = si, mine
        for part in name.split("."):
            a, b = getattr(a, part), getattr(b, part)
        np.testing.assert_array_equal(np.array(b), np.array(a), err_msg=name)
    for name in ("shape", "instance"):
        np.testing.assert_array_equal(np.array(dr.reinterpret_array(mi.UInt32, getattr(mine, name))),
                                      np.array(dr.reinterpret_array(mi.UInt32, getattr(si, name))), err_msg=name)
    ok = si.is_valid()
    theirs = dr.select(ok, dr.gather(mi.Int32, base.reg_to_slot, dr.reinterpret_array(mi.UInt32, si.shape), ok), -1)
    np.testing.assert_array_equal(np.array(slot), np.array(theirs))
    # the slot of a hit found in the kernel, from Embree's geometry id (no instance: the
    # shape's index in scene.shapes(); the LLVM variants)
    if inst is None and mi.variant().startswith("llvm"):
        assert base.geom_to_slot is not None
        identity = base.geom_slot_identity
        try:
            for base.geom_slot_identity in {identity, False}:   # the index itself, the table
                gslot, _, _ = record_slots(base, rec, pi, valid, fresh=True)
                np.testing.assert_array_equal(np.array(gslot), np.array(theirs))
        finally:
            base.geom_slot_identity = identity
    elif inst is not None:
        assert base.geom_to_slot is None
    if not box:
        hits = np.bincount(np.array(slot)[np.array(valid)], minlength=len(s.shapes()))
        assert np.all(hits > n_rays // 4), hits
    on_inst = None if inst is None else np.array(inst)[np.array(valid)]
    return rec, np.array(slot)[np.array(valid)], on_inst


@pytest.mark.parametrize("packets", [True, False], ids=["per-face table", "buffers"])
def test_mesh_record_is_mitsubas(variant, tmp_path, monkeypatch, packets):
    """The meshes' record from the per-face table (``MeshRecord.packets``) and, where a scene's
    table would be too big, from the meshes' buffers."""
    from links1_mitsuba import tables
    if not packets:
        monkeypatch.setattr(tables, "FACE_PACKETS_MAX_BYTES", 0)
    rec = _record_fields_equal(_load(tmp_path), 2000)[0]
    # (mixed: one mesh with texture coordinates, one flat shaded, one flipped)
    assert rec.face_off is not None and rec.has_uv is not None and rec.has_n is not None and rec.flip is not None
    assert (rec.packets is not None) == packets


@pytest.mark.parametrize("meshes, dispatch", [
    pytest.param(True, "if", id="with meshes"), pytest.param(False, "if", id="alone"),
    pytest.param(True, "select", id="with meshes, select", marks=pytest.mark.slow),
    pytest.param(True, "switch", id="with meshes, switch", marks=pytest.mark.slow)])
def test_analytic_record_is_mitsubas(variant, tmp_path, monkeypatch, meshes, dispatch):
    """Spheres, rectangles, disks and a cube (with the meshes: every kind's operations in
    one kernel, each lane's kind picked by each way of ``intersect.DISPATCH``)."""
    from links1_mitsuba import intersect
    monkeypatch.setattr(intersect, "DISPATCH", dispatch)
    rec = _record_fields_equal(_load(tmp_path, _analytic(), meshes=meshes), 1000, inside=0.3, short=0.1)[0]
    kinds = {intersect.KIND_MESH, intersect.KIND_RECT, intersect.KIND_SPHERE, intersect.KIND_DISK}
    assert rec.kinds == kinds and rec.kind is not None and rec.rows is not None


def _instanced(tmp_path, analytic):
    """A Mitsuba scene (``mi.load_string``: its instances kept, as links1_mitsuba's loader
    does not) with two shapegroups, the tetrahedron with vertex normals (and, with
    ``analytic``, a flipped sphere, a rectangle and a disk) and a cube, instanced four times
    (no transform, a translation, a rotation over a non-uniform scale, a negative scale), over
    a floor outside them."""
    import mitsuba as mi

    from links1_mitsuba import register
    register(mi.variant())
    tetra = tmp_path / "tetra.obj"
    tetra.write_text(TETRA)
    members = [_shape(tetra, PLASTIC)]
    if analytic:
        members += [
            '<shape type="sphere"><point name="center" x="1" y="0.5" z="0"/><float name="radius" value="0.4"/>'
            f'<boolean name="flip_normals" value="true"/>{MIRROR}</shape>', ANALYTIC[3].format(bsdf=PLASTIC),
            ANALYTIC[4].format(bsdf=MIRROR)]
    inst = '<shape type="instance"><ref id="{}"/>{}</shape>'
    return mi.load_string(scene(
        perspective("0, 3, 8", "0, 0.5, 0", fov=45, width=24, height=20, spp=2),
        '<integrator type="links1_whitted"><integer name="max_depth" value="3"/></integrator>', LAMP,
        '<shape type="shapegroup" id="g1">' + "".join(members) + "</shape>",
        '<shape type="shapegroup" id="g2">' + ANALYTIC[6].format(bsdf=PLASTIC) + "</shape>",
        inst.format("g1", ""), inst.format("g2", '<transform name="to_world"><translate x="2" y="1"/></transform>'),
        inst.format("g1", '<transform name="to_world"><scale x="0.7" y="1.3" z="0.9"/><rotate x="0.3" y="1" '
                          'angle="50"/><translate x="-2.2" z="-1"/></transform>'),
        inst.format("g1", '<transform name="to_world"><scale x="-0.8" y="0.8" z="0.8"/>'
                          '<translate x="2.5" y="-0.5" z="1"/></transform>'),
        '<shape type="rectangle"><transform name="to_world"><scale value="5"/><rotate x="1" angle="-90"/>'
        f'<translate y="-1.2"/></transform>{CHECKER}</shape>'))


@pytest.mark.parametrize("analytic", [False, True], ids=["meshes", "meshes, spheres, rectangles, disks"])
def test_instance_record_is_mitsubas(variant, tmp_path, analytic):
    """Hits on instances: the member's record in the group's space transformed back by the
    instance's ``to_world`` (Mitsuba's ``Instance::compute_surface_interaction``), the member's
    slot and shape, the instance."""
    if not variant.startswith("llvm"):
        pytest.skip("the member's slot from Embree's shape_index: LLVM variants alone make the record on instances")
    s = _instanced(tmp_path, analytic)
    rec, slots, on_inst = _record_fields_equal(s, 40000, box=True)
    assert rec.member_of is not None and rec.inst_obj == analytic
    # every member hit through an instance, many times
    members, counts = np.unique(slots[on_inst], return_counts=True)
    assert set(members) == set(np.array(rec.member_of)) and len(members) == (5 if analytic else 2)
    assert counts.min() > 100, counts


@pytest.mark.parametrize("analytic", [False, True], ids=["meshes", "meshes, spheres, rectangles, disks"])
def test_instance_record_renders_mitsubas(variant, tmp_path, analytic):
    s = _instanced(tmp_path, analytic)
    own, has = _frame(s, True)
    mitsuba, _ = _frame(s, False)
    assert has == variant.startswith("llvm")
    assert np.count_nonzero(own) > own.size // 3
    np.testing.assert_array_equal(own, mitsuba)
