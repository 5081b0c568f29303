"""A scene loaded the Mitsuba way (``mi.load_file``, ``mi.load_string``, ``mi.load_dict``) renders
with ``links1_whitted`` exactly as through ``links1_mitsuba.load_file``.

Shapes are matched to their own BSDFs and emitters by object, never by id (files written by
others rarely give shapes ids); ``links1_quadric`` and ``links1_blob`` arrive as proxies
(:mod:`links1_mitsuba.proxies`) the integrator intersects itself. The references: the loader's
image of the same file (bit for bit), and Mitsuba's own ``direct`` integrator on a file without
ids whose walls differ only in colour.
"""
from __future__ import annotations

import glob
import os
import re

import numpy as np
import pytest

from tests.plugins.conftest import SCENES, use_variant

from tests.scenes import perspective, scene, whitted

pytestmark = pytest.mark.mitsuba

SPP = 1


def _file_integrator(path):
    """``(type, max_depth or None)`` of the file's ``<integrator>``, or None."""
    m = re.search(r'<integrator type="(\w+)"\s*/?>(\s*<integer name="max_depth" value="(\d+)")?',
                  open(path).read())
    return None if m is None else (m.group(1), None if m.group(3) is None else int(m.group(3)))


def _params(path):
    return {"res": 48} if "$res" in open(path).read() else {}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(os.path.basename(p) for p in glob.glob(os.path.join(SCENES, "*.xml"))))
def test_mi_load_file_equals_the_loader(name):
    """Every committed scene: ``mi.load_file`` + ``links1_whitted`` (the file's own when it names
    it, else one made with ``mi.load_dict`` and the file's ``max_depth``, as the loader keeps it)
    gives the loader's image bit for bit."""
    use_variant("llvm_ad_rgb")
    import mitsuba as mi

    import links1_mitsuba
    path = os.path.join(SCENES, name)
    plain = mi.load_file(path, **_params(path))
    integ = _file_integrator(path)
    if integ is not None and integ[0] == "links1_whitted":
        assert type(plain.integrator()).__name__ == "Links1Whitted"
        got = np.array(mi.render(plain, spp=SPP))
    else:
        extra = {} if integ is None or integ[1] is None else {"max_depth": integ[1]}
        got = np.array(mi.render(plain, integrator=mi.load_dict({"type": "links1_whitted", **extra}), spp=SPP))
    want = np.array(mi.render(links1_mitsuba.load_file(path, **_params(path)), spp=SPP))
    assert got.shape == want.shape
    assert np.array_equal(got, want), f"{name}: {int((got != want).sum())} values differ, max {np.abs(got - want).max()}"


#: a Cornell-box-like room without a single id: red and green walls, a grey floor, two spheres
#: of different colours, a point light. With ids missing, matching BSDFs by id gave every shape
#: one material.
NO_IDS = scene(perspective("0, 1, 3.6", "0, 1, 0", fov=45, width=40), """
  <shape type="rectangle"><transform name="to_world"><rotate x="1" angle="-90"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.7, 0.7"/></bsdf></shape>
  <shape type="rectangle"><transform name="to_world"><rotate y="1" angle="90"/><translate x="-1" y="1"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.8, 0.05, 0.05"/></bsdf></shape>
  <shape type="rectangle"><transform name="to_world"><rotate y="1" angle="-90"/><translate x="1" y="1"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.05, 0.8, 0.05"/></bsdf></shape>
  <shape type="rectangle"><transform name="to_world"><translate y="1" z="-1"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.5, 0.9"/></bsdf></shape>
  <shape type="sphere"><point name="center" x="-0.4" y="0.35" z="-0.2"/><float name="radius" value="0.35"/>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.9, 0.6, 0.1"/></bsdf></shape>
  <shape type="sphere"><point name="center" x="0.45" y="0.3" z="0.2"/><float name="radius" value="0.3"/>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.1, 0.3, 0.9"/></bsdf></shape>
  <emitter type="point"><point name="position" x="0" y="1.8" z="0.5"/><rgb name="intensity" value="3"/></emitter>""")


def _rel_mse(a, b):
    return float(np.sum((a - b) ** 2) / np.sum(b ** 2))


