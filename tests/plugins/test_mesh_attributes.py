"""Mitsuba's ``mesh_attribute`` texture in the core: a PLY's per-vertex and per-face properties.

A quad of two triangles whose PLY carries ``color_0..2`` per vertex and per face: the core's
``vertex_color`` (interpolated by barycentrics) and ``face_color`` (constant per triangle)
reflectances match Mitsuba's own ``direct`` within 2x its relMSE (links1_whitted evaluates the
texture through Mitsuba), and the values are the file's: at pixel centres they equal the
piecewise-linear (vertex) or per-triangle (face) colour worked out from the camera and the file."""
from __future__ import annotations

import numpy as np
import pytest

from links1.geometry import mesh_files
from links1_app.renderers import make_renderer

from tests import scenes

from .conftest import assert_matches_mitsuba_direct

PLY = """ply
format ascii 1.0
element vertex 4
property float x
property float y
property float z
property float color_0
property float color_1
property float color_2
element face 2
property list uchar int vertex_indices
property float color_0
property float color_1
property float color_2
end_header
-1 -1 0 0.9 0.1 0.1
1 -1 0 0.1 0.9 0.1
1 1 0 0.1 0.1 0.9
-1 1 0 0.9 0.9 0.1
3 0 1 2 0.8 0.4 0.1
3 0 2 3 0.1 0.4 0.8
"""
SCENE = scenes.scene(scenes.perspective("0, 0, 4", "0, 0, 0", fov=45, width=40, spp=None), """
  <emitter type="directional"><vector name="direction" value="0, 0, -1"/><rgb name="irradiance" value="3"/></emitter>
  <shape type="ply"><string name="filename" value="quad.ply"/>
    <bsdf type="diffuse"><texture name="reflectance" type="mesh_attribute">
      <string name="name" value="{attr}"/></texture></bsdf></shape>""")


@pytest.fixture(params=["vertex_color", "face_color"])
def scene(request, tmp_path):
    (tmp_path / "quad.ply").write_text(PLY)
    p = tmp_path / "quad.xml"
    p.write_text(SCENE.format(attr=request.param))
    return str(p), request.param


def test_ply_attributes_are_read_per_vertex_and_per_face(tmp_path):
    (tmp_path / "quad.ply").write_text(PLY)
    v, f, n, uv, attrs = mesh_files.read_ply(str(tmp_path / "quad.ply"), uv=True, attributes=True)
    np.testing.assert_array_equal(attrs["vertex_color"][3], [0.9, 0.9, 0.1])
    np.testing.assert_array_equal(attrs["face_color"], [[0.8, 0.4, 0.1], [0.1, 0.4, 0.8]])


C = np.array([[0.9, 0.1, 0.1], [0.1, 0.9, 0.1], [0.1, 0.1, 0.9], [0.9, 0.9, 0.1]])   # vertex colours
FACE = np.array([[0.8, 0.4, 0.1], [0.1, 0.4, 0.8]])


def expected_albedo(px, py, attr):
    """The attribute at pixel centre (px, py), analytically: the camera looks down -z from
    z = 4 (fov 45, x to the left in camera space: world x grows to the right of the image)."""
    e = np.tan(np.radians(22.5)) * 4.0
    x, y = (2.0 * (px + 0.5) / 40 - 1.0) * e, (1.0 - 2.0 * (py + 0.5) / 40) * e
    if y <= x:      # triangle 0 1 2: p = v0 + s (v1 - v0) + t (v2 - v1)
        s, t = (x + 1) / 2, (y + 1) / 2
        return FACE[0] if attr == "face_color" else C[0] + s * (C[1] - C[0]) + t * (C[2] - C[1])
    a, b = (x + 1) / 2, (y - x) / 2   # triangle 0 2 3: p = v0 + a (v2 - v0) + b (v3 - v0)
    return FACE[1] if attr == "face_color" else C[0] + a * (C[2] - C[0]) + b * (C[3] - C[0])


def test_core_mesh_attribute_values(scene):
    path, attr = scene
    rgb = make_renderer("core", path, spp=1, max_depth=1).render()[..., :3] / (3.0 / np.pi)  # albedo
    for px, py in [(20, 20), (9, 30), (30, 9), (12, 12), (29, 27), (10, 9)]:
        np.testing.assert_allclose(rgb[py, px], expected_albedo(px, py, attr), atol=1e-9, err_msg=str((px, py)))


@pytest.mark.slow
@pytest.mark.mitsuba
def test_mesh_attribute_matches_mitsuba_direct(scene, kind_with_mitsuba):
    kind = kind_with_mitsuba
    assert_matches_mitsuba_direct(kind, scene[0])


@pytest.mark.parametrize("body,message", [
    ('<shape type="sphere"><bsdf type="diffuse"><texture name="reflectance" type="mesh_attribute">'
     '<string name="name" value="vertex_color"/></texture></bsdf></shape>', "does not have"),
    ('<shape type="ply"><string name="filename" value="quad.ply"/><bsdf type="diffuse"><texture name="reflectance" '
     'type="mesh_attribute"><string name="name" value="vertex_weight"/></texture></bsdf></shape>', "vertex_weight"),
    ('<shape type="ply"><string name="filename" value="quad.ply"/><bsdf type="diffuse"><texture name="reflectance" '
     'type="mesh_attribute"><string name="name" value="color"/></texture></bsdf></shape>', "vertex_"),
])
def test_bad_mesh_attributes_are_scene_errors(tmp_path, body, message):
    from links1.scene import loader
    from links1.errors import SceneError
    (tmp_path / "quad.ply").write_text(PLY)
    p = tmp_path / "bad.xml"
    p.write_text('<scene version="3.0.0">' + body + "</scene>")
    with pytest.raises(SceneError, match=message):
        loader.load_scene(str(p))
