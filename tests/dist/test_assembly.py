"""The assembled frame equals the single-process render bit for bit (every strategy and backend)."""
from __future__ import annotations

import numpy as np
import pytest

from links1_app.partition.executors import InProcess, render_plan
from links1_app.partition.local_pool import LocalPool
from links1.partition.loadmodel import scene_model
from links1_app.partition.runtime import get_renderer
from links1.partition.strategies import STRATEGIES, make_plan

from tests.scenes import perspective, scene, whitted

CASES = [(s, u) for s in STRATEGIES for u in (("scanline", "tile") if s == "dynamic" else ("tile",))]


def _plans(spec, nodes):
    r = get_renderer(spec)
    model = scene_model(r)
    lm = model.load_map()
    w, h = r.film_size
    return model, [make_plan(s, w, h, nodes, tiles_per_node=4, unit=u, load_map=lm) for s, u in CASES]


def test_inprocess_fake_every_strategy(fake_spec, fake_ref):
    _, plans = _plans(fake_spec, 3)
    for plan in plans:
        res = render_plan(plan, fake_spec, InProcess(), progress=False)
        assert np.array_equal(res.image, fake_ref), plan


@pytest.mark.slow
def test_core_renderer_every_strategy_workers_0_and_2(core_spec, core_ref):
    model, plans = _plans(core_spec, 2)
    for plan in plans:
        res = render_plan(plan, core_spec, InProcess(), progress=False)
        assert np.array_equal(res.image, core_ref), plan
    with LocalPool(2) as pool:
        for plan in plans:
            res = render_plan(plan, core_spec, pool, progress=False)
            assert np.array_equal(res.image, core_ref), plan
            nodes = {r["node"] for r in res.records.values()}
            assert nodes == {0, 1}


CULL_SCENE = scene(perspective("0, 0, 10", "0, 0, 0", fov=50, width=40, height=24, spp=None), whitted(1), """
  <emitter type="links1_point"><point name="position" x="0" y="0" z="12"/><rgb name="L1" value="50"/></emitter>
  %s""")
SPHERE = ('<shape type="links1_quadric"><string name="kind" value="sphere"/><transform name="to_world">'
          '<scale value="0.8"/><translate x="%g" y="%g" z="0"/></transform>'
          '<bsdf type="links1_phong"><rgb name="diffuse" value="0.7"/></bsdf></shape>')


@pytest.mark.slow
def test_core_renderer_cull_keeps_the_image(tmp_path):
    """--cull: nodes get only the objects their units need (4-4); the image is unchanged."""
    from links1_app.partition.cli import cull_map
    from links1_app.partition.runtime import RendererSpec
    from links1_app.renderers import make_renderer
    path = tmp_path / "cull.xml"
    path.write_text(CULL_SCENE % "".join(SPHERE % (x, y) for x in (-4, -1.5, 1.5, 4) for y in (-1.5, 1.5)))
    spec = RendererSpec.make("core", str(path), aovs=("id",))
    ref = make_renderer("core", str(path), aovs=("id",)).render()
    assert len(np.unique(ref[..., 3])) == 9  # eight spheres and the background
    model, plans = _plans(spec, 2)
    for plan in plans:
        cull = cull_map(plan, model, spec)
        if plan.strategy != "scanline":  # interleaved lines span the screen: nothing to cull there
            assert min(len(v) for v in cull.values()) < len(model.shapes), plan
        res = render_plan(plan, spec, InProcess(), progress=False, cull=cull)
        assert np.array_equal(res.image, ref), plan


@pytest.mark.slow
@pytest.mark.dask
def test_dask_local_every_strategy(fake_spec, fake_ref, core_spec, core_ref):
    pytest.importorskip("distributed")
    from links1_app.partition.dask_backend import DaskBackend
    from links1_app.partition.runtime import limit_blas
    _, plans = _plans(fake_spec, 2)
    blas = limit_blas(2)    # None where numpy has no OpenBLAS
    for static in (True, False):
        with DaskBackend(n_local=2, static=static) as be:
            for plan in plans:
                if plan.static != static:
                    continue
                res = render_plan(plan, fake_spec, be, progress=False)
                assert np.array_equal(res.image, fake_ref), plan
            # the root keeps one BLAS thread while its local nodes render
            assert blas is None or limit_blas(0) == 1
            if static:  # one real scene through Dask too
                _, cplans = _plans(core_spec, 2)
                res = render_plan(cplans[0], core_spec, be, progress=False)
                assert np.array_equal(res.image, core_ref)
        assert blas is None or limit_blas(0) == 2   # as it was, once the cluster is closed
    if blas is not None:
        limit_blas(blas)
