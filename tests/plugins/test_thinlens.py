"""Mitsuba's ``thinlens`` sensor in both renderers: depth of field by sampling the lens.

A thin lens of radius ``R`` focused at distance ``F`` looks straight at a plane at distance
``D`` lit evenly (a directional light along the view axis, irradiance π: radiance = albedo),
whose checkerboard leaves one vertical edge in view. A camera ray from aperture point ``a``
through the film point whose pinhole ray meets the plane at ``D·c`` meets it at
``D·c + a·(1 - D/F)``: a pixel sees the plane through a disk of radius ``ρ = R·|1 - D/F|``
(the circle of confusion on the plane) around its pinhole point. So

* in focus (``D = F``) the image is the pinhole camera's, pixel for pixel;
* out of focus, the fraction of a pixel's disk on the bright side of the edge at signed
  distance ``s`` is ``(acos(-s/ρ) + (s/ρ)·sqrt(1 - (s/ρ)²)) / π``: the column means follow it;
* both renderers match Mitsuba's own ``direct`` (relMSE within 1.5x Mitsuba's own at the same
  spp, against Mitsuba at 16x the spp), and each other (same lens samples: relMSE <= 1e-4).
"""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from links1_app.renderers import make_renderer

from .conftest import assert_both_match_mitsuba_direct

pytestmark = pytest.mark.mitsuba

W, H = 64, 32
D, FOV, R = 4.0, 30.0, 0.5
BRIGHT, DARK = 0.9, 0.1
SCENE = """<scene version="3.0.0">
  <sensor type="{sensor}">{lens}<float name="fov" value="{fov}"/>
    <transform name="to_world"><lookat origin="0, 5, {d}" target="0, 5, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="{w}"/><integer name="height" value="{h}"/>
      <rfilter type="box"/></film>
    <sampler type="independent"/>
  </sensor>
  <integrator type="direct"/>
  <emitter type="directional"><vector name="direction" x="0" y="0" z="-1"/>
    <rgb name="irradiance" value="3.141592653589793"/></emitter>
  <shape type="rectangle"><transform name="to_world"><scale value="10"/></transform>
    <bsdf type="diffuse"><texture name="reflectance" type="checkerboard">
      <rgb name="color0" value="{bright}"/><rgb name="color1" value="{dark}"/></texture></bsdf></shape>
</scene>"""


def _scene(tmp_path, name, focus=None):
    """The edge scene, seen through a thin lens focused at ``focus`` or (None) a pinhole."""
    lens = "" if focus is None else (f'<float name="aperture_radius" value="{R}"/>'
                                     f'<float name="focus_distance" value="{focus}"/>')
    p = tmp_path / f"{name}.xml"
    p.write_text(SCENE.format(sensor="perspective" if focus is None else "thinlens", lens=lens, fov=FOV, d=D,
                              w=W, h=H, bright=BRIGHT, dark=DARK))
    return str(p)


def _render(kind, path, spp, seed=0):
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # no warning: the lens is honoured
        return np.asarray(make_renderer(kind, path, spp=spp, max_depth=1, seed=seed).render(),
                          dtype=np.float64)[..., :3]


@pytest.mark.slow
def test_the_focus_plane_is_sharp(renderer_kind, tmp_path):
    """Focused on the plane, every lens ray of a film point meets the plane where the pinhole
    ray does: the image is the pinhole camera's, whatever the lens samples."""
    kind = renderer_kind
    thin = _render(kind, _scene(tmp_path, "focus", focus=D), spp=4)
    pin = _render(kind, _scene(tmp_path, "pinhole"), spp=4)
    assert np.allclose(thin, pin, rtol=1e-5, atol=1e-6)
    assert thin[..., 0].max() == pytest.approx(BRIGHT, rel=1e-5) and thin[..., 0].min() == pytest.approx(DARK, rel=1e-5)


def test_an_edge_out_of_focus_spreads_over_the_circle_of_confusion(renderer_kind, tmp_path):
    """Focused at D/2: the edge is blurred over ρ = R·|1 - D/F| = R on the plane (about 15
    pixels); the column means follow the disk's area fraction, not the pinhole's step."""
    kind = renderer_kind
    img = _render(kind, _scene(tmp_path, "blur", focus=D / 2), spp=16)
    g = (img[..., 0].mean(axis=0) - DARK) / (BRIGHT - DARK)       # bright fraction per column
    # signed distance on the plane from each column's pinhole point to the edge (film centre)
    x = (np.arange(W) + 0.5) / W
    s = D * (1.0 - 2.0 * x) * math.tan(math.radians(FOV) / 2.0)
    if g[0] < 0.5:
        s = -s                                                    # bright on the right
    t = np.clip(s / R, -1.0, 1.0)
    expect = (np.arccos(-t) + t * np.sqrt(1.0 - t * t)) / np.pi
    rms = float(np.sqrt(np.mean((g - expect) ** 2)))
    step = float(np.sqrt(np.mean((g - (s > 0)) ** 2)))
    assert rms < 0.03, f"{kind}: bright fraction off the circle of confusion's by {rms:.3g} (rms)"
    assert step > 5 * rms   # the blur is resolved: a pinhole's step is far off


@pytest.mark.slow
def test_matches_mitsuba_direct_and_each_other(variant, tmp_path):
    """Both renderers against Mitsuba's ``direct`` through the same thin lens (out of focus,
    and a sphere nearer than the focus plane), and the core against the plugin at equal spp."""
    path = _scene(tmp_path, "mi", focus=D / 2)
    text = open(path).read().replace("</scene>", """<shape type="sphere"><point name="center" x="0.3" y="5" z="1.5"/>
    <float name="radius" value="0.3"/><bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.6, 0.7"/></bsdf>
    </shape></scene>""")
    open(path, "w").write(text)
    assert_both_match_mitsuba_direct(path, 16, _render)


@pytest.mark.slow
def test_a_zero_aperture_is_the_pinhole(renderer_kind, tmp_path):
    """``aperture_radius`` 0 is float32's epsilon, as in Mitsuba: the pinhole camera's image."""
    kind = renderer_kind
    path = _scene(tmp_path, "zero", focus=D / 2)
    text = open(path).read().replace(f'<float name="aperture_radius" value="{R}"/>',
                                     '<float name="aperture_radius" value="0"/>')
    open(path, "w").write(text)
    assert np.allclose(_render(kind, path, spp=4), _render(kind, _scene(tmp_path, "pinhole"), spp=4),
                       rtol=1e-5, atol=1e-6)


def test_a_thin_lens_without_aperture_is_refused_in_one_line(tmp_path):
    from links1.errors import SceneError
    from links1.scene.loader import load_scene
    path = _scene(tmp_path, "noaperture", focus=D / 2)
    text = open(path).read().replace(f'<float name="aperture_radius" value="{R}"/>', "")
    open(path, "w").write(text)
    with pytest.raises(SceneError, match=f"^{path}:2: .*missing required parameter 'aperture_radius'"):
        load_scene(path)
