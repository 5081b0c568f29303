"""Mitsuba's ``ellipsoids`` and ``ellipsoidsmesh`` in the core (links1.geometry.ellipsoids): hit
distances and normals in closed form (axis-aligned and turned by a quaternion), back faces
culled, Mitsuba's PLY placement rule (to_world, scale_factor, extent, adaptive clamping), the
shells, and the loader's one-line refusals. Against Mitsuba itself:
tests/plugins/test_ellipsoids_vs_mitsuba.py."""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from links1 import load_scene
from links1.errors import SceneError
from links1.geometry import ellipsoids as ell

C = np.array([1.0, 2.0, 3.0])
S = np.array([2.0, 1.0, 0.5])


def _one(quat=(0.0, 0.0, 0.0, 1.0), mesh=False, **kw):
    rot = ell.quat_matrix(np.array([quat], dtype=np.float64))
    cls = ell.EllipsoidsMesh if mesh else ell.Ellipsoids
    return cls(C[None], rot, S[None], **kw)


def test_axis_aligned_hit_and_normal():
    """A ray along +x at height y = 0.5 meets (x/2)² + (y/1)² = 1 at x = -2 sqrt(3/4); the
    normal is the gradient (x/4, y, 0) normalised."""
    e = _one()
    o = C + np.array([-10.0, 0.5, 0.0])
    t, prim = e.intersect(o[None], np.array([[1.0, 0.0, 0.0]]), 0.0, np.inf)
    x = -2.0 * math.sqrt(0.75)
    assert prim[0] == 0 and t[0] == pytest.approx(10.0 + x, abs=1e-13)
    _, ng, ns = e.surface(o[None], np.array([[1.0, 0.0, 0.0]]), t, prim)
    g = np.array([x / 4.0, 0.5, 0.0])
    assert np.allclose(ng[0], g / np.linalg.norm(g), atol=1e-14) and np.array_equal(ng, ns)
    assert np.array_equal(e.uv(o[None], np.array([[1.0, 0.0, 0.0]]), t, prim), [[0.0, 0.0]])
    lo, hi = e.bounds()                      # the exact box: centre ± semi-axes
    assert np.allclose(lo, C - S) and np.allclose(hi, C + S)


def test_quaternion_turns_the_axes():
    """A quarter turn about z (q = (0, 0, sin 45°, cos 45°)) puts the long semi-axis (2) on y:
    a ray down the y axis hits at distance 10 - 2 with normal +y, one along x at 10 - 1."""
    h = math.sqrt(0.5)
    e = _one((0.0, 0.0, h, h))
    o = np.array([C + [0.0, 10.0, 0.0], C + [-10.0, 0.0, 0.0]])
    d = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])
    t, prim = e.intersect(o, d, 0.0, np.inf)
    assert np.allclose(t, [8.0, 9.0], atol=1e-13)
    _, ng, _ = e.surface(o, d, t, prim)
    assert np.allclose(ng, [[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]], atol=1e-14)


def test_random_rays_land_on_the_surface_and_back_faces_are_culled():
    """Hits of random rays lie on |diag(1/s) Rᵀ (p - c)| = 1 with the normal along its
    gradient; a ray from the centre (inside) sees nothing, one from outside stops at the entry,
    and a segment ending before the entry misses."""
    q = np.array([0.3, -0.2, 0.5, 0.8])
    e = _one(q / np.linalg.norm(q))
    rng = np.random.default_rng(3)
    o = rng.normal(size=(500, 3))
    o = C + 6.0 * o / np.linalg.norm(o, axis=1)[:, None]
    d = C + rng.normal(size=(500, 3)) - o
    d /= np.linalg.norm(d, axis=1)[:, None]
    t, prim = e.intersect(o, d, 0.0, np.inf)
    hit = np.isfinite(t)
    assert 100 < hit.sum() < 500
    p, ng, _ = e.surface(o[hit], d[hit], t[hit], prim[hit])
    R = e.rotations[0]
    local = (p - C) @ R / S
    assert np.allclose(np.linalg.norm(local, axis=1), 1.0, atol=1e-12)
    grad = (local / S) @ R.T
    assert np.allclose(ng, grad / np.linalg.norm(grad, axis=1)[:, None], atol=1e-12)
    assert np.all(np.einsum("ij,ij->i", ng, d[hit]) < 0)          # entries only
    inside, _ = e.intersect(np.repeat(C[None], 500, 0), d, 0.0, np.inf)
    assert not np.any(np.isfinite(inside))
    short, _ = e.intersect(o[hit], d[hit], 0.0, t[hit] * 0.999)
    assert not np.any(np.isfinite(short))
    assert np.array_equal(e.any_hit(o, d, 0.0, np.inf), hit)


