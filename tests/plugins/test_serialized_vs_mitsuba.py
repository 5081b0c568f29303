"""Mitsuba ``serialized`` meshes: the core loads what Mitsuba loads from the same file (vertex
positions, faces, normals and texcoords as ``mi.traverse`` reads them from
``mi.load_dict({'type': 'serialized', ...})``), and renders a scene holding one as the plugin
does (links1_mitsuba.load_file, where Mitsuba loads the mesh itself)."""
from __future__ import annotations

import os
import warnings

import numpy as np
import pytest

from links1 import load_scene
from tests.core.test_serialized import QUAD, TET, write_serialized

pytestmark = pytest.mark.mitsuba

#: a smooth open mesh: a 5x5 height-field patch (shared vertices, so recomputed normals vary)
_g = np.linspace(-1.0, 1.0, 5)
_x, _y = np.meshgrid(_g, _g)
GRID = dict(v=np.stack([_x.ravel(), _y.ravel(), 0.3 * np.cos(_x.ravel()) * np.cos(1.3 * _y.ravel())], 1),
            f=[[5 * i + j, 5 * i + j + 1, 5 * i + j + 6] for i in range(4) for j in range(4)]
            + [[5 * i + j, 5 * i + j + 6, 5 * i + j + 5] for i in range(4) for j in range(4)],
            uv=np.stack([(_x.ravel() + 1) / 2, (_y.ravel() + 1) / 2], 1), name="grid")

SKEW = [[0.5, -1.2, 0.3, 0.1], [0.9, 0.4, -0.2, 2.0], [0.0, 0.7, 1.5, -1.0], [0, 0, 0, 1]]
MIRROR = [[-1.5, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0.8, 0], [0, 0, 0, 1]]
CASES = {   # id: (version, shape_index, to_world, extra properties)
    "v4-first": (4, 0, None, {}),
    "v3-second": (3, 1, None, {}),
    "v4-third-double": (4, 2, SKEW, {}),
    "v3-recomputed-skew": (3, 2, SKEW, {}),
    "v4-face-normals": (4, 0, SKEW, {"face_normals": True}),
    "v4-flip": (4, 0, SKEW, {"flip_normals": True}),
    "v4-mirror-given-normals": (4, 0, MIRROR, {}),
    "v4-mirror-recomputed": (4, 2, MIRROR, {}),
    "v4-mirror-flip": (4, 0, MIRROR, {"flip_normals": True}),
}


def _file(d, version):
    p = os.path.join(d, f"m{version}.serialized")
    if not os.path.exists(p):
        write_serialized(p, [TET, QUAD, dict(GRID, double=True)], version)
    return p


def _xml_transform(m):
    return "" if m is None else (f'<transform name="to_world"><matrix value="'
                                 f'{" ".join(str(x) for x in np.ravel(m))}"/></transform>')


@pytest.mark.parametrize("case", CASES)
def test_core_loads_what_mitsuba_loads(case, tmp_path, scalar_rgb):
    mi = scalar_rgb
    version, index, to_world, extra = CASES[case]
    path = _file(str(tmp_path), version)
    spec = {"type": "serialized", "filename": path, "shape_index": index, **extra}
    if to_world is not None:
        spec["to_world"] = mi.ScalarTransform4f(to_world)
    shape = mi.load_dict(spec)
    prm = mi.traverse(shape)
    v_mi = np.array(prm["vertex_positions"], dtype=np.float64).reshape(-1, 3)
    f_mi = np.array(prm["faces"], dtype=np.int64).reshape(-1, 3)
    props = "".join(f'<boolean name="{k}" value="{str(v).lower()}"/>' for k, v in extra.items())
    (tmp_path / "s.xml").write_text(
        f'<scene version="3.0.0"><shape type="serialized"><string name="filename" value="{path}"/>'
        f'<integer name="shape_index" value="{index}"/>{props}{_xml_transform(to_world)}</shape></scene>')
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # no sensor
        (mesh,) = load_scene(str(tmp_path / "s.xml")).shapes
    np.testing.assert_allclose(mesh.vertices, v_mi, rtol=0, atol=1e-6 * (1 + np.abs(v_mi).max()))
    # the core turns the winding where Mitsuba negates the normals at a hit (flip_normals) and
    # where a mirroring to_world turned the winding against the normals the file gives
    given = index != 2 and not extra.get("face_normals")
    mirrored = to_world is not None and np.linalg.det(np.asarray(to_world)[:3, :3]) < 0
    turned = bool(extra.get("flip_normals")) != (mirrored and given)
    np.testing.assert_array_equal(mesh.faces, f_mi[:, [0, 2, 1]] if turned else f_mi)
    sign = -1.0 if extra.get("flip_normals") else 1.0
    if extra.get("face_normals"):
        assert mesh.normals is None and not shape.has_vertex_normals()
    else:
        n_mi = np.array(prm["vertex_normals"], dtype=np.float64).reshape(-1, 3)
        np.testing.assert_allclose(mesh.normals, sign * n_mi, rtol=0, atol=2e-6)
    if shape.has_vertex_texcoords():
        np.testing.assert_allclose(mesh.texcoords, np.array(prm["vertex_texcoords"]).reshape(-1, 2), atol=1e-7)
    else:
        assert mesh.texcoords is None


def test_core_renders_a_serialized_mesh_as_the_plugin(tmp_path, variant):
    """A lit serialized height field (shape 2 of a version-3 file, mirrored and skewed) and the
    quad (shape 1) as a floor: the core equals links1_mitsuba.load_file at equal spp."""
    from links1.tracing.render import render
    import links1_mitsuba
    import mitsuba as mi
    path = _file(str(tmp_path), 3)
    xml = f"""<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="40"/>
    <transform name="to_world"><lookat origin="0.5, -4, 5" target="0, 0, 1.2" up="0, 0, 1"/></transform>
    <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
    <film type="hdrfilm"><integer name="width" value="64"/><integer name="height" value="48"/><rfilter type="box"/></film>
  </sensor>
  <emitter type="point"><point name="position" value="1, -2, 5"/><rgb name="intensity" value="30"/></emitter>
  <shape type="serialized"><string name="filename" value="{path}"/><integer name="shape_index" value="1"/>
    <transform name="to_world"><scale value="3"/><translate value="0, 0, -2"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.5, 0.4"/></bsdf></shape>
  <shape type="serialized"><string name="filename" value="{path}"/><integer name="shape_index" value="2"/>
    <transform name="to_world"><scale x="-1" y="1" z="1"/><rotate z="1" angle="20"/><translate value="0, 0, 1"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.5, 0.8"/></bsdf></shape>
</scene>"""
    p = tmp_path / "scene.xml"
    p.write_text(xml)
    core = render(load_scene(str(p)), spp=4, seed=0)[..., :3]
    scene = links1_mitsuba.load_file(str(p))
    plug = np.array(mi.render(scene, spp=4, seed=0), dtype=np.float64)[..., :3]
    rel_mse = float(np.sum((plug - core) ** 2) / np.sum(core ** 2))
    assert core.mean() > 0.05 and rel_mse <= 1e-4, rel_mse
