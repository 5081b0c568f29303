"""Core textures (links1.shading.textures) with analytic expectations: a flat-lit checkerboard
rectangle, bitmap lookups at known texels, wrap modes, sRGB decoding, the uv of Mitsuba's
shapes at known points, and loader errors."""
from __future__ import annotations

import numpy as np
import pytest

import links1
from links1.geometry import mesh_files, meshes
from links1.shading import textures
from links1.errors import SceneError
from links1.imaging.image import srgb_to_linear
from links1.scene.loader import load_string
from links1.scene.xmlparse import SceneWarning
from links1.geometry.shapes import Disk, Quadric, TriangleMesh

RES = 40


def flat_scene(tex, eye_z=3.0, fov=60):
    """A rectangle [-1,1]² in z = 0 facing a camera on the +z axis, lit head-on by a
    directional light of irradiance 2."""
    return f"""<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="{fov}"/>
    <transform name="to_world"><lookat origin="0, 0, {eye_z}" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="{RES}"/><integer name="height" value="{RES}"/>
      <rfilter type="box"/></film></sensor>
  <emitter type="directional"><vector name="direction" x="0" y="0" z="-1"/><rgb name="irradiance" value="2"/></emitter>
  <shape type="rectangle"><bsdf type="diffuse">{tex}</bsdf></shape>
</scene>"""


def test_flat_lit_checkerboard_is_color_times_analytic_shading():
    """Each pixel whose footprint lies inside one checker cell equals colour x E/π exactly
    (diffuse: ρ/π · E cos 0); pixels across a cell border lie between the two."""
    c0, c1 = np.array([0.8, 0.3, 0.1]), np.array([0.1, 0.4, 0.9])
    tex = ('<texture type="checkerboard" name="reflectance"><rgb name="color0" value="0.8, 0.3, 0.1"/>'
           '<rgb name="color1" value="0.1, 0.4, 0.9"/><transform name="to_uv"><scale x="2" y="3"/>'
           '</transform></texture>')
    scene = load_string(flat_scene(tex))
    img = links1.render(scene, spp=4, max_depth=1)
    cam = scene.camera
    # uv of the four corners of every pixel: rays through the film corners, hit z = 0
    xs, ys = np.meshgrid(np.arange(RES + 1) / RES, np.arange(RES + 1) / RES)
    o, d, _, _ = cam.generate_rays(xs.ravel(), ys.ravel())
    t = -o[:, 2] / d[:, 2]
    p = o + t[:, None] * d
    u, v = (p[:, 0] + 1) / 2, (p[:, 1] + 1) / 2  # Mitsuba's rectangle uv
    s, w = 2 * u, 3 * v
    first = ((s - np.floor(s)) > 0.5) == ((w - np.floor(w)) > 0.5)
    inside = (np.abs(p[:, 0]) < 1) & (np.abs(p[:, 1]) < 1)
    first, inside = first.reshape(RES + 1, RES + 1), inside.reshape(RES + 1, RES + 1)
    corners = [first[:-1, :-1], first[:-1, 1:], first[1:, :-1], first[1:, 1:]]
    ins = inside[:-1, :-1] & inside[:-1, 1:] & inside[1:, :-1] & inside[1:, 1:]
    all0 = ins & np.logical_and.reduce(corners)
    all1 = ins & ~np.logical_or.reduce(corners)
    shade = 2.0 / np.pi
    assert all0.sum() > 100 and all1.sum() > 100
    np.testing.assert_allclose(img[all0], np.broadcast_to(c0 * shade, (all0.sum(), 3)), rtol=1e-12)
    np.testing.assert_allclose(img[all1], np.broadcast_to(c1 * shade, (all1.sum(), 3)), rtol=1e-12)
    mixed = ins & ~all0 & ~all1
    lo, hi = np.minimum(c0, c1) * shade, np.maximum(c0, c1) * shade
    assert np.all((img[mixed] >= lo - 1e-12) & (img[mixed] <= hi + 1e-12))


def test_bitmap_texel_centres_rows_and_srgb(tmp_path):
    """uv (0,0) is the top-left corner of the image (row 0); texel (i, j) is at
    ((j + .5)/W, (i + .5)/H); 8-bit PNG values are sRGB-decoded unless raw."""
    from PIL import Image
    rgb8 = np.arange(4 * 3 * 3, dtype=np.uint8).reshape(4, 3, 3) * 7
    Image.fromarray(rgb8).save(tmp_path / "t.png")
    lin = textures.read_bitmap(tmp_path / "t.png")
    np.testing.assert_allclose(lin, srgb_to_linear(rgb8 / 255.0), rtol=0, atol=0)
    raw = textures.read_bitmap(tmp_path / "t.png", raw=True)
    np.testing.assert_allclose(raw, rgb8 / 255.0)
    for ft in textures.FILTER_TYPES:
        b = textures.Bitmap(lin, ft)
        i, j = np.meshgrid(np.arange(4), np.arange(3), indexing="ij")
        uv = np.stack([(j.ravel() + 0.5) / 3, (i.ravel() + 0.5) / 4], axis=1)
        np.testing.assert_allclose(b.eval(uv), lin[i.ravel(), j.ravel()], rtol=1e-12)
    # bilinear half-way between texel centres (1,0) and (1,1): the mean of the two
    b = textures.Bitmap(lin)
    np.testing.assert_allclose(b.eval([[1.0 / 3, 1.5 / 4]]), [(lin[1, 0] + lin[1, 1]) / 2], rtol=1e-12)


