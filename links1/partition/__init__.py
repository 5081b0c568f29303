"""Root/node screen partitioning (paper section 4): the paper's maths of it.

strategies   units (tiles, scanlines) and the four strategies: subscreen (4-1, eq. 4.1),
             scanline (4-2), dynamic (4-3), grid (baseline)
loadmodel    per-object loads w_j, projected bounding rectangles, predicted load maps,
             per-node object data (4-4)

Both import only core modules. Running a plan (worker processes, Dask, checkpoints, the
``links1 schedule`` experiments) is a front end: :mod:`links1_app.partition`
(docs/partitioning.md).
"""
from __future__ import annotations

from .strategies import STRATEGIES, Plan, Unit, make_plan  # noqa: F401
