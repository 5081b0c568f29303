"""Camera views of the per-scene tables: a sensor as an object (:meth:`CameraViews._sensor_of`),
its view of the scene's tables (:meth:`CameraViews._camera_view`: a ``prepared.CameraView``
holding camera, film, filter, the eye's light buffer and reading the rest through the scene's
tables; one per sensor, kept with them) and its camera
(:meth:`CameraViews._set_camera`). A base class of ``tables.Tables``.
"""
from __future__ import annotations

import mitsuba as mi
import numpy as np

from links1.scene.params import MAX_EXTENT
from links1.sensor.filters import Filter

from . import lightbuffer
from .paramwatch import ParamWatch, own_param
from .prepared import CameraView
from .util import kind_of


class CameraViews:
    """A sensor's view of the scene's tables."""

    __slots__ = ()

    def _sensor_of(self, scene, sensor):
        """``sensor`` as a sensor object: an index into ``scene.sensors()`` (None: 0) or the
        object itself (a sensor of the scene or one made apart, ``mi.load_dict``)."""
        if sensor is None or isinstance(sensor, (int, np.integer)):
            sensors = scene.sensors()
            k = 0 if sensor is None else int(sensor)
            if not 0 <= k < len(sensors):
                raise IndexError(f"links1_whitted: sensor {k} does not exist: the scene has "
                                 f"{len(sensors)} sensor{'s' if len(sensors) != 1 else ''}")
            return sensors[k]
        if not isinstance(sensor, mi.Sensor):
            raise TypeError(f"links1_whitted: sensor must be an index or a mitsuba Sensor, got "
                            f"{type(sensor).__name__}")
        return sensor

    def _camera_view(self, B, scene, sensor):
        """The tables ``B`` with ``sensor``'s camera, film and filter (a :class:`CameraView`:
        it reads every other field through ``B``), one per sensor and kept with ``B``. A sensor
        that is not one of the scene's is watched (:class:`ParamWatch`) while
        ``verify_scene``, as the scene is."""
        own = any(sensor is s for s in B.keep_alive[2])
        check = self.verify_scene and not own
        V = B.views.get(id(sensor))
        if (V is not None and V.sensor is sensor and (V.sensor_watch is not None) == check
                and (not check or V.sensor_watch.unchanged(sensor))):
            return V
        V = CameraView()
        V.base = B
        V.sensor_watch = ParamWatch(sensor) if check else None
        self.n_camera_views += 1
        self._set_camera(V, sensor)
        # light buffer around a pinhole camera's eye for the camera rays' nearest quadric
        V.eye_buf = lightbuffer.plan_eye(V, scene) if B.tuning.light_buffer else None
        B.views[id(sensor)] = V     # V keeps the sensor alive: its id is not reused
        return V

    @staticmethod
    def _sensor_owning(B, node):
        """The sensor of the scene's tables ``B`` that ``node`` (a changed parameter's object,
        ``ParamWatch.changed``) is or whose film it is; None for any other object."""
        for s in B.keep_alive[2]:
            if node is s or (isinstance(node, mi.Film) and node is s.film()):
                return s
        return None

    def _refresh_cameras(self, B, scene, sensors, geo) -> bool:
        """The camera views of ``sensors`` (the scene's, :meth:`_sensor_owning`) brought up to
        their sensors' values in place (``Tables._update_values``): camera, film and filter read
        again (:meth:`_set_camera`), the eye buffer planned again where the eye moved (unless
        ``geo``: the caller plans every view's), the launch's inputs gathered again. The
        scene's tables are kept. Whether a view's camera changed (the frozen launches' kernels
        hold it as constants); a crop window alone changes none."""
        moved = False
        for s in sensors:
            V = B.views.get(id(s))
            if V is None or V.sensor is not s:
                continue          # no view yet: made at prepare
            old = _camera_of(V)
            self._set_camera(V, s)
            now = _camera_of(V)
            if now == old:
                continue
            moved = True
            if not geo and now[-1] != old[-1]:
                V.eye_buf = lightbuffer.plan_eye(V, scene) if B.tuning.light_buffer else None
            V.frozen_inputs = None
        return moved

    def _set_camera(self, P, sensor):
        """The camera of ``P``: ``sensor``'s film size, filter, projection and matrix."""
        film = sensor.film()
        P.sensor = sensor
        P.film_size = (int(film.size()[0]), int(film.size()[1]))
        P.rfilter = Filter.from_mitsuba(film.rfilter())
        # perspective and orthographic rays are made analytically (launch.py: _rays_at) from
        # the sensor's matrix, clip distances and field of view: the same rays as Mitsuba's
        kind = kind_of(sensor)
        P.lens = None
        if kind == "ThinLensCamera":   # depth of field (launch.py: _rays_at)
            P.lens = tuple(float(np.array(own_param(sensor, k)).ravel()[0])
                           for k in ("aperture_radius", "focus_distance"))
            if not (abs(P.lens[0]) <= MAX_EXTENT and 0 < P.lens[1] <= MAX_EXTENT):
                raise ValueError(f"{self.place(sensor)}: thinlens: 'aperture_radius' must be finite, "
                                 f"'focus_distance' > 0, both <= {MAX_EXTENT:g} in magnitude, got {P.lens}")
        P.projection = {"PerspectiveCamera": "perspective", "ThinLensCamera": "perspective",
                        "OrthographicCamera": "orthographic"}.get(kind)
        P.perspective = P.projection == "perspective"
        if P.projection is not None:
            if P.perspective:
                P.x_fov = float(np.array(own_param(sensor, "x_fov")).ravel()[0])
            P.cam = np.array(sensor.world_transform().matrix, dtype=np.float64).reshape(4, 4)
            P.near, P.far = float(sensor.near_clip()), float(sensor.far_clip())
        else:
            raise ValueError(f"links1_whitted renders perspective, thinlens and orthographic sensors, "
                             f"not {kind}")


def _camera_of(V):
    """What the kernels and the eye buffer read of a view's camera, comparable with ``==``
    (the eye's place, what :func:`lightbuffer.plan_eye` depends on, last)."""
    cam = np.asarray(V.cam, dtype=np.float64)
    return (V.film_size, V.rfilter, V.projection, V.x_fov, V.near, V.far, cam.tobytes(),
            (V.perspective, V.lens, cam[:3, 3].tobytes()))
