"""Tuning per integrator: ``integrator.tuning = Tuning(...)`` makes the switches that
integrator's alone. Two integrators of the same scene file in one process, one with
``eye_buffer=False``: each frame equals the frame of the module-wide setting it stands for
(bit for bit, the ``cost`` channel included), the two differ in ray-primitive tests, and the
module-wide tuning is left as it was."""
from __future__ import annotations

import numpy as np
import pytest

from .test_lightbuffer import _scene as _quadrics_scene

pytestmark = pytest.mark.mitsuba


def _frame(scene):
    return scene.integrator().render_window(scene, aovs=("cost",))


def test_an_integrators_own_tuning(variant):
    import links1_mitsuba
    from links1_mitsuba import tuning
    xml = _quadrics_scene(120)
    plain, own = links1_mitsuba.load_string(xml), links1_mitsuba.load_string(xml)
    default = tuning.current()
    off = tuning.Tuning(eye_buffer=False)
    own.integrator().tuning = off
    assert own.integrator().tuning == off and plain.integrator().tuning == default
    a, b = _frame(plain), _frame(own)
    assert tuning.current() == default                       # the module's switches untouched
    assert a[..., 3].sum() != b[..., 3].sum()                # the eye buffer saves tests
    with tuning.tuned(eye_buffer=False):                     # the module-wide way, another scene
        ref = _frame(links1_mitsuba.load_string(xml))
    assert np.array_equal(b, ref)
    assert np.array_equal(_frame(plain), a)                  # the other integrator unchanged
    own.integrator().tuning = None                           # back to the module's
    assert np.array_equal(_frame(own), a)
    with pytest.raises(TypeError, match="tuning must be"):
        own.integrator().tuning = {"eye_buffer": False}
