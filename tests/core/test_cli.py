"""The links1 CLI: render options, one-line errors with exit status 2, no half-written output."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from links1_app.cli import main

ROOT = Path(__file__).resolve().parents[2]
FIG4 = str(ROOT / "scenes" / "fig4.xml")


def run_cli(*args):
    return main(list(args))


def test_every_command_is_wired_to_its_front_end_module():
    """render, diff, schedule and animate, each run by its own module's runner: the commands come
    from plain imports (links1_app.cli imports diff, partition.schedule and animate), so a module
    that fails to import fails the command line instead of leaving its command out."""
    from links1_app import animate, cli, diff
    from links1_app.partition import schedule
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert sorted(sub.choices) == ["animate", "diff", "render", "schedule"]
    assert sub.choices["render"].get_default("func") is cli.cmd_render
    assert sub.choices["diff"].get_default("func") is diff.run_cli
    assert sub.choices["schedule"].get_default("func") is schedule.run_cli
    assert sub.choices["animate"].get_default("func") is animate.run_cli


def test_render_png_and_exr_with_aovs(tmp_path, capsys):
    from links1.imaging.image import read_exr
    png = tmp_path / "a.png"
    assert run_cli("render", FIG4, "--renderer", "core", "-D", "res=16", "-o", str(png), "--no-progress") == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    exr = tmp_path / "a.exr"
    assert run_cli("render", FIG4, "--renderer", "core", "-D", "res=16", "-o", str(exr),
                   "--aov", "depth,normal,id,cost", "--no-progress") == 0
    data, names = read_exr(str(exr))
    assert list(names) == ["R", "G", "B", "depth.T", "normal.X", "normal.Y", "normal.Z", "id.I", "cost.N"]
    depth, ids, cost = data[..., 3], data[..., 7], data[..., 8]
    hit = ids >= 0
    assert hit.any() and (~hit).any()
    assert np.all(depth[hit] > 0) and np.all(depth[~hit] == 0)
    assert np.all(cost[hit] >= 1)
    normals = data[..., 4:7][hit]
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)


def test_repeat_prints_timing_line(tmp_path, capsys):
    out = tmp_path / "t.exr"
    assert run_cli("render", FIG4, "--renderer", "core", "-D", "res=8", "-o", str(out), "--repeat", "2",
                   "--no-progress") == 0
    err = capsys.readouterr().err
    line = [ln for ln in err.splitlines() if ln.startswith("timing:")]
    assert len(line) == 1
    for key in ("first=", "median=", "min=", "max="):
        assert key in line[0]


@pytest.mark.parametrize("xml,needle", [
    ("<scene version='3.0.0'><shape type='sphere'>", "bad.xml"),                       # truncated
    ("<scene version='3.0.0'>\n<shape type='nosuchshape'/></scene>", "nosuchshape"),  # unknown plugin
    ("<scene version='3.0.0'>\n<shape type='sphere'><float name='radius' value='-1'/></shape></scene>", "radius"),
    ("<scene version='3.0.0'>\n<shape type='links1_blob'><string name='centers' value='0 0 0 1'/>"
     "<float name='threshold' value='0.5'/></shape></scene>", "centers"),
])
def test_bad_scene_is_one_line_exit_2_and_no_output(tmp_path, capsys, xml, needle):
    scene = tmp_path / "bad.xml"
    scene.write_text(xml)
    out = tmp_path / "out.exr"
    out.write_bytes(b"earlier output")
    rc = run_cli("render", str(scene), "--renderer", "core", "-o", str(out), "--no-progress")
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert len(err.splitlines()) == 1 and err.startswith("links1: error:")
    assert needle in err and "bad.xml" in err
    assert out.read_bytes() == b"earlier output"  # untouched


@pytest.mark.parametrize("args,needle", [
    (["--spp", "0"], "--spp"),
    (["--width", "-3"], "--width"),
    (["--aov", "depth,colour"], "colour"),
    (["-D", "novalue"], "name=value"),
])
def test_bad_options_exit_2(tmp_path, capsys, args, needle):
    with pytest.raises(SystemExit) as ei:
        run_cli("render", FIG4, "--renderer", "core", "-o", str(tmp_path / "x.exr"), *args)
    assert ei.value.code == 2
    err = capsys.readouterr().err
    assert needle in err
    assert not (tmp_path / "x.exr").exists()


def test_missing_scene_and_bad_extension(tmp_path, capsys):
    assert run_cli("render", str(tmp_path / "nope.xml"), "--renderer", "core", "-o", str(tmp_path / "x.exr")) == 2
    assert "nope.xml" in capsys.readouterr().err
    assert run_cli("render", FIG4, "--renderer", "core", "-o", str(tmp_path / "x.jpg")) == 2
    assert ".jpg" in capsys.readouterr().err or "x.jpg" in capsys.readouterr().err


@pytest.mark.slow
def test_subprocess_error_has_no_traceback(tmp_path):
    scene = tmp_path / "broken.xml"
    scene.write_text("<scene version='3.0.0'>\n  <shape type='sphere'>\n</scene>\n")
    res = subprocess.run([sys.executable, "-m", "links1_app.cli", "render", str(scene), "--renderer", "core",
                          "-o", str(tmp_path / "o.png")], capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    assert "Traceback" not in res.stderr
    assert "broken.xml" in res.stderr
    assert not (tmp_path / "o.png").exists()


def test_help_has_examples(capsys):
    with pytest.raises(SystemExit) as ei:
        run_cli("render", "--help")
    assert ei.value.code == 0
    out = capsys.readouterr().out
    assert "examples:" in out and "--aov" in out and "--repeat" in out


WARN_SCENE = """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="40"/>
    <transform name="to_world"><lookat origin="0,0,5" target="0,0,0" up="0,1,0"/></transform>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
  </sensor>
  <emitter type="point"><point name="position" x="2" y="2" z="4"/></emitter>
  <shape type="sphere"><bsdf type="diffuse"><spectrum name="reflectance" value="500:0, 540:1, 545:0"/></bsdf></shape>
  <shape type="sphere"><point name="center" x="1" y="0" z="0"/><bsdf type="hair"/></shape>
