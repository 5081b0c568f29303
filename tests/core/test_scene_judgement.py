"""Items 4-6 (core renderer): one judgement of a scene file, as Mitsuba's parser
judges it; every message names FILE:LINE and the element, once per element; the smaller CLI
points. Each test runs the real ``links1`` command line in a subprocess."""
from __future__ import annotations

import os
import re
import subprocess
import sys

import pytest

from links1_app.partition.checkpoint import atomic_write_json

HERE = os.path.dirname(os.path.abspath(__file__))
FIG4 = os.path.join(HERE, "..", "..", "scenes", "fig4.xml")

SCENE = """<scene version="3.0.0">
  <default name="spp" value="1"/>
  <integrator type="{integrator}"/>
  <sensor type="perspective">
    <transform name="to_world"><lookat origin="0,0,5" target="0,0,0" up="0,1,0"/></transform>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
    <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
  </sensor>
  <shape type="sphere">
    <bsdf type="diffuse"><rgb name="{reflectance}" value="0.5"/></bsdf>
  </shape>
  <emitter type="point"><point name="position" value="0,3,3"/></emitter>
</scene>
"""

#: two rough BSDFs (one shared by two spheres through a <ref>) and a thin-lens camera
WARN_SCENE = """<scene version="3.0.0">
  <sensor type="thinlens">
    <float name="aperture_radius" value="0.01"/><float name="focus_distance" value="5"/>
    <transform name="to_world"><lookat origin="0,0,5" target="0,0,0" up="0,1,0"/></transform>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
    <sampler type="independent"><integer name="sample_count" value="1"/></sampler>
  </sensor>
  <shape type="sphere">
    <point name="center" value="-1,0,0"/>
    <bsdf type="roughdielectric" id="frosted"/>
  </shape>
  <shape type="sphere">
    <point name="center" value="1,0,0"/>
    <bsdf type="roughdielectric"/>
  </shape>
  <shape type="sphere">
    <point name="center" value="0,1,0"/>
    <ref id="frosted"/>
  </shape>
  <emitter type="point"><point name="position" value="0,3,3"/></emitter>
</scene>
"""


def links1(*args, umask=None):
    """Run ``python -m links1_app.cli ARGS`` -> (exit status, stderr lines)."""
    env = dict(os.environ)
    p = subprocess.run([sys.executable, "-m", "links1_app.cli", *map(str, args)], capture_output=True, text=True,
                       timeout=300, env=env, preexec_fn=(lambda: os.umask(umask)) if umask is not None else None)
    return p.returncode, p.stderr.strip().splitlines()


def scene(tmp_path, name="s.xml", integrator="path", reflectance="reflectance", text=None):
    path = tmp_path / name
    path.write_text(text if text is not None else SCENE.format(integrator=integrator, reflectance=reflectance))
    return path


def render(path, out, *extra, renderer="core"):
    return links1("render", path, "--renderer", renderer, "--workers", "0", "--no-progress", "-o", out, *extra)


@pytest.mark.slow
def test_unused_define_is_refused_naming_file_and_parameter(tmp_path):
    """Mitsuba refuses an unused ``-D`` ("Found unused parameters"): the core too, now."""
    path, out = scene(tmp_path), tmp_path / "o.exr"
    rc, err = render(path, out, "-D", "res=64")
    assert rc == 2
    assert err == [f"links1: error: {path}:1: <scene>: unused parameter -D res=64: the scene has no $res "
                   "(Mitsuba refuses unused parameters)"]
    assert not out.exists()
    # a -D the scene takes is fine (control)
    rc, err = render(path, out, "-D", "spp=2")
    assert rc == 0 and out.exists(), err


def test_misspelt_parameter_is_refused_naming_line_and_element(tmp_path):
    """A name Mitsuba's diffuse never queries is an error in the core as in Mitsuba."""
    path, out = scene(tmp_path, reflectance="reflectnce"), tmp_path / "o.exr"
    rc, err = render(path, out)
    assert rc == 2 and len(err) == 1, err
    assert err[0].startswith(f"links1: error: {path}:10: <bsdf type='diffuse'> <rgb name='reflectnce'>: "
                             "unknown parameter 'reflectnce'")
    assert not out.exists()


