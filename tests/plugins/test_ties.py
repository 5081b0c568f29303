"""Ties: two shapes hit at exactly the same distance (coincident copies) resolve to
the one earlier in the file, in both renderers, on the unrolled and the BVH paths of
links1_whitted. Expectation: each shape is ambient-only in its own colour, so every covered
pixel must be exactly the earlier shape's colour."""
from __future__ import annotations

import numpy as np
import pytest

from tests.scenes import perspective, scene, whitted

RED, GREEN = "1, 0, 0", "0, 1, 0"


def _scene(first, second, copies):
    spheres = []
    for k in range(copies):  # coincident pairs in a row; `copies` large enough takes the BVH path
        x = (k - (copies - 1) / 2) * 0.5
        for colour in (first, second):
            spheres.append(f'<shape type="links1_quadric"><string name="kind" value="sphere"/>'
                           f'<transform name="to_world"><scale value="0.2"/><translate x="{x}" y="0" z="0"/></transform>'
                           f'<bsdf type="links1_phong"><rgb name="ambient" value="{colour}"/>'
                           f'<rgb name="diffuse" value="0"/></bsdf></shape>')
    return scene(perspective("0, 0, 6", "0, 0, 0", fov=60, width=64, height=16, spp=None), whitted(1), f"""
  {''.join(spheres)}""")


def _check(img, first):
    want = np.array([float(v) for v in first.split(",")])
    covered = img[..., :3].max(axis=-1) > 0
    assert covered.sum() >= 10
    np.testing.assert_array_equal(img[covered][:, :3], np.broadcast_to(want, (int(covered.sum()), 3)))


@pytest.mark.parametrize("copies", [1, 12], ids=["unrolled", "bvh"])
@pytest.mark.parametrize("first, second", [(RED, GREEN), (GREEN, RED)], ids=["red first", "green first"])
def test_core_tie_goes_to_the_earlier_shape(first, second, copies):
    import links1
    from links1.scene.loader import load_string
    _check(links1.render(load_string(_scene(first, second, copies)), spp=1), first)


@pytest.mark.mitsuba
@pytest.mark.parametrize("copies", [1, 12], ids=["unrolled", "bvh"])
@pytest.mark.parametrize("first, second", [(RED, GREEN), (GREEN, RED)], ids=["red first", "green first"])
def test_plugin_tie_goes_to_the_earlier_shape(variant, first, second, copies):
    from links1_mitsuba import load_string
    s = load_string(_scene(first, second, copies), variant=variant)
    _check(s.integrator().render_window(s, None, spp=1).astype(np.float64), first)