def test_shells_are_scaled_as_mitsuba_scales_them():
    """Each template divided by the smallest norm of a vertex or face centroid: the ico
    sphere's face centres then touch the unit sphere (its vertices lie outside), the box's face
    centres too (its corners at sqrt(3) / |(1/3, 1, 1/3)|)."""
    for kind, nv, nf in (("ico_sphere", 12, 20), ("uv_sphere", 38, 72), ("box", 24, 12)):
        v, f = ell.shell(kind)
        assert v.shape == (nv, 3) and f.shape == (nf, 3)
        cent = np.linalg.norm(v[f].mean(axis=1), axis=1)
        assert min(cent.min(), np.linalg.norm(v, axis=1).min()) == pytest.approx(1.0, abs=1e-12)
        n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        assert np.all(np.einsum("ij,ij->i", n, v[f].mean(axis=1)) > 0)   # wound outward
    v, _ = ell.shell("box")
    assert np.allclose(np.abs(v), 1.0 / math.sqrt(1.0 / 9.0 + 1.0 + 1.0 / 9.0))
    with pytest.raises(ValueError, match="shell 'cone' is not one of"):
        ell.shell("cone")


def test_mesh_culls_back_faces_and_flips_normals():
    """The box shell of an axis-aligned ellipsoid: a ray along +x enters its -x face at
    10 - 2 b (b the box's half width), with normal -x and barycentric uv; from the centre it
    sees nothing; flip_normals turns the normal, not the culling."""
    mesh = _one(mesh=True, shell_mesh=ell.shell("box"))
    b = ell.shell("box")[0].max()
    o, d = (C + [-10.0, 0.1, 0.05])[None], np.array([[1.0, 0.0, 0.0]])
    t, prim = mesh.intersect(o, d, 0.0, np.inf)
    assert t[0] == pytest.approx(10.0 - 2.0 * b, abs=1e-12)
    _, ng, _ = mesh.surface(o, d, t, prim)
    assert np.allclose(ng, [[-1.0, 0.0, 0.0]])
    uv = mesh.uv(o, d, t, prim)
    assert np.all((uv >= 0) & (uv <= 1)) and uv.sum() <= 1.0
    t_in, _ = mesh.intersect(C[None], d, 0.0, np.inf)
    assert not np.isfinite(t_in[0])
    flipped = _one(mesh=True, shell_mesh=ell.shell("box"), flip=True)
    t2, p2 = flipped.intersect(o, d, 0.0, np.inf)
    assert t2[0] == t[0] and np.allclose(flipped.surface(o, d, t2, p2)[1], [[1.0, 0.0, 0.0]])


