"""``links1_whitted``'s own parameters in the scene file reach every renderer.

``light_samples`` and ``min_weight`` given in the file's ``<integrator type="links1_whitted">``
are what the core, ``MitsubaRenderer`` (``links1 render``), ``mi.render`` and worker processes
use unless an option overrides them (both renderers used to drop them: the core ignored
them, ``MitsubaRenderer`` reset them to 1 and 1/255). ``--min-weight 0`` reaches worker
processes too (a 0 was dropped as false)."""
from __future__ import annotations

import numpy as np
import pytest

from links1_app.cli import main
from links1.imaging.image import read_exr
from links1_app.renderers import make_renderer

from tests.scenes import perspective, scene

SCENE = scene('<integrator type="links1_whitted"><integer name="max_depth" value="3"/>{params}</integrator>',
              perspective("0, 2, 5", "0, 0.5, 0", fov=50, width=32, height=24, spp=None), """
  <shape type="rectangle"><transform name="to_world"><scale value="0.6"/><rotate x="1" angle="90"/>
      <translate y="3"/></transform><emitter type="area"><rgb name="radiance" value="8"/></emitter></shape>
  <shape type="rectangle"><transform name="to_world"><scale value="5"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.6"/></bsdf></shape>
  <shape type="sphere"><transform name="to_world"><translate y="0.8"/></transform>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.5"/><rgb name="reflectance" value="0.003"/></bsdf></shape>""")
PARAMS = '<integer name="light_samples" value="8"/><float name="min_weight" value="0"/>'


@pytest.fixture
def files(tmp_path):
    a, b = tmp_path / "with.xml", tmp_path / "without.xml"
    a.write_text(SCENE.format(params=PARAMS))
    b.write_text(SCENE.format(params=""))
    return str(a), str(b)


@pytest.mark.slow
def test_the_files_parameters_are_the_defaults(files, renderer_kind):
    kind = renderer_kind
    with_, without = files
    r = make_renderer(kind, with_, spp=2)
    assert (r.light_samples, r.min_weight) == (8, 0.0)
    from_file = r.render()
    explicit = make_renderer(kind, without, spp=2, light_samples=8, min_weight=0.0).render()
    default = make_renderer(kind, without, spp=2).render()
    assert np.array_equal(from_file, explicit)
    assert not np.array_equal(from_file, default)     # the parameters change the image
    # an option still overrides the file
    assert np.array_equal(make_renderer(kind, with_, spp=2, light_samples=1, min_weight=1 / 255).render(), default)


@pytest.mark.slow
@pytest.mark.mitsuba
def test_mi_render_uses_them_too(variant, files):
    import mitsuba as mi

    from links1_mitsuba import load_file
    with_, _ = files
    img = np.array(mi.render(load_file(with_), spp=2), dtype=np.float64)
    ref = make_renderer("mitsuba", with_, spp=2).render()
    np.testing.assert_allclose(img, ref[..., :3], rtol=1e-6, atol=1e-7)


@pytest.mark.slow
def test_min_weight_zero_reaches_worker_processes(files, tmp_path):
    _, without = files
    one, two = tmp_path / "one.exr", tmp_path / "two.exr"
    for out, extra in ((one, []), (two, ["--workers", "2"])):
        assert main(["render", without, "--renderer", "core", "--spp", "2", "--min-weight", "0",
                     "-o", str(out), "--no-progress", *extra]) == 0
    assert np.array_equal(read_exr(str(one))[0], read_exr(str(two))[0])
    default = make_renderer("core", without, spp=2).render()[..., :3].astype(np.float32)
    assert not np.array_equal(read_exr(str(one))[0], default)
