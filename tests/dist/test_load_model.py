"""The eq. 4.1 load model against a scene built with a known load gradient.

Six vertical strips of the screen hold 1, 4, 7, 10, 13 and 16 small spheres: the work a strip
costs grows from left to right by construction. The model's predicted strip loads (eq. 4.1:
background + the sum of w_j over the objects whose projected rectangle covers a pixel) and the
renderer's measured ray-primitive tests (the deterministic ``cost`` AOV, not wall time) must
both rank the strips as the construction does.
"""
from __future__ import annotations

import numpy as np
import pytest

from links1_app.partition.costmodel import spearman
from links1.partition.loadmodel import scene_model
from links1.tracing.aovs import aov_channel
from links1_app.renderers import make_renderer

STRIPS, STRIP_W, H = 6, 16, 32
COUNTS = [1 + 3 * c for c in range(STRIPS)]


def gradient_scene(path):
    half_w = 10.0 * np.tan(np.radians(30.0))          # fov 60 along x, eye 10 from the plane z = 0
    half_h = half_w * H / (STRIPS * STRIP_W)
    rng = np.random.default_rng(7)
    r = 0.22
    shapes = []
    for c, n in enumerate(COUNTS):
        x0 = -half_w + c * 2 * half_w / STRIPS
        xs = rng.uniform(x0 + r, x0 + 2 * half_w / STRIPS - r, n)
        ys = rng.uniform(-half_h + r, half_h - r, n)
        zs = rng.uniform(-1.0, 1.0, n)
        shapes += [f'<shape type="sphere"><point name="center" x="{x}" y="{y}" z="{z}"/>'
                   f'<float name="radius" value="{r}"/><ref id="m"/></shape>' for x, y, z in zip(xs, ys, zs)]
    path.write_text(f"""<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="60"/><string name="fov_axis" value="x"/>
    <transform name="to_world"><lookat origin="0, 0, 10" target="0, 0, 0" up="0, 1, 0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="1"/></sampler>
    <film type="hdrfilm"><integer name="width" value="{STRIPS * STRIP_W}"/><integer name="height" value="{H}"/>
      <rfilter type="box"/></film></sensor>
  <bsdf type="diffuse" id="m"/>
  {''.join(shapes)}
  <emitter type="point"><point name="position" x="0" y="5" z="10"/><rgb name="intensity" value="50"/></emitter>
</scene>""")
    return str(path)


def strip_sums(img2d):
    return img2d.reshape(H, STRIPS, STRIP_W).sum(axis=(0, 2))


def test_eq41_predicts_a_known_load_gradient(tmp_path):
    path = gradient_scene(tmp_path / "gradient.xml")
    r = make_renderer("core", path, aovs=("cost",))
    predicted = strip_sums(scene_model(r).load_map())
    img = r.render()
    measured = strip_sums(img[..., aov_channel(r.channels, "cost")])
    # the construction's ranking, in the prediction and in the measurement
    assert np.all(np.diff(predicted) > 0), predicted
    assert np.all(np.diff(measured) > 0), measured
    assert spearman(predicted, measured) == 1.0
    # and not only the order: predicted and measured loads are nearly proportional
    assert np.corrcoef(predicted, measured)[0, 1] > 0.95


def _synthetic_model():
    """Five objects of three representations and finishes on a 64x48 film (rectangles given)."""
    from links1.partition.loadmodel import SceneModel
    shapes = [{"type": "quadric", "reflective": False, "transmissive": False},
              {"type": "quadric", "reflective": True, "transmissive": False},
              {"type": "trianglemesh", "reflective": False, "transmissive": False},
              {"type": "quadric", "reflective": False, "transmissive": True},
              {"type": "blob", "reflective": True, "transmissive": False}]
    rects = np.array([[0, 0, 20, 30], [10, 5, 40, 25], [0, 30, 64, 48], [30, 0, 60, 20], [45, 10, 64, 40]],
                     dtype=np.float64)
    return SceneModel(64, 48, shapes, np.ones(len(shapes)), rects)


def test_fit_load_table_recovers_the_table_that_made_the_times():
    """Unit times made by eq. 4.1 itself from a known table (plus a launch constant) are fitted
    back to that table: the representation, the finish extras and the background."""
    from dataclasses import replace

    from links1.partition.loadmodel import fit_load_table, object_loads
    from links1.partition.strategies import grid_shape, tile_units, unit_loads
    truth = {"representation": {"quadric": 1.0, "trianglemesh": 0.4, "blob": 3.0, "default": 1.0},
             "finish": {"reflective": 2.5, "transmissive": 6.0}, "background": 0.7}
    samples = []
    for tiles in (12, 48):  # two "scenes": the same objects cut two ways
        m = _synthetic_model()
        units = tile_units(64, 48, *grid_shape(64, 48, tiles))
        lm = replace(m, loads=object_loads(m.shapes, truth), background=truth["background"]).load_map()
        samples.append((m, units, 2e-7 * unit_loads(units, lm) + 3e-4))
    fit = fit_load_table(samples)
    for k, v in truth["representation"].items():
        if k != "default":
            assert fit["representation"][k] == pytest.approx(v, rel=1e-6), k
    assert fit["finish"] == pytest.approx(truth["finish"], rel=1e-9)
    assert fit["background"] == pytest.approx(truth["background"], rel=1e-6)
    assert fit["fit"]["launch_s"] == pytest.approx(3e-4, rel=1e-6)
    assert fit["fit"]["relative_rms"] < 1e-9


def test_each_renderer_plans_with_its_own_load_table(tmp_path):
    """``links1 schedule --renderer mitsuba`` predicts loads with the table fitted to the plugin
    renderer, the core with the default table, and a --load-table file overrides either."""
    import json

    from links1.partition.loadmodel import DEFAULT_LOAD_TABLE, RENDERER_LOAD_TABLES, load_table
    assert RENDERER_LOAD_TABLES["mitsuba"]["finish"] != DEFAULT_LOAD_TABLE["finish"]
    assert load_table(renderer="core") == DEFAULT_LOAD_TABLE
    mt = load_table(renderer="mitsuba")
    assert mt["background"] == RENDERER_LOAD_TABLES["mitsuba"]["background"]
    assert mt["representation"]["disk"] == DEFAULT_LOAD_TABLE["representation"]["disk"]  # not fitted: default
    f = tmp_path / "t.json"
    f.write_text(json.dumps({"background": 9.0}))
    over = load_table(f, renderer="mitsuba")
    assert over["background"] == 9.0 and over["finish"] == mt["finish"]