def test_ply_placement_rule(tmp_path):
    """Mitsuba's PLY rule: centres by the whole to_world, semi-axes exp(scale_k) times
    scale_factor times to_world's mean stretch, rotation to_world's rotation after the file's
    (rot_0 the real part); the ASCII file reads as the binary one."""
    c = np.array([[0.5, -1.0, 2.0], [0.0, 0.0, 0.0]])
    s = np.array([[0.1, 0.2, 0.3], [1.0, 1.0, 2.0]])
    h = math.sqrt(0.5)
    q = np.array([[0.0, 0.0, h, h], [0.0, 0.0, 0.0, 1.0]])
    ell.write_ellipsoids(tmp_path / "b.ply", c, s, q)
    ell.write_ellipsoids(tmp_path / "a.ply", c, s, q, binary=False)
    turn = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])        # 90° about x
    m = np.eye(4)
    m[:3, :3] = 3.0 * turn
    m[:3, 3] = [1.0, 2.0, 3.0]
    for name in ("b.ply", "a.ply"):
        centers, rot, scales, opac = ell.read_ellipsoids(tmp_path / name, m, scale_factor=0.5)
        assert np.allclose(centers, c @ (3.0 * turn).T + [1.0, 2.0, 3.0], atol=1e-6)
        assert np.allclose(scales, s * 1.5, rtol=1e-6)
        assert np.allclose(rot, turn[None] @ ell.quat_matrix(q), atol=1e-6)
        assert opac is None


def test_mirroring_to_world_as_mitsuba_takes_it():
    """Dr.Jit's ``transform_decompose`` negates only the diagonals of Q and S when ``det Q <
    0``: a mirror x -> -x (Q = diag(-1, 1, 1)) turns the ellipsoids half a turn about x and
    negates their semi-axes; a mirror after a quarter turn about z turns them by the half turn
    about (-1, 1, 0) that its negated diagonal makes; a proper map keeps its rotation."""
    rot, scale = ell.world_rotation(np.diag([-2.0, 2.0, 2.0]))
    assert np.allclose(rot, np.diag([1.0, -1.0, -1.0])) and scale == pytest.approx(-2.0)
    rot, scale = ell.world_rotation(np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]))
    assert np.allclose(rot, [[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]) and scale == pytest.approx(-1.0)
    rot, scale = ell.world_rotation(3.0 * ell.quat_matrix([[0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)]])[0])
    assert np.allclose(rot, [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]) and scale == pytest.approx(3.0)


def test_opacities_and_adaptive_extent(tmp_path):
    """An ``opacities`` property is the adaptive clamping's input: opacity 0.01 e^4.5 gives
    extent · sqrt(2 · 4.5) / 3 = extent; a 3DGS file's ``opacity`` goes through the sigmoid."""
    op = 0.01 * math.exp(4.5)
    ell.write_ellipsoids(tmp_path / "o.ply", np.zeros((2, 3)), np.ones((2, 3)), [[0, 0, 0, 1]] * 2,
                         extra={"opacities": [op, 0.5]})
    _, _, _, opac = ell.read_ellipsoids(tmp_path / "o.ply")
    assert np.allclose(opac, [op, 0.5], rtol=1e-6)
    ext = ell.extents(2, 2.0, opac)
    assert ext[0] == pytest.approx(2.0, rel=1e-6)
    assert ext[1] == pytest.approx(2.0 / 3.0 * math.sqrt(2.0 * math.log(50.0)), rel=1e-6)
    with pytest.raises(ValueError, match="opacity 0.005 <= 0.01"):
        ell.extents(1, 3.0, [0.005])
    ell.write_ellipsoids(tmp_path / "g.ply", np.zeros((1, 3)), np.ones((1, 3)), [[0, 0, 0, 1]],
                         extra={"f_dc_0": [0.1], "opacity": [0.0]})
    assert ell.read_ellipsoids(tmp_path / "g.ply")[3] == pytest.approx([0.5])


def _xml(tmp_path, shape):
    p = tmp_path / "s.xml"
    p.write_text(f'<scene version="3.0.0">\n{shape}\n</scene>\n')
    return p


def _refused(tmp_path, shape):
    p = _xml(tmp_path, shape)
    with pytest.raises(SceneError) as e:
        load_scene(str(p))
    message = str(e.value)
    assert "\n" not in message and message.startswith(f"{p}:")
    return message


