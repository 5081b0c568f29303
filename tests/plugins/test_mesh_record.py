"""Where every Mitsuba shape of a scene is a triangle mesh outside instances, links1_whitted makes
the nearest hit's surface record itself from Embree's preliminary hit and the meshes' buffers
(``tables.MeshRecord``, ``intersect.mesh_surface``) with the operations of Mitsuba's
``Mesh::compute_surface_interaction``, instead of ``scene.ray_intersect``'s record.

The reference is Mitsuba's record itself: on rays aimed at every mesh (texture coordinates or
not, vertex normals or face normals, flipped normals) each field is equal bit for bit, and the
frame with the record taken away (Mitsuba's) is the frame with it; a scene with another shape
keeps Mitsuba's record."""
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


def _load(tmp_path, sphere=False):
    """The floor, the tetrahedron (a mirror: its reflections are level 2's hits) and the
    tetrahedron again shifted, flat shaded (``face_normals``) with flipped normals."""
    import links1_mitsuba as lm
    floor, tetra = tmp_path / "floor.obj", tmp_path / "tetra.obj"
    floor.write_text(FLOOR)
    tetra.write_text(TETRA)
    moved = ('<transform name="to_world"><translate x="1.4" z="0.3"/></transform>'
             '<boolean name="face_normals" value="true"/><boolean name="flip_normals" value="true"/>')
    return lm.load_string(scene(perspective("0, 3, 6", "0, 0.5, 0", fov=45, width=24, height=20, spp=2),
                                '<integrator type="links1_whitted"><integer name="max_depth" value="3"/></integrator>',
                                LAMP, _shape(floor, CHECKER), _shape(tetra, MIRROR), _shape(tetra, PLASTIC, moved),
                                SPHERE if sphere else ""))


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


@pytest.mark.parametrize("sphere, made", [(False, True), (True, False)], ids=["meshes", "with a sphere"])
def test_mesh_record_renders_mitsubas(variant, tmp_path, sphere, made):
    s = _load(tmp_path, sphere)
    own, has = _frame(s, True)
    mitsuba, _ = _frame(s, False)
    assert has == made
    assert np.count_nonzero(own) > own.size // 2
    np.testing.assert_array_equal(own, mitsuba)


def test_mesh_record_is_mitsubas(variant, tmp_path):
    import drjit as dr
    import mitsuba as mi

    from links1_mitsuba.intersect import mesh_surface
    s = _load(tmp_path)
    mi.render(s, spp=1)
    tables = s.integrator().engine.tables.last
    rec = (tables.base or tables).mesh_record
    # (mixed: one mesh with texture coordinates, one flat shaded, one flipped)
    assert rec.face_off is not None and rec.has_uv is not None and rec.has_n is not None and rec.flip is not None
    # rays from around the scene to points sampled on every mesh
    rng = np.random.default_rng(3)
    targets = []
    for sh in s.shapes():
        u = rng.random((2, 2000)).astype(np.float32)
        targets.append(np.array(sh.sample_position(0.0, mi.Point2f(u[0], u[1])).p))
    tg = np.concatenate(targets, axis=1)
    o = (rng.random(tg.shape) * [[6], [3], [6]] - [[3], [-0.2], [3]]).astype(np.float32)
    ray = mi.Ray3f(mi.Point3f(o), mi.Vector3f((tg - o).astype(np.float32)))
    ray.d = dr.normalize(ray.d)
    si = s.ray_intersect(ray)
    pi = s.ray_intersect_preliminary(ray)
    valid = pi.is_valid()
    reg = dr.reinterpret_array(mi.UInt32, pi.shape)
    slot = dr.select(valid, dr.gather(mi.Int32, tables.reg_to_slot, reg, valid), -1)
    mine = mesh_surface(rec, ray, pi, slot, valid)
    hits = np.bincount(np.array(slot)[np.array(valid)], minlength=3)
    assert np.all(hits > 300), hits
    for name in ("t", "p", "n", "uv", "dp_du", "dp_dv", "wi", "prim_index", "sh_frame.s", "sh_frame.t", "sh_frame.n"):
        a, b = si, mine
        for part in name.split("."):
            a, b = getattr(a, part), getattr(b, part)
        np.testing.assert_array_equal(np.array(b), np.array(a), err_msg=name)
    np.testing.assert_array_equal(np.array(reg), np.array(dr.reinterpret_array(mi.UInt32, mine.shape)))
