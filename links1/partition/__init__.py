"""Root/node screen partitioning (paper section 4): strategies, executors, experiments.

The root is the links1 process; the nodes are worker processes on this machine (the local
pool) or the workers of a Dask cluster. Nothing here imports mitsuba/drjit, and dask is
imported only when a Dask backend is used. See ``docs/partitioning.md``.

Modules
-------
strategies   units (tiles, scanlines) and the four strategies: subscreen (4-1, eq. 4.1),
             scanline (4-2), dynamic (4-3), grid (baseline)
loadmodel    per-object loads w_j, projected bounding rectangles, predicted load maps,
             per-node object data (4-4)
runtime      what a node runs: renderer specs, one renderer per worker, culling
executors    the root's driver (assembly, checkpoint, progress, fault handling) and the
             in-process / local-pool backends
dask_backend the Dask backend (existing cluster or a LocalCluster on 127.0.0.1)
checkpoint   finished units kept on disk
experiment   schedule reports, simulation, plots
cli          ``links1 schedule`` and the distributed options of ``links1 render``
"""
from __future__ import annotations

from .strategies import STRATEGIES, Plan, Unit, make_plan  # noqa: F401
