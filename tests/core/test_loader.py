"""The core's Mitsuba XML reader: parameters, includes, references, transforms, plugins, errors.

Shapes are built through ``links1.scene.load_shapes._shape_class``; the tests replace it by recording stubs
so that they check the loader's contract (the constructor arguments) on their own.
"""
from __future__ import annotations

import math
import os
import warnings

import numpy as np
import pytest

from links1.scene import load_shapes, loader
from links1.shading import materials
from links1.maths import transform as tf
from links1.errors import SceneError
from links1.shading.lights import (ENV_LIGHT_ID, ConeSpotLight, ConstantEnvironment, CylinderSpotLight,
                           ParallelLight, PointLight)
from links1.scene.xmlparse import SceneWarning, parse_string

from tests.scenes import perspective, scene, whitted

DATA = os.path.join(os.path.dirname(__file__), "data")

# scenes without a sensor warn; tests that check a warning use pytest.warns, which sees it anyway
pytestmark = pytest.mark.filterwarnings("ignore::links1.scene.xmlparse.SceneWarning")


class _Stub:
    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


STUBS = {n: type(n, (_Stub,), {}) for n in ("TriangleMesh", "Quadric", "Disk", "Blob")}


@pytest.fixture(autouse=True)
def stub_shapes(monkeypatch):
    monkeypatch.setattr(load_shapes, "_shape_class", lambda name: STUBS[name])


def load(body: str, **params):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        return loader.load_string(scene(body), base_dir=DATA, **params)


def one_shape(body: str, **params):
    s = load(body, **params)
    assert len(s.shapes) == 1
    return s.shapes[0]


def to_world_of(op: str) -> np.ndarray:
    root = parse_string(scene(f'<shape type="sphere"><transform name="to_world">{op}'
                              '</transform></shape>'))
    return root.objects("shape")[0].props["to_world"].value


# -- parameters -----------------------------------------------------------------------------

def test_default_parameter_and_override():
    body = ('<default name="r" value="2"/>\n'
            '<shape type="sphere"><float name="radius" value="$r"/></shape>')
    np.testing.assert_allclose(one_shape(body).args[1], np.diag([2, 2, 2, 1.0]))
    np.testing.assert_allclose(one_shape(body, r=3).args[1], np.diag([3, 3, 3, 1.0]))
    np.testing.assert_allclose(one_shape(body, r="0.5").args[1], np.diag([0.5, 0.5, 0.5, 1.0]))


def test_parameter_inside_a_longer_value_and_in_type():
    body = ('<default name="kind" value="sphere"/><default name="x" value="1"/>\n'
            '<shape type="$kind"><point name="center" value="$x, 2, $x"/></shape>')
    np.testing.assert_allclose(one_shape(body).args[1][:3, 3], [1, 2, 1])
    np.testing.assert_allclose(one_shape(body, x=5).args[1][:3, 3], [5, 2, 5])


def test_undefined_parameter_is_an_error_naming_the_line(tmp_path):
    p = tmp_path / "params.xml"
    p.write_text(scene('<shape type="sphere">\n<float name="radius" value="$nope"/></shape>'))
    with pytest.raises(SceneError) as e:
        loader.load_scene(str(p))
    assert "params.xml:3" in str(e.value) and "$nope" in str(e.value)
    assert "<float name='radius'>" in str(e.value)


# -- include, path, ref -----------------------------------------------------------------------

