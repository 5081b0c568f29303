"""The Renderer contract in code and the factory (links1_app/renderers.py), and
the one AOV table and checker (links1/tracing/aovs.py)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import links1
from links1.tracing.aovs import AOVS, aov_channel, channel_names, check_aovs
from links1.errors import UsageError
import links1_app
from links1_app.renderers import Renderer, make_renderer

ROOT = Path(__file__).resolve().parents[2]
FIG11 = str(ROOT / "scenes" / "fig11.xml")


def test_core_renderer_is_a_renderer():
    r = make_renderer("core", FIG11, width=8, height=6, spp=1, aovs="id,cost")
    assert isinstance(r, Renderer) and r.kind == "core"
    assert r.film_size == (8, 6) and r.channels == ["R", "G", "B", "id.I", "cost.N"]
    full = r.render()
    assert full.shape == (6, 8, 5)
    (win,) = r.render_batch([(2, 1, 3, 4)])
    assert np.array_equal(win, full[1:5, 2:5])
    assert [d["index"] for d in r.shapes_info()] == list(range(len(r.shapes_info())))
    assert not isinstance(object(), Renderer)


def test_public_api_is_the_factory():
    """The front ends' package exports the factory; the core's does not (the core's root is no
    front end)."""
    assert links1_app.make_renderer is make_renderer and links1_app.Renderer is Renderer
    assert not hasattr(links1, "make_renderer") and not hasattr(links1, "Renderer")
    with pytest.raises(UsageError, match="unknown renderer 'povray'; choose 'mitsuba' or 'core'"):
        make_renderer("povray", FIG11)


def test_core_render_imports_no_plugin():
    """The core and the factory's core branch never import links1_mitsuba (or Mitsuba)."""
    code = ("import sys, links1, links1_app;"
            "links1_app.make_renderer('core', sys.argv[1], width=4, height=4, spp=1).render();"
            "links1.render(links1.load_scene(sys.argv[1]), width=4, height=4);"
            "bad = [m for m in sys.modules if m.split('.')[0] in ('links1_mitsuba', 'mitsuba', 'drjit')];"
            "print(bad)")
    out = subprocess.run([sys.executable, "-c", code, FIG11], capture_output=True, text=True, timeout=120,
                         cwd=str(ROOT))
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def test_one_aov_checker():
    """Strings (CLI ``--aov``, links1_whitted's ``aovs`` property) and sequences alike."""
    assert check_aovs(None) == check_aovs("") == check_aovs(()) == ()
    assert check_aovs("depth; id, cost,") == check_aovs(["depth", " id", "cost", ""]) == ("depth", "id", "cost")
    with pytest.raises(UsageError, match="unknown AOV 'albedo'; choose from depth, normal, id, cost, samples"):
        check_aovs("depth,albedo")
    assert isinstance(UsageError("x"), ValueError)   # the plugin's constructors raised ValueError
    names = channel_names(("normal", "samples"))
    assert names == ["R", "G", "B", "normal.X", "normal.Y", "normal.Z", "samples.N"]
    assert aov_channel(names, "samples") == 6 and aov_channel(names, "id") is None
    assert sum(len(v) for v in AOVS.values()) == 7
