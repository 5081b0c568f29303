"""Scenes with several sensors: ``mi.render(scene, sensor=k)``, a sensor
object (the scene's or one made apart with ``mi.load_dict``), ``links1.render(scene,
sensor=k)`` and ``links1 render --sensor k`` render that sensor's camera, film (size, crop
window, reconstruction filter) and sample count, in both renderers.

Judged against Mitsuba's own ``direct`` integrator on the same sensor: a point light and
diffuse surfaces, so Whitted at max_depth 1 computes what ``direct`` estimates; our relMSE
against ``direct`` at 16x the spp must be within 2x ``direct``'s own at equal spp (the corpus
criterion). Sensor 1 differs from sensor 0 in position, field of view, film size, crop window
and filter, so an image from sensor 0's camera fails by orders of magnitude."""
from __future__ import annotations

import numpy as np
import pytest

from links1.imaging.diff import relmse
from links1_app.renderers import make_renderer

from .conftest import assert_matches_mitsuba_direct, cli_variant, mitsuba_direct

pytestmark = pytest.mark.mitsuba

SPP = 16
SCENE = """<scene version="3.0.0">
  <integrator type="links1_whitted"><integer name="max_depth" value="1"/></integrator>
  <sensor type="perspective" id="front">
    <float name="fov" value="45"/>
    <transform name="to_world"><lookat origin="0, 1, 6" target="0, 1, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="48"/><integer name="height" value="32"/>
      <rfilter type="box"/></film>
    <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
  </sensor>
  <sensor type="perspective" id="top">
    <float name="fov" value="60"/>
    <transform name="to_world"><lookat origin="3, 5, 2" target="0, 0.5, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="40"/><integer name="height" value="40"/>
      <integer name="crop_offset_x" value="4"/><integer name="crop_offset_y" value="8"/>
      <integer name="crop_width" value="30"/><integer name="crop_height" value="24"/>
      <rfilter type="gaussian"/></film>
    <sampler type="independent"><integer name="sample_count" value="16"/></sampler>
  </sensor>
  <emitter type="point"><point name="position" x="1" y="4" z="3"/><rgb name="intensity" value="40"/></emitter>
  <shape type="sphere" id="ball"><point name="center" x="-0.5" y="1" z="0"/><float name="radius" value="1"/>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.5, 0.3"/></bsdf></shape>
  <shape type="cube" id="box"><transform name="to_world"><scale value="0.5"/><translate x="1.3" y="0.5" z="0.5"/>
    </transform><bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.6, 0.3"/></bsdf></shape>
  <shape type="rectangle" id="floor"><transform name="to_world"><scale value="10"/><rotate x="1" angle="-90"/>
    </transform><bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf></shape>
</scene>"""

#: a sensor made apart from the scene: another place, film size and filter
APART = {"type": "perspective", "fov": 50.0, "near_clip": 0.1,
         "film": {"type": "hdrfilm", "width": 36, "height": 20, "rfilter": {"type": "tent"}},
         "sampler": {"type": "independent", "sample_count": 8}}


@pytest.fixture
def path(tmp_path):
    p = tmp_path / "two_sensors.xml"
    p.write_text(SCENE)
    return str(p)


def _direct(scene, sensor, spp, seed):
    import mitsuba as mi
    return np.array(mi.render(scene, integrator=mi.load_dict({"type": "direct"}), sensor=sensor, spp=spp,
                              seed=seed), dtype=np.float64)[..., :3]


def _check_against_direct(scene, sensor, ours, what):
    ref = _direct(scene, sensor, SPP * 16, seed=1)
    theirs = relmse(_direct(scene, sensor, SPP, seed=2), ref)
    assert ours.shape == ref.shape, f"{what}: {ours.shape} vs Mitsuba's {ref.shape}"
    err = relmse(ours, ref)
    assert err <= 2 * theirs, f"{what}: relMSE {err:.3g} vs Mitsuba direct's own {theirs:.3g}"


