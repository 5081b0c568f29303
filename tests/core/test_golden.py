"""Golden images: every scene in scenes/ rendered by the core, against a stored baseline.

Uses the project's own regression tool (the ``links1_baseline`` fixture of
links1.pytest_plugin). Regenerate with ``pytest tests/core/test_golden.py --links1-update-baselines``
after an intended change, and look at the new images before committing them.
"""
from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCENES = sorted(p.name for p in (ROOT / "scenes").glob("*.xml"))


def test_every_scene_has_a_golden_test():
    assert len(SCENES) >= 9  # the paper figures, lights, bicubic, shadows, many, Mitsuba-only


@pytest.mark.parametrize("scene", SCENES)
def test_scene_matches_baseline(links1_baseline, scene):
    spp = 4 if scene == "fig11.xml" else 1
    links1_baseline.check_scene(str(ROOT / "scenes" / scene), renderer="core", spp=spp,
                                params={"res": 64}, metric="relmse", threshold=1e-8,
                                name=f"{Path(scene).stem}_spp{spp}")
