"""Core textures against Mitsuba: ``bitmap`` and ``checkerboard`` on Mitsuba's BSDFs, with the
uv of meshes (obj ``vt``, ply ``u v``, rectangle, cube) and analytic shapes (sphere, cylinder,
disk), rendered by the core and compared with Mitsuba's ``direct`` integrator and with the
plugin (which evaluates the textures through Mitsuba's BSDFs).

Texture values themselves are compared with Mitsuba's texture plugins at random uv (every
filter and wrap mode, sRGB and raw, PNG and EXR).
"""
from __future__ import annotations

import os

import numpy as np
import pytest

from links1.geometry import meshes
from links1.shading import textures
from links1.imaging.image import write_exr

from tests.scenes import integrator, perspective, scene, whitted

pytestmark = pytest.mark.mitsuba

RES = 48


def rel_mse(a, b):
    return float(np.sum((a - b) ** 2) / max(np.sum(b ** 2), 1e-30))


def _write_png(path, rgb8):
    from PIL import Image
    Image.fromarray(rgb8).save(path)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    return make_files(tmp_path_factory.mktemp("tex"))


def make_files(d):
    """The test bitmaps (8-bit sRGB PNG and JPEG, 8- and 16-bit grey PNG, float EXR) and
    textured meshes, in ``d``."""
    rng = np.random.default_rng(7)
    _write_png(d / "rgb.png", rng.integers(0, 256, size=(6, 9, 3), dtype=np.uint8))
    _write_png(d / "grey.png", rng.integers(0, 256, size=(5, 4), dtype=np.uint8))
    write_exr(d / "lin.exr", (rng.random((7, 5, 3)) * 1.2).astype(np.float32))
    from PIL import Image
    Image.fromarray(rng.integers(0, 256, size=(8, 10, 3), dtype=np.uint8)).save(d / "rgb.jpg", quality=95)
    Image.fromarray(rng.integers(0, 65536, size=(5, 6), dtype=np.uint16)).save(d / "grey16.png")
    # a quad with uv ranging over [-0.5, 1.5] (exercises wrap modes), as OBJ (vt, flipped by
    # Mitsuba) and as PLY (u v, not flipped)
    with open(d / "quad.obj", "w") as fh:
        fh.write("v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\n"
                 "vt -0.5 -0.5\nvt 1.5 -0.5\nvt 1.5 1.5\nvt -0.5 1.2\n"
                 "f 1/1 2/2 3/3\nf 1/1 3/3 4/4\n")
    ply = ["ply", "format ascii 1.0", "element vertex 4", "property float x", "property float y",
           "property float z", "property float u", "property float v", "element face 2",
           "property list uchar int vertex_indices", "end_header",
           "-1 -1 0 0 0", "1 -1 0 2 0", "1 1 0 2 1.5", "-1 1 0 0 1.5", "3 0 1 2", "3 0 2 3"]
    (d / "quad.ply").write_text("\n".join(ply) + "\n")
    return d


def scene_xml(body):
    """The scene around ``body`` without an integrator: :func:`plugin` and :func:`mitsuba` put one in."""
    return scene(perspective("0, 3.5, 7", "0, 0.6, 0", fov=45, width=RES),
                 '<emitter type="point"><point name="position" x="1" y="5" z="4"/>'
                 '<rgb name="intensity" value="40"/></emitter>',
                 '<emitter type="directional"><vector name="direction" x="0.3" y="-1" z="-0.4"/>'
                 '<rgb name="irradiance" value="0.7"/></emitter>', body)


def checker(name, c0="0.8, 0.2, 0.1", c1="0.1, 0.3, 0.9", scale="4, 3"):
    sx, sy = scale.split(",")
    return (f'<texture type="checkerboard" name="{name}"><rgb name="color0" value="{c0}"/>'
            f'<rgb name="color1" value="{c1}"/><transform name="to_uv"><scale x="{sx}" y="{sy}"/>'
            f'</transform></texture>')


def bitmap(name, fn, filt="bilinear", wrap="repeat", raw=False, extra=""):
    return (f'<texture type="bitmap" name="{name}"><string name="filename" value="{fn}"/>'
            f'<string name="filter_type" value="{filt}"/><string name="wrap_mode" value="{wrap}"/>'
            f'<boolean name="raw" value="{"true" if raw else "false"}"/>{extra}</texture>')


def diffuse(tex):
    return f'<bsdf type="diffuse">{tex}</bsdf>'