@pytest.mark.slow
@pytest.mark.parametrize("how", ["index", "object"])
@pytest.mark.parametrize("k", [0, 1])
def test_mi_render_renders_the_chosen_sensor(variant, path, k, how):
    """``mi.render(scene, sensor=k)`` and ``mi.render(scene, sensor=scene.sensors()[k])``:
    sensor k's crop window (sensor 1: 30x24 of a 40x40 film, Gaussian filter) from its camera."""
    import mitsuba as mi

    import links1_mitsuba
    scene = links1_mitsuba.load_file(path)
    arg = k if how == "index" else scene.sensors()[k]
    ours = np.array(mi.render(scene, sensor=arg, spp=SPP), dtype=np.float64)
    assert ours.shape == ((32, 48, 3) if k == 0 else (24, 30, 3))
    _check_against_direct(scene, k, ours, f"sensor {k} by {how}")


@pytest.mark.slow
def test_sensor_order_does_not_matter(variant, path):
    """Sensor 1 after sensor 0 on one scene gives the image sensor 1 gives first on a fresh
    scene: the first sensor's recorded camera is never replayed for the second."""
    import mitsuba as mi

    import links1_mitsuba
    a = links1_mitsuba.load_file(path)
    first0 = np.array(mi.render(a, sensor=0, spp=4))
    then1 = np.array(mi.render(a, sensor=1, spp=4))
    again0 = np.array(mi.render(a, sensor=0, spp=4))
    fresh1 = np.array(mi.render(links1_mitsuba.load_file(path), sensor=1, spp=4))
    assert np.array_equal(then1, fresh1)
    assert np.array_equal(first0, again0)


@pytest.mark.slow
def test_sensor_made_apart(variant, path):
    """A sensor from ``mi.load_dict`` passed to ``mi.render``: its film (36x20, tent) and camera;
    moved afterwards (``params.update()``), the next render follows it."""
    import mitsuba as mi

    import links1_mitsuba
    scene = links1_mitsuba.load_file(path)
    sensor = mi.load_dict({**APART, "to_world": mi.ScalarTransform4f().look_at(
        origin=[-4, 2, 4], target=[0, 0.8, 0], up=[0, 1, 0])})
    ours = np.array(mi.render(scene, sensor=sensor, spp=SPP), dtype=np.float64)
    assert ours.shape == (20, 36, 3)
    _check_against_direct(scene, sensor, ours, "sensor made apart")
    prm = mi.traverse(sensor)
    prm["to_world"] = mi.ScalarTransform4f().look_at(origin=[4, 3, -4], target=[0, 0.5, 0], up=[0, 1, 0])
    prm.update()
    moved = np.array(mi.render(scene, sensor=sensor, spp=SPP), dtype=np.float64)
    assert not np.array_equal(moved, ours)
    _check_against_direct(scene, sensor, moved, "sensor made apart, moved")


@pytest.mark.slow
def test_renderers_take_a_sensor_index(path, kind_with_mitsuba):
    """``make_renderer(kind, path, sensor=1)`` (``links1 render --sensor 1``): sensor 1's whole
    40x40 film, its Gaussian filter and camera, against Mitsuba's ``direct`` on that sensor."""
    kind = kind_with_mitsuba
    ours, ref = assert_matches_mitsuba_direct(kind, path, spp=SPP, sensor=1)
    assert ours.shape == (40, 40, 3)


@pytest.mark.slow
def test_core_render_takes_a_sensor(llvm, path):
    """The core's ``links1.render(scene, sensor=1)``: the film's crop window (30x24) from
    sensor 1, as ``mi.render`` gives it; sensor 1's sample count (16) when none is given.

    LLVM only: a test of the core, which no variant changes; its reference (Mitsuba's direct)
    runs once, on llvm_ad_rgb."""
    import links1
    import links1_mitsuba
    scene = links1.load_scene(path)
    ours = links1.render(scene, sensor=1, max_depth=1)
    assert ours.shape == (24, 30, 3)
    assert np.array_equal(ours, links1.render(scene, sensor=1, spp=16, max_depth=1))
    _check_against_direct(links1_mitsuba.load_file(path), 1, ours, "core sensor 1")


