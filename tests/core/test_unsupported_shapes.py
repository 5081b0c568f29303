"""Mitsuba shapes the core cannot intersect (curves, ``sdfgrid``, ellipsoids) are refused at
load time in one line naming the file, the line and the element."""
from __future__ import annotations

import pytest

from links1 import load_scene
from links1.errors import SceneError


@pytest.mark.parametrize("plugin", ["bsplinecurve", "linearcurve", "sdfgrid", "ellipsoids"])
def test_refused_with_file_and_line(tmp_path, plugin):
    p = tmp_path / "s.xml"
    p.write_text(f'<scene version="3.0.0">\n\n<shape type="{plugin}"/>\n</scene>\n')
    with pytest.raises(SceneError) as e:
        load_scene(str(p))
    message = str(e.value)
    assert "\n" not in message
    assert message.startswith(f"{p}:3: <shape type='{plugin}'>")
    assert f"shape type '{plugin}' is not supported by the core" in message
