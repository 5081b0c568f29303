"""Shadow-ray planning on Mitsuba's meshes follows the core's planar rule
(links1.tracing.occluders): a planar mesh (a floor, a wall) is convex and shadows nothing toward
a light that it and every other shape have on one side. The plan for OBJ meshes equals the
core's on the same geometry (its own meshes, built here from the corners) but for the closed
convex box, which the plugin leaves an occluder of itself (``shadow_plan._mesh_rules``), and
the frame it plans is the frame without the rule, bit for bit, with fewer shadow rays where
only planar meshes could occlude."""
from __future__ import annotations

import numpy as np
import pytest

from tests.scenes import perspective, scene, whitted

pytestmark = pytest.mark.mitsuba

# a floor quad (y = 0), a box standing on it, and an open mesh folded along x = 0 (neither
# planar nor closed), all in world coordinates
FLOOR_V = np.array([[-4.0, 0, -4], [4, 0, -4], [4, 0, 4], [-4, 0, 4]])
FLOOR_F = np.array([[0, 2, 1], [0, 3, 2]])
BOX_LO, BOX_HI = np.array([-1.0, 0.0, -0.5]), np.array([0.5, 1.5, 1.0])
FOLD_V = np.array([[-1.0, 2.5, -3], [0, 2.0, -3], [0, 2.0, -2], [-1, 2.5, -2], [1, 2.5, -3], [1, 2.5, -2]])
FOLD_F = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]])


def _box():
    """The box's 8 corners and 12 outward-wound faces."""
    c = np.array([[x, y, z] for x in (BOX_LO[0], BOX_HI[0]) for y in (BOX_LO[1], BOX_HI[1])
                  for z in (BOX_LO[2], BOX_HI[2])])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return c, np.array([t for a, b, cc, d in quads for t in ((a, b, cc), (a, cc, d))])


def _obj(path, v, f, split):
    """An OBJ file of ``v``, ``f``; ``split``: one normal per face (``vn``), so that Mitsuba's
    loader makes each face's vertices its own."""
    lines = [f"v {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in v]
    for k, (a, b, c) in enumerate(f):
        if split:
            n = np.cross(v[b] - v[a], v[c] - v[a])
            lines.append("vn {!r} {!r} {!r}".format(*(float(c_) for c_ in n / np.linalg.norm(n))))
            lines.append(f"f {a + 1}//{k + 1} {b + 1}//{k + 1} {c + 1}//{k + 1}")
        else:
            lines.append(f"f {a + 1} {b + 1} {c + 1}")
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def _scene(tmp_path, light, fold=True, box=True):
    bv, bf = _box()
    files = {"floor": _obj(tmp_path / "floor.obj", FLOOR_V, FLOOR_F, False),
             "box": _obj(tmp_path / "box.obj", bv, bf, True) if box else None,
             "fold": _obj(tmp_path / "fold.obj", FOLD_V, FOLD_F, False) if fold else None}
    shapes = "".join(f'<shape type="obj" id="{k}"><string name="filename" value="{p}"/>'
                     f'<bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf></shape>'
                     for k, p in files.items() if p is not None)
    return scene(whitted(1), perspective("3,6,9", "0,0.5,0", fov=45, width=32, height=24, spp=2),
                 f'<emitter type="point"><point name="position" value="{light}"/>'
                 f'<rgb name="intensity" value="40"/></emitter>{shapes}')


def _core_plan(light):
    from links1.geometry.shapes import TriangleMesh
    from links1.shading.lights import PointLight
    from links1.tracing.occluders import closed_convex, shadow_plan, _convex, _plane_of
    bv, bf = _box()
    meshes = {"floor": TriangleMesh(FLOOR_V, FLOOR_F), "box": TriangleMesh(bv, bf),
              "fold": TriangleMesh(FOLD_V, FOLD_F)}
    shapes = list(meshes.values())
    occ, _ = shadow_plan(shapes, [PointLight(np.array(light), np.ones(3))])
    return {k: dict(convex=_convex(m), closed=bool(closed_convex([m])[0]), planar=_plane_of(m) is not None,
                    occluder=bool(occ[0][i])) for i, (k, m) in enumerate(meshes.items())}


@pytest.mark.parametrize("light", [(1.5, 4.0, 2.0), (-3.0, 3.0, -2.5)])
def test_the_plan_on_obj_meshes_is_the_cores(variant, tmp_path, light):
    import links1_mitsuba
    sc = links1_mitsuba.load_string(_scene(tmp_path, ",".join(map(str, light))))
    tables = sc.integrator().prepare(sc)
    base = tables.base or tables
    G = base.occ_shapes
    want = _core_plan(light)
    got = {}
    for s, sl in zip(base.shape_list, base.slot_list):
        got[s.id()] = dict(convex=bool(G["convex"][sl]), closed=bool(G["closed"][sl]),
                           planar=G["plane"][sl] is not None, occluder=sl in base.occ_mslots[0])
    # the box: closed and convex for the core, neither for the plugin (an occluder either way)
    assert want["box"]["closed"] and want["box"]["occluder"]
    want["box"].update(convex=False, closed=False)
    assert got == want
    # the rule acts: the floor never shadows; the fold is neither planar nor convex
    assert not want["floor"]["occluder"] and not want["fold"]["convex"]


def test_the_frame_is_the_one_without_the_mesh_rule(variant, tmp_path, monkeypatch):
    import links1_mitsuba
    import mitsuba as mi
    from links1_mitsuba import shadow_plan

    def frames(xml):
        sc = links1_mitsuba.load_string(xml)
        img = np.array(mi.render(sc, spp=2))
        return img, sc.integrator().stats["shadow"]
    # the box and the fold shadow the floor; without them the floor's hits need no shadow ray
    xmls = [_scene(tmp_path, "1.5,4,2"), _scene(tmp_path, "1.5,4,2", fold=False, box=False)]
    now = [frames(x) for x in xmls]
    monkeypatch.setattr(shadow_plan, "_mesh_rules", lambda s_: (False, False, None))
    ref = [frames(x) for x in xmls]
    for (img, _), (img_ref, _) in zip(now, ref):
        assert np.array_equal(img, img_ref)
        assert np.count_nonzero(img_ref) > 0.3 * img_ref.size
    assert now[0][1] == ref[0][1] and now[1][1] == 0 < ref[1][1]
