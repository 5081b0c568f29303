"""`links1 render` with the distributed options, and the per-unit overhead target."""
from __future__ import annotations

import numpy as np
import pytest

from .conftest import MANY


def test_render_workers_2_matches_in_process(tmp_path, core_ref):
    from links1.cli import main
    from links1.image import read_image
    a, b = tmp_path / "a.exr", tmp_path / "b.exr"
    base = ["render", MANY, "--renderer", "core", "-D", "res=32", "--aov", "id,cost", "--no-progress"]
    assert main(base + ["-o", str(a), "--workers", "0"]) == 0
    assert main(base + ["-o", str(b), "--workers", "2", "--partition", "subscreen",
                        "--checkpoint", str(tmp_path / "ck")]) == 0
    ia, ib = read_image(a), read_image(b)
    ia = ia[0] if isinstance(ia, tuple) else ia
    ib = ib[0] if isinstance(ib, tuple) else ib
    assert np.array_equal(np.asarray(ia), np.asarray(ib))


@pytest.mark.slow
@pytest.mark.xfail(strict=False, reason="the core's per-window cost (numpy calls per hierarchy leaf) makes 64 "
                   "small windows ~2.7x a full 128x128 frame; the target is render.py's")
def test_64_units_cost_at_most_115_percent_of_a_frame():
    from links1.partition.experiment import measure_overhead
    from links1.partition.runtime import RendererSpec
    r = measure_overhead(RendererSpec.make("core", MANY, params={"res": "64"}), repeat=1)
    assert r["ratio"] <= 1.15, r
