"""Mitsuba shapes the core does not build (``merge``) are refused at load time in one line
naming the file, the line and the element; so are bad ``sdfgrid``, ``linearcurve`` and
``bsplinecurve`` files, at the file's own line where it has lines (bad ``ellipsoids`` files:
tests/core/test_ellipsoids.py)."""
from __future__ import annotations

import pytest

from links1 import load_scene
from links1.errors import SceneError


@pytest.mark.parametrize("plugin", ["merge"])
def test_refused_with_file_and_line(tmp_path, plugin):
    p = tmp_path / "s.xml"
    p.write_text(f'<scene version="3.0.0">\n\n<shape type="{plugin}"/>\n</scene>\n')
    with pytest.raises(SceneError) as e:
        load_scene(str(p))
    message = str(e.value)
    assert "\n" not in message
    assert message.startswith(f"{p}:3: <shape type='{plugin}'>")
    assert f"shape type '{plugin}' is not supported by the core" in message


def _load(tmp_path, shape):
    p = tmp_path / "s.xml"
    p.write_text(f'<scene version="3.0.0">\n{shape}\n</scene>\n')
    with pytest.raises(SceneError) as e:
        load_scene(str(p))
    assert "\n" not in str(e.value)
    return str(e.value)


def test_bad_curve_file_names_its_line(tmp_path):
    (tmp_path / "c.txt").write_text("0 0 0 0.1\n1 0 0 0.1\n\n0 1 0 0.1\n1 1 zero 0.1\n")
    message = _load(tmp_path, '<shape type="linearcurve"><string name="filename" value="c.txt"/></shape>')
    assert f"{tmp_path / 'c.txt'}:5: a control point is 4 finite numbers" in message


@pytest.mark.parametrize("plugin, least", [("linearcurve", 2), ("bsplinecurve", 4)])
def test_short_curve_refused(tmp_path, plugin, least):
    (tmp_path / "c.txt").write_text("0 0 0 0.1\n1 0 0 0.1\n2 0 0 0.1\n3 1 0 0.1\n\n0 1 0 0.1\n")
    message = _load(tmp_path, f'<shape type="{plugin}"><string name="filename" value="c.txt"/></shape>')
    assert f"{tmp_path / 'c.txt'}:6: a curve needs at least {least} control points" in message


def test_bad_sdf_files_refused(tmp_path):
    (tmp_path / "bad.vol").write_bytes(b"NOTAVOL" + bytes(60))
    message = _load(tmp_path, '<shape type="sdfgrid"><string name="filename" value="bad.vol"/></shape>')
    assert "not a Mitsuba grid volume" in message and "s.xml:2" in message
    import numpy as np
    head = b"VOL" + bytes([3]) + np.array([1, 2, 2, 2, 1], "<i4").tobytes() + bytes(24)
    (tmp_path / "empty.vol").write_bytes(head + np.ones(8, "<f4").tobytes())
    message = _load(tmp_path, '<shape type="sdfgrid"><string name="filename" value="empty.vol"/></shape>')
    assert "no voxel holds the surface" in message
    message = _load(tmp_path, '<shape type="sdfgrid"><string name="filename" value="empty.vol"/>'
                              '<string name="normals" value="flat"/></shape>')
    assert "normals must be 'analytic' or 'smooth'" in message
