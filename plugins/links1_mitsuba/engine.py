"""The engine of ``links1_whitted``: its configuration (:class:`~.config.Config`) and the parts
it is composed of, each an object with its own declared state.

``Links1Whitted`` (integrator.py) is a thin Mitsuba integrator: it reads its properties into a
:class:`Config`, holds one :class:`Engine` out of :func:`drjit.freeze`'s walk
(:class:`~links1_mitsuba.util.Hidden`) and hands every entry point to it (``render``,
``render_forward``, ``render_backward``, ``traverse``, ``parameters_changed``, the window
API). The engine composes (docs/architecture.md, "How links1_whitted is composed"):

- ``shapes``: :class:`~.sceneshapes.SceneShapes`, the links1 shapes of its scene;
- ``launches``: :class:`~.launch.Launches`, the frozen launches' recordings, the film's batch
  tables, the ray counters;
- ``tables``: :class:`~.tables.Tables`, the per-scene tables and their camera views (given
  ``shapes``, and ``launches`` to start their recordings anew);
- ``gradients``: :class:`~.gradients.Gradients`, the derivative pass and a kept frame (given
  ``shapes``, ``tables``, ``launches``);

and per frame a :class:`~.raytree.Tracer` (the ray tree: ``Config`` and the frame's
:class:`~.tuning.Tuning`), which calls the plain functions of lights.py and intersect.py. An
entry point is a straight script: the switches, the tables, the tracer, the launch. Its state
is read through :meth:`Engine.info`.
"""
from __future__ import annotations

import mitsuba as mi
import numpy as np

from links1.interrupts import interruptible
from links1.tracing.adaptive import render_adaptive_window
from links1.tracing.aovs import channel_names
from links1.tracing.aovs import check_aovs as parse_aovs  # the one AOV table and checker (links1/tracing/aovs.py)

from . import tuning
from .config import Config
from .gradients import Gradients
from .launch import Launches
from .raytree import Tracer
from .sceneshapes import SceneShapes
from .tables import Tables
from .views import render_request


def _config_field(name):
    return property(lambda self: getattr(self.config, name),
                    lambda self, v: setattr(self.config, name, v))


