"""Ctrl-C stops a core render on every back end: one line, status 130, no file, no process left.

Twenty tries per back end (tests/interrupts.py): SIGINT at seeded random moments from start-up
on (parsing, scene loading, workers or a cluster starting, rendering), to the process group as a
terminal sends it or to the root alone. A try that hangs fails after its timeout. The frame is
large enough (fig11 at 128², 16 spp: seconds of work) that it never ends before the interrupt.
"""
from __future__ import annotations

import pytest

from tests.interrupts import interrupt_tries

CORE = ["scenes/fig11.xml", "--renderer", "core", "--width", "128", "--height", "128", "--spp", "16"]


@pytest.mark.slow
@pytest.mark.parametrize("backend, seed", [(["--workers", "0"], 1), (["--workers", "2"], 2)],
                         ids=["single-process", "workers-2"])
def test_ctrl_c_stops_a_core_render(backend, seed, tmp_path):
    bad = interrupt_tries(CORE + backend, tmp_path, seed=seed)
    assert not bad, "\n".join(bad)


@pytest.mark.slow
def test_ctrl_c_stops_a_dask_local_render(tmp_path):
    pytest.importorskip("distributed")
    bad = interrupt_tries(CORE + ["--dask-local", "2"], tmp_path, seed=3)
    assert not bad, "\n".join(bad)
