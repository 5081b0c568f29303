"""AOV channel names: one naming, Mitsuba's ``name.X`` convention (what its own
``aov`` integrator writes), whatever the renderer, back end or worker count."""
from __future__ import annotations

import os

import numpy as np

import pytest

from .conftest import ROOT

SCENE = os.path.join(ROOT, "scenes", "fig4.xml")
EXPECTED = ["R", "G", "B", "depth.T", "normal.X", "normal.Y", "normal.Z", "id.I", "cost.N", "samples.N"]
BACKENDS = {"one process": ["--workers", "0"], "2 workers": ["--workers", "2"],
            "dask-local 2": ["--dask-local", "2"]}


def test_names_follow_mitsubas_aov_integrator():
    """The convention is Mitsuba's, asked of Mitsuba itself (not copied into the test)."""
    mi = pytest.importorskip("mitsuba")
    from links1.tracing.aovs import AOVS
    mi.set_variant("llvm_ad_rgb")
    aov = mi.load_dict({"type": "aov", "aovs": "depth:depth,normal:sh_normal,id:shape_index"})
    assert aov.aov_names() == [c for a in ("depth", "normal", "id") for c in AOVS[a]]


@pytest.mark.slow
@pytest.mark.parametrize("backend", list(BACKENDS))
@pytest.mark.parametrize("renderer", ["core", "mitsuba"])
def test_exr_channel_names(tmp_path, renderer, backend):
    from links1_app.cli import main
    from links1.imaging.image import read_exr
    if renderer == "mitsuba":
        pytest.importorskip("mitsuba")
    out = tmp_path / "a.exr"
    argv = ["render", SCENE, "--renderer", renderer, "-D", "res=12", "--aov", "depth,normal,id,cost,samples", "--spp", "2",
            "--no-progress", "-o", str(out)] + BACKENDS[backend]
    assert main(argv) == 0
    img, names = read_exr(str(out))
    assert list(names) == EXPECTED
    assert img.shape[-1] == len(EXPECTED)
    assert np.all(img[..., names.index("samples.N")] == 2)   # the camera samples of each pixel
