"""The engine of ``links1_whitted``: its configuration (:class:`Config`), its state (the
:class:`Engine`'s declared slots) and the parts that render with them.

``Links1Whitted`` (integrator.py) is a thin Mitsuba integrator: it reads its properties into a
:class:`Config`, holds one :class:`Engine` out of :func:`drjit.freeze`'s walk
(:class:`~links1_mitsuba.util.Hidden`) and hands every entry point to it (``render``,
``render_forward``, ``render_backward``, ``traverse``, ``parameters_changed``, the window
API). The engine is a plain Python class (not a variant's Mitsuba class), so it inherits its
parts as Python classes do: :class:`~links1_mitsuba.tables.Tables` (the per-scene tables),
:class:`~links1_mitsuba.lights.Lights`, :class:`~links1_mitsuba.intersect.Intersect`,
:class:`~links1_mitsuba.raytree.RayTree`, :class:`~links1_mitsuba.launch.Launches`,
:class:`~links1_mitsuba.gradients.Gradients`. Its state is declared once, in ``__slots__``
(a misspelt name is an AttributeError), and read through :meth:`Engine.info`.
"""
from __future__ import annotations

import dataclasses

import mitsuba as mi
import numpy as np

from links1.scene.params import default as l1_default
from links1.scene.params import read as l1_read
from links1.tracing.adaptive import DEFAULT_ADAPTIVE_DEPTH
from links1.tracing.aovs import channel_names
from links1.tracing.aovs import check_aovs as parse_aovs  # the one AOV table and checker (links1/tracing/aovs.py)

from . import geometry, proxies, tuning
from .gradients import Gradients
from .launch import Launches
from .tables import Tables
from .util import place_of


@dataclasses.dataclass
class Config:
    """The integrator's parameters (``links1_whitted``'s properties, docs/guide.md)."""

    #: surface interactions along one branch of the ray tree (primary hit = 1)
    max_depth: int
    #: seed of the sample pattern (links1.maths.sampling)
    seed: int
    #: a secondary ray is traced only if its weight in the pixel exceeds this
    min_weight: float
    #: shadow rays per sampled light per hit
    light_samples: int
    #: the extra channels (links1.tracing.aovs)
    aovs: list
    #: adaptive anti-aliasing threshold (links1.tracing.adaptive) instead of the sampler's count
    adaptive: float | None = None
    adaptive_depth: int = DEFAULT_ADAPTIVE_DEPTH
    #: check the scene's parameters (mi.traverse) before reusing the prepared tables;
    #: MitsubaRenderer, whose scene is its own, turns it off for its launches
    verify_scene: bool = True
    #: render windows through a frozen function (Launches._frozen_fn): no re-tracing
    use_freeze: bool = True
    #: add the visibility (boundary) term to the derivatives (boundary.py)
    projective: bool = False

    @classmethod
    def from_props(cls, props) -> "Config":
        """The parameters of ``props`` checked by the rules the core's reader applies too
        (links1.scene.params)."""
        def param(name, conv):
            return l1_read("links1_whitted", name, conv(props[name]) if name in props else None)
        md = param("max_depth", int)
        if md == -1:
            md = l1_default("links1_whitted", "max_depth")
        if md < 1:
            raise ValueError(f"links1_whitted: max_depth must be >= 1 (or -1), got {md}")
        cfg = cls(max_depth=md, seed=param("seed", int), min_weight=param("min_weight", float),
                  light_samples=param("light_samples", int), aovs=parse_aovs(props.get("aovs", "")),
                  projective=param("projective", bool))
        if "adaptive" in props:
            from links1.tracing.adaptive import check_options
            try:
                cfg.adaptive, cfg.adaptive_depth = check_options(
                    props.get("adaptive"), props.get("adaptive_depth", DEFAULT_ADAPTIVE_DEPTH))
            except Exception as e:
                raise ValueError(f"links1_whitted: {e}") from None
        elif "adaptive_depth" in props:
            raise ValueError("links1_whitted: adaptive_depth needs adaptive")
        return cfg


def _config_field(name):
    return property(lambda self: getattr(self.config, name),
                    lambda self, v: setattr(self.config, name, v))


