"""A parameter a links1 plugin does not take (a typo) is an error, as Mitsuba refuses a property
no plugin reads: one line naming FILE:LINE of the property, the element, the property and the
closest name it takes. The core's reader here; both renderers and every loader of the Mitsuba
plugins in tests/plugins/test_links1_parameters.py."""
from __future__ import annotations

import pytest

from links1.errors import SceneError
from links1.scene import params
from links1.scene.loader import load_scene

#: every links1 plugin, one parameter per line (line numbers below are the file's)
SCENE = """<scene version="3.0.0">
    <integrator type="links1_whitted">
        <integer name="max_depth" value="2"/>
    </integrator>
    <sensor type="perspective">
        <transform name="to_world"><lookat origin="0,0,5" target="0,0,0" up="0,1,0"/></transform>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
        <sampler type="independent"><integer name="sample_count" value="1"/></sampler>
    </sensor>
    <bsdf type="links1_phong" id="mat">
        <rgb name="diffuse" value="0.5"/>
        <float name="exponent" value="20"/>
    </bsdf>
    <shape type="links1_quadric">
        <string name="kind" value="sphere"/>
        <boolean name="capped" value="false"/>
        <ref id="mat"/>
    </shape>
    <shape type="links1_blob">
        <string name="centers" value="2 0 0 1 1"/>
        <float name="threshold" value="0.5"/>
        <string name="solver" value="exact"/>
    </shape>
    <emitter type="links1_point">
        <point name="position" value="0,3,3"/>
        <rgb name="L1" value="1"/>
    </emitter>
    <emitter type="links1_spot">
        <vector name="direction" value="0,-1,0"/>
        <float name="radius" value="0.5"/>
        <point name="origin" value="0,3,0"/>
    </emitter>
    <shape type="links1_bicubic">
        <string name="filename" value="FLAT"/>
        <integer name="subdivisions" value="2"/>
    </shape>
</scene>
"""

#: (element, property tag, the name in SCENE, a typo of it, its line, the name suggested or None)
TYPOS = [
    ("<integrator type='links1_whitted'>", "integer", "max_depth", "max_dpeth", 3, "max_depth"),
    ("<bsdf type='links1_phong' id='mat'>", "rgb", "diffuse", "difuse", 11, "diffuse"),
    ("<bsdf type='links1_phong' id='mat'>", "float", "exponent", "exponnent", 12, "exponent"),
    ("<shape type='links1_quadric'>", "boolean", "capped", "caped", 16, "capped"),
    ("<shape type='links1_blob'>", "string", "solver", "solvr", 22, "solver"),
    ("<emitter type='links1_point'>", "rgb", "L1", "L_1", 26, "L1"),
    ("<emitter type='links1_spot'>", "float", "radius", "radiuss", 30, "radius"),
    ("<shape type='links1_bicubic'>", "integer", "subdivisions", "subdivisons", 35, "subdivisions"),
]


def scene_text(good: str | None = None, typo: str | None = None) -> str:
    """SCENE with the parameter ``good`` renamed ``typo`` (the first one of that name)."""
    from .test_loader import DATA
    import os
    text = SCENE.replace("FLAT", os.path.join(DATA, "flat.patch"))
    return text if good is None else text.replace(f'name="{good}"', f'name="{typo}"', 1)


def write_scene(tmp_path, good=None, typo=None):
    path = tmp_path / "typo.xml"
    path.write_text(scene_text(good, typo))
    return path


def expected(path, element, tag, typo, line, hint) -> str:
    """The one line every loader gives (without the CLI's ``links1: error:`` prefix)."""
    plugin = element.split("'")[1]
    kind = element[1:].split()[0]
    mean = f" (did you mean '{hint}'?)" if hint else ""
    return (f"{path}:{line}: {element} <{tag} name='{typo}'>: unknown parameter '{typo}'{mean}: "
            f"links1's {kind} '{plugin}' does not take it (Mitsuba refuses unreferenced properties)")


def test_the_scene_without_typos_loads(tmp_path):
    scene = load_scene(write_scene(tmp_path))
    assert scene.max_depth == 2 and len(scene.shapes) == 3 and len(scene.lights) == 2


@pytest.mark.parametrize("element, tag, good, typo, line, hint", TYPOS, ids=[t[3] for t in TYPOS])
def test_core_refuses_a_misspelt_links1_parameter(tmp_path, element, tag, good, typo, line, hint):
    path = write_scene(tmp_path, good, typo)
    with pytest.raises(SceneError) as e:
        load_scene(path)
    assert str(e.value) == expected(path, element, tag, typo, line, hint)


def test_every_links1_plugin_is_judged_by_the_table():
    """Each plugin of the table has its typo above, and a name it takes is never refused."""
    assert {t[0].split("'")[1] for t in TYPOS} == {t for _, t in params.PLUGINS}
    for _, plugin in params.PLUGINS:
        assert all(params.takes(plugin, n) for n in params.names_of(plugin))
    assert params.takes("links1_quadric", "clip_3_offset") and not params.takes("links1_quadric", "clip_offset")


def test_a_name_far_from_any_gets_no_suggestion():
    msg = params.unknown_parameter("shape", "links1_quadric", "radius", params.names_of("links1_quadric"))
    assert "did you mean" not in msg and msg.startswith("unknown parameter 'radius': links1's shape")


def test_a_misspelt_parameter_of_a_replaced_integrator_is_refused(tmp_path):
    """links1 replaces a Mitsuba integrator, whose parameters are still Mitsuba's to judge."""
    path = tmp_path / "path.xml"
    path.write_text(scene_text().replace('type="links1_whitted"', 'type="path"').replace("max_depth", "max_dpeth"))
    with pytest.raises(SceneError, match=r":3: <integrator type='path'> <integer name='max_dpeth'>: unknown "
                                         r"parameter 'max_dpeth' \(did you mean 'max_depth'\?\): Mitsuba's"):
        load_scene(path)
