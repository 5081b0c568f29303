"""A loaded scene given other ``$name`` values in place (links1.scene.scenefile, CoreRenderer.set_params):
each frame renders as a fresh load with its values, bit for bit, without reading the file again,
building again only the elements whose parameters changed."""
from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from links1.errors import SceneError
from links1.scene.scenefile import SceneFile
from links1.scene.xmlparse import parse_string
from links1.tracing.render import CoreRenderer

SCENES = Path(__file__).resolve().parents[2] / "scenes"
OPTS = dict(width=24, height=24, spp=1, aovs=("cost", "depth"))


def copy_scene(tmp_path, name):
    """The scene and the camera it includes, copied where the test may delete them."""
    shutil.copy(f"{SCENES}/{name}", tmp_path / name)
    (tmp_path / "include").mkdir()
    shutil.copy(f"{SCENES}/include/camera.xml", tmp_path / "include" / "camera.xml")
    return str(tmp_path / name)


def check_updates(tmp_path, path, frames, moved):
    """Frames 1.. rendered by one renderer updated in place equal fresh loads; the files are
    deleted before the updates (nothing reads them); ``moved``: the changed elements are shapes."""
    fresh = [CoreRenderer(path, params=v, **OPTS).render() for v in frames]
    r = CoreRenderer(path, params=frames[0], **OPTS)
    assert np.array_equal(r.render(), fresh[0])
    shutil.rmtree(tmp_path / "include")
    (tmp_path / path.rsplit("/", 1)[1]).unlink()
    scene = r.scene
    for k, v in enumerate(frames[1:], 1):
        shapes, accel = list(scene.shapes), scene.accel
        assert r.set_params(v) == set(v)
        assert r.scene is scene and r.source.sources.reads == 2      # the scene file and its include, once
        kept = [a is b for a, b in zip(shapes, scene.shapes)]
        assert (scene.accel is accel) is (not moved)                  # a camera move keeps the BVH
        assert kept.count(False) == (1 if moved else 0), kept          # only the moved shape is new
        assert np.array_equal(r.render(), fresh[k]), f"frame {k} differs from a fresh load"
    return r


def test_camera_orbit_updates_the_camera_alone(tmp_path):
    path = copy_scene(tmp_path, "many.xml")
    frames = [{"eye": f"{14 * math.sin(a)!r}, 9, {14 * math.cos(a)!r}"} for a in map(math.radians, (0, 30, 60))]
    r = check_updates(tmp_path, path, frames, moved=False)
    assert r.source.rebuilt == [0]          # the included sensor, the scene's first element


def test_moving_blob_centres_rebuild_that_blob_alone(tmp_path):
    path = copy_scene(tmp_path, "blobs_moving.xml")
    frames = [{"x0": "-1.0", "y4": "1.8"}, {"x0": "-0.7", "y4": "1.6"}, {"x0": "-0.4", "y4": "1.9"}]
    r = check_updates(tmp_path, path, frames, moved=True)
    assert r.source.rebuilt == [2]          # sensor, integrator, then the blob


def test_uses_follow_defaults_and_references():
    """An element takes the parameters of the objects it references and of the <default>s it reads."""
    root = parse_string("""<scene version="3.0.0">
        <default name="a" value="0.5"/> <default name="c" value="$a"/> <default name="r" value="1"/>
        <bsdf type="diffuse" id="m"><rgb name="reflectance" value="$c"/></bsdf>
        <shape type="sphere"><float name="radius" value="$r"/><ref id="m"/></shape>
        <shape type="sphere"><float name="radius" value="2"/></shape>
        <sensor type="perspective"><float name="fov" value="$r"/></sensor>
    </scene>""")
    assert [n.uses for _, n in root.children] == [{"c", "a"}, {"r", "c", "a"}, set(), {"r"}]


def test_a_bad_value_is_the_load_error_and_leaves_the_scene(tmp_path):
    path = copy_scene(tmp_path, "blobs_moving.xml")
    sf = SceneFile(path, x0="-1.0")
    before = sf.scene.shapes[0]
    with pytest.raises(SceneError, match="threshold"):
        sf.update(x0="-1.0", threshold="-1")
    with pytest.raises(SceneError, match="unused parameter"):
        sf.update(x0="-1.0", nothing="1")
    assert sf.scene.shapes[0] is before and sf.params == {"x0": "-1.0"}
    assert sf.update(x0="-1.0") == set() and sf.rebuilt == []