class Engine:
    """What ``links1_whitted`` renders with: its :class:`Config` and its parts, each holding
    its own state (see the module's docstring). Its entry points are straight scripts: the
    frame's switches (:meth:`current_tuning`), the tables (``tables.prepare``), the frame's ray
    tree (a :class:`~.raytree.Tracer`), the launches (or the derivative pass)."""

    __slots__ = (
        "config",       # the integrator's parameters (Config)
        "shapes",       # the links1 shapes of the scene (sceneshapes.SceneShapes)
        "launches",     # the frozen launches, the film's batch tables, the ray counters (launch.Launches)
        "tables",       # the per-scene tables and their camera views (tables.Tables)
        "gradients",    # render_forward / render_backward and a kept derivative frame (gradients.Gradients)
        "own_tuning",   # this engine's switches (tuning.Tuning), or None: the module-wide ones
    )

    # the integrator's parameters, read and set as the engine's too
    max_depth = _config_field("max_depth")
    seed = _config_field("seed")
    min_weight = _config_field("min_weight")
    light_samples = _config_field("light_samples")
    aovs = _config_field("aovs")
    adaptive = _config_field("adaptive")
    adaptive_depth = _config_field("adaptive_depth")
    verify_scene = _config_field("verify_scene")
    use_freeze = _config_field("use_freeze")

    def __init__(self, config: Config, custom_bsdfs=None, shared_bsdfs=()):
        self.config = config
        self.shapes = SceneShapes(custom_bsdfs, shared_bsdfs)
        self.launches = Launches(config)
        self.tables = Tables(config, self.shapes, self.launches)
        self.gradients = Gradients(config, self.shapes, self.tables, self.launches)
        self.own_tuning = None

    def current_tuning(self) -> tuning.Tuning:
        """The switches this engine renders with: its own (``Links1Whitted.tuning = ...``) or,
        without, the module-wide ones (:func:`links1_mitsuba.tuning.current`)."""
        return self.own_tuning if self.own_tuning is not None else tuning.current()

    def set_tuning(self, value):
        """Make ``value`` (a :class:`~.tuning.Tuning`) this engine's switches; None: the
        module-wide ones again. It takes effect at the next frame."""
        if value is not None and not isinstance(value, tuning.Tuning):
            raise TypeError(f"links1_whitted: tuning must be a links1_mitsuba.tuning.Tuning or None, "
                            f"got {type(value).__name__}")
        self.own_tuning = value

    def _tracer(self) -> Tracer:
        """The ray tree of a frame: the integrator's parameters and this frame's switches."""
        return Tracer(self.config, self.current_tuning())

    # -------------------------------------------------------------- the scene's links1 shapes
    def attach(self, custom, slot_of_id, shape_names=None, places=None, shapes=()):
        """Called by the loader: the custom shapes, the file order of all shapes, where each
        object is in the file (for warnings) and the scene's Mitsuba shapes as loaded (their
        vertices: :meth:`.tables.Tables.loaded`); the tables are made anew."""
        self.shapes.attach(custom, slot_of_id, shape_names, places)
        self.tables.forget()
        self.tables.loaded(shapes)

    def adopt(self, scene):
        """A scene the loader did not attach: see :meth:`.sceneshapes.SceneShapes.adopt`."""
        if self.shapes.adopt(scene):
            self.tables.forget()

    def place(self, obj, what: str = "links1_whitted") -> str:
        """``FILE:LINE: <element>`` of a scene object for a warning, else ``what``."""
        return self.shapes.place(obj, what)

    def channels(self):
        return channel_names(self.config.aovs)

    def prepare(self, scene, sensor=None):
        """The tables of ``scene`` seen from ``sensor`` (:meth:`.tables.Tables.prepare`) with this
        frame's switches: a :class:`~.prepared.CameraView`."""
        return self.tables.prepare(scene, sensor, self.current_tuning())

    # -------------------------------------------------------------- the frame
    def render(self, scene, sensor=0, seed=0, spp=0):
        """``Links1Whitted.render``: the frame of ``sensor``'s crop window as a ``mi.TensorXf``."""
        sensor, win, spp, seed = render_request(scene, sensor, seed, spp, self.config.seed)
        if self.config.adaptive is not None:   # refined on the host (links1.tracing.adaptive)
            img = self.render_adaptive(scene, win, seed=seed, sensor=sensor)
            return mi.TensorXf(img.astype(np.float32))
        tuned = self.current_tuning()
        kept = self.gradients.render_keeping_graph(scene, sensor, win, spp, seed, tuned)
        if kept is not None:   # mi.render(scene, params): the derivative pass's frame (gradients.py)
            return kept
        # the frame made on the device and returned as it is (links1_mitsuba.film)
        tables = self.tables.prepare(scene, sensor, tuned)
        return self.launches.render_windows_device(tables, scene, Tracer(self.config, tuned), [win], spp=spp,
                                                   seed=seed, dtype=mi.Float)[0]

    def render_forward(self, scene, params, sensor=0, seed=0, spp=0):
        """See :meth:`links1_mitsuba.gradients.Gradients.render_forward`."""
        return self.gradients.render_forward(scene, params, sensor, seed, spp, self.current_tuning())

    def render_backward(self, scene, params, grad_in, sensor=0, seed=0, spp=0):
        """See :meth:`links1_mitsuba.gradients.Gradients.render_backward`."""
        self.gradients.render_backward(scene, params, grad_in, sensor, seed, spp, self.current_tuning())

    # -------------------------------------------------------------- windows, points
    def render_window(self, scene, window=None, spp=1, seed=None, aovs=None, sensor=None):
        """Render ``window = (x0, y0, w, h)`` of the full film (row 0 at the top).

        Returns a float64 ndarray ``(h, w, 3 + aov channels)``: the pixel's ``spp`` samples
        at the positions of :mod:`links1.maths.sampling` and those of its neighbours within the
        film's reconstruction filter, weighted by it (:mod:`links1.sensor.filters`; box: the mean).
        ``sensor``: an index into ``scene.sensors()`` or a sensor object (None: the first):
        its camera, film size and filter (:meth:`prepare`).
        """
        return self.render_windows(scene, [window], spp=spp, seed=seed, aovs=aovs, sensor=sensor)[0]

    @interruptible
    def render_windows(self, scene, windows, spp=1, seed=None, aovs=None, sensor=None):
        """See :meth:`links1_mitsuba.launch.Launches.render_windows`."""
        tracer = self._tracer()
        tables = self.tables.prepare(scene, sensor, tracer.tuning)
        return self.launches.render_windows(tables, scene, tracer, windows, spp, seed, aovs)

    @interruptible
    def render_windows_device(self, scene, windows, spp=1, seed=None, aovs=None, sensor=None, dtype=None):
        """See :meth:`links1_mitsuba.launch.Launches.render_windows_device`."""
        tracer = self._tracer()
        tables = self.tables.prepare(scene, sensor, tracer.tuning)
        return self.launches.render_windows_device(tables, scene, tracer, windows, spp, seed, aovs, dtype)

    def window_samples(self, scene, window=None, spp=1, seed=None, aovs=None, sensor=None):
        """See :meth:`links1_mitsuba.launch.Launches.window_samples`."""
        tracer = self._tracer()
        tables = self.tables.prepare(scene, sensor, tracer.tuning)
        return self.launches.window_samples(tables, scene, tracer, window, spp, seed, aovs)

    @interruptible
    def trace_points(self, scene, xf, yf, keys, sensor=None):
        """See :meth:`links1_mitsuba.launch.Launches.trace_points` (``sensor``: see
        :meth:`prepare`; None: the scene's first)."""
        tracer = self._tracer()
        tables = self.tables.prepare(scene, sensor, tracer.tuning)
        return self.launches.trace_points(tables, scene, tracer, xf, yf, keys)

    def render_adaptive(self, scene, window=None, seed=None, aovs=None, threshold=None, depth=None,
                        sensor=None):
        """Adaptive anti-aliasing of ``window`` (:func:`links1.tracing.adaptive.render_adaptive_window`,
        as the core): one :meth:`trace_points` launch per refinement level; AOVs depth,
        normal, id at the pixel centres (an spp-1 :meth:`render_window`)."""
        tables = self.prepare(scene, sensor)
        sensor = tables.sensor
        W, H = tables.film_size
        win = (0, 0, W, H) if window is None else tuple(int(v) for v in window)
        seed = self.config.seed if seed is None else int(seed)
        aovs = self.config.aovs if aovs is None else parse_aovs(aovs)
        threshold = self.config.adaptive if threshold is None else threshold
        depth = self.config.adaptive_depth if depth is None else depth
        if threshold is None:
            raise ValueError("links1_whitted: no adaptive threshold (give adaptive=...)")
        return render_adaptive_window(
            lambda xf, yf, keys: self.trace_points(scene, xf, yf, keys, sensor=sensor),
            lambda w, names: self.render_window(scene, w, spp=1, seed=seed, aovs=list(names),
                                                sensor=sensor)[..., 3:],
            win, (W, H), threshold, depth, seed, aovs, rfilter=tables.rfilter)

    # -------------------------------------------------------------- parameters
    def traverse(self, callback, flags):
        """The links1 shapes' parameters (``Links1Whitted.traverse``); ``flags``: Mitsuba's
        ``(differentiable, differentiable | discontinuous)``."""
        self.shapes.traverse(callback, flags)

    def parameters_changed(self, keys):
        """See ``Links1Whitted.parameters_changed``."""
        if self.shapes.parameters_changed() and not self.config.verify_scene:
            self.tables.forget()    # (while verify_scene, the next frame's prepare sees the change
            #                          and makes the shapes' tables again: Tables._update_values)

    # -------------------------------------------------------------- what it made
    @property
    def stats(self):
        """Ray counters of the last render (``Launches.stats``: summed when first read)."""
        return self.launches.stats

    @stats.setter
    def stats(self, v):
        self.launches.stats = v

    @property
    def batches(self) -> dict:
        """The film's batch tables by windows (``Launches.batches``, :func:`.film.cached_batch`)."""
        return self.launches.batches

    @batches.setter
    def batches(self, value):
        self.launches.batches = value

    def info(self) -> dict:
        """What the engine was given and made so far, for tests, tools and benchmarks (its
        inspection API; the engine's other names are its own):

        - ``scene_builds``, ``camera_views``, ``value_updates``: tables built, camera views
          made, in-place updates of the tables (tables.py, views.py);
        - ``tables``: the last prepared camera view (a :class:`~links1_mitsuba.prepared.CameraView`,
          its scene's tables as ``base``; None before the first frame or after :meth:`forget`),
          whose fields :mod:`links1_mitsuba.prepared` documents;
        - ``launch``, ``point_launch``: the frozen window launch and the frozen point launch
          (:func:`drjit.freeze` functions; None until the first, and again after a change
          that starts them anew), ``recordings`` and ``point_recordings`` their recordings
          (0 while None);
        - ``custom_shapes``: the links1 shapes (``QuadricSpec``, ``BlobSpec``), in file order;
        - ``kept_graph``: whether a derivative pass's frame waits for ``render_backward``.

        It reads nothing back from the device (so a test may call it between kernels it
        counts); the ray counters are :attr:`stats`.

        White-box tests may also read (and empty) ``Engine.batches``, the film's batch tables by
        windows (:func:`links1_mitsuba.film.cached_batch`): part of this inspection API."""
        tables, launches = self.tables, self.launches
        recordings, point_recordings = launches.recordings()
        return {"scene_builds": tables.n_scene_builds, "camera_views": tables.n_camera_views,
                "value_updates": tables.n_value_updates,
                "launch": launches.window_launch, "point_launch": launches.point_launch,
                "recordings": recordings, "point_recordings": point_recordings,
                "custom_shapes": tuple(self.shapes.custom),
                "tables": tables.last, "kept_graph": self.gradients.kept_graph is not None}

    def forget(self):
        """Drop what the engine keeps between frames: its prepared tables (the next frame
        prepares them again, as after a change of the parameters they are made from:
        ``MitsubaRenderer``) and a derivative pass's kept frame (gradients.py)."""
        self.tables.forget()
        self.gradients.kept_graph = None

    def shape_slots(self, shapes):
        """``(slot_list, nslots)``: the slot of each of the Mitsuba ``shapes`` (file order, or
        the loader's ``slot_of_id``) and the number of slots, links1 shapes included
        (:meth:`.sceneshapes.SceneShapes.slots`)."""
        return self.shapes.slots(shapes)
