"""links1: the LINKS-1 ray tracing method (Osaka University, early 1980s) as modern software.

The standalone core renders Mitsuba 3 XML scenes in float64 numpy::

    import links1
    scene = links1.load_scene("scenes/fig11.xml", spp=4)
    image = links1.render(scene)            # (H, W, 3) linear radiance, float64
    links1.write_image("fig11.exr", image)

The Mitsuba 3 plugin suite is the package :mod:`links1_mitsuba`; the front ends (the
``links1`` command, the pytest plugin, the partitioning runtime, and ``make_renderer("core" |
"mitsuba", path)``, which gives either renderer) are the package :mod:`links1_app`, above both
(docs/architecture.md, "Dependencies").
"""
from __future__ import annotations

__version__ = "0.1.0"

from .errors import Links1Error, SceneError, UsageError  # noqa: E402
from .imaging.image import write_image  # noqa: E402
from .scene.loader import load_scene  # noqa: E402
# The function (the module is links1.tracing.render).
from .tracing.render import render  # noqa: E402

__all__ = ["load_scene", "render", "write_image", "SceneError", "UsageError", "Links1Error"]