def test_include_path_and_ref():
    s = loader.load_scene(os.path.join(DATA, "main_include.xml"))
    mesh, sphere = s.shapes
    assert isinstance(mesh, STUBS["TriangleMesh"]) and mesh.kwargs["name"] == "sub_mesh"
    np.testing.assert_array_equal(mesh.args[0], [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    np.testing.assert_allclose(mesh.kwargs["normals"], [[0, 0, 1]] * 3)  # smooth normals computed
    np.testing.assert_allclose(sphere.args[1], np.diag([0.5, 0.5, 0.5, 1]))
    assert isinstance(sphere.material, materials.Diffuse)
    np.testing.assert_allclose(sphere.material.reflectance, [0.9, 0.1, 0.1])
    assert sphere.kwargs["name"] == "main_sphere"
    assert s.path.endswith("main_include.xml")


def test_alias_names_the_same_object():
    """``<alias id="a" as="b"/>``: a reference to ``b`` is the object ``a`` (the BSDF named ``a``)."""
    s = load('<bsdf type="diffuse" id="red"><rgb name="reflectance" value="0.9, 0.1, 0.1"/></bsdf>\n'
             '<alias id="red" as="crimson"/>\n'
             '<shape type="sphere"><ref id="crimson"/></shape><shape type="disk"><ref id="red"/></shape>')
    a, b = (sh.material for sh in s.shapes)
    for m in (a, b):
        assert isinstance(m, materials.Diffuse) and m.name == "red"
        np.testing.assert_allclose(m.reflectance, [0.9, 0.1, 0.1])
    with pytest.raises(SceneError, match="unknown id 'nope'"):
        load('<alias id="nope" as="x"/>')


def test_version_before_2_upgrades_camel_case_names():
    """A scene older than 2.0 (Mitsuba 0.6 style ``nearClip``, ``sampleCount``, ``cropOffsetX``)
    reads as its snake_case names, with one warning naming the version."""
    body = ('<sensor type="perspective"><float name="fov" value="40"/>'
            '<float name="nearClip" value="0.5"/><float name="farClip" value="50"/>'
            '<sampler type="independent"><integer name="sampleCount" value="9"/></sampler>'
            '<film type="hdrfilm"><integer name="width" value="40"/><integer name="height" value="30"/>'
            '<integer name="cropOffsetX" value="8"/><integer name="cropWidth" value="16"/></film></sensor>')
    with pytest.warns(SceneWarning, match=r"scene version 0\.6\.0 is older than 2\.0"):
        c = loader.load_string(scene(body, version="0.6.0"), base_dir=DATA)
    assert (c.camera.near_clip, c.camera.far_clip, c.spp) == (0.5, 50.0, 9)
    assert c.camera.crop_offset[0] == 8 and c.camera.crop_size[0] == 16
    # the same names in a 3.0 scene are Mitsuba's error: the upgrade is what made them valid
    with pytest.raises(SceneError):
        loader.load_string(scene(body), base_dir=DATA)


def test_forward_ref_and_named_ref():
    body = ('<shape type="sphere"><ref name="bsdf" id="m"/></shape>\n'
            '<bsdf type="conductor" id="m"/>')
    assert isinstance(one_shape(body).material, materials.Conductor)


def test_shared_bsdf_by_ref_in_two_shapes():
    body = ('<bsdf type="diffuse" id="g"><rgb name="reflectance" value="0.2"/></bsdf>\n'
            '<shape type="sphere"><ref id="g"/></shape><shape type="disk"><ref id="g"/></shape>')
    s = load(body)
    for sh in s.shapes:
        np.testing.assert_allclose(sh.material.reflectance, [0.2] * 3)


# -- transforms -----------------------------------------------------------------------------

def test_transform_children_compose_in_mitsubas_order():
    m = to_world_of('<translate x="1"/><rotate z="1" angle="90"/>')
    np.testing.assert_allclose(m, tf.rotate([0, 0, 1], 90) @ tf.translate([1, 0, 0]), atol=1e-15)
    np.testing.assert_allclose(m[:3, 3], [0, 1, 0], atol=1e-15)  # the translation is rotated


def test_rotate_axis_conventions():
    # right-handed: +90 about z maps x to y, about x maps y to z, about y maps z to x
    for axis, src, dst in (("z", [1, 0, 0], [0, 1, 0]), ("x", [0, 1, 0], [0, 0, 1]),
                           ("y", [0, 0, 1], [1, 0, 0])):
        m = to_world_of(f'<rotate {axis}="1" angle="90"/>')
        np.testing.assert_allclose(m[:3, :3] @ src, dst, atol=1e-15)
    m = to_world_of('<rotate value="0, 1, 0" angle="30"/>')
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    np.testing.assert_allclose(m[:3, :3], [[c, 0, s], [0, 1, 0], [-s, 0, c]], atol=1e-15)


def test_rotate_axis_is_not_normalised_like_mitsuba():
    # Mitsuba 3.9.1 applies Rodrigues' formula to the raw axis (checked with mi.traverse)
    with pytest.warns(SceneWarning, match="not unit length"):
        m = to_world_of('<rotate value="2 0 0" angle="33"/>')
    c, s = math.cos(math.radians(33)), math.sin(math.radians(33))
    np.testing.assert_allclose(m[:3, :3], [[4 * (1 - c) + c, 0, 0], [0, c, -2 * s], [0, 2 * s, c]],
                               atol=1e-15)


def test_scale_translate_matrix_forms():
    np.testing.assert_array_equal(to_world_of('<scale value="2"/>'), np.diag([2, 2, 2, 1.0]))
    np.testing.assert_array_equal(to_world_of('<scale x="2"/>'), np.diag([2, 1, 1, 1.0]))
    np.testing.assert_array_equal(to_world_of('<scale value="1 2 3"/>'), np.diag([1, 2, 3, 1.0]))
    np.testing.assert_array_equal(to_world_of('<translate value="1,2,3"/>')[:3, 3], [1, 2, 3])
    m = to_world_of('<matrix value="1 0 0 1  0 1 0 2  0 0 1 3  0 0 0 1"/>')
    np.testing.assert_array_equal(m[:3, 3], [1, 2, 3])  # row-major
    m = to_world_of('<matrix value="1 2 0 0 1 0 0 0 1"/>')
    np.testing.assert_array_equal(m, [[1, 2, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    m = to_world_of('<scale value="2"/><translate x="1"/>')
    np.testing.assert_array_equal(m, tf.translate([1, 0, 0]) @ np.diag([2, 2, 2, 1.0]))


def test_lookat_columns_and_default_up():
    m = to_world_of('<lookat origin="1, 2, 3" target="1, 2, 4" up="0, 1, 0"/>')
    # columns: left, up, direction, origin (Mitsuba)
    np.testing.assert_allclose(m, [[1, 0, 0, 1], [0, 1, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1]], atol=1e-15)
    # without 'up' Mitsuba uses coordinate_system(dir).s; for dir = -z that is +x
    m = to_world_of('<lookat origin="0,0,5" target="0,0,0"/>')
    np.testing.assert_allclose(m, [[0, 1, 0, 0], [1, 0, 0, 0], [0, 0, -1, 5], [0, 0, 0, 1]], atol=1e-15)


# -- sensor, film, sampler, integrator --------------------------------------------------------

def sensor(inner: str, film: str = '<integer name="width" value="64"/><integer name="height" value="32"/>'):
    return load(f'<sensor type="perspective">{inner}<film type="hdrfilm">{film}</film></sensor>')


def test_fov_axis_conversion():
    t = math.tan(math.radians(30) / 2)
    cases = {"x": 30.0, "y": math.degrees(2 * math.atan(t * 2)),
             "diagonal": math.degrees(2 * math.atan(t * 64 / math.hypot(64, 32))),
             "smaller": math.degrees(2 * math.atan(t * 2)), "larger": 30.0}
    for axis, fov_x in cases.items():
        s = sensor(f'<float name="fov" value="30"/><string name="fov_axis" value="{axis}"/>')
        assert s.camera.fov_x == pytest.approx(fov_x, rel=1e-14), axis


def test_focal_length_default_and_explicit():
    # values read from Mitsuba 3.9.1 (mi.traverse(sensor)['x_fov']) for the same films
    s = sensor("")  # 50mm on 64x32
    assert s.camera.fov_x == pytest.approx(42.31171417236328, rel=1e-6)
    s = sensor('<string name="focal_length" value="18mm"/>', film="")  # 768x576
    assert s.camera.fov_x == pytest.approx(87.74993133544922, rel=1e-6)


def test_camera_fields_crop_sampler_integrator():
    s = load('<integrator type="path"><integer name="max_depth" value="7"/></integrator>'
             '<sensor type="perspective"><float name="fov" value="40"/>'
             '<float name="near_clip" value="0.5"/><float name="far_clip" value="50"/>'
             '<transform name="to_world"><translate x="1"/></transform>'
             '<sampler type="independent"><integer name="sample_count" value="9"/></sampler>'
             '<film type="hdrfilm"><integer name="width" value="40"/><integer name="height" value="30"/>'
             '<integer name="crop_offset_x" value="8"/><integer name="crop_offset_y" value="4"/>'
             '<integer name="crop_width" value="16"/><integer name="crop_height" value="10"/>'
             '<rfilter type="box"/></film></sensor>')
    c = s.camera
    assert (c.width, c.height, c.near_clip, c.far_clip) == (40, 30, 0.5, 50.0)
    assert tuple(c.crop_offset) == (8, 4) and tuple(c.crop_size) == (16, 10)
    np.testing.assert_array_equal(c.origin, [1, 0, 0])
    assert (s.spp, s.max_depth, s.integrator) == (9, 7, "path")


def test_the_tests_scene_helper_writes_what_it_is_given():
    """tests/scenes.py, which most tests write their scenes with: each argument reaches the
    loaded scene, and ``None`` leaves Mitsuba's default (4 spp, the gaussian filter)."""
    s = load(whitted(3, min_weight=0.0) + perspective([1, 2, 3], "1, 2, 0", fov=30, width=20, height=10, spp=7,
                                                      rfilter="tent", near=0.5, far=50))
    c = s.camera
    assert (c.width, c.height, c.near_clip, c.far_clip, c.rfilter.name) == (20, 10, 0.5, 50.0, "tent")
    assert c.fov_x == pytest.approx(30.0, rel=1e-14)
    np.testing.assert_array_equal(c.origin, [1, 2, 3])
    np.testing.assert_allclose(c.to_world[:3, 2], [0, 0, -1], atol=1e-15)  # toward the target
    assert (s.spp, s.max_depth, s.integrator) == (7, 3, "links1_whitted")
    d = load(perspective("0, 0, 5", "0, 0, 0", spp=None, rfilter=None))
    assert (d.spp, d.camera.rfilter.name, d.camera.width, d.camera.height) == (4, "gaussian", 24, 24)


def test_defaults_without_sensor_follow_mitsuba():
    s = load("")
    assert (s.camera.width, s.camera.height, s.spp, s.max_depth) == (768, 576, 4, 5)
    # Mitsuba 3.9.1: 50mm on 768x576 -> x_fov 38.1712 (diagonal of a 36 x 24 mm film)
    assert s.camera.fov_x == pytest.approx(math.degrees(2 * math.atan(math.hypot(36, 24) / 100 * 0.8)))


def test_rfilter_types_parameters_and_mitsuba_default():
    def rf(inner):
        return loader.load_string(scene('<sensor type="perspective"><film type="hdrfilm">'
                                        f'{inner}</film></sensor>')).camera.rfilter
    # Mitsuba 3.9.1: no rfilter -> gaussian, stddev 0.5, radius 4 stddev
    assert (rf("").name, rf("").radius) == ("gaussian", 2.0)
    assert load("").camera.rfilter.name == "gaussian"
    assert rf('<rfilter type="gaussian"><float name="stddev" value="0.25"/></rfilter>').radius == 1.0
    assert rf('<rfilter type="lanczos"><integer name="lobes" value="2"/></rfilter>').radius == 2.0
    assert rf('<rfilter type="tent"><float name="radius" value="1.5"/></rfilter>').border == 1
    assert rf('<rfilter type="mitchell"><float name="B" value="0.2"/></rfilter>').params == {"B": 0.2, "C": 1 / 3}
    assert (rf('<rfilter type="box"/>').radius, rf('<rfilter type="box"/>').border) == (0.5, 0)
    with pytest.raises(SceneError, match=r"<string>:\d+: <rfilter type='tent'>: .*radius must be a positive"):
        rf('<rfilter type="tent"><float name="radius" value="-1"/></rfilter>')
    with pytest.raises(SceneError, match="unknown plugin 'blackman'"):
        rf('<rfilter type="blackman"/>')


# -- shapes ---------------------------------------------------------------------------------

def test_sphere_center_radius_to_world():
    sh = one_shape('<shape type="sphere"><point name="center" x="1" y="2" z="3"/>'
                   '<float name="radius" value="0.5"/>'
                   '<transform name="to_world"><translate z="10"/></transform></shape>')
    assert isinstance(sh, STUBS["Quadric"]) and sh.args[0] == "sphere"
    np.testing.assert_allclose(sh.args[1], tf.translate([0, 0, 10]) @ tf.translate([1, 2, 3])
                               @ tf.scale(0.5))
    assert sh.kwargs["clips"] == [] and sh.kwargs["capped"] is False
    assert isinstance(sh.material, materials.Diffuse)  # Mitsuba's default bsdf
    np.testing.assert_allclose(sh.material.reflectance, [0.5] * 3)
    assert sh.emission is None


def test_cylinder_is_a_clipped_open_quadric():
    sh = one_shape('<shape type="cylinder"><point name="p0" x="1" y="0" z="0"/>'
                   '<point name="p1" x="1" y="3" z="0"/><float name="radius" value="0.5"/></shape>')
    kind, m = sh.args
    assert kind == "cylinder" and sh.kwargs["capped"] is False
    np.testing.assert_allclose(tf.apply_point(m, np.zeros(3)), [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(tf.apply_point(m, np.array([0, 0, 1.0])), [1, 3, 0], atol=1e-15)
    for y in ([1.0, 0, 0], [0, 1.0, 0]):  # unit circle -> radius 0.5, perpendicular to the axis
        w = tf.apply_vector(m, np.array(y))
        assert np.linalg.norm(w) == pytest.approx(0.5) and abs(w[1]) < 1e-15
    (n0, h0), (n1, h1) = sh.kwargs["clips"]
    np.testing.assert_array_equal(n0, [0, 0, -1]); assert h0 == 0
    np.testing.assert_array_equal(n1, [0, 0, 1]); assert h1 == 1


def test_rectangle_to_world_and_flip_normals():
    sh = one_shape('<shape type="rectangle"><boolean name="flip_normals" value="true"/>'
                   '<transform name="to_world"><scale value="2"/><rotate x="1" angle="90"/></transform>'
                   '</shape>')
    v, f = sh.args
    n = sh.kwargs["normals"]
    np.testing.assert_allclose(n, [[0, 1, 0]] * 4, atol=1e-15)  # +z rotated to -y, then flipped
    p = v[f]
    fn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    assert np.all(fn[:, 1] > 0)
    np.testing.assert_allclose(np.abs(v).max(0), [2, 0, 2], atol=1e-15)


def test_cube_is_closed_mesh():
    sh = one_shape('<shape type="cube"/>')
    assert sh.kwargs["closed"] is True and sh.args[0].shape == (24, 3)


def test_obj_and_ply_and_face_normals():
    sh = one_shape('<shape type="obj"><string name="filename" value="quad_poly.obj"/></shape>')
    np.testing.assert_array_equal(sh.args[1], [[0, 1, 2], [0, 2, 3]])
    np.testing.assert_allclose(sh.kwargs["normals"], [[0, 0, 1]] * 4)
    sh = one_shape('<shape type="ply"><string name="filename" value="quad_binary.ply"/>'
                   '<boolean name="face_normals" value="true"/></shape>')
    assert sh.kwargs["normals"] is None


def test_links1_quadric_with_clip_planes():
    sh = one_shape('<shape type="links1_quadric"><string name="kind" value="cylinder"/>'
                   '<vector name="clip_0" x="0" y="0" z="1"/><float name="clip_0_offset" value="2"/>'
                   '<vector name="clip_1" x="0" y="0" z="-1"/><float name="clip_1_offset" value="1"/>'
                   '<boolean name="capped" value="true"/>'
                   '<transform name="to_world"><scale value="3"/></transform></shape>')
    assert sh.args[0] == "cylinder" and sh.kwargs["capped"] is True
    np.testing.assert_array_equal(sh.args[1], np.diag([3, 3, 3, 1.0]))
    (n0, h0), (n1, h1) = sh.kwargs["clips"]
    np.testing.assert_array_equal(n0, [0, 0, 1]); assert h0 == 2
    np.testing.assert_array_equal(n1, [0, 0, -1]); assert h1 == 1


def test_links1_blob():
    sh = one_shape('<shape type="links1_blob"><string name="centers" value="0 0 0 1 1, 1 0 0 -0.5 2"/>'
                   '<float name="threshold" value="0.5"/><string name="solver" value="paper"/>'
                   '<integer name="samples" value="12"/></shape>')
    np.testing.assert_array_equal(sh.args[0], [[0, 0, 0, 1, 1], [1, 0, 0, -0.5, 2]])
    assert sh.args[1] == 0.5
    assert sh.kwargs["solver"] == "paper" and sh.kwargs["samples"] == 12
    assert sh.kwargs["to_world"] is None


def test_links1_bicubic_file_and_inline():
    sh = one_shape('<shape type="links1_bicubic"><string name="filename" value="flat.patch"/>'
                   '<integer name="subdivisions" value="2"/></shape>')
    assert sh.args[0].shape == (9, 3) and sh.args[1].shape == (8, 3)
    np.testing.assert_allclose(sh.kwargs["normals"], [[0, 0, 1]] * 9, atol=1e-15)
    pts = " ".join(f"{i} {j} 0" for i in range(4) for j in range(4))
    sh = one_shape(f'<shape type="links1_bicubic"><string name="control_points" value="{pts}"/>'
                   '<transform name="to_world"><translate z="1"/></transform></shape>')
    assert sh.args[0].shape == (81, 3)
    np.testing.assert_allclose(sh.args[0][:, 2], 1.0)
    np.testing.assert_allclose(sh.args[0].max(0), [3, 3, 1])


def test_area_emitter_sets_emission():
    s = loader.load_string(scene('<shape type="disk"><emitter type="area">'
                                 '<rgb name="radiance" value="1, 2, 3"/></emitter></shape>'))
    np.testing.assert_array_equal(s.shapes[0].emission, [1, 2, 3])  # (the light: test_area_lights)


# -- BSDFs ----------------------------------------------------------------------------------

def material(bsdf: str):
    return one_shape(f'<shape type="sphere">{bsdf}</shape>').material


def test_bsdf_mapping():
    m = material('<bsdf type="twosided"><bsdf type="diffuse"><rgb name="reflectance" value="0.1 0.2 0.3"/></bsdf></bsdf>')
    assert isinstance(m, materials.Diffuse) and m.two_sided
    np.testing.assert_allclose(m.reflectance, [0.1, 0.2, 0.3])
    m = material('<bsdf type="conductor"/>')
    assert isinstance(m, materials.Conductor) and m.eta is None
    m = material('<bsdf type="conductor"><rgb name="eta" value="0.2"/><rgb name="k" value="3"/></bsdf>')
    np.testing.assert_allclose(m.eta, [0.2] * 3)
    m = material('<bsdf type="dielectric"><string name="int_ior" value="water"/>'
                 '<float name="ext_ior" value="1.0"/></bsdf>')
    assert isinstance(m, materials.Dielectric) and m.eta == pytest.approx(1.333)
    m = material('<bsdf type="dielectric"/>')
    assert m.eta == pytest.approx(1.5046 / 1.000277)
    m = material('<bsdf type="thindielectric"/>')
    assert isinstance(m, materials.ThinDielectric)
    m = material('<bsdf type="plastic"><boolean name="nonlinear" value="true"/></bsdf>')
    assert isinstance(m, materials.Plastic) and m.nonlinear
    assert m.eta == pytest.approx(1.49 / 1.000277)
    m = material('<bsdf type="links1_phong"><rgb name="ambient" value="0.1"/><rgb name="diffuse" value="0.6"/>'
                 '<rgb name="specular" value="0.3"/><float name="exponent" value="50"/>'
                 '<rgb name="transmittance" value="0.25"/><float name="ior" value="1.33"/></bsdf>')
    assert isinstance(m, materials.Phong)
    np.testing.assert_allclose(m.reflectance, [0.3] * 3)  # defaults to specular
    assert (m.exponent, m.ior) == (50, 1.33)
    np.testing.assert_allclose(m.transmittance, [0.25] * 3)


def test_unsupported_bsdf_and_texture_warn_with_location():
    with pytest.warns(SceneWarning, match=r"<string>:3: <bsdf type='hair'>.*approximated"):
        loader.load_string(scene('<shape type="sphere">\n<bsdf type="hair"/></shape>'))
    with pytest.warns(SceneWarning, match="0.5 grey"):
        s = loader.load_string(scene('<shape type="sphere"><bsdf type="diffuse">'
                                     '<texture type="volume" name="reflectance"/></bsdf></shape>'))
    np.testing.assert_allclose(s.shapes[0].material.reflectance, [0.5] * 3)


# -- emitters -------------------------------------------------------------------------------

def test_emitters():
    s = load('<emitter type="point"><point name="position" x="1" y="2" z="3"/>'
             '<rgb name="intensity" value="5"/></emitter>'
             '<emitter type="point"><transform name="to_world"><translate x="4"/></transform></emitter>'
             '<emitter type="links1_point"><point name="position" value="0 1 0"/>'
             '<vector name="direction" value="0 -1 0"/><rgb name="L1" value="0.2"/>'
             '<rgb name="L2" value="0.8"/><string name="falloff" value="inverse_square"/></emitter>'
             '<emitter type="directional"><transform name="to_world">'
             '<lookat origin="0,0,0" target="0,-1,0" up="0,0,1"/></transform>'
             '<rgb name="irradiance" value="2"/></emitter>'
             '<emitter type="spot"><float name="cutoff_angle" value="30"/></emitter>'
             '<emitter type="links1_spot"><point name="origin" value="0 5 0"/>'
             '<vector name="direction" value="0 -2 0"/><float name="radius" value="1.5"/></emitter>'
             '<emitter type="constant"><rgb name="radiance" value="0.25"/></emitter>')
    p1, p2, lp, d, sp, cs, env = s.lights
    assert isinstance(env, ConstantEnvironment) and env.light_id == ENV_LIGHT_ID
    assert isinstance(p1, PointLight) and p1.falloff == "inverse_square"
    np.testing.assert_array_equal(p1.position, [1, 2, 3]); np.testing.assert_array_equal(p1.L1, [5] * 3)
    np.testing.assert_array_equal(p2.position, [4, 0, 0])
    assert lp.falloff == "inverse_square"
    np.testing.assert_allclose(lp.direction, [0, -1, 0]); np.testing.assert_allclose(lp.L2, [0.8] * 3)
    assert isinstance(d, ParallelLight)
    np.testing.assert_allclose(d.direction, [0, -1, 0], atol=1e-15)
    np.testing.assert_array_equal(d.irradiance, [2] * 3)
    assert isinstance(sp, ConeSpotLight) and sp.cutoff_angle == 30 and sp.beam_width == 22.5
    assert isinstance(cs, CylinderSpotLight) and cs.radius == 1.5
    np.testing.assert_allclose(cs.direction, [0, -1, 0])
    np.testing.assert_array_equal(s.background, [0.25] * 3)


def test_envmap_missing_file_is_a_scene_error():
    with pytest.raises(SceneError, match="envmap: cannot read 'x.exr'"):
        loader.load_string(scene('<emitter type="envmap"><string name="filename" value="x.exr"/></emitter>'))


# -- errors: every one names file, line and element -------------------------------------------

ERROR_CASES = {
    # name: (body with the offending element on line 3 of the file, element text, message part)
    "malformed": ('<shape type="sphere"><float name="radius" value="1">\n</shape>',
                  "<float name='radius'>", "mismatched tag"),
    "unknown_plugin": ('<shape type="teapot"/>', "<shape type='teapot'>", "unknown plugin 'teapot'"),
    "unknown_element": ('<sphere/>', "<sphere>", "unknown element"),
    "missing_file": ('<shape type="obj"><string name="filename" value="nope.obj"/></shape>',
                     "<shape type='obj'>", "file not found"),
    "missing_include": ('<include filename="nope.xml"/>', "<include>", "file not found"),
    "nan": ('<shape type="sphere"><float name="radius" value="nan"/></shape>', "<float name='radius'>", "finite"),
    "inf": ('<shape type="sphere"><point name="center" x="inf"/></shape>', "<point name='center'>", "finite"),
    "negative_radius": ('<shape type="sphere"><float name="radius" value="-1"/></shape>',
                        "<float name='radius'>", "must be > 0"),
    "singular_quadric": ('<shape type="links1_quadric"><string name="kind" value="sphere"/>'
                         '<transform name="to_world"><scale z="0"/></transform></shape>',
                         "<shape type='links1_quadric'>", "singular"),
    "blob_S": ('<shape type="links1_blob"><string name="centers" value="0 0 0 1 0"/>'
               '<float name="threshold" value="0.5"/></shape>', "<string name='centers'>", "S must be > 0"),
    "blob_threshold": ('<shape type="links1_blob"><string name="centers" value="0 0 0 1 1"/>'
                       '<float name="threshold" value="0"/></shape>', "<float name='threshold'>", "> 0"),
    "blob_empty": ('<shape type="links1_blob"><string name="centers" value=" "/>'
                   '<float name="threshold" value="1"/></shape>', "<string name='centers'>", "empty"),
    "blob_ragged": ('<shape type="links1_blob"><string name="centers" value="0 0 0 1 1 2"/>'
                    '<float name="threshold" value="1"/></shape>', "<string name='centers'>", "groups of five"),
    "ior": ('<bsdf type="dielectric" id="g"><float name="int_ior" value="-1.5"/></bsdf>',
            "<float name='int_ior'>", "must be > 0"),
    "phong_ior": ('<bsdf type="links1_phong" id="p"><float name="ior" value="0"/></bsdf>',
                  "<float name='ior'>", "must be > 0"),
    "zero_resolution": ('<sensor type="perspective"><film type="hdrfilm"><integer name="width" value="0"/>'
                        '</film></sensor>', "<integer name='width'>", ">= 1"),
    "bad_crop": ('<sensor type="perspective"><film type="hdrfilm"><integer name="crop_offset_x" value="700"/>'
                 '<integer name="crop_width" value="100"/></film></sensor>', "<film type='hdrfilm'>", "exceeds"),
    "radiancemeter": ('<sensor type="radiancemeter"/>', "<sensor type='radiancemeter'>", "not supported"),
    "unknown_ref": ('<shape type="sphere"><ref id="ghost"/></shape>', "<ref", "unknown id 'ghost'"),
    "duplicate_id": ('<bsdf type="diffuse" id="a"/><bsdf type="diffuse" id="a"/>', "<bsdf type='diffuse' id='a'>",
                     "duplicate id"),
    "spot_radius": ('<emitter type="links1_spot"><vector name="direction" z="1"/>'
                    '<float name="radius" value="-2"/></emitter>', "<float name='radius'>", "> 0"),
    "bad_integer": ('<sensor type="perspective"><film type="hdrfilm"><integer name="width" value="1.5"/>'
                    '</film></sensor>', "<integer name='width'>", "integer"),
    "wrong_kind": ('<shape type="sphere"><rgb name="radius" value="1"/></shape>', "<rgb name='radius'>", "<float>"),
    "bad_patch": ('<shape type="links1_bicubic"><string name="control_points" value="1 2 3"/></shape>',
                  "<string name='control_points'>", "48 numbers"),
    "area_top_level": ('<emitter type="area"/>', "<emitter type='area'>", "nested in a shape"),
    "unknown_bsdf": ('<shape type="sphere"><bsdf type="velvet"/></shape>', "<bsdf type='velvet'>",
                     "unknown plugin 'velvet'"),
}


@pytest.mark.parametrize("case", sorted(ERROR_CASES))
def test_errors_name_file_line_element(tmp_path, case):
    body, element, message = ERROR_CASES[case]
    p = tmp_path / f"bad_{case}.xml"
    p.write_text('<scene version="3.0.0">\n\n' + body + "\n</scene>\n")
    with pytest.raises(SceneError) as e, warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        loader.load_scene(str(p))
    text = str(e.value)
    assert f"bad_{case}.xml:" in text, text
    assert e.value.line in (3, 4), text  # the element's line (end tag line for mismatched tags)
    assert f":{e.value.line}:" in text
    assert element in text, text
    assert message in text, text


def test_truncated_file(tmp_path):
    p = tmp_path / "cut.xml"
    p.write_text('<scene version="3.0.0">\n<shape type="sphere">\n<float name="radius" value="1"/>')
    with pytest.raises(SceneError) as e:
        loader.load_scene(str(p))
    assert "cut.xml:3" in str(e.value) and "malformed XML" in str(e.value)


def test_missing_scene_file_and_version(tmp_path):
    with pytest.raises(SceneError, match="nothere.xml"):
        loader.load_scene(str(tmp_path / "nothere.xml"))
    p = tmp_path / "nover.xml"
    p.write_text("<scene>\n</scene>\n")
    with pytest.raises(SceneError, match=r"nover.xml:1: <scene>: missing 'version'"):
        loader.load_scene(str(p))


def test_error_inside_included_file_names_that_file(tmp_path):
    (tmp_path / "inner.xml").write_text('<scene version="3.0.0">\n<shape type="sphere">\n'
                                        '<float name="radius" value="0"/></shape></scene>')
    (tmp_path / "outer.xml").write_text(scene('<include filename="inner.xml"/>'))
    with pytest.raises(SceneError, match=r"inner.xml:3: .*radius.*> 0"):
        loader.load_scene(str(tmp_path / "outer.xml"))


def test_shape_constructor_value_error_becomes_scene_error(monkeypatch):
    def failing(name):
        def ctor(*a, **k):
            raise ValueError("bad blob")
        return ctor
    monkeypatch.setattr(load_shapes, "_shape_class", failing)
    with pytest.raises(SceneError, match=r"<string>:2: <shape type='links1_blob'>: bad blob"):
        loader.load_string(scene('<shape type="links1_blob"><string name="centers" value="0 0 0 1 1"/>'
                                 '<float name="threshold" value="0.5"/></shape>'))


def test_unknown_parameter_is_refused_as_mitsuba_refuses_it():
    """A name Mitsuba's plugin never queries is an error (Mitsuba: "Found 1
    unreferenced property"), naming file, line and element."""
    with pytest.raises(SceneError, match=r"<string>:2: <shape type='sphere'> <float name='colour'>: "
                                         r"unknown parameter 'colour'"):
        loader.load_string(scene('<shape type="sphere"><float name="colour" value="1"/></shape>'))


def test_mitsuba_parameter_the_core_ignores_warns():
    """A real Mitsuba parameter the core does not read is a warning, not an error."""
    with pytest.warns(SceneWarning, match="'silhouette_sampling_weight' is not used"):
        loader.load_string(scene('<shape type="sphere"><float name="silhouette_sampling_weight" '
                                 'value="1"/></shape>'))


# -- the real shape classes (when links1.geometry.shapes / links1.geometry.blob exist) ---------------------------

def test_real_shape_classes(monkeypatch):
    pytest.importorskip("links1.geometry.shapes")
    monkeypatch.undo()
    body = ('<shape type="sphere"/><shape type="cylinder"/><shape type="disk"/><shape type="cube"/>'
            '<shape type="rectangle"/><shape type="links1_quadric"><string name="kind" value="sphere"/>'
            '</shape><shape type="obj"><string name="filename" value="quad_poly.obj"/></shape>'
            '<shape type="links1_bicubic"><string name="filename" value="flat.patch"/></shape>')
    try:
        import links1.geometry.blob  # noqa: F401
        body += ('<shape type="links1_blob"><string name="centers" value="0 0 0 1 1"/>'
                 '<float name="threshold" value="0.5"/></shape>')
    except ImportError:
        pass
    s = loader.load_string(scene(body), base_dir=DATA)
    assert len(s.shapes) == body.count("<shape ")
    for i, sh in enumerate(s.shapes):
        assert sh.index == i and sh.material is not None
        lo, hi = sh.bounds()
        assert np.all(np.isfinite(lo)) and np.all(lo <= hi)


def test_files_named_in_an_included_fragment_resolve_from_the_main_scene_dir(tmp_path):
    """Mitsuba resolves the meshes a fragment in a subdirectory names against the main scene
    file's directory (its file resolver), as mitsuba-data's Cornell box relies on."""
    (tmp_path / "meshes").mkdir()
    (tmp_path / "fragments").mkdir()
    (tmp_path / "meshes" / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (tmp_path / "fragments" / "shapes.xml").write_text(
        '<scene version="3.0.0"><shape type="obj"><string name="filename" value="meshes/tri.obj"/>'
        '<ref id="glow"/></shape></scene>')
    (tmp_path / "main.xml").write_text(
        '<scene version="3.0.0"><include filename="fragments/shapes.xml"/>'
        '<emitter type="area" id="glow"><rgb name="radiance" value="2"/></emitter></scene>')
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        scene = loader.load_scene(str(tmp_path / "main.xml"))
    assert len(scene.shapes) == 1 and not scene.lights
    np.testing.assert_array_equal(scene.shapes[0].emission, [2.0, 2.0, 2.0])
