"""The Renderer contract on the plugin side: windows, AOVs, shapes_info, registration."""
from __future__ import annotations

import os

import numpy as np
import pytest

from .conftest import SCENES

pytestmark = pytest.mark.mitsuba
FIG11 = os.path.join(SCENES, "fig11.xml")


@pytest.mark.skipif(not os.path.exists(FIG11), reason="scenes/fig11.xml missing")
def test_windows_equal_full_frame_without_recompiling(llvm):
    import drjit as dr
    from links1_mitsuba import MitsubaRenderer
    r = MitsubaRenderer(FIG11, params={"res": 40}, spp=4, aovs=("depth", "normal", "id", "cost"))
    assert r.film_size == (40, 40)
    assert r.channels == ["R", "G", "B", "depth", "nx", "ny", "nz", "id", "cost"]
    full = r.render()
    assert full.shape == (40, 40, 9) and full.dtype == np.float64
    windows = [(0, 0, 40, 1), (13, 17, 9, 11), (39, 39, 1, 1), (5, 2, 20, 30)]
    for win in windows:
        x0, y0, w, h = win
        out = r.render(win)
        assert np.array_equal(out, full[y0:y0 + h, x0:x0 + w]), win
    # warm: new offsets and sizes reuse the kernels (a level with no mirror or no
    # refraction children is a different, finite code path: covered by the pass above)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()
    for x0, y0, w, h in [(4, 6, 21, 25), (12, 3, 27, 31), (1, 9, 33, 17)]:
        out = r.render((x0, y0, w, h))
        assert np.array_equal(out, full[y0:y0 + h, x0:x0 + w])
    hist = dr.kernel_history()
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    compiled = [k for k in hist if not k.get("cache_hit", True) and k.get("codegen_time", 0) > 0
                and not k.get("cache_disk", False)]
    # windows whose ray tree has no mirror (or no refraction) children at some level take a
    # different (finite) code path; a handful of such variants may compile once
    assert len(compiled) <= 6, f"{len(compiled)} kernels compiled for new windows"


@pytest.mark.skipif(not os.path.exists(FIG11), reason="scenes/fig11.xml missing")
def test_shapes_info_and_register_idempotent(llvm):
    import links1_mitsuba
    assert links1_mitsuba.register("llvm_ad_rgb") == links1_mitsuba.register("llvm_ad_rgb")
    r = links1_mitsuba.MitsubaRenderer(FIG11, params={"res": 16})
    info = r.shapes_info()
    assert [d["index"] for d in info] == list(range(len(info)))
    for d in info:
        assert set(d) >= {"index", "name", "type", "bounds_lo", "bounds_hi", "reflective",
                          "transmissive", "nbytes"}
        assert np.all(d["bounds_lo"] <= d["bounds_hi"])
    assert any(d["reflective"] for d in info) and any(d["transmissive"] for d in info)
