"""Ctrl-C stops the plugin renderer: the CLI as the core's (tests/dist/test_interrupts.py), and
``mi.render`` with ``links1_whitted`` raises as it does with Mitsuba's own ``direct``."""
from __future__ import annotations

import _thread
import threading

import pytest

from tests.interrupts import interrupt_tries

from .conftest import SCENES

pytestmark = pytest.mark.mitsuba


@pytest.mark.slow
def test_ctrl_c_stops_a_plugin_render(tmp_path, llvm):
    """20 seeded Ctrl-Cs at random moments of ``links1 render`` with the plugin: one line, status
    130, no file, no process left. LLVM only: the stop between launches is the same code on
    every variant, and 20 CLI runs are the time of one variant."""
    # 512², 64 spp: 16.7 M samples, four launches of LAUNCH_LANES (the stop comes between them)
    args = ["scenes/fig11.xml", "--width", "512", "--height", "512", "--spp", "64", "--variant", llvm]
    bad = interrupt_tries(args, tmp_path, seed=4)
    assert not bad, "\n".join(bad)


def _interrupted(render, delay):
    """What ``render()`` raises when the main thread is interrupted ``delay`` s into it."""
    timer = threading.Timer(delay, _thread.interrupt_main)
    timer.start()
    try:
        for _ in range(20):   # until the interrupt lands
            render()
    except BaseException as e:  # noqa: BLE001 - the point
        return e
    finally:
        timer.cancel()
    return None


def _caused_by_interrupt(e) -> bool:
    while e is not None:
        if isinstance(e, KeyboardInterrupt):
            return True
        e = e.__cause__ or e.__context__
    return False


@pytest.mark.slow
@pytest.mark.parametrize("integrator", ["links1_whitted", "direct"])
def test_mi_render_raises_keyboard_interrupt(integrator, llvm):
    """SIGINT in the middle of ``mi.render``: a KeyboardInterrupt, with ``links1_whitted`` as
    with Mitsuba's own ``direct`` (the reference; ``dr.custom`` in ``mi.render`` turns one
    raised inside the integrator into a RuntimeError caused by it, for both), and the SIGINT
    handler as it was before. LLVM only: the launch whose interrupt went missing was LLVM's."""
    import signal

    import mitsuba as mi
    import links1_mitsuba
    scene = links1_mitsuba.load_file(f"{SCENES}/fig11.xml")
    integ = None if integrator == "links1_whitted" else mi.load_dict({"type": "direct"})
    mi.render(scene, integrator=integ, spp=1)   # compiled before the interrupt
    before = signal.getsignal(signal.SIGINT)
    e = _interrupted(lambda: mi.render(scene, integrator=integ, spp=64), 0.3)
    assert e is not None and _caused_by_interrupt(e), f"mi.render went on: {e!r}"
    assert signal.getsignal(signal.SIGINT) is before