@pytest.mark.parametrize("mode, expect", [("repeat", [2, 0, 1, 2, 0]), ("mirror", [0, 0, 1, 2, 2]),
                                          ("clamp", [0, 0, 1, 2, 2])])
def test_wrap_modes(mode, expect):
    """Nearest lookups at texel centres -1 .. 3 of a 3-texel-wide image."""
    data = np.zeros((2, 3, 3))
    data[:, :, 0] = [0.0, 1.0, 2.0]
    b = textures.Bitmap(data, "nearest", mode)
    u = (np.arange(-1, 4) + 0.5) / 3
    got = b.eval(np.stack([u, np.full(5, 0.25)], axis=1))[:, 0]
    np.testing.assert_array_equal(got, expect)
    # mirror continues with period 2 x size: texel -4 is texel 3 reflected -> 2
    m = textures.Bitmap(data, "nearest", "mirror").eval([[(-4 + 0.5) / 3, 0.25]])[0, 0]
    assert m == 2.0


def test_one_pixel_bitmap_is_constant():
    b = textures.Bitmap(np.array([[[0.2, 0.4, 0.6]]]))
    np.testing.assert_allclose(b.eval(np.random.default_rng(0).uniform(-3, 3, (50, 2))),
                               np.tile([0.2, 0.4, 0.6], (50, 1)))


def test_shape_uv_at_known_points():
    """Mitsuba's parameterisations: sphere (φ/2π, θ/π), cylinder (φ/2π, z), disk (r, φ/2π),
    rectangle ((x+1)/2, (y+1)/2), mesh without texcoords (b1, b2)."""
    sph = Quadric("sphere", np.diag([2.0, 2.0, 2.0, 1.0]))
    o = np.array([[5.0, 0, 0], [0, 5.0, 0], [0, 0, 5.0], [-5.0, 0, 0]])
    d = -o / 5.0
    t, prim = sph.intersect(o, d, 0, np.inf)
    np.testing.assert_allclose(sph.uv(o, d, t, prim), [[0, 0.5], [0.25, 0.5], [0, 0], [0.5, 0.5]],
                               atol=1e-12)
    cyl = Quadric("cylinder", np.diag([1.0, 1.0, 4.0, 1.0]),
                  clips=[(np.array([0, 0, -1.0]), 0.0), (np.array([0, 0, 1.0]), 1.0)])
    o = np.array([[0, -5.0, 1.0]])
    t, prim = cyl.intersect(o, np.array([[0, 1.0, 0]]), 0, np.inf)
    np.testing.assert_allclose(cyl.uv(o, np.array([[0, 1.0, 0]]), t, prim), [[0.75, 0.25]], atol=1e-12)
    disk = Disk(np.diag([2.0, 2.0, 1.0, 1.0]))
    o, d = np.array([[0, -1.0, 3.0]]), np.array([[0, 0, -1.0]])
    t, prim = disk.intersect(o, d, 0, np.inf)
    np.testing.assert_allclose(disk.uv(o, d, t, prim), [[0.5, 0.75]], atol=1e-12)
    v, f, n, uv = meshes.rectangle_mesh(uv=True)
    rect = TriangleMesh(v, f, n, texcoords=uv)
    o, d = np.array([[0.5, -0.5, 2.0]]), np.array([[0, 0, -1.0]])
    t, prim = rect.intersect(o, d, 0, np.inf)
    np.testing.assert_allclose(rect.uv(o, d, t, prim), [[0.75, 0.25]], atol=1e-12)
    tri = TriangleMesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    o = np.array([[0.2, 0.3, 1.0]])
    t, prim = tri.intersect(o, d, 0, np.inf)
    np.testing.assert_allclose(tri.uv(o, d, t, prim), [[0.2, 0.3]], atol=1e-12)


def test_obj_and_ply_texcoords(tmp_path):
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0.25\nvt 0 1\n"
                                    "f 1/1 2/2 3/3\n")
    v, f, n, uv = mesh_files.read_obj(tmp_path / "m.obj", uv=True)
    np.testing.assert_allclose(uv, [[0, 0], [1, 0.25], [0, 1]])
    with pytest.warns(SceneWarning, match="no sensor"):
        scene = load_string(f"""<scene version="3.0.0"><shape type="obj"><string name="filename"
            value="{tmp_path / 'm.obj'}"/></shape></scene>""")
    np.testing.assert_allclose(scene.shapes[0].texcoords, [[0, 1], [1, 0.75], [0, 0]])  # flipped


