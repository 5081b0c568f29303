"""Camera views of the per-scene tables: a sensor as an object (:func:`sensor_of`), what a
``render``-style call asks for (:func:`render_request`), a sensor's view of the scene's tables
(:func:`camera_view`: a ``prepared.CameraView`` holding camera, film, filter, the eye's light
buffer and reading the rest through the scene's tables; one per sensor, kept with them), its
camera (:func:`set_camera`) and its refresh after a sensor's change (:func:`refresh_cameras`).
Plain functions: ``tables.Tables`` keeps the views (in the scene's tables).
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


def sensor_of(scene, sensor):
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


def render_request(scene, sensor, seed, spp, base_seed):
    """What a ``render``-style call (``mi.render``, ``render_forward``/``_backward``) asks for:
    ``(sensor object, its crop window, spp (the sampler's when 0 or None), the pattern's seed
    = the integrator's ``base_seed`` + the call's)``."""
    sensor = sensor_of(scene, sensor)
    film = sensor.film()
    off, size = film.crop_offset(), film.crop_size()
    if spp == 0 or spp is None:
        spp = sensor.sampler().sample_count()
    s = int(seed) if not hasattr(seed, "__len__") else int(np.array(seed).ravel()[0])
    win = (int(off[0]), int(off[1]), int(size[0]), int(size[1]))
    return sensor, win, int(spp), base_seed + s


def camera_view(base, scene, sensor, verify, place):
    """The scene's tables ``base`` with ``sensor``'s camera, film and filter (a
    :class:`CameraView`: it reads every other field through ``base``), one per sensor and kept
    with ``base``, and whether it was made now. A sensor that is not one of the scene's is
    watched (:class:`ParamWatch`) while ``verify`` (``Config.verify_scene``), as the scene is;
    ``place``: where an object is in the file, for errors."""
    own = any(sensor is s for s in base.keep_alive[2])
    check = verify and not own
    view = base.views.get(id(sensor))
    if (view is not None and view.sensor is sensor and (view.sensor_watch is not None) == check
            and (not check or view.sensor_watch.unchanged(sensor))):
        return view, False
    view = CameraView()
    view.base = base
    view.sensor_watch = ParamWatch(sensor) if check else None
    set_camera(view, sensor, place)
    # light buffer around a pinhole camera's eye for the camera rays' nearest quadric
    view.eye_buf = lightbuffer.plan_eye(view, scene) if base.tuning.light_buffer else None
    base.views[id(sensor)] = view     # view keeps the sensor alive: its id is not reused
    return view, True


def sensor_owning(base, node):
    """The sensor of the scene's tables ``base`` that ``node`` (a changed parameter's object,
    ``ParamWatch.changed``) is or whose film it is; None for any other object."""
    for s in base.keep_alive[2]:
        if node is s or (isinstance(node, mi.Film) and node is s.film()):
            return s
    return None


def refresh_cameras(base, scene, sensors, geo, place) -> bool:
    """The camera views of ``sensors`` (the scene's, :func:`sensor_owning`) brought up to
    their sensors' values in place (``Tables._update_values``): camera, film and filter read
    again (:func:`set_camera`), the eye buffer planned again where the eye moved or turned (unless
    ``geo``: the caller plans every view's), the launch's inputs gathered again. The
    scene's tables are kept. Whether a view's camera changed (the frozen launches' kernels
    hold it as constants); a crop window alone changes none."""
    moved = False
    for s in sensors:
        view = base.views.get(id(s))
        if view is None or view.sensor is not s:
            continue          # no view yet: made at prepare
        old = _camera_of(view)
        set_camera(view, s, place)
        now = _camera_of(view)
        if now == old:
            continue
        moved = True
        if not geo and now[-1] != old[-1]:
            view.eye_buf = lightbuffer.plan_eye(view, scene) if base.tuning.light_buffer else None
        view.frozen_inputs = None
    return moved


def set_camera(view, sensor, place):
    """The camera of ``view``: ``sensor``'s film size, filter, projection and matrix (``place``:
    where an object is in the file, for errors)."""
    film = sensor.film()
    view.sensor = sensor
    view.film_size = (int(film.size()[0]), int(film.size()[1]))
    view.rfilter = Filter.from_mitsuba(film.rfilter())
    # perspective and orthographic rays are made analytically (camera.py: rays_at) from
    # the sensor's matrix, clip distances and field of view: the same rays as Mitsuba's
    kind = kind_of(sensor)
    view.lens = None
    if kind == "ThinLensCamera":   # depth of field (camera.py: rays_at)
        view.lens = tuple(float(np.array(own_param(sensor, k)).ravel()[0])
                          for k in ("aperture_radius", "focus_distance"))
        if not (abs(view.lens[0]) <= MAX_EXTENT and 0 < view.lens[1] <= MAX_EXTENT):
            raise ValueError(f"{place(sensor)}: thinlens: 'aperture_radius' must be finite, "
                             f"'focus_distance' > 0, both <= {MAX_EXTENT:g} in magnitude, got {view.lens}")
    view.projection = {"PerspectiveCamera": "perspective", "ThinLensCamera": "perspective",
                       "OrthographicCamera": "orthographic"}.get(kind)
    view.perspective = view.projection == "perspective"
    if view.projection is not None:
        if view.perspective:
            view.x_fov = float(np.array(own_param(sensor, "x_fov")).ravel()[0])
        view.cam = np.array(sensor.world_transform().matrix, dtype=np.float64).reshape(4, 4)
        view.near, view.far = float(sensor.near_clip()), float(sensor.far_clip())
    else:
        raise ValueError(f"links1_whitted renders perspective, thinlens and orthographic sensors, "
                         f"not {kind}")


def _camera_of(view):
    """What the kernels and the eye buffer read of a view's camera, comparable with ``==``
    (what :func:`lightbuffer.plan_eye` depends on last: the eye's place, the camera's frame,
    field of view and film, over which its grid lies)."""
    cam = np.asarray(view.cam, dtype=np.float64)
    return (view.film_size, view.rfilter, view.projection, view.x_fov, view.near, view.far,
            cam.tobytes(), (view.perspective, view.lens, cam.tobytes(), view.x_fov, view.film_size))
