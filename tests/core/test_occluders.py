"""No shadow rays where no occluder can be, with unchanged images."""
from __future__ import annotations

import numpy as np

from links1.sensor.camera import Camera
from links1.shading.lights import ParallelLight, PointLight
from links1.shading.materials import Phong
from links1.tracing.occluders import shadow_plan
from links1.tracing.render import render
from links1.scene.scene import Scene
from links1.geometry.shapes import Quadric, TriangleMesh
from links1.maths.transform import look_at, scale, translate
from links1.tracing import occluders


def floor(y=0.0, half=5.0):
    v = np.array([[-half, y, -half], [-half, y, half], [half, y, half], [half, y, -half]], float)
    m = TriangleMesh(v, np.array([[0, 1, 2], [0, 2, 3]]), name="floor")
    m.material = Phong(diffuse=0.6)
    return m


def ball(center, r=1.0):
    q = Quadric("sphere", translate(center) @ scale(r))
    q.material = Phong(diffuse=0.7, specular_=0.2)
    return q


def test_plan_lone_sphere_over_a_floor():
    shapes = [floor(), ball([0, 1, 0])]
    occ, need = shadow_plan(shapes, [PointLight(position=[0, 5, 0])])
    # The floor cannot block a light above it: only the sphere occludes; the sphere (convex)
    # needs no shadow rays, the floor does (the sphere shadows it).
    assert occ[0].tolist() == [False, True]
    assert need[0].tolist() == [True, False]


def test_plan_light_below_the_floor_keeps_it_an_occluder():
    shapes = [floor(), ball([0, 1, 0])]
    occ, need = shadow_plan(shapes, [PointLight(position=[0, -5, 0])])
    assert occ[0].tolist() == [True, True]
    assert need[0].tolist() == [True, True]


def test_skipping_changes_no_pixel_and_saves_rays(monkeypatch):
    def scene():
        shapes = [floor(), ball([0, 1, 0])]
        cam = Camera(to_world=look_at([0, 4, 8], [0, 0.5, 0], [0, 1, 0]), fov_x=45, width=40, height=30)
        lights = [PointLight(position=[2, 6, 3], L1=1.0),
                  ParallelLight(direction=[0.3, -1, -0.2], irradiance=0.5)]
        return Scene(camera=cam, shapes=shapes, lights=lights, max_depth=2)
    img = render(scene(), aovs=("cost",))
    # Reference: a plan where every shape occludes and every hit casts a shadow ray (what the
    # plan avoids), on a new scene (a scene keeps the plan it was first rendered with)
    monkeypatch.setattr(occluders, "shadow_plan", lambda shapes, lights: (
        [np.ones(len(shapes), bool) for _ in lights], [np.ones(len(shapes), bool) for _ in lights]))
    ref = render(scene(), aovs=("cost",))
    np.testing.assert_array_equal(img[..., :3], ref[..., :3])
    assert img[..., 3].sum() < ref[..., 3].sum()  # fewer ray-primitive tests
