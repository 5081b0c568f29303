"""Sensors other than the pinhole in both renderers.

The orthographic sensor, against Mitsuba's own ``direct`` integrator:

A scaled orthographic camera looks down at a diffuse sphere on a diffuse floor under a point
light (delta light, diffuse surfaces: Whitted at max_depth 1 is Mitsuba's ``direct``). Both
renderers' relative MSE against Mitsuba's ``direct`` at 16x the spp must be within 2x
Mitsuba's own at the same spp (the corpus criterion), and the picture must be orthographic:
the sphere's disk is round and as wide as the sphere, wherever it sits in the frame."""
from __future__ import annotations

import numpy as np
import pytest

from links1_app.renderers import make_renderer

from .conftest import assert_matches_mitsuba_direct

pytestmark = pytest.mark.mitsuba

W, H = 48, 32
SCENE = """<scene version="3.0.0">
  <sensor type="orthographic">
    <float name="near_clip" value="0.5"/><float name="far_clip" value="50"/>
    <transform name="to_world"><scale x="2.5" y="2.5"/>
      <lookat origin="0.7, 6, 1.2" target="0.7, 0, 1.2" up="0, 0, -1"/></transform>
    <film type="hdrfilm"><integer name="width" value="{W}"/><integer name="height" value="{H}"/>
      <rfilter type="box"/></film>
    <sampler type="independent"><integer name="sample_count" value="16"/></sampler>
  </sensor>
  <integrator type="direct"/>
  <emitter type="point"><point name="position" x="2" y="5" z="3"/><rgb name="intensity" value="30"/></emitter>
  <shape type="sphere"><point name="center" x="{cx}" y="1" z="0.8"/><float name="radius" value="1"/>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.5, 0.3"/></bsdf></shape>
  <shape type="rectangle"><transform name="to_world"><scale value="10"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf></shape>
</scene>"""


@pytest.fixture(params=[0.0, 2.0], ids=["centre", "off-centre"])
def scene(request, tmp_path):
    p = tmp_path / "ortho.xml"
    p.write_text(SCENE.format(W=W, H=H, cx=request.param))
    return str(p), request.param


@pytest.mark.slow
def test_orthographic_scene_matches_mitsuba_direct(scene, kind_with_mitsuba):
    kind = kind_with_mitsuba
    path, cx = scene
    assert_matches_mitsuba_direct(kind, path)
    # orthographic: the unit sphere's silhouette is a disk of radius 1 world unit around its
    # centre's film position (2.5 world units per half film width: W / 5 pixels per unit)
    px = W / 5.0
    centre = (W / 2.0 + (cx - 0.7) * px, H / 2.0 + (0.8 - 1.2) * px)   # camera x: world -x, up: -z
    ids = np.asarray(make_renderer(kind, path, spp=1, max_depth=1, aovs=("id",)).render())[..., 3]
    sphere = ids == 0   # the id AOV at the pixel centres (spp 1): the sphere is shape 0
    yy, xx = np.mgrid[0:H, 0:W] + 0.5
    r = np.hypot(xx - centre[0], yy - centre[1])
    assert sphere[r < 0.95 * px].all() and not sphere[r > 1.05 * px].any()


def test_other_sensors_are_refused_in_one_line(variant, tmp_path):
    p = tmp_path / "r.xml"
    p.write_text(SCENE.format(W=1, H=1, cx=0.0).replace(
        '<sensor type="orthographic">', '<sensor type="radiancemeter"><point name="origin" x="0" y="5" z="0"/><!-- 1x1 film -->'
        '<vector name="direction" x="0" y="-1" z="0"/>').replace(
        '<transform name="to_world"><scale x="2.5" y="2.5"/>\n      <lookat origin="0.7, 6, 1.2" target="0.7, 0, 1.2" '
        'up="0, 0, -1"/></transform>', "").replace('<float name="near_clip" value="0.5"/><float name="far_clip" '
                                                   'value="50"/>', ""))
    with pytest.raises(Exception, match="perspective, thinlens and orthographic sensors, not RadianceMeter"):
        make_renderer("mitsuba", str(p), spp=1).render()


@pytest.mark.parametrize("sensor", ["orthographic", "perspective"])
def test_crop_window_is_those_pixels_of_the_full_film(renderer_kind, sensor, tmp_path):
    """A film's crop window (``crop_offset_x/y``, ``crop_width/height``; ``links1.tracing.render`` and
    ``mi.render`` with links1_whitted render it) is exactly those
    pixels of the uncropped film, bit for bit, with a filter wider than a pixel (Gaussian,
    radius 2): its border pixels gather samples from outside the window, from the whole film."""
    kind = renderer_kind
    body = SCENE.format(W=W, H=H, cx=0.0).replace('<rfilter type="box"/>', '<rfilter type="gaussian"/>')
    if sensor == "perspective":
        body = body.replace('<sensor type="orthographic">', '<sensor type="perspective"><float name="fov" value="40"/>') \
            .replace('<scale x="2.5" y="2.5"/>', "")
    x0, y0, w, h = 13, 5, 17, 11
    full, crop = tmp_path / "full.xml", tmp_path / "crop.xml"
    full.write_text(body)
    crop.write_text(body.replace("<rfilter", f'<integer name="crop_offset_x" value="{x0}"/>'
                                 f'<integer name="crop_offset_y" value="{y0}"/><integer name="crop_width" value="{w}"/>'
                                 f'<integer name="crop_height" value="{h}"/><rfilter'))
    if kind == "core":
        import links1

        def film(path):
            return np.asarray(links1.render(links1.load_scene(str(path)), spp=4, seed=3))
    else:
        import mitsuba as mi

        import links1_mitsuba

        def film(path):   # mi.render renders the film's crop window
            return np.array(mi.render(links1_mitsuba.load_file(str(path)), spp=4, seed=3), dtype=np.float64)
    a, b = film(full), film(crop)
    assert a.shape[:2] == (H, W) and b.shape[:2] == (h, w)
    assert np.array_equal(b, a[y0:y0 + h, x0:x0 + w]) and b[..., 0].max() > 0
