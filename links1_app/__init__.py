"""links1_app: the front ends of links1, above both renderers.

They choose and drive a renderer, the core's (:mod:`links1`) or the Mitsuba plugin's
(:mod:`links1_mitsuba`), and import down only: neither renderer imports anything here
(docs/architecture.md, "Dependencies")::

    from links1_app import make_renderer
    r = make_renderer("core", "scenes/fig11.xml", spp=4)   # or "mitsuba"
    image = r.render()                                      # (H, W, C) float64

Modules
-------
renderers      the Renderer protocol, make_renderer("core" | "mitsuba", ...), require_mitsuba,
               Mitsuba's errors in one line, renderer_warnings
cli_options    the options ``links1 render`` and ``links1 schedule`` share
cli            ``links1 render | diff | schedule`` (the console script ``links1``)
diff           ``links1 diff`` (the metrics are the core's :mod:`links1.imaging.diff`)
pytest_plugin  golden-image fixture for users' test suites (pytest entry point ``links1``)
partition      the partitioning runtime: executors, Dask back end, checkpoints, ``links1
               schedule``, reports, cost model, simulator, plots (the strategies and the
               eq. 4.1 load model are the core's :mod:`links1.partition`)
"""
from __future__ import annotations

from .renderers import Renderer, make_renderer, renderer_warnings, require_mitsuba

__all__ = ["Renderer", "make_renderer", "require_mitsuba", "renderer_warnings"]