def test_integrator_links1_replaces_may_be_unknown(tmp_path):
    """A Bitterli scene's ``<integrator type="mat">``: the core replaces any integrator."""
    path, out = scene(tmp_path, integrator="mat"), tmp_path / "o.exr"
    rc, err = render(path, out)
    assert rc == 0 and out.exists(), err
    assert not [ln for ln in err if "warning" in ln or "error" in ln], err


def test_core_warnings_once_per_element_with_place(tmp_path):
    # the core renders roughdielectric as Mitsuba; a measured BSDF (its data out of reach) is
    # what it still approximates, with a warning
    text = WARN_SCENE.replace('<bsdf type="roughdielectric" id="frosted"/>',
                              '<bsdf type="measured" id="frosted"><string name="filename" value="m.bsdf"/></bsdf>')
    text = text.replace('<bsdf type="roughdielectric"/>',
                        '<bsdf type="measured"><string name="filename" value="m.bsdf"/></bsdf>')
    path = scene(tmp_path, text=text)
    rc, err = render(path, tmp_path / "o.exr")
    assert rc == 0, err
    warns = [ln for ln in err if ln.startswith("links1: warning:")]
    rough = [ln for ln in warns if "measured" in ln]
    # the shared BSDF (line 10, read for two spheres) and the other one (line 14): once each
    assert len(rough) == 2, rough
    assert rough[0].startswith(f"links1: warning: {path}:10: <bsdf type='measured' id='frosted'>: ")
    assert rough[1].startswith(f"links1: warning: {path}:14: <bsdf type='measured'>: ")
    assert not [ln for ln in warns if "thinlens" in ln]   # its depth of field is rendered


@pytest.mark.slow
def test_unknown_command_has_one_prefix():
    rc, err = links1("bogus")
    assert rc == 2
    assert err == ["links1: error: argument COMMAND: invalid choice: 'bogus' (choose from 'render', 'diff', "
                   "'schedule', 'animate')"]
    rc, err = links1("render")
    assert rc == 2 and err[-1].startswith("links1: error: render: the following arguments are required")


@pytest.mark.slow
def test_repeat_timing_has_units(tmp_path):
    rc, err = render(FIG4, tmp_path / "t.exr", "-D", "res=8", "--repeat", "1")
    assert rc == 0, err
    line = [ln for ln in err if ln.startswith("timing:")]
    assert len(line) == 1
    assert re.fullmatch(r"timing: first=[\d.]+ ms median=[\d.]+ ms min=[\d.]+ ms max=[\d.]+ ms", line[0]), line


@pytest.mark.slow
def test_checkpoint_resume_says_so(tmp_path):
    ck, out = tmp_path / "ck", tmp_path / "o.exr"
    args = ("render", FIG4, "--renderer", "core", "-D", "res=16", "--no-progress", "-o", out, "--checkpoint", ck)
    rc, err = links1(*args)
    assert rc == 0 and not [ln for ln in err if "resumed" in ln], err
    rc, err = links1(*args)
    assert rc == 0, err
    resumed = [ln for ln in err if "resumed" in ln]
    assert len(resumed) == 1
    m = re.fullmatch(r"links1: resumed (\d+) of (\d+) units from the checkpoint (\S+)", resumed[0])
    assert m and m.group(1) == m.group(2) and int(m.group(1)) > 0, resumed
    assert m.group(3).startswith(str(ck)) and os.path.isdir(m.group(3))


@pytest.mark.parametrize("umask,mode", [(0o022, 0o644), (0o077, 0o600)])
def test_atomic_writes_follow_the_umask(tmp_path, umask, mode):
    """``links1 schedule``'s report and plot (and checkpoint units) are written through
    atomic_write_bytes: the mode of a plain open(), not mkstemp's 0600."""
    old = os.umask(umask)
    try:
        atomic_write_json(tmp_path / "r.json", {"a": 1})
    finally:
        os.umask(old)
    assert os.stat(tmp_path / "r.json").st_mode & 0o777 == mode


@pytest.mark.slow
def test_schedule_report_is_world_readable(tmp_path):
    report, plot = tmp_path / "r.json", tmp_path / "r.png"
    rc, err = links1("schedule", FIG4, "--renderer", "core", "-D", "res=16", "--nodes", "1", "--partition",
                     "scanline", "--report", report, "--no-progress", "--reference-repeat", "1", umask=0o022)
    assert rc == 0, err
    assert os.stat(report).st_mode & 0o777 == 0o644