@pytest.mark.slow
def test_shapes_without_ids_keep_their_own_materials():
    """The room without ids: ``mi.load_string`` + ``links1_whitted`` equals the loader's image bit
    for bit and Mitsuba's ``direct`` (bsdf_samples 0, 256 spp) to its noise; the red wall is
    red and the green wall green (each wall's mean colour, measured in the image)."""
    use_variant("llvm_ad_rgb")
    import mitsuba as mi

    import links1_mitsuba
    plain = mi.load_string(NO_IDS)
    assert all(s.id() == "" for s in plain.shapes())
    got = np.array(mi.render(plain, integrator=mi.load_dict({"type": "links1_whitted", "max_depth": 1}),
                             spp=16), dtype=np.float64)
    loaded = np.array(mi.render(links1_mitsuba.load_string(NO_IDS), spp=16), dtype=np.float64)
    assert np.array_equal(got, loaded)
    ref = np.array(mi.render(plain, integrator=mi.load_dict({"type": "direct", "bsdf_samples": 0,
                                                              "emitter_samples": 1}), spp=256),
                   dtype=np.float64)
    assert _rel_mse(got, ref) < 2e-3, _rel_mse(got, ref)
    left, right = got[16:24, 1:3].mean(axis=(0, 1)), got[16:24, -3:-1].mean(axis=(0, 1))
    assert left[0] > 4 * left[1] and right[1] > 4 * right[0], (left, right)


QUADRIC_XML = scene(perspective("0, 1, 5", "0, 0.5, 0", fov=40, width=32, height=24), whitted(2), """
  <shape type="rectangle"><transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.6, 0.6"/></bsdf></shape>
  <shape type="links1_quadric"><string name="kind" value="sphere"/>
    <transform name="to_world"><scale value="0.6"/><translate x="-0.7" y="0.6"/></transform>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.8, 0.2, 0.1"/><rgb name="reflectance" value="0.3"/></bsdf></shape>
  <shape type="links1_blob"><string name="centers" value="0.6 0.5 0 1 0.5, 1.1 0.5 0 1 0.5"/>
    <float name="threshold" value="0.5"/>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.1, 0.4, 0.9"/></bsdf></shape>
  <emitter type="links1_point"><point name="position" x="1" y="3" z="2"/><rgb name="L1" value="6"/></emitter>""")


@pytest.mark.slow
def test_links1_shapes_from_mi_load_string_and_load_dict():
    """``links1_quadric`` and ``links1_blob`` in a file Mitsuba parses alone (proxies), and the same
    scene as a dict: both equal the loader's image bit for bit, and the shapes are there (the
    image differs from the floor alone). Mitsuba's own integrators see no proxy surface."""
    use_variant("llvm_ad_rgb")
    import mitsuba as mi

    import links1_mitsuba
    want = np.array(mi.render(links1_mitsuba.load_string(QUADRIC_XML)))
    plain = mi.load_string(QUADRIC_XML)
    got = np.array(mi.render(plain))
    assert np.array_equal(got, want)
    floor_only = re.sub(r'<shape type="links1_(quadric|blob)">.*?</shape>', "", QUADRIC_XML, flags=re.S)
    assert np.abs(np.array(mi.render(mi.load_string(floor_only))) - got).max() > 0.1
    d = {"type": "scene",
         "cam": {"type": "perspective", "fov": 40,
                 "to_world": mi.ScalarTransform4f().look_at([0, 1, 5], [0, 0.5, 0], [0, 1, 0]),
                 "sampler": {"type": "independent", "sample_count": 1},
                 "film": {"type": "hdrfilm", "width": 32, "height": 24, "rfilter": {"type": "box"}}},
         "floor": {"type": "rectangle",
                   "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], -90).scale(4),
                   "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.6, 0.6, 0.6]}}},
         "ball": {"type": "links1_quadric", "kind": "sphere",
                  "to_world": mi.ScalarTransform4f().translate([-0.7, 0.6, 0]).scale(0.6),
                  "bsdf": {"type": "links1_phong", "diffuse": {"type": "rgb", "value": [0.8, 0.2, 0.1]},
                           "reflectance": {"type": "rgb", "value": [0.3, 0.3, 0.3]}}},
         "blob": {"type": "links1_blob", "centers": "0.6 0.5 0 1 0.5, 1.1 0.5 0 1 0.5", "threshold": 0.5,
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.1, 0.4, 0.9]}}},
         "light": {"type": "links1_point", "position": [1, 3, 2], "L1": {"type": "rgb", "value": [6, 6, 6]}}}
    from_dict = np.array(mi.render(mi.load_dict(d), integrator=mi.load_dict({"type": "links1_whitted",
                                                                             "max_depth": 2})))
    assert np.abs(from_dict - want).max() < 1e-5, np.abs(from_dict - want).max()
    # Mitsuba's own integrator: the proxies are invisible (the floor's image)
    seen = np.array(mi.render(plain, integrator=mi.load_dict({"type": "direct"}), spp=4))
    floor = np.array(mi.render(mi.load_string(floor_only), integrator=mi.load_dict({"type": "direct"}), spp=4))
    assert np.array_equal(seen, floor)


