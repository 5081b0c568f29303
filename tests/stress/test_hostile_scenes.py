"""The edited scenes that crashed, printed "internal error" or wrote NaN pixels,
each through ``links1 render`` with both renderers (in process: the segfault they once
caused is fixed and guarded by tests/plugins/test_missing_bsdf.py).

Each case asserts the contract: exit 0 with a finite image equal to what the scene means,
or exit 2 with exactly one ``links1: error:`` line naming the file, line and element.
"""
from __future__ import annotations

import os
import re
import subprocess
import sys

import numpy as np
import pytest

from links1.scene import params
from links1_app.cli import main
from links1.imaging.image import read_image

from .fuzz import ROOT, SCENES

RES = ["--width", "24", "--height", "24", "--spp", "1", "--no-progress"]


def _kinds():
    return ["core", pytest.param("mitsuba", marks=pytest.mark.mitsuba)]


@pytest.fixture
def renderer(request):
    kind = request.param
    if kind == "mitsuba":
        from tests.stress.test_fuzz import _mitsuba_problem
        if why := _mitsuba_problem():
            pytest.skip(f"mitsuba renderer unavailable: {why}")
    return kind


def _links(tmp_path):
    """The scenes' include/ and meshes/ folders, beside the edited copies."""
    for sub in ("include", "meshes"):
        if not (tmp_path / sub).exists():
            os.symlink(os.path.join(SCENES, sub), tmp_path / sub)


def _edited(tmp_path, scene, line_no, old, new, name=None):
    _links(tmp_path)
    lines = open(os.path.join(SCENES, scene), encoding="utf-8").read().split("\n")
    assert old in lines[line_no - 1], (scene, line_no, lines[line_no - 1])
    lines[line_no - 1] = lines[line_no - 1].replace(old, new, 1)
    path = tmp_path / (name or scene)
    path.write_text("\n".join(lines))
    return str(path)


def _render(capsys, path, out, renderer, *extra):
    capsys.readouterr()
    rc = main(["render", path, "-o", str(out), "--renderer", renderer, *RES, *extra])
    err = capsys.readouterr().err
    return rc, err


def _one_error(rc, err, path, line, pattern):
    errors = [ln for ln in err.splitlines() if ln.startswith("links1: error:")]
    assert rc == 2 and len(errors) == 1, err
    assert "internal error" not in err and "Traceback" not in err
    assert f"{path}:{line}:" in errors[0], errors[0]
    assert re.search(pattern, errors[0]), errors[0]


@pytest.mark.slow
@pytest.mark.parametrize("renderer", _kinds(), indirect=True)
def test_quadric_without_bsdf_beside_ones_with_one(renderer, tmp_path, capsys):
    """fig4.xml with the first quadric's <ref id="shell"/> removed (exit 139 before): it
    renders, and the shell looks as it does with an explicit <bsdf type="diffuse"/>."""
    none = _edited(tmp_path, "fig4.xml", 38, '<ref id="shell"/>', "", "none.xml")
    explicit = _edited(tmp_path, "fig4.xml", 38, '<ref id="shell"/>', '<bsdf type="diffuse"/>', "explicit.xml")
    images = []
    for path in (none, explicit):
        rc, err = _render(capsys, path, tmp_path / "o.exr", renderer)
        assert rc == 0, err
        images.append(read_image(str(tmp_path / "o.exr")))
    assert np.all(np.isfinite(images[0]))
    assert np.array_equal(images[0], images[1])


@pytest.mark.parametrize("renderer", _kinds(), indirect=True)
@pytest.mark.parametrize("z", ["0", "-0"])
def test_rectangle_scaled_to_zero_thickness_is_still_a_rectangle(renderer, tmp_path, capsys, z):
    """lights.xml's floor with <scale z="0"/> (LinAlgError before): a rectangle lies in its
    z = 0 plane, so it renders as with z = 1 (Mitsuba 3.9.1 hits it but derives NaN normals
    from the singular map; links1 gives it the normal of a positive z scale)."""
    flat = _edited(tmp_path, "lights.xml", 25, 'z="1"', f'z="{z}"', "flat.xml")
    rc, err = _render(capsys, flat, tmp_path / "flat.exr", renderer)
    assert rc == 0, err
    rc, err = _render(capsys, os.path.join(SCENES, "lights.xml"), tmp_path / "ref.exr", renderer)
    assert rc == 0, err
    a, b = read_image(str(tmp_path / "flat.exr")), read_image(str(tmp_path / "ref.exr"))
    assert np.all(np.isfinite(a))
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-5)


