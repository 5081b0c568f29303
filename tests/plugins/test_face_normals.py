"""Where a scene's one Mitsuba shape is a triangle mesh, links1_whitted makes its geometric normal
(the shadow rays' offset side) itself from the mesh's faces and vertices
(``tables._face_normal_table``, ``raytree._face_normal``) with the operations of Mitsuba's
``Mesh::face_normal``, instead of reading ``si.n`` from Mitsuba's record.

The reference is Mitsuba's ``si.n`` itself: on a scene's camera-ray hits the two are equal bit
for bit, and the frame with the table taken away (Mitsuba's normal) is the frame with it; scenes
with another shape, two meshes or flipped normals keep Mitsuba's normal."""
from __future__ import annotations

import numpy as np
import pytest

from tests.scenes import perspective, scene

pytestmark = pytest.mark.mitsuba

LAMP = '<emitter type="point"><point name="position" x="1" y="5" z="2"/><rgb name="intensity" value="20"/></emitter>'
MESH = ('<shape type="obj"><string name="filename" value="{obj}"/>{extra}'
        '<bsdf type="twosided"><bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.5, 0.4"/></bsdf></bsdf></shape>')
SPHERE = '<shape type="sphere"><point name="center" x="1.2" y="0.5" z="0.5"/><float name="radius" value="0.4"/></shape>'

#: a floor (texture coordinates on its two triangles) and a tetrahedron over it that shadows it
OBJ = """v -3 0 -3
v 3 0 -3
v 3 0 3
v -3 0 3
v -0.2 1.6 0.2
v -0.8 0.4 0.8
v -0.8 1.2 -0.4
v 0.4 0.6 -0.2
vt 0 0
vt 1 0
vt 1 1
vt 0 1
f 1/1 3/3 2/2
f 1/1 4/4 3/3
f 5 6 7
f 5 8 6
f 5 7 8
f 6 8 7
"""


def _load(tmp_path, flip=False, sphere=False, two=False):
    import links1_mitsuba as lm
    path = tmp_path / "floor_tetra.obj"
    path.write_text(OBJ)
    extra = '<boolean name="flip_normals" value="true"/>' if flip else ""
    second = MESH.format(obj=path, extra='<transform name="to_world"><translate x="7"/></transform>') if two else ""
    return lm.load_string(scene(perspective("0, 3, 6", "0, 0.5, 0", fov=45, width=24, height=20, spp=2),
                                '<integrator type="links1_whitted"/>', LAMP, MESH.format(obj=path, extra=extra),
                                SPHERE if sphere else "", second))


def _frame(s, own):
    """A frame of ``s`` with its tables' face normals (``own``) or Mitsuba's everywhere, and
    whether the tables have them (the launches recorded anew)."""
    import mitsuba as mi
    engine = s.integrator().engine
    mi.render(s, seed=1)                       # the tables
    base = engine.tables.last.base or engine.tables.last
    table = base.face_normals
    base.face_normals = table if own else None
    engine.launches.forget()
    try:
        return np.array(mi.render(s, seed=1)), table is not None
    finally:
        base.face_normals = table
        engine.launches.forget()


@pytest.mark.parametrize("flip, sphere, two, made", [
    (False, False, False, True), (True, False, False, False), (False, True, False, False),
    (False, False, True, False)], ids=["one mesh", "flipped", "with a sphere", "two meshes"])
def test_face_normals_render_mitsubas(variant, tmp_path, flip, sphere, two, made):
    s = _load(tmp_path, flip, sphere, two)
    own, has = _frame(s, True)
    mitsuba, _ = _frame(s, False)
    assert has == made
    assert np.count_nonzero(own) > own.size // 2
    np.testing.assert_array_equal(own, mitsuba)


def test_face_normal_is_mitsubas_si_n(variant, tmp_path):
    import drjit as dr
    import mitsuba as mi

    from links1_mitsuba.raytree import _face_normal
    s = _load(tmp_path)
    mi.render(s, spp=1)
    table = s.integrator().engine.tables.last.face_normals
    n = 64 * 64
    i = dr.arange(mi.UInt32, n)
    pos = mi.Point2f((mi.Float(i % 64) + 0.37) / 64, (mi.Float(i // 64) + 0.61) / 64)
    ray, _ = s.sensors()[0].sample_ray(0.0, 0.5, pos, mi.Point2f(0.5))
    si = s.ray_intersect(ray)
    valid = np.array(si.is_valid())
    hits_tetra = np.array(si.prim_index)[valid] >= 2
    assert valid.sum() > n // 2 and hits_tetra.sum() > 50
    np.testing.assert_array_equal(np.array(_face_normal(table, si)), np.array(si.n))
