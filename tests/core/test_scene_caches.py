"""The core's per-scene caches (BVH, integrator plan) follow the scene's content:
changed after its first render, a scene renders as a scene built that way from the start."""
from __future__ import annotations

import os

import numpy as np
import pytest

import links1
from links1.scene.loader import load_scene
from links1.shading.materials import Phong

SHADOWS = os.path.join(os.path.dirname(__file__), "..", "..", "scenes", "shadows.xml")


def _load():
    return load_scene(SHADOWS, res="24")


def _opaque_panes(scene):  # the two tinted panes (shapes 1, 2) become opaque grey
    for s in scene.shapes[1:3]:
        s.material = Phong(ambient=0.02, diffuse=0.3)


def _drop_far_sphere(scene):  # a sphere far behind the camera's back: no pixel sees it
    scene.shapes.append(load_scene_sphere())


def load_scene_sphere():
    from links1.scene.loader import load_string
    return load_string("""<scene version="3.0.0"><shape type="sphere"><point name="center" x="0" y="2.2" z="0"/>
        <float name="radius" value="0.5"/><bsdf type="links1_phong"><rgb name="diffuse" value="0.5"/></bsdf></shape>
        <emitter type="point"><point name="position" x="0" y="9" z="0"/><rgb name="intensity" value="1"/></emitter>
        </scene>""").shapes[0]


def _move_light(scene):
    scene.lights[0].position = np.asarray(scene.lights[0].position, dtype=np.float64) + np.array([1.5, 0.0, 0.0])


@pytest.mark.parametrize("change", [_opaque_panes, _drop_far_sphere, _move_light],
                         ids=["material replaced", "shape appended", "light moved in place"])
def test_changed_after_a_render_equals_built_that_way(change):
    a = _load()
    before = links1.render(a)
    change(a)
    after = links1.render(a)
    b = _load()
    change(b)
    fresh = links1.render(b)
    assert not np.array_equal(before, fresh)  # the change shows in the image
    np.testing.assert_array_equal(after, fresh)


def test_content_key_ignores_nothing_it_needs():
    a = _load()
    k = a.content_key()
    assert _load().content_key() == k                     # same file, same key
    a.shapes[0].material.diffuse = a.shapes[0].material.diffuse * 0.5
    assert a.content_key() != k                           # an array changed in place


def test_a_culled_copy_does_not_share_the_plan():
    """partition --cull renders a dataclasses.replace() copy with fewer shapes: its plan (one
    material per shape) is built for it, not copied from the full scene."""
    from dataclasses import replace
    a = _load()
    links1.render(a)
    sub = replace(a, shapes=a.shapes[:1])
    img = links1.render(sub)
    only_floor = _load()
    del only_floor.shapes[1:]
    np.testing.assert_array_equal(img, links1.render(only_floor))


def test_a_pinned_scene_is_hashed_once_and_unpinned_follows_changes(monkeypatch):
    """A partition node's CoreRenderer renders one window per call: it pins its scene's key
    at load, so a window's launch does not re-hash every shape; an unpinned scene still follows changes."""
    from links1.scene import scene as scene_mod
    from links1.tracing.render import CoreRenderer
    r = CoreRenderer(SHADOWS, params={"res": "24"})
    full = r.render()
    calls = []
    real = scene_mod.content_key
    monkeypatch.setattr(scene_mod, "content_key", lambda o: calls.append(1) or real(o))
    win = r.render(window=(4, 6, 10, 8))
    np.testing.assert_array_equal(win, full[6:14, 4:14])
    assert calls == []                                    # no hashing per window
    r.scene.unpin_content()
    _opaque_panes(r.scene)
    after = r.render()
    assert calls                                          # unpinned: the key is computed again
    fresh = _load()
    _opaque_panes(fresh)
    np.testing.assert_array_equal(after, links1.render(fresh))  # and the caches follow the change