@pytest.mark.parametrize("renderer", _kinds(), indirect=True)
def test_rectangle_scaled_to_zero_area_is_refused(renderer, tmp_path, capsys):
    """A pane of shadows.xml with x="-0" (LinAlgError before): a rectangle of zero area
    (Mitsuba draws nothing) is refused, naming the element."""
    path = _edited(tmp_path, "shadows.xml", 22, 'x="1.2" y', 'x="-0" y')
    rc, err = _render(capsys, path, tmp_path / "o.exr", renderer)
    _one_error(rc, err, path, 21, r"<shape type='rectangle'>: to_world is singular")
    assert not (tmp_path / "o.exr").exists()


@pytest.mark.parametrize("renderer", _kinds(), indirect=True)
@pytest.mark.parametrize("value, line, pattern", [
    ("1e300", 17, r"<scale>: z: \|value\| must be <= 1e\+30"),        # OverflowError before
    ("1e20", 17, r"<scale>: the transform's entries must be finite and <= 1e\+15"),
    ("1e-20", 17, r"<shape type='links1_quadric'>: to_world scales the shape by 1e-20"),
])
def test_quadric_scale_out_of_range(renderer, tmp_path, capsys, value, line, pattern):
    path = _edited(tmp_path, "many.xml", 17, 'z="0.2203"', f'z="{value}"')
    rc, err = _render(capsys, path, tmp_path / "o.exr", renderer)
    _one_error(rc, err, path, line, pattern)


@pytest.mark.parametrize("renderer", _kinds(), indirect=True)
@pytest.mark.parametrize("value", ["1.5", "1e300", "-0.1"])
def test_diffuse_reflectance_outside_0_1_is_refused(renderer, tmp_path, capsys, value):
    """Mitsuba refuses an RGB reflectance outside [0, 1]; the core wrote inf/NaN pixels for
    1e300 before."""
    _links(tmp_path)
    xml = tmp_path / "d.xml"
    xml.write_text(open(os.path.join(SCENES, "lights.xml")).read().replace(
        '<ref id="white"/>\n    </shape>',
        f'<bsdf type="diffuse"><rgb name="reflectance" value="{value}"/></bsdf>\n    </shape>', 1))
    rc, err = _render(capsys, str(xml), tmp_path / "o.exr", renderer)
    errors = [ln for ln in err.splitlines() if ln.startswith("links1: error:")]
    assert rc == 2 and len(errors) == 1, err
    assert "reflectance" in errors[0] and ("[0, 1]" in errors[0] or ">= 0" in errors[0] or "1e+30" in errors[0])


@pytest.mark.parametrize("renderer", _kinds(), indirect=True)
@pytest.mark.parametrize("plugin, param, value", [
    ("links1_phong", "diffuse", "2"), ("links1_phong", "reflectance", "1e20"),
    ("links1_whitted", "light_samples", str(params.MAX_LIGHT_SAMPLES + 1)),
    ("links1_whitted", "min_weight", "1.5"),
])
def test_links1_parameters_follow_the_shared_table(renderer, tmp_path, capsys, plugin, param, value):
    """The core's reader and the plugins read the ranges of links1/scene/params.py."""
    text = open(os.path.join(SCENES, "lights.xml")).read()
    tag = "rgb" if params.param(plugin, param).kind == "rgb" else params.param(plugin, param).kind
    tag = {"int": "integer"}.get(tag, tag)
    if plugin == "links1_phong":
        text = text.replace("</scene>", f'<shape type="links1_quadric"><string name="kind" value="sphere"/>'
                            f'<bsdf type="links1_phong"><{tag} name="{param}" value="{value}"/></bsdf></shape></scene>')
    else:
        text = text.replace("</integrator>", f'<{tag} name="{param}" value="{value}"/></integrator>', 1)
    assert f'name="{param}" value="{value}"' in text
    _links(tmp_path)
    xml = tmp_path / "p.xml"
    xml.write_text(text)
    rc, err = _render(capsys, str(xml), tmp_path / "o.exr", renderer)
    errors = [ln for ln in err.splitlines() if ln.startswith("links1: error:")]
    assert rc == 2 and len(errors) == 1, err
    assert f"'{param}'" in errors[0] and plugin.split("_")[1] in errors[0], errors[0]