def body_diffuse(d):
    """Diffuse surfaces: every shape's uv convention and every bitmap option."""
    return f"""
  <shape type="rectangle"><transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/></transform>
    {diffuse(checker("reflectance"))}</shape>
  <shape type="sphere"><point name="center" x="-1.6" y="0.9" z="0"/><float name="radius" value="0.9"/>
    {diffuse(bitmap("reflectance", d / "rgb.png", extra='<transform name="to_uv"><scale x="2" y="1"/></transform>'))}</shape>
  <shape type="obj"><string name="filename" value="{d / 'quad.obj'}"/>
    <transform name="to_world"><scale value="0.8"/><translate x="0.3" y="1.0" z="-1"/></transform>
    {diffuse(bitmap("reflectance", d / "lin.exr", "nearest", "mirror"))}</shape>
  <shape type="ply"><string name="filename" value="{d / 'quad.ply'}"/>
    <transform name="to_world"><scale value="0.6"/><translate x="2.2" y="0.8" z="-0.5"/></transform>
    {diffuse(bitmap("reflectance", d / "grey.png", "bilinear", "clamp", raw=True))}</shape>
  <shape type="cylinder"><point name="p0" x="1.5" y="0" z="1.2"/><point name="p1" x="1.5" y="1.6" z="1.2"/>
    <float name="radius" value="0.5"/>{diffuse(checker("reflectance", scale="6, 4"))}</shape>
  <shape type="disk"><transform name="to_world"><scale value="0.7"/><rotate x="1" angle="-60"/>
    <translate x="-0.2" y="0.4" z="1.8"/></transform>{diffuse(checker("reflectance", scale="3, 8"))}</shape>
  <shape type="cube"><transform name="to_world"><scale value="0.45"/><rotate y="1" angle="35"/>
    <translate x="0.1" y="0.45" z="0.4"/></transform>
    {diffuse(bitmap("reflectance", d / "rgb.png", "nearest", "repeat"))}</shape>
"""


def body_bsdfs(d):
    """Textures on the other BSDF parameters Mitsuba accepts them for (delta-light parts)."""
    return f"""
  <shape type="rectangle"><transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="twosided"><bsdf type="plastic">{checker("diffuse_reflectance")}
      {bitmap("specular_reflectance", d / "grey.png")}</bsdf></bsdf></shape>
  <shape type="sphere"><point name="center" x="-1.4" y="0.9" z="0"/><float name="radius" value="0.9"/>
    <bsdf type="plastic">{bitmap("diffuse_reflectance", d / "rgb.png")}</bsdf></shape>
  <shape type="sphere"><point name="center" x="1.3" y="0.8" z="0.3"/><float name="radius" value="0.8"/>
    <bsdf type="conductor">{checker("specular_reflectance", scale="8, 4")}</bsdf></shape>
  <shape type="cube"><transform name="to_world"><scale value="0.4"/><translate x="0" y="0.4" z="1.5"/></transform>
    <bsdf type="dielectric">{checker("specular_reflectance", "1, 1, 1", "0.2, 0.2, 0.2", "2, 2")}
      {bitmap("specular_transmittance", d / "lin.exr")}</bsdf></shape>
"""


def core(xml, spp, max_depth):
    import links1
    from links1.scene.loader import load_string
    return links1.render(load_string(xml), spp=spp, max_depth=max_depth)


def plugin(xml, variant, spp, max_depth):
    from links1_mitsuba import load_string
    sc = load_string(xml.replace("<emitter", whitted(max_depth) + "<emitter", 1), variant=variant)
    return sc.integrator().render_window(sc, None, spp=spp)


def mitsuba(xml, variant, method, spp):
    import mitsuba as mi
    from links1_mitsuba import load_string
    sc = load_string(xml.replace("<emitter", f"{method}<emitter", 1), links1_integrator="scene",
                     variant=variant)
    return np.array(mi.render(sc, spp=spp), dtype=np.float64)[..., :3]