class Engine(Tables, Launches, Gradients):
    """What ``links1_whitted`` renders with: its :class:`Config`, the scene it was given (the
    links1 shapes) and what it made from it (tables, recordings, counters)."""

    __slots__ = (
        "config",
        # -- the links1 shapes (loader: attach; plain loading: adopt)
        "custom",          # QuadricSpec / BlobSpec, by file order
        "geo",             # the Dr.Jit values of their geometry, by slot (geometry.hold)
        "geo_seen",        # the variables of those values seen last (geometry.seen)
        "custom_bsdfs",    # slot -> the BSDF of a links1 shape
        "shared_bsdfs",    # slots whose BSDF is a top-level object of the file (traverse leaves it out)
        "adopted",         # the ids of the shapes of the scene adopt() made custom of
        "proxy_slots",     # the slots of the proxies among them
        "slot_of_id",      # Mitsuba shape id -> slot (file order), set by the loader
        "shape_names",     # (slot, name, ...) of every shape, set by the loader
        "places",          # object id -> "FILE:LINE: <element>", set by the loader
        # -- made from the scene
        "_prep",           # the last prepared tables (a camera view: prepared.Prepared)
        "_freeze",         # the frozen window launch (Launches._frozen_fn)
        "_freeze_points",  # the frozen point launch (Launches._frozen_points_fn)
        "kept_graph",      # the derivative pass's frame kept for render_backward (gradients.py)
        "batches",         # the film's batch tables by windows (film.cached_batch)
        "stats_now",       # ray counters of the last render, summed
        "stats_pending",   # ... or the launches' counters, summed when first read
        # -- counters (tests and benchmarks read them through info())
        "n_scene_builds", "n_camera_views", "n_value_updates",
        # -- this engine's switches (tuning.Tuning), or None: the module-wide ones
        "own_tuning",
    )

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
        self.custom = []
        self.geo = self.geo_seen = None
        self.custom_bsdfs = dict(custom_bsdfs or {})
        self.shared_bsdfs = set(shared_bsdfs)
        self.adopted = self.proxy_slots = None
        self.slot_of_id = self.shape_names = self.places = None
        self._prep = self._freeze = self._freeze_points = None
        self.kept_graph = None
        self.batches = {}
        self.stats_now = self.stats_pending = None
        self.n_scene_builds = self.n_camera_views = self.n_value_updates = 0
        self.own_tuning = None

    def current_tuning(self) -> tuning.Tuning:
        """The switches this engine renders with: its own (``Links1Whitted.tuning = ...``) or,
        without, the module-wide ones (:func:`links1_mitsuba.tuning.current`)."""
        return self.own_tuning if self.own_tuning is not None else tuning.current()

    # -------------------------------------------------------------- the scene's links1 shapes
    def attach(self, custom, slot_of_id, shape_names=None, places=None):
        """Called by the loader: the custom shapes, the file order of all shapes and where
        each object is in the file (for warnings)."""
        self.custom = list(custom)
        self.geo = {sp.slot: geometry.hold(sp) for sp in self.custom}
        self.geo_seen = {sl: geometry.seen(h) for sl, h in self.geo.items()}
        self.slot_of_id = dict(slot_of_id)
        self.shape_names = shape_names
        self.places = places
        self._prep = None

    def adopt(self, scene):
        """A scene the loader did not attach (``mi.load_file``, ``mi.load_string``,
        ``mi.load_dict``): its links1 shapes are the proxies among its shapes
        (:mod:`links1_mitsuba.proxies`), each shape's slot its place in ``scene.shapes()``,
        and each proxy's BSDF its own (matched by object, never by id). Made again only
        for another scene (or other shapes)."""
        if self.slot_of_id is not None:      # the loader's scene: attach() said it all
            return
        shapes = list(scene.shapes())
        key = tuple(id(s) for s in shapes)
        if self.adopted == key:
            return
        found = proxies.specs_of(shapes)
        self.custom = [sp for _, sp in found]
        self.geo = {sp.slot: geometry.hold(sp) for sp in self.custom}
        self.geo_seen = {sl: geometry.seen(h) for sl, h in self.geo.items()}
        self.custom_bsdfs = {sl: shapes[sl].bsdf() for sl, _ in found}
        self.shared_bsdfs = set(self.custom_bsdfs)    # each proxy's BSDF is named under its shape
        self.proxy_slots = frozenset(sl for sl, _ in found)
        self.adopted = key
        self._prep = None

    def place(self, obj, what: str = "links1_whitted") -> str:
        """``FILE:LINE: <element>`` of a scene object for a warning, else ``what``."""
        return place_of(obj, self.places or {}) or what

    def channels(self):
        return channel_names(self.aovs)

    # -------------------------------------------------------------- the frame
    def render(self, scene, sensor=0, seed=0, spp=0):
        """``Links1Whitted.render``: the frame of ``sensor``'s crop window as a ``mi.TensorXf``."""
        sensor, win, spp, seed = self._render_request(scene, sensor, seed, spp)
        if self.adaptive is not None:   # refined on the host (links1.tracing.adaptive)
            img = self.render_adaptive(scene, win, seed=seed, sensor=sensor)
            return mi.TensorXf(img.astype(np.float32))
        kept = self._render_keeping_graph(scene, sensor, win, spp, seed)
        if kept is not None:   # mi.render(scene, params): the derivative pass's frame (gradients.py)
            return kept
        # the frame made on the device and returned as it is (links1_mitsuba.film)
        return self.render_windows_device(scene, [win], spp=spp, seed=seed, sensor=sensor,
                                          dtype=mi.Float)[0]

    def _render_request(self, scene, sensor, seed, spp):
        """What a ``render``-style call (``mi.render``, ``render_forward``/``_backward``) asks for:
        ``(sensor object, its crop window, spp (the sampler's when 0 or None), the pattern's seed
        = the integrator's seed + the call's)``."""
        sensor = self._sensor_of(scene, sensor)
        film = sensor.film()
        off, size = film.crop_offset(), film.crop_size()
        if spp == 0 or spp is None:
            spp = sensor.sampler().sample_count()
        s = int(seed) if not hasattr(seed, "__len__") else int(np.array(seed).ravel()[0])
        win = (int(off[0]), int(off[1]), int(size[0]), int(size[1]))
        return sensor, win, int(spp), self.seed + s

    # -------------------------------------------------------------- parameters
    def traverse(self, callback, flags):
        """The links1 shapes' parameters (``Links1Whitted.traverse``); ``flags``: Mitsuba's
        ``(differentiable, differentiable | discontinuous)``."""
        names = self._shape_name_of()
        for sl, b in sorted(self.custom_bsdfs.items()):
            if sl in self.shared_bsdfs:   # named by its own id (a top-level BSDF of the file)
                continue
            callback.put(f"{names(sl)}.bsdf", b, flags[0])
        for sp in self.custom:
            held = (self.geo or {}).get(sp.slot)
            for k in geometry.param_names(sp) if held is not None else []:
                callback.put(f"{names(sp.slot)}.{k}", held[k], flags[1])

    def _shape_name_of(self):
        names = {sl: name for sl, name, _ in (self.shape_names or [])}
        return lambda sl: names.get(sl, f"_links1_slot_{sl}")

    def parameters_changed(self, keys):
        """See ``Links1Whitted.parameters_changed``."""
        changed = False
        for i, sp in enumerate(self.custom):
            held = (self.geo or {}).get(sp.slot)
            mine = geometry.changed(held, self.geo_seen[sp.slot]) if held is not None else []
            if mine:
                self.custom[i] = geometry.updated(sp, held, mine)
                self.geo_seen[sp.slot] = geometry.seen(held)
                changed = True
        if changed and not self.verify_scene:
            self._prep = None    # (while verify_scene, the next frame's prepare sees the change
            #                       and makes the shapes' tables again: Tables._update_values)

    # -------------------------------------------------------------- what it made
    @property
    def stats(self):
        """Ray counters of the last render (``Launches._read_stats``: summed when first read)."""
        return self._read_stats()

    @stats.setter
    def stats(self, v):
        self._set_stats(v)

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
        return {"scene_builds": self.n_scene_builds, "camera_views": self.n_camera_views,
                "value_updates": self.n_value_updates,
                "launch": self._freeze, "point_launch": self._freeze_points,
                "recordings": 0 if self._freeze is None else self._freeze.n_recordings,
                "point_recordings": 0 if self._freeze_points is None else self._freeze_points.n_recordings,
                "custom_shapes": tuple(self.custom),
                "tables": self._prep, "kept_graph": self.kept_graph is not None}

    def forget(self):
        """Drop what the engine keeps between frames: its prepared tables (the next frame
        prepares them again, as after a change of the parameters they are made from:
        ``MitsubaRenderer``) and a derivative pass's kept frame (gradients.py)."""
        self._prep = None
        self.kept_graph = None

    def shape_slots(self, shapes):
        """``(slot_list, nslots)``: the slot of each of the Mitsuba ``shapes`` (file order, or
        the loader's ``slot_of_id``) and the number of slots, links1 shapes included
        (``Tables._slots``)."""
        return self._slots(shapes)