@pytest.mark.parametrize("renderer", _kinds(), indirect=True)
def test_film_too_large_is_refused_before_allocation(renderer, tmp_path, capsys):
    """200000x200000: one line with the size asked for and the limit (MemoryError /
    ValueError before)."""
    rc = main(["render", os.path.join(SCENES, "fig4.xml"), "-o", str(tmp_path / "o.exr"), "--renderer",
               renderer, "--width", "200000", "--height", "200000", "--spp", "1", "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("links1: error:") == 1, err
    assert "200000x200000" in err and "4,294,967,295" in err


@pytest.mark.parametrize("renderer", _kinds(), indirect=True)
def test_nesting_deeper_than_the_limit_is_refused(renderer, tmp_path, capsys):
    """5,000 nested elements (RecursionError before)."""
    text = open(os.path.join(SCENES, "fig4.xml")).read()
    i = text.index("<shape")
    n = 5000
    deep = ('<shape type="sphere">' + '<bsdf type="twosided">' * n + '<bsdf type="diffuse"/>'
            + "</bsdf>" * n + "</shape>")
    _links(tmp_path)
    xml = tmp_path / "deep.xml"
    xml.write_text(text[:i] + deep + text[i:])
    rc, err = _render(capsys, str(xml), tmp_path / "o.exr", renderer)
    assert rc == 2 and err.count("links1: error:") == 1, err
    assert f"nested deeper than {params.MAX_NESTING} levels" in err


def test_nesting_at_the_limit_is_read(tmp_path):
    """The limit is the documented one, not lower: MAX_NESTING - 1 levels load."""
    from links1.scene.loader import load_string
    n = params.MAX_NESTING - 4   # scene > shape > twosided ... > diffuse > rgb
    xml = ('<scene version="3.0.0"><shape type="sphere">' + '<bsdf type="twosided">' * n
           + '<bsdf type="diffuse"><rgb name="reflectance" value="0.3"/></bsdf>' + "</bsdf>" * n + "</shape></scene>")
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene = load_string(xml)
    np.testing.assert_allclose(scene.shapes[0].material.reflectance, 0.3)


@pytest.mark.slow
@pytest.mark.parametrize("renderer", _kinds(), indirect=True)
def test_partition_workers_print_one_error_line(renderer, tmp_path):
    """``--workers 2`` on bad scenes: one error line, not one per worker (subprocess: the
    workers are processes). A value the core's reader refuses, and for mitsuba a scene only
    Mitsuba refuses (an unreferenced parameter)."""
    cases = [_edited(tmp_path, "many.xml", 17, 'z="0.2203"', 'z="1e300"')]
    if renderer == "mitsuba":
        cases.append(_edited(tmp_path, "lights.xml", 28, '<float name="radius" value="0.8"/>',
                             '<float name="radius" value="0.8"/><float name="nosuch" value="1"/>'))
    env = dict(os.environ, PYTHONPATH=ROOT)
    for path in cases:
        p = subprocess.run([sys.executable, "-m", "links1_app.cli", "render", path, "-o", str(tmp_path / "o.exr"),
                            "--renderer", renderer, "--workers", "2", *RES], capture_output=True, text=True,
                           env=env, cwd=ROOT, timeout=240)
        errors = [ln for ln in p.stderr.splitlines() if ln.startswith("links1: error:")]
        assert p.returncode == 2 and len(errors) == 1, p.stderr
        assert "Traceback" not in p.stderr and "internal error" not in p.stderr
        assert not [ln for ln in p.stderr.splitlines() if "links1: warning:" in ln and "cannot read" in ln]
        assert not (tmp_path / "o.exr").exists()


def test_shared_table_defaults_are_the_renderers_defaults():
    """One home for the defaults: the core's and the plugin's constants are the table's."""
    from links1.tracing.integrator import DEFAULT_MIN_WEIGHT
    from links1.scene.loader import DEFAULT_MAX_DEPTH
    from links1.scene.scene import Scene
    assert DEFAULT_MIN_WEIGHT == params.default("links1_whitted", "min_weight") == 1.0 / 255.0
    assert DEFAULT_MAX_DEPTH == Scene.max_depth == params.default("links1_whitted", "max_depth") == 5


def test_nesting_counts_across_includes(tmp_path):
    """30 included files of 50 nested elements each: 1,500 levels in all, refused by the
    same limit (each file alone is within it)."""
    from links1.errors import SceneError
    from links1.scene.loader import load_scene
    n = 30
    for k in range(n):
        inner = f'<include filename="i{k + 1}.xml"/>' if k + 1 < n else '<bsdf type="diffuse"/>'
        (tmp_path / f"i{k}.xml").write_text('<bsdf type="twosided">' * 50 + inner + "</bsdf>" * 50)
    main_xml = tmp_path / "main.xml"
    main_xml.write_text('<scene version="3.0.0"><shape type="sphere"><include filename="i0.xml"/></shape></scene>')
    with pytest.raises(SceneError, match=f"nested deeper than {params.MAX_NESTING} levels"):
        load_scene(str(main_xml))
