"""One judgement of a links1 plugin's parameters, whoever reads the file: a typo is the same
one-line ``FILE:LINE: <element>`` error from both renderers of ``links1 render`` (exit 2) and
from :func:`links1_mitsuba.load_file` as from the core's reader
(tests/core/test_links1_parameters.py); ``mi.load_file`` and ``mi.load_dict`` refuse it naming
the element and the closest name. And :func:`links1_mitsuba.load_file`'s own options never
shadow a scene's ``$parameters``."""
from __future__ import annotations

import re

import pytest

from links1.errors import SceneError
from tests.core.test_links1_parameters import TYPOS, expected, scene_text, write_scene
from tests.core.test_scene_judgement import render

from .conftest import cli_variant

pytestmark = [pytest.mark.mitsuba, pytest.mark.usefixtures("llvm")]

BY_TYPO = {t[3]: t for t in TYPOS}


@pytest.mark.slow
@pytest.mark.parametrize("typo", ["difuse", "solvr", "max_dpeth"])
def test_both_renderers_print_the_same_line(tmp_path, typo):
    element, tag, good, _, line, hint = BY_TYPO[typo]
    path = write_scene(tmp_path, good, typo)
    for kind in ("core", "mitsuba"):
        out = tmp_path / f"{kind}.exr"
        rc, err = render(path, out, *cli_variant(kind), renderer=kind)
        assert (rc, err) == (2, [f"links1: error: {expected(path, element, tag, typo, line, hint)}"])
        assert not out.exists()


@pytest.mark.parametrize("element, tag, good, typo, line, hint", TYPOS, ids=[t[3] for t in TYPOS])
def test_load_file_says_what_the_core_says(tmp_path, element, tag, good, typo, line, hint):
    import links1_mitsuba
    path = write_scene(tmp_path, good, typo)
    with pytest.raises(SceneError) as e:
        links1_mitsuba.load_file(str(path))
    assert str(e.value) == expected(path, element, tag, typo, line, hint)


def _without_analytic_shapes(text: str) -> str:
    """The quadric and the blob as comments (the lines stay where they were)."""
    return re.sub(r'(<shape type="links1_(quadric|blob)">.*?</shape>)', r"<!-- \1 -->", text, flags=re.S)


#: the element's own line, where Mitsuba's parser places a plugin's error
ELEMENT_LINE = {"max_dpeth": 2, "difuse": 10, "L_1": 24, "radiuss": 28, "subdivisons": 33}


@pytest.mark.parametrize("typo", sorted(ELEMENT_LINE))
def test_mitsubas_own_loader_refuses_it_naming_the_element(tmp_path, typo):
    import mitsuba as mi
    element, tag, good, _, _, hint = BY_TYPO[typo]
    path = tmp_path / "typo.xml"
    path.write_text(_without_analytic_shapes(scene_text(good, typo)))
    with pytest.raises(RuntimeError) as e:
        mi.load_file(str(path))
    text = str(e.value)
    assert f"{path} (line {ELEMENT_LINE[typo]}," in text
    assert text.splitlines()[-1] == f"ValueError: {element} <{tag} name='{typo}'>: " + \
        expected(path, element, tag, typo, 0, hint).split(f"<{tag} name='{typo}'>: ")[1]


@pytest.mark.parametrize("d, says", [
    ({"type": "links1_phong", "difuse": 0.5},
     "<bsdf type='links1_phong'> <float name='difuse'>: unknown parameter 'difuse' (did you mean 'diffuse'?)"),
    ({"type": "links1_whitted", "max_dpeth": 2},
     "<integrator type='links1_whitted'> <integer name='max_dpeth'>: unknown parameter 'max_dpeth' "
     "(did you mean 'max_depth'?)"),
    ({"type": "links1_point", "id": "lamp", "L_1": 1.0},
     "<emitter type='links1_point' id='lamp'> <float name='L_1'>: unknown parameter 'L_1' (did you mean 'L1'?)"),
], ids=["phong", "whitted", "point"])
def test_load_dict_names_the_element(d, says):
    import mitsuba as mi
    with pytest.raises(RuntimeError) as e:
        mi.load_dict(d)
    assert says in str(e.value)


def test_names_the_mitsuba_base_classes_read_are_taken():
    """``hide_emitters`` (``mi.SamplingIntegrator``) and ``sampling_weight`` (``mi.Emitter``)
    are in the table: Mitsuba itself then finds them read (no "unreferenced property")."""
    import mitsuba as mi
    assert mi.load_dict({"type": "links1_whitted", "hide_emitters": True, "block_size": 16}) is not None
    assert mi.load_dict({"type": "links1_point", "sampling_weight": 2.0}) is not None


# ------------------------------------------------------------------ load_file's own options
PARAMETRIC = """<scene version="3.0.0">
    <default name="integrator" value="links1_whitted"/>
    <default name="max_depth" value="5"/>
    <integrator type="$integrator"><integer name="max_depth" value="$max_depth"/></integrator>
    <sensor type="perspective">
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
    </sensor>
    <shape type="sphere"><point name="center" value="0,0,4"/></shape>
    <emitter type="point"><point name="position" value="0,0,0"/></emitter>
</scene>
"""


def test_integrator_and_max_depth_are_scene_parameters(tmp_path):
    import links1
    import links1_mitsuba
    from links1_mitsuba.loader import whitted_of
    path = tmp_path / "parametric.xml"
    path.write_text(PARAMETRIC)
    own = links1_mitsuba.load_file(str(path), integrator="path", max_depth="2", links1_integrator="scene")
    assert str(own.integrator()).replace("\n", "").replace(" ", "") == "PathIntegrator[max_depth=2,rr_depth=5]"
    # links1_whitted replaces it, keeping its max_depth, as the core does with the same values
    assert whitted_of(links1_mitsuba.load_file(str(path), integrator="path", max_depth=2)).max_depth == 2
    core = links1.load_scene(str(path), integrator="path", max_depth=2)
    assert (core.integrator, core.max_depth) == ("path", 2)
    # params= holds scene values too, whatever their names
    assert whitted_of(links1_mitsuba.load_file(str(path), params={"max_depth": 3})).max_depth == 3


def test_the_options_old_name_is_a_scene_parameter_and_the_error_says_so(tmp_path):
    import links1_mitsuba
    path = write_scene(tmp_path)
    with pytest.raises(SceneError, match=r"unused parameter -D integrator=scene: the scene has no \$integrator "
                                         r".*links1's own choice of integrator is the keyword links1_integrator="):
        links1_mitsuba.load_file(str(path), integrator="scene")
    with pytest.raises(ValueError, match="links1_integrator must be 'links1' or 'scene', got 'path'"):
        links1_mitsuba.load_file(str(path), links1_integrator="path")
