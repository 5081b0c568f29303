"""A new user's first hour, scripted with the README's commands: render a scene, compare the two
renderers, interrupt a longer render with Ctrl-C and resume it from its checkpoint, keep a
baseline with the pytest plugin and rerun it unchanged, misspell a parameter. Each step runs
the ``links1`` command (or pytest) in a subprocess on a copy of ``scenes/``."""
from __future__ import annotations

import glob
import os
import re
import shutil
import signal
import subprocess
import sys
import time

import pytest

from tests.core.test_pytest_plugin import PLUGIN_ARGS   # the plugin by its entry point, else by name

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: the console script the README runs (``.venv/bin/links1``), else the same entry point
_SCRIPT = os.path.join(os.path.dirname(sys.executable), "links1")
LINKS1 = [_SCRIPT] if os.path.exists(_SCRIPT) else [sys.executable, "-m", "links1_app.cli"]


@pytest.fixture
def scenes(tmp_path):
    """A copy of the project's scenes, as a user's working folder."""
    shutil.copytree(os.path.join(ROOT, "scenes"), tmp_path / "scenes")
    return tmp_path / "scenes"


def links1(*args, cwd):
    p = subprocess.run([*LINKS1, *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=240)
    return p.returncode, p.stderr.strip().splitlines(), p.stdout


def _mitsuba_runs() -> bool:
    try:
        from tests.plugins.conftest import variant_problem
    except Exception:   # pragma: no cover - a checkout without the plugin tests
        return False
    return variant_problem("llvm_ad_rgb") is None


@pytest.mark.slow
@pytest.mark.parametrize("renderer", ["core", pytest.param("mitsuba", marks=pytest.mark.mitsuba)])
def test_render_a_scene_then_compare_the_renderers(scenes, renderer):
    if renderer == "mitsuba" and not _mitsuba_runs():
        pytest.skip("Mitsuba's LLVM variant cannot run here")
    work = scenes.parent
    rc, err, _ = links1("render", "scenes/fig11.xml", "-o", "core.exr", "--renderer", "core", "-D", "res=48",
                        "--no-progress", cwd=work)
    assert (rc, err) == (0, [f"links1: wrote core.exr (48x48, core)"])
    if renderer == "mitsuba":   # the README's first command (the plugin is the default renderer)
        rc, err, _ = links1("render", "scenes/fig11.xml", "-o", "fig11.exr", "-D", "res=48", "--no-progress",
                            cwd=work)
        assert (rc, err) == (0, ["links1: wrote fig11.exr (48x48, mitsuba)"])
        # both renderers follow the same method: the README's diff command finds them alike
        rc, err, out = links1("diff", "core.exr", "fig11.exr", "--metric", "flip", "--threshold", "0.05", cwd=work)
        assert rc == 0 and "ok: flip" in out, (err, out)


@pytest.mark.slow
def test_interrupt_a_render_then_resume_it_from_the_checkpoint(scenes):
    """Ctrl-C (SIGINT) once the first unit is on disk: exit 130, one line, no image; the same
    command again resumes the units done and writes the image."""
    work = scenes.parent
    args = [*LINKS1, "render", "scenes/fig4.xml", "-o", "long.exr", "--renderer", "core", "-D", "res=256",
            "--spp", "4", "--no-progress", "--checkpoint", "ck"]
    p = subprocess.Popen(args, cwd=work, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not glob.glob(str(work / "ck" / "*" / "*.npy")) and p.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert p.poll() is None, "the render ended before its first unit reached the checkpoint"
    p.send_signal(signal.SIGINT)
    try:
        err = p.communicate(timeout=30)[1]
    except subprocess.TimeoutExpired:
        p.kill()
        p.communicate()
        pytest.fail("links1 render did not stop within 30 s of SIGINT")
    assert (p.returncode, err.strip().splitlines()) == (130, ["links1: interrupted"])
    assert not (work / "long.exr").exists()
    done = len(glob.glob(str(work / "ck" / "*" / "*.npy")))
    rc, err, _ = links1(*args[len(LINKS1):], cwd=work)
    assert rc == 0, err
    m = re.fullmatch(r"links1: resumed (\d+) of (\d+) units from the checkpoint \S+", err[0])
    assert m and int(m.group(1)) >= done >= 1 and int(m.group(1)) < int(m.group(2)), err
    assert err[1:] == ["links1: wrote long.exr (256x256, core)"]


BASELINE_TESTS = '''
def test_fig4(links1_baseline):
    links1_baseline.check_scene("scenes/fig4.xml", spp=2, params={"res": 24}, name="fig4")

def test_fig4_statistical(links1_baseline):
    links1_baseline.check_scene("scenes/fig4.xml", spp=2, statistical=True, runs=4, params={"res": 16},
                                name="fig4_statistical")
'''


@pytest.mark.slow
def test_baselines_written_then_an_unchanged_rerun_passes_and_a_change_fails(scenes):
    """The pytest plugin (README: ``--links1-update-baselines``) in a user's project."""
    work = scenes.parent
    (work / "test_images.py").write_text(BASELINE_TESTS)

    def pytest_run(*extra):
        p = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *PLUGIN_ARGS, "-p",
                            "no:hypothesispytest", "--rootdir", str(work), "-c", os.devnull, "test_images.py", *extra],
                           capture_output=True, text=True, cwd=work, timeout=240)
        return p.returncode, p.stdout

    rc, out = pytest_run("--links1-update-baselines")
    assert rc == 0 and "2 passed" in out, out
    assert {"fig4.exr", "fig4_statistical.exr"} <= set(os.listdir(work / "baselines"))
    rc, out = pytest_run()
    assert rc == 0 and "2 passed" in out, out
    # a changed scene is caught: a brighter light
    fig4 = scenes / "fig4.xml"
    fig4.write_text(fig4.read_text().replace('<rgb name="L1" value="0.35"/>', '<rgb name="L1" value="0.7"/>'))
    rc, out = pytest_run("-k", "not statistical")
    assert rc == 1 and "1 failed" in out, out


@pytest.mark.slow
def test_a_misspelt_parameter_is_one_line_naming_file_line_and_element(scenes):
    work = scenes.parent
    fig4 = scenes / "fig4.xml"
    rc, err, _ = links1("render", "scenes/fig4.xml", "-o", "fig4.exr", "--renderer", "core", "-D", "res=16",
                        "--no-progress", cwd=work)
    assert rc == 0, err
    before = (work / "fig4.exr").read_bytes()
    text = fig4.read_text()
    line = text[:text.index('<rgb name="diffuse" value="0.85, 0.55, 0.2"/>')].count("\n") + 1
    fig4.write_text(text.replace('<rgb name="diffuse" value="0.85, 0.55, 0.2"/>',
                                 '<rgb name="difuse" value="0.85, 0.55, 0.2"/>'))
    renderers = ["core"] + (["mitsuba"] if _mitsuba_runs() else [])
    for renderer in renderers:
        rc, err, _ = links1("render", "scenes/fig4.xml", "-o", "fig4.exr", "--renderer", renderer, "-D", "res=16",
                            "--no-progress", cwd=work)
        assert (rc, err) == (2, [f"links1: error: scenes/fig4.xml:{line}: <bsdf type='links1_phong' id='shell'> "
                                 "<rgb name='difuse'>: unknown parameter 'difuse' (did you mean 'diffuse'?): "
                                 "links1's bsdf 'links1_phong' does not take it (Mitsuba refuses unreferenced "
                                 "properties)"])
        assert (work / "fig4.exr").read_bytes() == before   # the earlier image untouched