@pytest.mark.slow
def test_texture_values_match_mitsuba(files, variant):
    """Bitmap (each filter, wrap mode, raw flag; PNG, JPEG, 8/16-bit grey PNG, EXR) and
    checkerboard values at random uv, through ``to_uv``, against Mitsuba's texture plugins."""
    import mitsuba as mi
    rng = np.random.default_rng(3)
    uv = rng.uniform(-2.0, 3.0, size=(4000, 2)).astype(np.float32)
    si = mi.SurfaceInteraction3f()
    si.uv = mi.Point2f(uv[:, 0], uv[:, 1])
    uv = uv.astype(np.float64)
    to_uv = mi.ScalarTransform4f().translate([0.1, 0.2, 0]).rotate([0, 0, 1], 20).scale([1.3, 0.7, 1])
    m = np.array(to_uv.matrix, dtype=np.float64)
    for fn in ("rgb.png", "grey.png", "lin.exr", "rgb.jpg", "grey16.png"):
        for raw in (False, True):
            for ft in textures.FILTER_TYPES:
                for wm in textures.WRAP_MODES:
                    ref = mi.load_dict({"type": "bitmap", "filename": str(files / fn), "raw": raw,
                                        "filter_type": ft, "wrap_mode": wm, "to_uv": to_uv})
                    want = np.array(ref.eval(si), dtype=np.float64).T
                    got = textures.Bitmap(textures.read_bitmap(files / fn, raw), ft, wm, to_uv=m).eval(uv)
                    assert np.max(np.abs(got - want)) < 1e-5, (fn, raw, ft, wm)
    ref = mi.load_dict({"type": "checkerboard", "to_uv": to_uv,
                        "color0": {"type": "rgb", "value": [0.9, 0.1, 0.2]},
                        "color1": {"type": "rgb", "value": [0.1, 0.5, 0.7]}})
    want = np.array(ref.eval(si), dtype=np.float64).T
    got = textures.Checkerboard([0.9, 0.1, 0.2], [0.1, 0.5, 0.7], to_uv=m).eval(uv)
    # float32 vs float64 uv: only points within rounding of a cell border may differ
    assert np.mean(np.any(np.abs(got - want) > 1e-6, axis=1)) < 1e-3


@pytest.mark.slow
def test_textured_diffuse_scene_vs_direct(files, variant):
    """Every shape's uv and every bitmap option on diffuse surfaces under delta lights: the core
    (Whitted depth 1) against Mitsuba's ``direct`` (its error no larger than twice that of
    ``direct`` itself at equal spp) and against the plugin (same samples)."""
    xml = scene_xml(body_diffuse(files))
    spp = 64
    a = core(xml, spp=spp, max_depth=1)
    ref = mitsuba(xml, variant, integrator("direct"), spp=2048)
    own = mitsuba(xml.replace('<sampler type="independent">',
                              '<sampler type="independent"><integer name="seed" value="5"/>'),
                  variant, integrator("direct"), spp=spp)
    err = rel_mse(a, ref)
    assert err < 1e-3 and err < 2.0 * rel_mse(own, ref), (err, rel_mse(own, ref))
    assert abs(a.mean() - ref.mean()) / ref.mean() < 5e-3
    c = plugin(xml, variant, spp=16, max_depth=1)
    assert rel_mse(core(xml, spp=16, max_depth=1), c) < 1e-6  # same samples: float32 vs float64


@pytest.mark.slow
def test_textured_bsdf_parameters_vs_path(files, variant):
    """Textures on plastic, conductor, dielectric and twosided parameters: core against the
    plugin (Mitsuba's BSDFs evaluate the textures) and Mitsuba's ``path``."""
    xml = scene_xml(body_bsdfs(files))
    a = core(xml, spp=16, max_depth=3)
    c = plugin(xml, variant, spp=16, max_depth=3)
    assert rel_mse(a, c) < 1e-5  # same samples (measured 6e-7)
    b = mitsuba(xml, variant, integrator("path", max_depth=4), spp=1024)
    # path adds the diffuse inter-reflections Whitted leaves out (measured 1.9e-3)
    assert rel_mse(a, b) < 5e-3


SHAPES = {
    "sphere": '<shape type="sphere"><point name="center" x="0.2" y="-0.1" z="0.3"/><float name="radius" value="0.9"/>'
              '<transform name="to_world"><rotate y="1" angle="40"/></transform></shape>',
    "cylinder": '<shape type="cylinder"><point name="p0" x="0.1" y="-0.8" z="0.2"/><point name="p1" x="-0.3" y="0.9" z="0"/>'
                '<float name="radius" value="0.6"/></shape>',
    "disk": '<shape type="disk"><transform name="to_world"><scale x="0.9" y="0.6"/><rotate x="1" angle="-50"/>'
            '<rotate z="1" angle="30"/></transform></shape>',
    "rectangle": '<shape type="rectangle"><transform name="to_world"><scale x="0.9" y="0.6"/><rotate x="1" angle="-50"/>'
                 '</transform></shape>',
    "cube": '<shape type="cube"><transform name="to_world"><scale value="0.6"/><rotate x="1" y="2" z="0.5" angle="35"/>'
            '</transform></shape>',
    "obj": '<shape type="obj"><string name="filename" value="{d}/quad.obj"/><transform name="to_world">'
           '<rotate y="1" angle="20"/></transform></shape>',
    "ply": '<shape type="ply"><string name="filename" value="{d}/quad.ply"/></shape>',
    "obj_no_vt": '<shape type="obj"><string name="filename" value="{d}/plain.obj"/></shape>',
    "obj_no_vt_flipped": '<shape type="obj"><string name="filename" value="{d}/plain.obj"/>'
                         '<boolean name="flip_normals" value="true"/></shape>',
    "cube_flipped": '<shape type="cube"><boolean name="flip_normals" value="true"/></shape>',
}


