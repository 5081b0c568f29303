"""Items 4-5 (Mitsuba renderer): the same judgement of a scene file as the core
(tests/core/test_scene_judgement.py), the plugin's warnings with FILE:LINE and element once
per element, no deprecated Mitsuba API."""
from __future__ import annotations

import warnings

import pytest

from links1.errors import SceneError
from tests.core.test_scene_judgement import WARN_SCENE, render, scene

from .conftest import cli_variant

# every test on each variant (conftest.py): the command line and the plugins render on the
# active one
pytestmark = [pytest.mark.mitsuba, pytest.mark.usefixtures("variant")]


@pytest.mark.slow
def test_unused_define_same_line_in_both_renderers(tmp_path):
    path = scene(tmp_path)
    lines = {}
    for kind in ("core", "mitsuba"):
        out = tmp_path / f"{kind}.exr"
        rc, err = render(path, out, "-D", "res=64", *cli_variant(kind), renderer=kind)
        assert rc == 2 and len(err) == 1 and not out.exists(), err
        lines[kind] = err[0]
    assert lines["core"] == lines["mitsuba"]
    assert lines["mitsuba"].startswith(f"links1: error: {path}:1: <scene>: unused parameter -D res=64")


def test_plugin_api_names_the_file_for_unused_parameters(tmp_path):
    """links1_mitsuba.load_file (Mitsuba's parser, no core check first) names the file too."""
    import links1_mitsuba
    path = scene(tmp_path)
    with pytest.raises(SceneError) as e:
        links1_mitsuba.load_file(str(path), res=64)
    assert str(e.value).startswith(f"{path}:1: <scene>: unused parameter -D res=64: the scene has no $res")
    assert links1_mitsuba.load_file(str(path), spp=2) is not None   # a parameter it takes: fine


@pytest.mark.slow
def test_misspelt_parameter_same_decision_in_both_renderers(tmp_path):
    path = scene(tmp_path, reflectance="reflectnce")
    lines = {}
    for kind in ("core", "mitsuba"):
        rc, err = render(path, tmp_path / f"{kind}.exr", *cli_variant(kind), renderer=kind)
        assert rc == 2 and len(err) == 1, err
        lines[kind] = err[0]
    assert lines["core"] == lines["mitsuba"]
    assert f"{path}:10: <bsdf type='diffuse'> <rgb name='reflectnce'>: unknown parameter" in lines["mitsuba"]
    # Mitsuba itself refuses the same file (the table the core judges with agrees with it)
    import links1_mitsuba
    with pytest.raises(RuntimeError, match="(?s)unreferenced property.*reflectnce"):
        links1_mitsuba.load_file(str(path))


@pytest.mark.slow
def test_integrator_links1_replaces_is_not_instantiated(tmp_path):
    """``<integrator type="mat">`` (a Bitterli scene): links1_whitted replaces it; with
    ``--integrator scene`` Mitsuba needs it, and refuses it in one line."""
    path = scene(tmp_path, integrator="mat")
    rc, err = render(path, tmp_path / "o.exr", *cli_variant("mitsuba"), renderer="mitsuba")
    assert rc == 0 and (tmp_path / "o.exr").exists(), err
    rc, err = render(path, tmp_path / "s.exr", "--integrator", "scene", *cli_variant("mitsuba"), renderer="mitsuba")
    assert rc == 2 and len(err) == 1 and "mat" in err[0] and str(path) in err[0], err
    assert not (tmp_path / "s.exr").exists()


@pytest.mark.slow
def test_plugin_warnings_name_place_once_per_element(tmp_path):
    path = scene(tmp_path, text=WARN_SCENE)
    rc, err = render(path, tmp_path / "o.exr", *cli_variant("mitsuba"), renderer="mitsuba")
    assert rc == 0, err
    glossy = [ln for ln in err if "glossy lobes" in ln]
    # two roughdielectric elements (the one at line 10 is shared by two spheres): one line each
    assert sorted(glossy) == [
        f"links1: warning: {path}:10: <bsdf type='roughdielectric' id='frosted'>: BSDF RoughDielectric has glossy "
        "lobes; it gets direct light only (its glossy interreflections are not Whitted's light paths)",
        f"links1: warning: {path}:14: <bsdf type='roughdielectric'>: BSDF RoughDielectric has glossy lobes; it "
        "gets direct light only (its glossy interreflections are not Whitted's light paths)"], err
    assert not [ln for ln in err if "thinlens" in ln], err   # its depth of field is rendered
    assert all(ln.startswith("links1: ") for ln in err), err


def test_loader_uses_no_deprecated_mitsuba_api(tmp_path):
    import links1_mitsuba
    path = scene(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        assert links1_mitsuba.load_file(str(path)) is not None
