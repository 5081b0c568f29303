"""Inverse rendering through an outline: ``compare.inverse``'s ``quadric_outline`` fit, short.

A ``links1_quadric`` sphere of one constant colour before black, its translation started 0.4
of its range (0.5 a component) from the truth: only its outline moves with it, so without the
visibility term (``projective`` off) every gradient is 0 and the start stays where it is.
With it, Adam on the L2 image loss must bring the worst component within 2 % of the range in
100 iterations at 32², spp 4 and the derivative pass at 1 (a margin: it ends under 1 %, as the 64² fit of
``python -m compare.inverse`` does).
"""
from __future__ import annotations

import numpy as np
import pytest

from tests.plugins.conftest import use_variant

pytestmark = [pytest.mark.mitsuba, pytest.mark.slow]

WIDTH, ITERS, BOUND = 32, 100, 0.02


def _fit(case):
    """The worst parameter error / range after the short fit of ``case`` (compare.inverse)."""
    import drjit as dr
    import mitsuba as mi
    from compare import inverse
    from links1_mitsuba import tuning
    name, cls, variables, lrs, _ = next(c for c in inverse.make_cases({"default": ITERS}) if c[0] == case)
    with tuning.tuned():   # compare.inverse.load sets keep_graph: restored after the fit
        r, _ = inverse.run_case(mi, dr, name, cls, variables, lrs, ITERS, WIDTH, lambda s: None)
    return r


def test_quadric_placed_from_its_outline():
    use_variant("llvm_ad_rgb")
    r = _fit("quadric_outline")
    assert r["worst_error"][0] == pytest.approx(0.4)
    assert r["final_worst_error"] <= BOUND, r["worst_error"][::10]
    # the same fit without the visibility term: no gradient, the bound is not met
    off = _fit("quadric_outline_off")
    assert off["final_worst_error"] > BOUND
    np.testing.assert_allclose(off["final"]["t"], off["start"]["t"], atol=1e-6)