@pytest.mark.parametrize("kind", sorted(SHAPES))
def test_shape_uv_matches_mitsuba(files, variant, kind):
    """The uv of each shape's hits equals Mitsuba's ``si.uv`` for the same rays (u and the
    angular coordinates compared modulo 1: the seam at φ = 0 may fall on either side)."""
    import mitsuba as mi
    from links1.scene.loader import load_string
    (files / "plain.obj").write_text("v -1 -1 0\nv 1 -1 0\nv 0.5 1 0\nv -1 1 0\nf 1 2 3\nf 1 3 4\n")
    xml = f'<scene version="3.0.0">{SHAPES[kind].format(d=files)}</scene>'
    rng = np.random.default_rng(11)
    n = 2000
    o = rng.normal(size=(n, 3))
    o = 4.0 * o / np.linalg.norm(o, axis=1, keepdims=True)
    d = rng.uniform(-0.7, 0.7, size=(n, 3)) - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ms = mi.load_string(xml)
    ray = mi.Ray3f(mi.Point3f(*o.T.astype(np.float32)), mi.Vector3f(*d.T.astype(np.float32)))
    si = ms.ray_intersect(ray)
    t_mi = np.array(si.t, dtype=np.float64)
    uv_mi = np.array(si.uv, dtype=np.float64).T
    with pytest.warns(Warning):
        shape = load_string(xml).shapes[0]
    o, d = o.astype(np.float32).astype(np.float64), d.astype(np.float32).astype(np.float64)
    t, prim = shape.intersect(o, d, 0.0, np.inf)
    with np.errstate(invalid="ignore"):
        both = np.isfinite(t) & np.isfinite(t_mi) & (np.abs(t - t_mi) < 1e-4)
    assert both.sum() > 200
    uv = shape.uv(o[both], d[both], t[both], prim[both])
    diff = np.abs(uv - uv_mi[both])
    periodic = {"sphere": [0], "cylinder": [0], "disk": [1]}.get(kind, [])
    for k in periodic:
        diff[:, k] = np.minimum(diff[:, k], 1.0 - diff[:, k])
    assert np.max(diff) < 1e-4, kind


@pytest.mark.slow
@pytest.mark.parametrize("count", [1, 12])
def test_textured_links1_quadrics_plugin_matches_core(files, variant, count):
    """links1_quadric spheres and cylinders with textured Mitsuba BSDFs: the plugin gives them
    the core's uv (one code block per quadric, or the quadric BVH from 8 on)."""
    shapes = []
    for i in range(count):
        kind = "sphere" if i % 2 == 0 else "cylinder"
        x, z = -2.0 + 4.0 * (i % 4) / 3.0, -1.0 + 1.2 * (i // 4)
        clips = ('<vector name="clip_0" value="0 0 1"/><float name="clip_0_offset" value="1"/>'
                 '<vector name="clip_1" value="0 0 -1"/><float name="clip_1_offset" value="1"/>'
                 if kind == "cylinder" else "")
        tex = (checker("reflectance", scale="6, 3") if i % 3 != 1 else
               bitmap("reflectance", files / "rgb.png"))
        shapes.append(f'<shape type="links1_quadric"><string name="kind" value="{kind}"/>{clips}'
                      f'<transform name="to_world"><scale value="0.45"/><rotate x="1" angle="-70"/>'
                      f'<translate x="{x}" y="0.6" z="{z}"/></transform>{diffuse(tex)}</shape>')
    xml = scene_xml("".join(shapes))
    a = core(xml, spp=4, max_depth=1)
    c = plugin(xml, variant, spp=4, max_depth=1)
    assert np.count_nonzero(a.max(axis=2)) > 25 * count
    assert rel_mse(a, c) < 1e-5
