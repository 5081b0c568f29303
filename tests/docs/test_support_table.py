"""The user's guide's support table (docs/guide.md) ("What of Mitsuba's scene format each renderer supports"): every
cell marked ✓ or ≈ names the test file(s) that assert it for that renderer, and those files
exist; a ≈ cell may instead say ``untested``, and a ✓ cell never does."""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
HEADING = "### What of Mitsuba's scene format each renderer supports"
TEST_PATH = re.compile(r"`(tests/[\w/.-]+\.py)`")


def support_table(text: str) -> list[tuple[str, str, str]]:
    """(feature, core, mitsuba) cells of the first table after the heading."""
    after = text[text.index(HEADING):]
    rows = []
    for line in after.splitlines()[1:]:
        if line.startswith("|"):
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            if cells[0] in ("feature",) or set(cells[0]) <= set("- "):
                continue
            rows.append(tuple(cells))
        elif rows:
            break
    return rows


def problems(rows, root: Path = ROOT) -> list[str]:
    out = []
    for row in rows:
        assert len(row) == 3, f"support table row with {len(row)} cells: {row}"
        feature = row[0]
        for column, cell in zip(("core", "mitsuba"), row[1:]):
            named = TEST_PATH.findall(cell) + TEST_PATH.findall(feature)
            missing = [p for p in named if not (root / p).is_file()]
            if missing:
                out.append(f"{feature[:50]} [{column}]: no such test file {missing}")
            if cell.startswith("✓"):
                if not TEST_PATH.findall(cell):
                    out.append(f"{feature[:50]} [{column}]: ✓ names no test file")
                if "untested" in cell:
                    out.append(f"{feature[:50]} [{column}]: ✓ and untested")
            elif cell.startswith("≈") and not TEST_PATH.findall(cell) and "untested" not in cell:
                out.append(f"{feature[:50]} [{column}]: ≈ names no test file and does not say untested")
    return out


def test_every_supported_row_names_existing_tests():
    rows = support_table((ROOT / "docs" / "guide.md").read_text(encoding="utf-8"))
    assert len(rows) >= 25
    assert problems(rows) == []


def test_the_check_catches_a_missing_or_unnamed_test():
    rows = [("`envmap`", "✓ light", "✓ (`tests/plugins/test_area_lights_vs_mitsuba.py`)"),
            ("`constant`", "✓ (`tests/plugins/no_such_test.py`)", "≈ ignored"),
            ("`thinlens`", "≈ pinhole (untested)", "✓ untested (`tests/plugins/test_sensors.py`)")]
    found = problems(rows)
    assert any("`envmap` [core]: ✓ names no test" in p for p in found)
    assert any("`constant` [core]: no such test file" in p for p in found)
    assert any("`constant` [mitsuba]: ≈ names no test" in p for p in found)
    assert any("`thinlens` [mitsuba]: ✓ and untested" in p for p in found)
    assert len(found) == 4
