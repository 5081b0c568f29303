"""The core imports and renders with numpy and OpenEXR alone (no mitsuba, drjit, dask)."""
from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

BLOCKER = """
import sys
class _Block:
    BLOCKED = ("mitsuba", "drjit", "dask", "distributed")
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in self.BLOCKED:
            raise ImportError(f"blocked for this test: {name}")
        return None
sys.meta_path.insert(0, _Block())
"""


@pytest.mark.slow
def test_core_renders_without_mitsuba_drjit_or_dask(tmp_path):
    out = tmp_path / "iso.exr"
    code = BLOCKER + textwrap.dedent(f"""
        import links1, links1_app.cli
        from links1.imaging.image import read_exr
        scene = links1.load_scene({str(ROOT / 'scenes' / 'fig4.xml')!r}, res=16)
        img = links1.render(scene)
        assert img.shape == (16, 16, 3) and img.max() > 0
        rc = links1_app.cli.main(["render", {str(ROOT / 'scenes' / 'fig11.xml')!r}, "--renderer", "core",
                              "--width", "12", "--height", "8", "-o", {str(out)!r}, "--no-progress"])
        assert rc == 0, rc
        data, names = read_exr({str(out)!r})
        assert data.shape[:2] == (8, 12)
        bad = [m for m in sys.modules if m.split(".")[0] in ("mitsuba", "drjit", "dask", "distributed")]
        assert not bad, bad
        print("ISOLATED-OK")
    """)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "ISOLATED-OK" in res.stdout