def test_loaded_from_a_scene_file(tmp_path):
    """Both shapes load from XML with the file's data: the ellipsoids' box is centre ± 2 ×
    extent × semi-axes under a scale-2 to_world; the mesh is a copy of its shell per ellipsoid."""
    ell.write_ellipsoids(tmp_path / "e.ply", [[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]], [[0.1, 0.2, 0.3]] * 2,
                         [[0, 0, 0, 1]] * 2)
    body = ('<shape type="{}"><string name="filename" value="e.ply"/><float name="extent" value="2"/>{}'
            '<transform name="to_world"><scale value="2"/></transform></shape>')
    scene = load_scene(str(_xml(tmp_path, body.format("ellipsoids", "")
                                + body.format("ellipsoidsmesh", '<string name="shell" value="uv_sphere"/>'))))
    e, m = scene.shapes
    assert isinstance(e, ell.Ellipsoids) and isinstance(m, ell.EllipsoidsMesh)
    lo, hi = e.bounds()
    assert np.allclose(lo, [-0.4, -0.8, -1.2], rtol=1e-6) and np.allclose(hi, [6.4, 0.8, 1.2], rtol=1e-6)
    assert m.faces.shape == (2 * 72, 3)
    nested = ('<shape type="ellipsoidsmesh"><string name="filename" value="e.ply"/>'
              '<shape type="cube" name="shell"/></shape>')
    assert load_scene(str(_xml(tmp_path, nested))).shapes[0].faces.shape == (2 * 12, 3)


@pytest.mark.parametrize("shape, expect", [
    ('<shape type="ellipsoids"><string name="filename" value="e.ply"/>\n<string name="data" value="1"/></shape>',
     ":3: <shape type='ellipsoids'> <string name='data'>: 'data' is a tensor"),
    ('<shape type="ellipsoidsmesh"><string name="filename" value="e.ply"/>\n'
     '<string name="shell" value="cone"/></shape>', ":3: <shape type='ellipsoidsmesh'> <string name='shell'>"),
    ('<shape type="ellipsoids"><string name="filename" value="e.ply"/>\n<float name="extent" value="0"/></shape>',
     "'extent' must be > 0"),
    ('<shape type="ellipsoids"><string name="filename" value="e.ply"/>\n'
     '<emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>', "an area emitter on ellipsoids"),
    ('<shape type="ellipsoids"><string name="filename" value="d.ply"/></shape>',
     "d.ply:3: property 'y' of element 'vertex' is not a float"),
    ('<shape type="ellipsoids"><string name="filename" value="n.ply"/></shape>',
     "n.ply:3: element 'vertex' must start with the properties x y z nx ny nz"),
    ('<shape type="shapegroup" id="g"><shape type="ellipsoids"><string name="filename" value="e.ply"/></shape></shape>'
     '<shape type="instance"><ref id="g"/></shape>', "ellipsoids in an instance is not supported"),
])
def test_bad_input_refused_in_one_line(tmp_path, shape, expect):
    ell.write_ellipsoids(tmp_path / "e.ply", [[0.0, 0.0, 0.0]], [[0.1, 0.2, 0.3]], [[0, 0, 0, 1]])
    head = "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n"
    rest = "".join(f"property float {n}\n" for n in ("z", "nx", "ny", "nz") + ell.PLY_TAIL) + "end_header\n"
    (tmp_path / "d.ply").write_bytes((head + "property double y\n" + rest).encode() + bytes(60))
    (tmp_path / "n.ply").write_bytes((head + rest).encode() + bytes(52))
    assert expect in _refused(tmp_path, shape)


def test_adaptive_clamping_without_opacities_warns(tmp_path):
    ell.write_ellipsoids(tmp_path / "e.ply", [[0.0, 0.0, 0.0]], [[0.1, 0.2, 0.3]], [[0, 0, 0, 1]])
    p = _xml(tmp_path, '<shape type="ellipsoids"><string name="filename" value="e.ply"/>'
                       '<boolean name="extent_adaptive_clamping" value="true"/></shape>')
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        scene = load_scene(str(p))
    assert any("needs an 'opacities' attribute" in str(x.message) for x in w)
    assert np.allclose(scene.shapes[0].bounds()[1], [0.3, 0.6, 0.9], rtol=1e-6)   # extent 3 kept