@pytest.mark.slow
def test_cli_sensor(path, tmp_path, kind_with_mitsuba, capsys):
    """``links1 render --sensor 1`` writes sensor 1's film; ``--sensor 5`` is one line naming
    the scene file and its two sensors, exit status 2, no output file."""
    kind = kind_with_mitsuba
    from links1_app.cli import main
    from links1.imaging.image import read_image
    out = tmp_path / "s1.exr"
    assert main(["render", path, "-o", str(out), "--renderer", kind, "--sensor", "1", "--spp", str(SPP),
                 "--max-depth", "1", "--no-progress", *cli_variant(kind)]) == 0
    img = np.asarray(read_image(str(out)), dtype=np.float64)[..., :3]
    ref = mitsuba_direct(path, SPP * 16, seed=1, sensor=1)
    theirs = relmse(mitsuba_direct(path, SPP, seed=2, sensor=1), ref)
    assert img.shape == (40, 40, 3) and relmse(img, ref) <= 2 * theirs
    capsys.readouterr()
    bad = tmp_path / "bad.exr"
    assert main(["render", path, "-o", str(bad), "--renderer", kind, "--sensor", "5", *cli_variant(kind)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and path in err[0] and "2 sensors" in err[0] and "sensor 5" in err[0], err
    assert not bad.exists()


def test_core_sensor_equals_a_file_with_that_sensor_alone(tmp_path, path):
    """No Mitsuba needed: the core's sensor 1 of the two-sensor file renders the bits of the
    same file with sensor 0 removed (camera, film, crop, filter and spp all come from it)."""
    import links1
    alone = tmp_path / "alone.xml"
    start = SCENE.index('  <sensor type="perspective" id="front">')
    end = SCENE.index('  <sensor type="perspective" id="top">')
    alone.write_text(SCENE[:start] + SCENE[end:])
    a = links1.render(links1.load_scene(path), sensor=1, max_depth=1)
    b = links1.render(links1.load_scene(str(alone)), max_depth=1)
    assert a.shape == (24, 30, 3) and np.array_equal(a, b)
    r = make_renderer("core", path, sensor=1, spp=2)
    assert r.film_size == (40, 40) and r.spp == 2


@pytest.mark.slow
def test_moving_a_scene_sensor_is_seen(variant, path):
    """``params['top.to_world'] = ...; params.update()`` after a render of sensor 1: the next
    render is from the moved camera (the tables' digest covers every sensor of the scene)."""
    import mitsuba as mi

    import links1_mitsuba
    scene = links1_mitsuba.load_file(path)
    before = np.array(mi.render(scene, sensor=1, spp=SPP), dtype=np.float64)
    prm = mi.traverse(scene)
    prm["top.to_world"] = mi.ScalarTransform4f().look_at(origin=[-3, 4, 3], target=[0, 0.5, 0], up=[0, 1, 0])
    prm.update()
    after = np.array(mi.render(scene, sensor=1, spp=SPP), dtype=np.float64)
    assert not np.array_equal(before, after)
    _check_against_direct(scene, 1, after, "sensor 1 moved")


@pytest.mark.slow
def test_workers_render_the_chosen_sensor(path, tmp_path, kind_with_mitsuba):
    """``--sensor 1 --workers 2``: the worker processes render sensor 1 too (the same bits as
    in-process)."""
    kind = kind_with_mitsuba
    from links1_app.cli import main
    from links1.imaging.image import read_image
    imgs = []
    for w in ("0", "2"):
        out = tmp_path / f"w{w}.exr"
        assert main(["render", path, "-o", str(out), "--renderer", kind, "--sensor", "1", "--spp", "2",
                     "--max-depth", "1", "--workers", w, "--no-progress", *cli_variant(kind)]) == 0
        imgs.append(np.asarray(read_image(str(out))))
    assert imgs[0].shape == (40, 40, 3) and np.array_equal(imgs[0], imgs[1])
