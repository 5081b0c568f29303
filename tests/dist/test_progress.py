"""Progress bars follow tqdm's convention: on a terminal, or when asked (``--progress``);
never in redirected stderr unless asked, never with ``--no-progress``."""
from __future__ import annotations

import io

import pytest

from links1_app.partition.executors import InProcess, render_plan
from links1.partition.strategies import make_plan

from .conftest import MANY


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def _plan(spec):
    from links1_app.partition.runtime import get_renderer
    w, h = get_renderer(spec).film_size
    return make_plan("scanline", w, h, 2, tiles_per_node=4)


@pytest.mark.parametrize("progress, terminal, shown", [
    (None, False, False), (None, True, True), (True, False, True), (False, True, False)])
def test_render_plan_bar(fake_spec, monkeypatch, progress, terminal, shown):
    err = _Terminal() if terminal else io.StringIO()
    monkeypatch.setattr("sys.stderr", err)
    render_plan(_plan(fake_spec), fake_spec, InProcess(), progress=progress)
    assert ("links1: " in err.getvalue() and "%|" in err.getvalue()) == shown, err.getvalue()


@pytest.mark.parametrize("progress, terminal, shown", [
    (None, False, False), (None, True, True), (True, False, True), (False, True, False)])
def test_core_render_bar(monkeypatch, progress, terminal, shown):
    from links1.tracing.render import _progress
    monkeypatch.setattr("sys.stderr", _Terminal() if terminal else io.StringIO())
    bar = _progress(4, progress)
    assert (bar is not None and not bar.disable) == shown
    if bar is not None:
        bar.close()


@pytest.mark.slow
@pytest.mark.parametrize("flag, shown", [([], False), (["--progress"], True), (["--no-progress"], False)])
def test_cli_distributed_render_into_redirected_stderr(tmp_path, capsys, flag, shown):
    from links1_app.cli import main
    assert main(["render", MANY, "--renderer", "core", "-D", "res=16", "--workers", "1",
                 "--partition", "scanline", "-o", str(tmp_path / "a.exr")] + flag) == 0
    err = capsys.readouterr().err
    assert ("links1: " in err and "%|" in err) == shown, err


@pytest.mark.parametrize("flag, progress", [([], None), (["--progress"], True), (["--no-progress"], False)])
def test_cli_render_asks_the_core_for(tmp_path, monkeypatch, flag, progress):
    from links1_app.cli import main
    from links1.tracing.render import CoreRenderer
    asked = []
    plain = CoreRenderer.render
    monkeypatch.setattr(CoreRenderer, "render", lambda self, window=None, progress=False:
                        asked.append(progress) or plain(self, window, progress))
    assert main(["render", MANY, "--renderer", "core", "-D", "res=8", "--workers", "0",
                 "-o", str(tmp_path / "a.exr")] + flag) == 0
    assert asked == [progress]


def test_cli_progress_flags_exclude_each_other(tmp_path, capsys):
    from links1_app.cli import main
    with pytest.raises(SystemExit) as info:
        main(["render", MANY, "-o", str(tmp_path / "a.exr"), "--progress", "--no-progress"])
    assert info.value.code == 2
    assert "not allowed with argument" in capsys.readouterr().err
