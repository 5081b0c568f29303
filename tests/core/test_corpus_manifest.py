"""The corpus list (tests/corpus/manifest.py) is consistent with SOURCES.md and the files."""
from __future__ import annotations

import os

from tests.corpus.manifest import HERE, SCENES, table_rows


def test_sources_md_is_the_manifest_table():
    """Every scene's repository, path, commit, licence and expectation, as the test reads them."""
    lines = open(os.path.join(HERE, "SOURCES.md"), encoding="utf-8").read().splitlines()
    for row in table_rows():
        assert row in lines, f"SOURCES.md is out of date (python -m tests.corpus.manifest): {row}"


def test_committed_scenes_are_present_with_their_licence():
    assert len(SCENES) >= 10 and len({sc.id for sc in SCENES}) == len(SCENES)
    for sc in SCENES:
        assert sc.expect in ("direct", "renders")
        if sc.committed:
            assert os.path.exists(sc.local_path), sc.id
            assert os.path.exists(os.path.join(HERE, sc.repo.replace("/", "+"), "LICENSE")), sc.id
