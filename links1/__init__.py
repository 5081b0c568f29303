"""links1: the LINKS-1 ray tracing method (Osaka University, early 1980s) as modern software.

The standalone core renders Mitsuba 3 XML scenes in float64 numpy::

    import links1
    scene = links1.load_scene("scenes/fig11.xml", spp=4)
    image = links1.render(scene)            # (H, W, 3) linear radiance, float64
    links1.write_image("fig11.exr", image)

The Mitsuba 3 plugin suite is the package :mod:`links1_mitsuba`; ``make_renderer("core" |
"mitsuba", path)`` gives either renderer (:mod:`links1.renderers`, the one module that names
the plugin; docs/architecture.md, "Dependencies").
"""
from __future__ import annotations

__version__ = "0.1.0"

from .errors import Links1Error, SceneError, UsageError  # noqa: E402


def load_scene(path, **params):
    """Load a Mitsuba 3 XML scene with the core's reader; ``params`` fill ``$name`` references."""
    from .loader import load_scene as _load
    return _load(path, **params)


# Imported eagerly so that ``links1.render`` stays the function after ``import links1.render``.
from .render import render  # noqa: E402
from .renderers import Renderer, make_renderer  # noqa: E402  (imports no plugin until asked)


def write_image(path, image, channels=None):
    """Write an (H, W, C) image as EXR (linear float32) or PNG (8-bit sRGB), atomically."""
    from .image import write_image as _write
    return _write(path, image, channels) if channels is not None else _write(path, image)


__all__ = ["load_scene", "render", "make_renderer", "Renderer", "write_image", "SceneError", "UsageError", "Links1Error"]
