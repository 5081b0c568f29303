"""An install without the ``mitsuba`` extra: ``links1 render`` (default
renderer) and ``links1 schedule`` say in one line which extra to install or to use the core,
exit 2 and write nothing; ``--renderer core`` still renders. Run in a subprocess whose
``import mitsuba`` fails (a ``mitsuba`` package first on PYTHONPATH that raises ImportError)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCENE = str(ROOT / "scenes" / "mitsuba_direct.xml")


@pytest.fixture
def no_mitsuba_env(tmp_path):
    fake = tmp_path / "site" / "mitsuba"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("raise ImportError(\"No module named 'mitsuba'\")\n")
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(tmp_path / "site"), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return env


def _cli(env, *args):
    return subprocess.run([sys.executable, "-m", "links1_app.cli", *args], capture_output=True, text=True,
                          env=env, cwd=str(ROOT), timeout=240)


@pytest.mark.slow
@pytest.mark.parametrize("command", ["render", "schedule"])
def test_missing_mitsuba_names_the_extra(tmp_path, no_mitsuba_env, command):
    out = tmp_path / "out.png"
    args = (["render", SCENE, "-o", str(out)] if command == "render"
            else ["schedule", SCENE, "--nodes", "2", "--report", str(tmp_path / "r.json")])
    p = _cli(no_mitsuba_env, *args, "--width", "8", "--height", "8")
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2, p.stderr
    assert len(lines) == 1, lines
    assert "pip install 'links1[mitsuba]'" in lines[0] and "--renderer core" in lines[0]
    assert "internal error" not in lines[0]
    assert not out.exists() and not (tmp_path / "r.json").exists()


def test_core_renders_without_mitsuba(tmp_path, no_mitsuba_env):
    out = tmp_path / "core.png"
    p = _cli(no_mitsuba_env, "render", SCENE, "-o", str(out), "--renderer", "core", "--width", "8",
             "--height", "8", "--no-progress")
    assert p.returncode == 0, p.stderr
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