@pytest.mark.slow
def test_one_integrator_for_several_plain_scenes():
    """One ``links1_whitted`` object rendering two plain scenes in turn gives each its own image
    (its links1 shapes and slots are the scene's, made again for another scene)."""
    use_variant("llvm_ad_rgb")
    import mitsuba as mi
    integ = mi.load_dict({"type": "links1_whitted", "max_depth": 2})
    a, b = mi.load_string(QUADRIC_XML), mi.load_string(NO_IDS)
    first = np.array(mi.render(a, integrator=integ))
    np.array(mi.render(b, integrator=integ))
    again = np.array(mi.render(a, integrator=integ))
    assert np.array_equal(first, again)
    assert np.array_equal(first, np.array(mi.render(mi.load_string(QUADRIC_XML))))


def test_an_emitter_inside_a_proxy_is_refused_in_one_line():
    use_variant("llvm_ad_rgb")
    import mitsuba as mi
    xml = QUADRIC_XML.replace('<string name="kind" value="sphere"/>',
                              '<string name="kind" value="sphere"/><emitter type="area"/>')
    with pytest.raises(RuntimeError, match=r"links1_quadric: an emitter inside this shape needs "
                                           r"links1_mitsuba\.load_file\(\)"):
        mi.load_string(xml)


INSTANCES = scene(perspective("0, 2.2, 4.5", "0, 0.4, 0", fov=45, width=40, height=30), """
  <shape type="rectangle"><transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.6, 0.6"/></bsdf></shape>
  <shape type="shapegroup" id="pair">
    <shape type="sphere"><point name="center" x="0" y="0.3" z="0"/><float name="radius" value="0.3"/>
      <bsdf type="diffuse"><rgb name="reflectance" value="0.9, 0.2, 0.1"/></bsdf></shape>
    <shape type="cube"><transform name="to_world"><scale value="0.2"/><translate x="0.6" y="0.2"/></transform>
      <bsdf type="diffuse"><rgb name="reflectance" value="0.1, 0.3, 0.9"/></bsdf></shape>
  </shape>
  <shape type="instance"><ref id="pair"/><transform name="to_world"><translate x="-1.2"/></transform></shape>
  <shape type="instance"><ref id="pair"/><transform name="to_world"><rotate y="1" angle="40"/><translate x="0.5" z="-0.5"/></transform></shape>
  <emitter type="point"><point name="position" x="1" y="3" z="2"/><rgb name="intensity" value="10"/></emitter>""")


@pytest.mark.slow
def test_instances_from_mi_load_string():
    """Mitsuba's instances in a plain load: a hit names the shapegroup's member, which has a
    slot (and BSDF) of its own. The image equals the loader's (which flattens the instances
    into copies) to float32 rounding and Mitsuba's ``direct``."""
    use_variant("llvm_ad_rgb")
    import mitsuba as mi

    import links1_mitsuba
    plain = mi.load_string(INSTANCES)
    got = np.array(mi.render(plain, integrator=mi.load_dict({"type": "links1_whitted", "max_depth": 1}), spp=16),
                   dtype=np.float64)
    flat = np.array(mi.render(links1_mitsuba.load_string(INSTANCES), spp=16), dtype=np.float64)
    assert np.abs(got - flat).max() < 1e-4, np.abs(got - flat).max()
    ref = np.array(mi.render(plain, integrator=mi.load_dict({"type": "direct", "bsdf_samples": 0}), spp=256),
                   dtype=np.float64)
    assert _rel_mse(got, ref) < 2e-3, _rel_mse(got, ref)
    assert got.max() > 0.05