def test_texture_errors_name_the_element(tmp_path):
    xml = flat_scene('<texture type="bitmap" name="reflectance"><string name="filename" value="nope.png"/>'
                     '</texture>')
    with pytest.raises(SceneError, match="nope.png"):
        load_string(xml, base_dir=tmp_path)
    (tmp_path / "bad.png").write_bytes(b"not an image")
    with pytest.raises(SceneError, match="bad.png"):
        load_string(xml.replace("nope.png", "bad.png"), base_dir=tmp_path)
    with pytest.raises(SceneError, match="wrap_mode"):
        load_string(flat_scene('<texture type="checkerboard" name="reflectance"/>').replace(
            "checkerboard", "bitmap").replace('name="reflectance"/>',
            'name="reflectance"><string name="filename" value="x.png"/>'
            '<string name="wrap_mode" value="wrap"/></texture>'), base_dir=tmp_path)


def test_cylinder_on_a_skew_axis_is_right_circular():
    """Mitsuba's frame of the axis is orthonormal for every direction: the hits of a cylinder
    from p0 to p1 lie at its radius from the axis, and their v is the position along it."""
    p0, p1, r = np.array([0.1, -0.8, 0.2]), np.array([-0.3, 0.9, 0.0]), 0.6
    scene = load_string(f"""<scene version="3.0.0"><sensor type="perspective"/><shape type="cylinder">
        <point name="p0" value="{' '.join(map(str, p0))}"/><point name="p1" value="{' '.join(map(str, p1))}"/>
        <float name="radius" value="{r}"/></shape></scene>""")
    cyl = scene.shapes[0]
    rng = np.random.default_rng(5)
    o = rng.normal(size=(500, 3))
    o = 4 * o / np.linalg.norm(o, axis=1, keepdims=True)
    d = rng.uniform(-0.5, 0.5, (500, 3)) - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t, prim = cyl.intersect(o, d, 0, np.inf)
    hit = np.isfinite(t)
    assert hit.sum() > 100
    p = o[hit] + t[hit, None] * d[hit]
    axis = (p1 - p0) / np.linalg.norm(p1 - p0)
    along = (p - p0) @ axis
    radial = np.linalg.norm((p - p0) - along[:, None] * axis, axis=1)
    np.testing.assert_allclose(radial, r, rtol=1e-9)
    uv = cyl.uv(o[hit], d[hit], t[hit], prim[hit])
    np.testing.assert_allclose(uv[:, 1], along / np.linalg.norm(p1 - p0), atol=1e-9)


def test_referenced_and_nested_textures():
    """A top-level ``<texture id>`` referenced by a BSDF, and a checkerboard whose color0 is
    itself a checkerboard: values follow Mitsuba's rule at known uv."""
    xml = """<scene version="3.0.0"><sensor type="perspective"/>
      <texture type="checkerboard" id="inner"><rgb name="color0" value="0.9"/><rgb name="color1" value="0.5"/>
        <transform name="to_uv"><scale x="4" y="4"/></transform></texture>
      <texture type="checkerboard" id="outer"><ref id="inner" name="color0"/><rgb name="color1" value="0.1"/></texture>
      <shape type="rectangle"><bsdf type="diffuse"><ref id="outer" name="reflectance"/></bsdf></shape></scene>"""
    m = load_string(xml).shapes[0].material
    assert m.textured == ("reflectance",)
    uv = np.array([[0.05, 0.05], [0.2, 0.05], [0.7, 0.2], [0.7, 0.7]])
    # outer cell of (0.7, 0.2) is color1; inner at 4uv: (0.2,0.2)->c0, (0.8,0.2)->c1, (0.8,2.8)->c0
    np.testing.assert_allclose(m.at(uv).reflectance[:, 0], [0.9, 0.5, 0.1, 0.9])


def test_unsupported_bsdf_keeps_its_texture_in_the_diffuse_stand_in():
    xml = """<scene version="3.0.0"><sensor type="perspective"/><shape type="rectangle">
      <bsdf type="hair"><texture type="checkerboard" name="reflectance"/></bsdf>
      </shape></scene>"""
    with pytest.warns(SceneWarning, match="hair.*approximated as a diffuse surface of "
                                          "reflectance its texture"):
        m = load_string(xml).shapes[0].material
    np.testing.assert_allclose(m.at([[0.1, 0.1], [0.6, 0.1]]).reflectance, [[0.4] * 3, [0.2] * 3])


def test_textured_window_equals_full_frame(tmp_path):
    """Texture lookups are per hit: a window renders the same bits as the full frame."""
    from PIL import Image
    Image.fromarray(np.random.default_rng(1).integers(0, 256, (5, 7, 3), dtype=np.uint8)).save(
        tmp_path / "t.png")
    tex = f'<texture type="bitmap" name="reflectance"><string name="filename" value="{tmp_path / "t.png"}"/></texture>'
    scene = load_string(flat_scene(tex, fov=40))
    full = links1.render(scene, spp=2, max_depth=1)
    win = links1.render(scene, spp=2, max_depth=1, window=(7, 11, 13, 9))
    np.testing.assert_array_equal(win, full[11:20, 7:20])
    assert len(np.unique(full[..., 0])) > 20  # the texture shows
