"""What ``params.update()`` and the loaders say about a value the links1 plugins refuse: one
line naming the parameter, and the element by ``FILE:LINE`` (or its id), never an empty id."""
from __future__ import annotations

import re

import pytest

pytestmark = pytest.mark.mitsuba

SCENE = """<scene version="3.0.0">
    <integrator type="links1_whitted"/>
    <sensor type="perspective">
        <transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
    </sensor>
    <emitter type="links1_point"><point name="position" x="0" y="3" z="3"/></emitter>
    <shape type="links1_quadric">
        <string name="kind" value="sphere"/>QUADRIC
        <bsdf type="links1_phong"><rgb name="diffuse" value="0.3"/></bsdf>
    </shape>
    <shape type="links1_blob">
        <string name="centers" value="0 0 0 1 0.5"/>
        <float name="threshold" value="0.3"/>BLOB
    </shape>
</scene>
"""
QUADRIC_LINE, BSDF_LINE, BLOB_LINE = 8, 10, 12
SINGULAR = '<transform name="to_world"><scale value="0"/></transform>'


def _file(tmp_path, quadric="", blob=""):
    path = tmp_path / ("bad.xml" if quadric or blob else "scene.xml")
    path.write_text(SCENE.replace("QUADRIC", quadric).replace("BLOB", blob))
    return str(path)


def _wide(mi, width=2):
    return mi.Color3f(*[[0.1 * (i + 1) for i in range(width)]] * 3)


def test_phong_update_of_a_wide_colour_names_the_parameter(variant):
    import mitsuba as mi
    bsdf = mi.load_dict({"type": "links1_phong", "id": "shell"})
    params = mi.traverse(bsdf)
    params["diffuse.value"] = _wide(mi)
    with pytest.raises(ValueError, match=r"^links1_phong 'shell': 'diffuse.value' must be one "
                                         r"Color3f \(width 1\), got width 2$"):
        params.update()
    bsdf = mi.load_dict({"type": "links1_phong"})
    params = mi.traverse(bsdf)
    params["exponent"] = mi.Float([10.0, 20.0, 30.0])
    with pytest.raises(ValueError, match=r"^links1_phong: 'exponent' must be one Float \(width 1\), "
                                         r"got width 3$"):
        params.update()
    params = mi.traverse(mi.load_dict({"type": "links1_phong"}))
    params["diffuse.value"] = mi.Color3f(0.1, 0.2, 1.5)     # (the range check names it too)
    with pytest.raises(ValueError, match=r"^links1_phong: invalid RGB reflectance .* for 'diffuse'"):
        params.update()


def test_phong_update_error_of_a_loaded_file_gives_its_line(variant, tmp_path):
    import mitsuba as mi
    import links1_mitsuba
    path = _file(tmp_path)
    scene = links1_mitsuba.load_file(path)
    params = mi.traverse(scene)
    key, = (k for k in params.keys() if k.endswith("diffuse.value"))
    params[key] = _wide(mi, 4)
    with pytest.raises(ValueError, match=rf"^{re.escape(path)}:{BSDF_LINE}: <bsdf type='links1_phong'>: "
                                         r"'diffuse.value' must be one Color3f \(width 1\), got width 4$"):
        params.update()


def test_a_links1_light_warns_at_its_line_in_the_file(variant):
    """A links1 plugin's own warning names its place that the loader handed it (a property of
    its object, ``util.PLACE_PROPERTY``): an out-of-gamut spectrum on a ``links1_point``
    through ``links1_mitsuba.load_string`` names ``<string>:LINE: <emitter ...>``; the same
    XML through ``mi.load_string`` (no loader, no place) names the parameter alone."""
    import warnings
    import mitsuba as mi
    import links1_mitsuba
    xml = SCENE.replace('<point name="position" x="0" y="3" z="3"/>',
                        '<spectrum name="L1" value="500:0, 540:1, 545:0"/>').replace("QUADRIC", "").replace("BLOB", "")
    said = []
    for load in (links1_mitsuba.load_string, mi.load_string):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            load(xml)
        said.append([str(w.message) for w in caught if "out-of-gamut" in str(w.message)])
    assert [len(s) for s in said] == [1, 1], said
    assert said[0][0].startswith("<string>:7: <emitter type='links1_point'> <spectrum name='L1'>: clamping ")
    assert said[1][0].startswith("'L1': clamping ")


@pytest.mark.parametrize("plugin, line", [("links1_quadric", QUADRIC_LINE), ("links1_blob", BLOB_LINE)])
def test_shape_without_id_is_named_by_file_and_line(variant, tmp_path, plugin, line):
    import mitsuba as mi
    import links1_mitsuba
    quadric = plugin == "links1_quadric"
    bad = _file(tmp_path, **{"quadric" if quadric else "blob": SINGULAR})
    expect = rf"^{re.escape(bad)}:{line}: {plugin}: to_world is singular \(a scale of 0 flattens the shape\)$"
    with pytest.raises(ValueError, match=expect):                    # in the file
        links1_mitsuba.load_file(bad)
    good = _file(tmp_path)
    params = mi.traverse(links1_mitsuba.load_file(good))
    params[f"links1_whitted.{plugin}_{0 if quadric else 1}.to_world"] = mi.Transform4f().scale(0.0)
    with pytest.raises(ValueError, match=expect.replace(re.escape(bad), re.escape(good))):
        params.update()                                              # by params.update()
    with pytest.raises(Exception) as info:                           # through mi.load_file
        mi.load_file(bad)
    assert f"{plugin}: to_world is singular" in str(info.value)
    assert f"{plugin} ''" not in str(info.value)


def test_shape_with_id_is_named_by_it_after_a_load_dict(variant):
    import mitsuba as mi
    from links1_mitsuba import geometry
    from links1_mitsuba.shapes import QuadricSpec
    import numpy as np
    spec = QuadricSpec(0, "ball", "sphere", np.eye(4))
    held = geometry.hold(spec)
    held["to_world"] = mi.Transform4f().scale(0.0)
    with pytest.raises(ValueError, match=r"^links1_quadric 'ball': to_world is singular"):
        geometry.updated(spec, held, ["to_world"])
    with pytest.raises(ValueError, match=r"^links1_quadric: to_world is singular"):
        QuadricSpec(0, "", "sphere", np.zeros((4, 4)))
