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


def headlight_scene(near_ball=False, light_shift=0.0):
    """A floor and two balls seen from (0, 4, 8), a point light at the eye (shifted up by
    ``light_shift``); ``near_ball``: a small ball 0.5 from the eye toward the scene, before a
    near plane 1.5 away."""
    eye = np.array([0.0, 4.0, 8.0])
    cam = Camera(to_world=look_at(eye, [0, 0.5, 0], [0, 1, 0]), fov_x=45, width=40, height=30, near_clip=1.5)
    shapes = [floor(), ball([0, 1, 0]), ball([1.5, 0.5, -1], 0.5)]
    if near_ball:
        d = -eye + [0, 0.5, 0]
        shapes.append(ball(eye + 0.5 * d / np.linalg.norm(d), 0.15))
    lights = [PointLight(position=eye + [0, light_shift, 0], L1=40.0)]
    return Scene(camera=cam, shapes=shapes, lights=lights, max_depth=1)


def test_a_headlight_needs_no_shadow_ray_and_changes_no_pixel(monkeypatch):
    sc = headlight_scene()
    assert occluders.camera_lights_at_eye(sc.camera, sc.shapes, sc.lights) == [True]
    img = render(sc, aovs=("cost",))
    # the reference traces every shadow ray (the rule off), on a new scene
    monkeypatch.setattr(occluders, "camera_lights_at_eye", lambda cam, shapes, lights: [False] * len(lights))
    ref = render(headlight_scene(), aovs=("cost",))
    np.testing.assert_array_equal(img[..., :3], ref[..., :3])
    assert img[..., 3].sum() < ref[..., 3].sum()
    assert img[..., :3].max() > 0.1


def test_the_headlight_rule_keeps_shadows_it_cannot_rule_out():
    # a ball before the near plane: unseen, but it shadows the middle of the view
    sc = headlight_scene(near_ball=True)
    assert occluders.camera_lights_at_eye(sc.camera, sc.shapes, sc.lights) == [False]
    dark = render(sc)[..., :3].sum(-1)
    lit = render(headlight_scene())[..., :3].sum(-1)
    assert np.count_nonzero(dark < 0.5 * lit) > 20
    # a light a millimetre off the eye; a thin lens; an orthographic camera; no position
    sc = headlight_scene(light_shift=1e-3)
    assert occluders.camera_lights_at_eye(sc.camera, sc.shapes, sc.lights) == [False]
    sc = headlight_scene()
    for cam in (Camera(to_world=sc.camera.to_world, aperture_radius=0.1, focus_distance=8.0),
                Camera(to_world=sc.camera.to_world, projection="orthographic")):
        assert occluders.camera_lights_at_eye(cam, sc.shapes, sc.lights) == [False]
    assert occluders.camera_lights_at_eye(sc.camera, sc.shapes, [ParallelLight(direction=[0, -1, 0], irradiance=1.0)]) == [False]


def test_lights_at_eye_by_distance_to_the_boxes():
    eye = np.array([1.0, 2.0, 3.0])
    box = (np.array([1.0, 2.0, 3.5]), np.array([2.0, 3.0, 4.0]))    # 0.5 from the eye
    assert occluders.lights_at_eye(eye, 0.49, [eye, None], [box]) == [True, False]
    assert occluders.lights_at_eye(eye, 0.5, [eye], [box]) == [False]
    assert occluders.lights_at_eye(eye, 0.1, [eye], [(box[0], np.array([2.0, np.inf, 4.0]))]) == [False]
    # equal in float32 is at the eye; one float32 step off is not
    assert occluders.lights_at_eye(eye, 0.1, [eye + 1e-12], [box]) == [True]
    step = np.nextafter(np.float32(3.0), np.float32(4.0))
    assert occluders.lights_at_eye(eye, 0.1, [np.array([1.0, 2.0, float(step)])], [box]) == [False]