</scene>
"""


@pytest.mark.slow
@pytest.mark.parametrize("workers", ["0", "2"])
def test_warnings_are_one_clean_line_each(tmp_path, workers):
    """Scene warnings: `links1: warning: FILE:LINE: ...`, once each, never Python's format
    (file.py:N: SceneWarning + the source line), in the root and in worker processes."""
    scene = tmp_path / "warn.xml"
    scene.write_text(WARN_SCENE)
    res = subprocess.run([sys.executable, "-m", "links1_app.cli", "render", str(scene), "--renderer", "core",
                          "--workers", workers, "--no-progress", "-o", str(tmp_path / "o.exr")],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    lines = res.stderr.splitlines()
    assert all(ln.startswith("links1: ") for ln in lines), res.stderr
    warns = [ln for ln in lines if ln.startswith("links1: warning: ")]
    assert len(warns) == 2 and len(set(warns)) == 2, res.stderr
    assert warns[0].startswith(f"links1: warning: {scene}:7: ") and "clamping out-of-gamut" in warns[0]
    assert warns[1].startswith(f"links1: warning: {scene}:8: ") and "hair" in warns[1]
    assert "SceneWarning" not in res.stderr and ".py:" not in res.stderr


class _Anything:
    pass


def interrupted_from_a_finaliser(real):
    """``CoreRenderer.render`` (``real``) that first sends this process SIGINT from a finaliser,
    where Python prints and drops the KeyboardInterrupt the signal's handler raises."""
    import gc
    import os
    import signal
    import weakref

    def render(self, *a, **k):
        obj = _Anything()
        weakref.finalize(obj, os.kill, os.getpid(), signal.SIGINT)
        del obj                          # the finaliser runs here, the signal's handler inside it
        gc.collect()
        return real(self, *a, **k)
    return render


