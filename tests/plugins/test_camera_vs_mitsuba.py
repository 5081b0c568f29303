"""Camera conventions: the core's pixel -> ray mapping equals Mitsuba's perspective sensor."""
from __future__ import annotations

import numpy as np
import pytest

from links1.sensor.camera import Camera, fov_x_from
from links1.maths.transform import look_at

mi = pytest.importorskip("mitsuba", reason="mitsuba is not installed")
pytestmark = pytest.mark.mitsuba


def mitsuba_rays(sensor, xy):
    """Mitsuba's rays through film points ``xy`` (n, 2): origins, directions (n, 3), maxt."""
    ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(xy[:, 0], xy[:, 1]), mi.Point2f(0.5, 0.5))
    rows = lambda a: a.T if a.shape[0] == 3 else a  # noqa: E731
    return rows(np.array(ray.o)), rows(np.array(ray.d)), np.array(ray.maxt)


@pytest.mark.parametrize("fov_axis", ["x", "y", "diagonal", "smaller", "larger"])
@pytest.mark.parametrize("size", [(64, 48), (30, 70)])
def test_rays_match_mitsuba_sensor(variant, fov_axis, size):
    w, h = size
    origin, target, up = [1.0, 2.0, 6.0], [0.2, 0.5, -1.0], [0.1, 1.0, 0.0]
    sensor = mi.load_dict({
        "type": "perspective", "fov": 50.0, "fov_axis": fov_axis, "near_clip": 0.5, "far_clip": 300.0,
        "to_world": mi.ScalarTransform4f().look_at(origin=origin, target=target, up=up),
        "film": {"type": "hdrfilm", "width": w, "height": h},
    })
    cam = Camera(to_world=look_at(origin, target, up), fov_x=fov_x_from(50.0, fov_axis, w, h),
                 near_clip=0.5, far_clip=300.0, width=w, height=h)
    rng = np.random.default_rng(3)
    xy = np.concatenate([rng.random((200, 2)), [[0.5, 0.5], [0.0, 0.0], [1.0, 1.0], [0.0, 1.0]]])
    o_mi, d_mi, maxt_mi = mitsuba_rays(sensor, xy)
    o, d, tmin, tmax = cam.generate_rays(xy[:, 0], xy[:, 1])
    np.testing.assert_allclose(d, d_mi, atol=2e-6)
    # Mitsuba starts the ray on the near plane: o_mi = o + tmin d
    np.testing.assert_allclose(o + tmin[:, None] * d, o_mi, atol=2e-5)
    np.testing.assert_allclose(tmax - tmin, maxt_mi, rtol=2e-5)


@pytest.mark.parametrize("size", [(64, 48), (30, 70)])
def test_orthographic_rays_match_mitsuba_sensor(variant, size):
    """The orthographic sensor: the film on the near plane of a scaled camera frame."""
    w, h = size
    origin, target, up = [1.0, 2.0, 6.0], [0.2, 0.5, -1.0], [0.1, 1.0, 0.0]
    to_world = mi.ScalarTransform4f().look_at(origin=origin, target=target, up=up) @ \
        mi.ScalarTransform4f().scale([2.0, 3.0, 1.5])
    sensor = mi.load_dict({"type": "orthographic", "near_clip": 0.5, "far_clip": 300.0, "to_world": to_world,
                           "film": {"type": "hdrfilm", "width": w, "height": h}})
    cam = Camera(to_world=np.array(to_world.matrix, dtype=np.float64).reshape(4, 4), near_clip=0.5,
                 far_clip=300.0, width=w, height=h, projection="orthographic")
    rng = np.random.default_rng(4)
    xy = np.concatenate([rng.random((200, 2)), [[0.5, 0.5], [0.0, 0.0], [1.0, 1.0], [0.0, 1.0]]])
    o_mi, d_mi, maxt_mi = mitsuba_rays(sensor, xy)
    o, d, tmin, tmax = cam.generate_rays(xy[:, 0], xy[:, 1])
    np.testing.assert_allclose(d, np.broadcast_to(d_mi, d.shape), atol=2e-6)   # one direction
    np.testing.assert_allclose(o + tmin[:, None] * d, o_mi, atol=2e-5)
    np.testing.assert_allclose(tmax - tmin, np.broadcast_to(maxt_mi, tmax.shape), rtol=2e-5)
    # parallel rays, and the film's corners 2 x 2/aspect scaled units apart on the near plane
    assert np.allclose(d, d[0], atol=1e-12)
    o00, o10 = cam.generate_rays(np.array([0.0, 1.0]), np.array([0.0, 0.0]))[0]
    assert np.isclose(np.linalg.norm(o00 - o10), 2 * 2.0)
