"""Area emitters and environments light the scene in the core.

Analytic first: a diffuse plane under a ``constant`` sky is exactly ``ρ L`` (cosine-weighted
environment samples), under a uniform ``envmap`` ``ρ c``, under a facing disk of radiance ``L``
``ρ L R²/(h² + R²)``, under a sphere ``ρ L r²/D²``. Then the light-sample lattice (keys, strata)
and the warning for an emitter the core cannot sample; the comparison with Mitsuba's
``direct`` lives in ``tests/plugins/test_area_lights_vs_mitsuba.py``.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from links1 import load_scene
from links1.imaging.image import write_exr
from links1.tracing.integrator import WhittedIntegrator
from links1.shading.lights import AreaLight
from links1.tracing.render import render
from links1.maths.sampling import light_samples_uv, mix32

RHO = np.array([0.7, 0.5, 0.3])


def _scene(tmp_path, light, name="s.xml"):
    xml = f"""<scene version="3.0.0">
  <sensor type="perspective"><transform name="to_world"><lookat origin="0, 4, 0.01" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/><rfilter type="box"/></film></sensor>
  <shape type="rectangle"><transform name="to_world"><scale value="50"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="{', '.join(map(str, RHO))}"/></bsdf></shape>
  {light}
</scene>"""
    p = tmp_path / name
    p.write_text(xml)
    return load_scene(str(p))


def _radiance_at_origin(scene, n=4096):
    """Mean radiance leaving the floor at the origin toward +y, over ``n`` light samples laid
    on one lattice (the rays are ``n`` camera samples of one pixel)."""
    integ = WhittedIntegrator(scene, max_depth=1)
    o = np.tile([0.0, 0.5, 0.0], (n, 1))
    d = np.tile([0.0, -1.0, 0.0], (n, 1))
    keys = mix32(np.arange(n, dtype=np.uint32))
    L, _, _ = integ.trace(o, d, np.zeros(n), np.full(n, np.inf), np.zeros(n, dtype=np.int64),
                          keys=keys, sample=(np.full(n, 12345, dtype=np.uint32), np.arange(n), n))
    return L.mean(axis=0)


def test_constant_environment_is_exactly_albedo_times_radiance(tmp_path):
    s = _scene(tmp_path, '<emitter type="constant"><rgb name="radiance" value="0.8, 0.9, 1.1"/></emitter>')
    img = render(s, spp=4)[..., :3]
    np.testing.assert_allclose(img, np.broadcast_to(RHO * [0.8, 0.9, 1.1], img.shape), rtol=1e-12)


def test_uniform_envmap_gives_albedo_times_value(tmp_path):
    write_exr(tmp_path / "u.exr", np.full((9, 16, 3), 0.6, dtype=np.float32))
    s = _scene(tmp_path, '<emitter type="envmap"><string name="filename" value="u.exr"/>'
                         '<float name="scale" value="2"/></emitter>')
    np.testing.assert_allclose(_radiance_at_origin(s), RHO * 1.2, rtol=2e-3)


def test_facing_disk_light(tmp_path):
    L, R, h = 5.0, 0.5, 2.0
    s = _scene(tmp_path, f"""<shape type="disk"><transform name="to_world"><scale value="{R}"/>
      <rotate x="1" angle="90"/><translate value="0, {h}, 0"/></transform>
      <emitter type="area"><rgb name="radiance" value="{L}"/></emitter></shape>""")
    (light,) = s.lights
    assert isinstance(light, AreaLight) and light.shape is s.shapes[1] and light.light_id == 0
    np.testing.assert_allclose(_radiance_at_origin(s), RHO * L * R * R / (h * h + R * R), rtol=2e-3)


def test_sphere_light(tmp_path):
    L, r, D = 3.0, 0.4, 2.5
    s = _scene(tmp_path, f"""<shape type="sphere"><point name="center" value="0, {D}, 0"/>
      <float name="radius" value="{r}"/><emitter type="area"><rgb name="radiance" value="{L}"/></emitter></shape>""")
    np.testing.assert_allclose(_radiance_at_origin(s), RHO * L * r * r / (D * D), rtol=2e-3)


def test_rectangle_light_facing_away_lights_nothing(tmp_path):
    # Mitsuba's area emitters are one-sided: a rectangle whose normal points up emits upward
    up = _scene(tmp_path, """<shape type="rectangle"><transform name="to_world"><scale value="0.5"/>
      <rotate x="1" angle="-90"/><translate value="0, 2, 0"/></transform>
      <emitter type="area"><rgb name="radiance" value="5"/></emitter></shape>""")
    assert np.all(_radiance_at_origin(up, 256) == 0.0)
    down = _scene(tmp_path, """<shape type="rectangle"><transform name="to_world"><scale value="0.5"/>
      <rotate x="1" angle="90"/><translate value="0, 2, 0"/></transform>
      <emitter type="area"><rgb name="radiance" value="5"/></emitter></shape>""", "down.xml")
    # a small square (side 1) at height 2: E ≈ L A cos² / d² (slightly less: it has extent)
    got = _radiance_at_origin(down)
    approx = RHO * 5.0 * 1.0 / 4.0 / np.pi
    assert np.all(got < approx) and np.all(got > 0.9 * approx)


def test_lattice_points_are_stratified_and_keyed():
    n = 64
    u, v = light_samples_uv(np.full(n, 7, dtype=np.uint32), 3, np.arange(n), n)
    # one point per column stratum and per row stratum (a shifted rank-1 lattice)
    assert sorted(np.floor(u * n).astype(int)) == list(range(n))
    assert sorted(np.floor(v * n).astype(int)) == list(range(n))
    u2, _ = light_samples_uv(np.full(n, 8, dtype=np.uint32), 3, np.arange(n), n)
    u3, _ = light_samples_uv(np.full(n, 7, dtype=np.uint32), 4, np.arange(n), n)
    assert not np.allclose(u, u2) and not np.allclose(u, u3)   # other pixel / other light


def test_light_samples_option_averages(tmp_path):
    # the light is out of view: every pixel sees the lit floor only
    s = _scene(tmp_path, """<shape type="sphere"><point name="center" value="2.5, 2, 0"/><float name="radius" value="0.3"/>
      <emitter type="area"><rgb name="radiance" value="4"/></emitter></shape>""")
    a = render(s, spp=1, light_samples=16)[..., :3]
    b = render(s, spp=16, light_samples=1)[..., :3]
    assert np.all(a > 0)
    assert abs(a.mean() / b.mean() - 1.0) < 0.01
    with pytest.raises(ValueError, match="light_samples"):
        render(s, spp=1, light_samples=0)


def test_tiled_equals_untiled(tmp_path):
    write_exr(tmp_path / "e.exr", np.random.default_rng(1).random((6, 12, 3)).astype(np.float32))
    s = _scene(tmp_path, """<shape type="sphere"><point name="center" value="0.5, 2, 0"/><float name="radius" value="0.3"/>
      <emitter type="area"><rgb name="radiance" value="4"/></emitter></shape>
      <shape type="sphere"><point name="center" value="0, 0.5, 0"/><float name="radius" value="0.5"/></shape>
      <emitter type="envmap"><string name="filename" value="e.exr"/></emitter>""")
    full = render(s, spp=4, light_samples=2, seed=3)
    tile = render(s, spp=4, light_samples=2, seed=3, window=(3, 2, 4, 5))
    assert np.array_equal(tile, full[2:7, 3:7])


def test_unsampleable_area_emitter_warns_once_by_name(tmp_path):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        s = _scene(tmp_path, """<shape type="cylinder" id="tube"><float name="radius" value="0.2"/>
          <emitter type="area"><rgb name="radiance" value="4"/></emitter></shape>""")
    msgs = [str(x.message) for x in w if "tube" in str(x.message)]
    assert len(msgs) == 1 and "\n" not in msgs[0] and "lights nothing" in msgs[0]
    assert not any(hasattr(light, "shape") for light in s.lights)


def test_area_lights_are_numbered_by_place_not_file_order(tmp_path):
    """Two area lights written in either order get the same sample streams (``light_id`` by
    place, as ``mi.load_file``'s own shape order would otherwise change them) and the same image,
    bit for bit; ids are ranks by centroid (x first)."""
    a = """<shape type="rectangle"><transform name="to_world"><scale value="0.3"/><rotate x="1" angle="90"/>
      <translate value="-1, 2, 0"/></transform><emitter type="area"><rgb name="radiance" value="4"/></emitter></shape>"""
    b = """<shape type="sphere"><point name="center" value="1, 1.5, 0.5"/><float name="radius" value="0.2"/>
      <emitter type="area"><rgb name="radiance" value="2, 3, 5"/></emitter></shape>"""
    s1, s2 = _scene(tmp_path, a + b, "ab.xml"), _scene(tmp_path, b + a, "ba.xml")
    for s in (s1, s2):
        ids = {light.kind: light.light_id for light in s.lights}
        assert ids == {"mesh": 0, "sphere": 1}
    np.testing.assert_array_equal(render(s1, spp=4), render(s2, spp=4))