def test_an_interrupt_python_drops_still_stops_the_render(tmp_path, capsys, monkeypatch):
    """Ctrl-C that lands in a finaliser (Python prints and drops the KeyboardInterrupt raised
    there: an import's module lock, say) still ends the command as Ctrl-C does: status 130, the
    one line, no output file, and no dropped-exception report."""
    import threading

    from links1.tracing.render import CoreRenderer
    from links1_app import cli
    monkeypatch.setattr(CoreRenderer, "render", interrupted_from_a_finaliser(CoreRenderer.render))
    for owner, name in ((sys, "excepthook"), (sys, "unraisablehook"), (threading, "excepthook")):
        monkeypatch.setattr(owner, name, getattr(owner, name))   # an interrupted command keeps its hooks
    out = tmp_path / "a.exr"
    assert run_cli("render", FIG4, "--renderer", "core", "-D", "res=8", "-o", str(out), "--no-progress") == 130
    assert not out.exists()
    assert capsys.readouterr().err.strip().splitlines() == ["links1: interrupted"]
    cli._INTERRUPTED.clear()


def test_an_interrupt_python_drops_still_stops_animate(tmp_path, capsys, monkeypatch):
    """The same dropped Ctrl-C during a sequence's first frame: status 130, the one line, and no
    frame written after it (the sequence renders on, each finished frame checked before its write)."""
    import threading

    from links1_app import cli
    from links1_app.partition.sequence import SequenceRenderer
    monkeypatch.setattr(SequenceRenderer, "_render", interrupted_from_a_finaliser(SequenceRenderer._render))
    for owner, name in ((sys, "excepthook"), (sys, "unraisablehook"), (threading, "excepthook")):
        monkeypatch.setattr(owner, name, getattr(owner, name))
    assert run_cli("animate", FIG4, "--renderer", "core", "-D", "res=8", "--frames", "2", "-o",
                   str(tmp_path / "f_%d.exr"), "--no-progress") == 130
    assert list(tmp_path.iterdir()) == []
    assert capsys.readouterr().err.strip().splitlines() == ["links1: interrupted"]
    cli._INTERRUPTED.clear()


#: a render interrupted from a finaliser (as above), then the teardown's noise: a thread's
#: direct print and a write to the descriptor after ``main`` returned
_NOISY_TEARDOWN = """
import os, sys, threading
from links1_app import cli
from links1.tracing.render import CoreRenderer
from tests.core.test_cli import interrupted_from_a_finaliser
CoreRenderer.render = interrupted_from_a_finaliser(CoreRenderer.render)
program = sys.argv.pop(1) == "program"
status = cli.main(sys.argv[1:], program=program)
t = threading.Thread(target=lambda: print("Traceback (most recent call last): noise", file=sys.stderr))
t.start()
t.join()
os.write(2, b"OSError: [Errno 9] Bad file descriptor\\n")
sys.exit(status)
"""


@pytest.mark.parametrize("program", [True, False], ids=["console-script", "called-from-python"])
def test_after_the_interrupted_line_the_program_prints_nothing(tmp_path, program):
    """As the console script runs it, the command's process ends with ``links1: interrupted`` as
    its last word on stderr, whatever its teardown prints after; called from Python (a caller's
    process that goes on), stderr is left as it was."""
    out = tmp_path / "a.exr"
    args = ["program" if program else "python", "render", FIG4, "--renderer", "core", "-D", "res=8",
            "-o", str(out), "--no-progress"]
    p = subprocess.run([sys.executable, "-c", _NOISY_TEARDOWN, *args], cwd=ROOT, capture_output=True, text=True,
                       timeout=120)
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 130 and not out.exists()
    assert lines[0] == "links1: interrupted"
    assert (lines == ["links1: interrupted"]) == program, lines
