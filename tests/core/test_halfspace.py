"""The side-of-plane rule that plans shadow rays (links1.maths.halfspace), in closed form:
the plane z = 1 (normal +z) and boxes above it, below it, across it, touching it, unbounded."""
from __future__ import annotations

import numpy as np

from links1.maths.halfspace import box_side, point_side

N = np.array([0.0, 0.0, 1.0])


def dist(corners):
    return corners @ N - 1.0


def test_point_side():
    assert point_side(0.5, 1e-6) == 1
    assert point_side(-0.5, 1e-6) == -1
    assert point_side(1e-7, 1e-6) == 0       # within the tolerance: on the plane
    assert point_side(0.0, 0.0) == 0
    assert point_side(float("nan"), 0.0) == 0


def test_box_side():
    assert box_side([0, 0, 2], [1, 1, 3], dist, 1e-9) == 1
    assert box_side([0, 0, -3], [1, 1, 0], dist, 1e-9) == -1
    assert box_side([0, 0, 0], [1, 1, 2], dist, 1e-9) == 0        # across the plane
    assert box_side([0, 0, 1], [1, 1, 2], dist, 0.0) == 1         # touching from above
    assert box_side([0, 0, 1 - 1e-7], [1, 1, 2], dist, 1e-6) == 1   # into it by less than tol
    assert box_side([0, 0, 1 - 1e-5], [1, 1, 2], dist, 1e-6) == 0
    assert box_side([0, 0, 2], [1, 1, np.inf], dist, 1e-9) == 0   # unbounded
    # a tolerance made from the corners (the core's: relative to their magnitude)
    rel = lambda c: 1e-3 * (1.0 + np.max(np.abs(c)))  # noqa: E731
    assert box_side([0, 0, 1 - 2e-3], [1, 1, 2], dist, rel) == 1   # tol = 3e-3 here
    assert box_side([0, 0, 1 - 4e-3], [1, 1, 2], dist, rel) == 0


def test_the_core_plans_with_it():
    """links1.tracing.occluders takes the rule from links1.maths.halfspace (its own plane form
    and tolerance as arguments)."""
    from links1.maths import halfspace
    from links1.tracing import occluders
    assert occluders.box_side is halfspace.box_side and occluders.point_side is halfspace.point_side
    assert occluders._box_side([0, 0, 2], [1, 1, 3], N, np.array([0.0, 0.0, 1.0])) == 1
    assert occluders._box_side([0, 0, 0], [1, 1, 3], N, np.array([0.0, 0.0, 1.0])) == 0
