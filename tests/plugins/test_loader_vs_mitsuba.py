"""The core's XML reader against Mitsuba's own: transforms, camera, film, sampler, meshes.

Mitsuba is used here (tests/plugins) only; the scalar_rgb variant needs no LLVM.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from links1.scene import load_shapes, loader
from links1.scene.xmlparse import SceneWarning

mi = pytest.importorskip("mitsuba")

pytestmark = [pytest.mark.mitsuba, pytest.mark.usefixtures("scalar_rgb")]



class _Stub:
    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


@pytest.fixture(autouse=True)
def stub_shapes(monkeypatch):
    monkeypatch.setattr(load_shapes, "_shape_class", lambda name: type(name, (_Stub,), {}))


def ours(xml: str, **params):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        return loader.load_string(xml, **params)


SENSORS = [
    '<float name="fov" value="45"/><transform name="to_world">'
    '<lookat origin="1, 2, 3" target="0, 0.5, 0" up="0, 1, 0"/></transform>',
    '<float name="fov" value="30"/><string name="fov_axis" value="y"/><transform name="to_world">'
    '<rotate y="1" angle="30"/><translate x="1" y="-2"/><rotate x="1" angle="-20"/></transform>',
    '<float name="fov" value="60"/><string name="fov_axis" value="diagonal"/>'
    '<transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0"/></transform>',
    '<float name="fov" value="50"/><string name="fov_axis" value="smaller"/>'
    '<transform name="to_world"><matrix value="0 0 1 1  0 1 0 2  -1 0 0 3  0 0 0 1"/></transform>',
    '<string name="focal_length" value="$f"/>',
]


@pytest.mark.parametrize("i", range(len(SENSORS)))
@pytest.mark.parametrize("film", [(64, 32), (30, 50)])
def test_sensor_matches_mitsuba(i, film):
    w, h = film
    xml = (f'<scene version="3.0.0"><default name="f" value="35mm"/>'
           f'<sensor type="perspective">{SENSORS[i]}'
           f'<float name="near_clip" value="0.1"/><float name="far_clip" value="100"/>'
           f'<sampler type="independent"><integer name="sample_count" value="7"/></sampler>'
           f'<film type="hdrfilm"><integer name="width" value="{w}"/><integer name="height" value="{h}"/>'
           f'<integer name="crop_offset_x" value="3"/><integer name="crop_width" value="9"/>'
           f'<rfilter type="box"/></film></sensor></scene>')
    scene = ours(xml)
    ref = mi.load_string(xml)
    sensor = ref.sensors()[0]
    np.testing.assert_allclose(scene.camera.to_world, np.array(sensor.world_transform().matrix),
                               atol=2e-6)
    params = mi.traverse(sensor)
    assert scene.camera.fov_x == pytest.approx(float(params["x_fov"]), rel=2e-6)
    assert (scene.camera.width, scene.camera.height) == tuple(sensor.film().size())
    assert tuple(scene.camera.crop_offset) == tuple(sensor.film().crop_offset())
    assert tuple(scene.camera.crop_size) == tuple(sensor.film().crop_size())
    assert scene.spp == sensor.sampler().sample_count()
    assert scene.camera.near_clip == pytest.approx(0.1) and scene.camera.far_clip == pytest.approx(100)


def test_camera_rays_match_mitsuba():
    xml = ('<scene version="3.0.0"><sensor type="perspective"><float name="fov" value="40"/>'
           '<transform name="to_world"><lookat origin="1, 2, 3" target="0, 0, 0" up="0, 0, 1"/></transform>'
           '<film type="hdrfilm"><integer name="width" value="40"/><integer name="height" value="30"/></film>'
           '</sensor></scene>')
    cam = ours(xml).camera
    sensor = mi.load_string(xml).sensors()[0]
    pts = [(0.5, 0.5), (0.1, 0.2), (0.9, 0.75), (0.0, 1.0)]
    o, d, tmin, tmax = cam.generate_rays(np.array([p[0] for p in pts]), np.array([p[1] for p in pts]))
    for k, (x, y) in enumerate(pts):
        ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(x, y), mi.Point2f(0.5, 0.5))
        np.testing.assert_allclose(d[k], np.array(ray.d), atol=1e-6)
        np.testing.assert_allclose(o[k] + tmin[k] * d[k], np.array(ray.o), atol=1e-5)


@pytest.mark.parametrize("tr", [
    '<scale value="0.5"/><translate x="1" y="2" z="3"/>',
    '<rotate x="0.6" y="0.8" angle="33"/><translate z="-2"/>',
    '<lookat origin="1, 1, 1" target="0, 0, 0" up="0, 1, 0"/>',
    '<scale x="2" y="1" z="0.5"/><rotate z="1" angle="45"/>',
])
def test_mesh_and_sphere_transforms_match_mitsuba(tr):
    xml = (f'<scene version="3.0.0"><shape type="cube"><transform name="to_world">{tr}</transform></shape>'
           f'<shape type="sphere"><point name="center" x="0.5" y="-1" z="2"/><float name="radius" value="0.75"/>'
           f'<transform name="to_world">{tr}</transform></shape></scene>')
    cube, sphere = ours(xml).shapes
    ref = mi.load_string(xml)
    mcube = [s for s in ref.shapes() if s.is_mesh()][0]
    p = mi.traverse(mcube)
    np.testing.assert_allclose(cube.args[0], np.array(p["vertex_positions"]).reshape(-1, 3), atol=2e-6)
    np.testing.assert_array_equal(cube.args[1], np.array(p["faces"]).reshape(-1, 3))
    np.testing.assert_allclose(cube.kwargs["normals"], np.array(p["vertex_normals"]).reshape(-1, 3),
                               atol=2e-6)
    # Mitsuba's sphere: to_world * translate(center) * scale(radius); compare where points land
    msphere = [s for s in ref.shapes() if not s.is_mesh()][0]
    m = np.array(mi.traverse(msphere)["to_world"].matrix)
    expect_center = (m @ np.r_[0.0, 0, 0, 1])[:3]
    np.testing.assert_allclose(sphere.args[1][:3, 3], expect_center, atol=2e-6)


def test_obj_with_to_world_matches_mitsuba(tmp_path):
    obj = tmp_path / "m.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0.5\nvn 0 0 1\nvn 0 0.3 1\n"
                   "f 1//1 2//1 3//2 4//2\n")
    xml = (f'<scene version="3.0.0"><shape type="obj"><string name="filename" value="{obj}"/>'
           '<transform name="to_world"><scale x="2"/><rotate y="1" angle="20"/></transform></shape></scene>')
    ours_mesh = ours(xml).shapes[0]
    p = mi.traverse(mi.load_string(xml).shapes()[0])
    mv = np.array(p["vertex_positions"]).reshape(-1, 3)
    mf = np.array(p["faces"]).reshape(-1, 3)
    mn = np.array(p["vertex_normals"]).reshape(-1, 3)
    # compare triangle corners (vertex order may differ)
    np.testing.assert_allclose(np.sort(ours_mesh.args[0][ours_mesh.args[1]].reshape(-1, 9), axis=0),
                               np.sort(mv[mf].reshape(-1, 9), axis=0), atol=2e-6)
    np.testing.assert_allclose(np.sort(ours_mesh.kwargs["normals"][ours_mesh.args[1]].reshape(-1, 9), axis=0),
                               np.sort(mn[mf].reshape(-1, 9), axis=0), atol=2e-6)