@pytest.mark.slow
def test_sdfgrid_in_a_rotating_instance(tmp_path):
    """An ``sdfgrid`` cannot take a rotating ``to_world`` (Mitsuba: "use instancing"): the loader
    keeps its instance (where it flattens other groups) and the plugin shades the member's
    hits. A sphere's signed distances in a grid, rotated and scaled through an instance: the
    plugin equals Mitsuba's ``direct``; through the loader and through ``mi.load_string``."""
    use_variant("llvm_ad_rgb")
    import mitsuba as mi

    import links1_mitsuba
    n = 24
    x = (np.arange(n) + 0.5) / n
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    sdf = np.sqrt((X - 0.5) ** 2 + (Y - 0.5) ** 2 + (Z - 0.5) ** 2) - 0.3
    mi.VolumeGrid(np.ascontiguousarray(sdf.transpose(2, 1, 0)[..., None]).astype(np.float32)).write(
        str(tmp_path / "ball.vol"))
    xml = INSTANCES.replace('''<shape type="shapegroup" id="pair">''', f'''<shape type="shapegroup" id="pair">
    <shape type="sdfgrid"><string name="filename" value="{tmp_path / 'ball.vol'}"/>
      <transform name="to_world"><translate x="-0.5" y="0.6" z="-0.5"/></transform>
      <bsdf type="diffuse"><rgb name="reflectance" value="0.3, 0.9, 0.3"/></bsdf></shape>''')
    plain = mi.load_string(xml)
    ref = np.array(mi.render(plain, integrator=mi.load_dict({"type": "direct", "bsdf_samples": 0}), spp=256),
                   dtype=np.float64)
    loaded = np.array(mi.render(links1_mitsuba.load_string(xml), spp=16), dtype=np.float64)
    got = np.array(mi.render(plain, integrator=mi.load_dict({"type": "links1_whitted", "max_depth": 1}), spp=16),
                   dtype=np.float64)
    green = (ref[..., 1] > 1.5 * ref[..., 0]) & (ref[..., 1] > 0.05)
    assert green.sum() > 20                     # the balls are in the picture
    for img in (loaded, got):
        assert _rel_mse(img, ref) < 3e-3, _rel_mse(img, ref)
        assert np.abs(img[green] - ref[green]).mean() < 0.02


@pytest.mark.slow
def test_ellipsoids_from_mi_load_dict():
    """Mitsuba's ``ellipsoids`` shape (its own intersection) in a dict scene: links1_whitted at
    max_depth 1 equals Mitsuba's ``direct`` (bsdf_samples 0) to its noise at 256 spp, and the
    red ellipsoids are in the picture."""
    use_variant("llvm_ad_rgb")
    import mitsuba as mi
    d = {"type": "scene",
         "cam": {"type": "perspective", "fov": 40,
                 "to_world": mi.ScalarTransform4f().look_at([0, 1.5, 5], [0, 0.5, 0], [0, 1, 0]),
                 "film": {"type": "hdrfilm", "width": 40, "height": 30, "rfilter": {"type": "box"}}},
         "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], -90).scale(4),
                   "bsdf": {"type": "diffuse"}},
         "ell": {"type": "ellipsoids",
                 "centers": mi.TensorXf(np.array([[0, 0.6, 0], [1, 0.5, 0.3]], np.float32)),
                 "scales": mi.TensorXf(np.array([[0.5, 0.3, 0.4], [0.3, 0.3, 0.3]], np.float32)),
                 "quaternions": mi.TensorXf(np.array([[0, 0, 0, 1], [0, 0, 0, 1]], np.float32)),
                 "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.8, 0.2, 0.1]}}},
         "light": {"type": "point", "position": [1, 3, 2], "intensity": {"type": "rgb", "value": [10, 10, 10]}}}
    s = mi.load_dict(d)
    got = np.array(mi.render(s, integrator=mi.load_dict({"type": "links1_whitted", "max_depth": 1}), spp=16),
                   dtype=np.float64)
    ref = np.array(mi.render(s, integrator=mi.load_dict({"type": "direct", "bsdf_samples": 0}), spp=256),
                   dtype=np.float64)
    assert _rel_mse(got, ref) < 2e-3, _rel_mse(got, ref)
    assert (ref[..., 0] > 2 * ref[..., 1]).sum() > 100
