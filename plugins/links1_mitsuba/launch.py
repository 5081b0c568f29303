"""The launch machinery of ``links1_whitted`` (its one home): camera rays of any pixel set,
the :func:`drjit.freeze` launch replayed for any window, batch size or spp, and the frame made
on the device from its samples (:mod:`.film`); numpy only where a caller asks for it
(:meth:`Launches.render_windows`' float64 arrays, :meth:`Launches.trace_points` of adaptive
anti-aliasing).

:class:`Launches` owns what the launches keep between frames (the frozen launches' recordings,
the film's batch tables, the ray counters); the engine (engine.py) hands each call the tables
to render (``Tables.prepare``), the scene and the frame's ray tree (:class:`~.raytree.Tracer`).
The camera rays are :mod:`.camera`'s. Its methods name ``mi.Float``, ``mi.Ray3f``, ... when
called, so the class serves every Mitsuba variant.
"""
from __future__ import annotations

import dataclasses
import gc

import drjit as dr
import mitsuba as mi
import numpy as np

from links1.interrupts import check_interrupt, interruptible
from links1.tracing.aovs import check_aovs as parse_aovs  # the one AOV table and checker (links1/tracing/aovs.py)
from links1.maths.sampling import key_seed, strata

from .camera import camera_rays, rays_at
from .config import Config
from .film import Batch, cached_batch, concat, reconstruct, sample_ids, sample_window, widen
from .raytree import Tracer
from . import raytree_ad
from .raytree_ad import hits, trace_tree_ad
from .util import Hidden, aligned

#: Most samples (lanes) per launch of the window function; more are split into launches.
LAUNCH_LANES = 1 << 22

#: A render keeps the per-lane ray counters its tracing kernels wrote (no reduction kernel)
#: for this many lanes in all, and sums them only when ``stats`` is read
#: (``Launches._launch_counts``); the launches past it have theirs summed on the device at the
#: render's end (``Launches._set_stats``; memory: up to 6 bytes a lane are kept after the
#: frame). One launch of a frame fits (``LAUNCH_LANES``).
LAZY_COUNT_LANES = LAUNCH_LANES

#: The launches hand the ray tree their camera rays as a function of the lanes too
#: (``Tracer.trace_tree``'s ``rays``), so that its camera level stores the hits of the samples
#: with children, not the children (False: it stores the children; before/after runs). Read
#: when a launch is recorded: a frozen launch keeps what it was recorded with
REMAKE = True
#: the camera rays' hits of a derivative pass (:meth:`Launches.seeing_hits`) take the window's
#: batch and sample ids from the launches' cache, which the pass's window then takes too
#: (False: a batch of their own, its sample ids made anew every pass)
SEEING_BATCH_CACHED = True


def _columns(v, n=None):
    """(N, 3) float32 numpy array of a Dr.Jit 3-vector (or of a flat, interleaved Float).

    A 3-vector is read one component at a time: converting it whole runs a packing kernel
    whose strides (the window size) are literals, i.e. one compile per window size."""
    import drjit as dr
    if dr.size_v(v) == 3:
        n = dr.width(v) if n is None else n
        return np.stack([np.asarray(_lanes(v[k], n), dtype=np.float32) for k in range(3)], axis=1)
    return np.asarray(v.numpy(), dtype=np.float32).reshape(-1, 3)


def _lanes(v, n):
    """numpy copy of a Dr.Jit array with ``n`` lanes (a kernel output) or of a literal (one
    value; a frozen function returns literals at their recorded width): broadcast to ``n``."""
    a = np.asarray(v.numpy())
    return a if a.shape[0] == n else np.broadcast_to(a[:1], (n,) + a.shape[1:])


class SceneInputs:
    """The part of a Mitsuba scene that the frozen launches read, as :func:`drjit.freeze` input.

    Freeze walks every input on every call. Given the scene, it walks the scene's object tree
    (each shape, emitter and sensor once as a member and again among the scene's children:
    fig11 yields 690 variables, 241 distinct) and then, for the registry domains of the
    pointer arrays it met (shapes, emitters, sensors), every registered object again: 0.16-0.21
    ms a launch on fig11, many, mitsuba_glass. The launches make camera rays themselves and
    never read the sensors (their film, sampler: 79 variables). So this input hands freeze the
    scene's variables once each, without the sensors' ones and without the sensor pointer
    array (whose domain would make freeze walk every registered sensor): 0.06-0.10 ms.
    The shape and emitter pointer arrays keep their registry domains, so freeze still walks
    the registered shapes and emitters that Dr.Jit's calls through those arrays may reach.

    The scene's variables are collected once (through its ``_traverse_1_cb_ro``, the walk
    freeze itself makes); they stay valid while the scene is not changed, i.e. for one set of
    prepared tables (``tables.scene_input``: rebuilt with them). A recording that reads a variable
    outside this set fails in Dr.Jit ("... was not specified as an input variable"); the
    launch then records with the whole scene instead (:meth:`Launches._call_frozen`). It holds
    the variables, not the scene: the scene owns the integrator, which holds the tables
    (a reference cycle through C++ objects would keep every scene and its registered
    objects alive).
    """

    __slots__ = ("items", "held", "stale")

    def __init__(self, scene, extra=(), skip=()):
        import drjit as dr

        def collect(obj):
            out = []
            with dr.scoped_set_flag(dr.JitFlag.EnableObjectTraversal, True):
                obj._traverse_1_cb_ro(lambda index, variant, domain: out.append((index, variant, domain)))
            return out

        used = {i for objs in (scene.shapes(), scene.emitters()) for o in objs for i, _, _ in collect(o)}
        camera_only = {i for s in scene.sensors() for i, _, _ in collect(s)} - used
        # objects whose values the launches never read (``skip``: the links1_phong BSDFs of a
        # scene whose BSDFs are all links1_phong: the kernels read their tables, never call them),
        # so that a new coefficient (``Tables._update_values``) leaves this input as it is
        camera_only |= {i for o in skip for i, _, _ in collect(o)}
        items = {}
        # an extra scene's own items 1 and 2 (Mitsuba 3.9.1's Scene traversal: two scene-level
        # values equal to the main scene's) are not read by its ray tests, and freeze merges
        # them with the main scene's, handing back other variables (the whole scene each call
        # then); a ray test that did read one fails to record and falls back (_call_frozen)
        for index, variant, domain in [x for sc in (scene, *extra) for k, x in enumerate(collect(sc))
                                       if sc is scene or k not in (1, 2)]:
            if index not in camera_only and domain != "Sensor":
                items.setdefault(index, (index, variant, domain))
        self.items = tuple(items.values())
        #: a reference to each of those variables (one array per index, whatever its type:
        #: never read), so that none is freed while this input lives: a scene object that
        #: replaces a buffer (a mesh's ``parameters_changed``) frees the old one, and a freed
        #: index handed to freeze aborts the process
        self.held = dr.detail.update_indices([mi.Float() for _ in self.items], [i for i, _, _ in self.items])
        #: freeze handed back another variable for one of them (it would update the scene's
        #: own): the launches of these tables take the whole scene from then on
        self.stale = False

    def _traverse_1_cb_ro(self, fn):
        for item in self.items:
            fn(*item)

    def _traverse_1_cb_rw(self, fn):
        for item in self.items:
            if fn(*item) != item[0]:
                self.stale = True


#: ``tables.scene_input`` when a recording needed more than :class:`SceneInputs` holds
_WHOLE_SCENE = "whole scene"


def _unread_bsdfs(tables) -> list:
    """The BSDFs whose values no launch of ``tables`` reads: every one when all are
    ``links1_phong`` (the kernels read the material tables and never call a BSDF), else none."""
    if not tables.all_phong or tables.any_mitsuba_emission:
        return []
    return [b for b in tables.keep_alive[3] if b is not None]


def _extra_scenes(tables) -> tuple:
    """The Mitsuba scenes besides the scene itself that the launches trace rays in (the
    shadow rays' sub-scenes, ``shadow_plan.shadow_split``): frozen inputs too."""
    split = getattr(tables, "shadow_split", None)
    if split is None:
        return ()
    return tuple(x for x in [split["opaque"], *[t[0] for t in split["trans"]]] if x is not None)


def _ray_counts(spp, seed):
    """``(spp_, seeds)``, what a launch's camera rays take (``camera.camera_rays``) as opaque
    ``UInt32`` (one kernel for every count and seed): ``(spp, strata(spp))`` and ``(seed``'s
    low 32 bits, ``key_seed(seed))``."""
    spp = int(spp)
    return ((dr.opaque(mi.UInt32, spp), dr.opaque(mi.UInt32, strata(spp))),
            (dr.opaque(mi.UInt32, seed & 0xFFFFFFFF), dr.opaque(mi.UInt32, key_seed(seed))))


def _rays_of(tables, sid, spp, seeds):
    """``Tracer.trace_tree``'s ``rays``: the camera rays (``camera.camera_rays``: ``o, d, tmin,
    tmax, key``) of the lanes ``idx`` of the sample ids ``sid``."""
    if not REMAKE:
        return None
    return lambda idx: camera_rays(tables, dr.gather(mi.UInt32, sid, idx), spp, seeds)[:5]


def _between_launches():
    """Wait for the launch just made, then raise ``KeyboardInterrupt`` if Ctrl-C came meanwhile
    (the render methods hold SIGINT, :func:`links1.interrupts.held_interrupts`): a render of
    many launches stops after the one in flight (fig11 at 2048², 16 spp: 16 launches of
    ``LAUNCH_LANES`` samples, ~1.3 s each here), not at its end."""
    dr.sync_thread()
    check_interrupt()


def frozen_inputs(tables):
    """Every Dr.Jit array the trace reads from the per-scene tables (the frozen
    function must receive them as inputs), gathered once per ``tables``: the fields of ``tables``
    (a slotted dataclass, :class:`~links1_mitsuba.prepared.Prepared`) and what they hold
    through dicts, lists, tuples and objects' ``__dict__``. An object with its own traversal
    callbacks is not walked, as freeze walks it through them: a
    :class:`~links1_mitsuba.util.Hidden` (``ParamWatch``: nothing) or :class:`SceneInputs`
    (the launch's scene input)."""
    if getattr(tables, "frozen_inputs", None) is None:
        found, seen = [], set()

        def walk(x, depth=0):
            if depth > 12 or id(x) in seen:
                return
            seen.add(id(x))
            if dr.is_array_v(x):
                found.append(x)
            elif isinstance(x, dict):
                for v in x.values():
                    walk(v, depth + 1)
            elif isinstance(x, (list, tuple)):
                for v in x:
                    walk(v, depth + 1)
            elif hasattr(x, "_traverse_1_cb_ro"):
                pass   # an object that hands freeze its own variables (Hidden: none)
            elif hasattr(x, "__dict__") and not isinstance(x, (mi.Object, type)) \
                    and not callable(x):
                for v in vars(x).values():
                    walk(v, depth + 1)
            elif dataclasses.is_dataclass(x) and not isinstance(x, type):
                # a dataclass with slots (prepared.Prepared): its fields that are set
                for f in dataclasses.fields(x):
                    walk(getattr(x, f.name, None), depth + 1)
        walk(tables)
        tables.frozen_inputs = found
    return tables.frozen_inputs


def literal_key(parts) -> tuple:
    """What the frozen launches' kernels may take as literals from ``parts`` (some of the
    tables: those made from the links1 shapes' geometry, ``Tables._update_values``), as one
    hashable value. A recording holds the Python values a trace read as constants of its
    kernels, and :func:`drjit.freeze` keys only its inputs' layout; so while this key is
    unchanged a recording replays for new arrays of the same tables, and when it changes
    the recordings must start anew (``Launches.forget``).

    Walked as :func:`frozen_inputs` walks the tables: Python scalars and numpy arrays by
    value, Dr.Jit arrays by type and width (a trace that reads ``dr.width`` of a table makes
    it a literal: the blob hierarchy's node count), containers and objects by their contents,
    a links1 shape by its own ``literals()`` and the widths of its tables; Mitsuba objects by
    identity; objects with their own traversal callbacks (``Hidden``) not at all."""
    memo, open_ = {}, set()

    def walk(x, depth=0):
        if dr.is_array_v(x):
            return (type(x).__name__, dr.width(x))
        if x is None or isinstance(x, (bool, int, float, str)):
            return x
        if isinstance(x, np.generic):
            return x.item()
        if isinstance(x, np.ndarray):
            return (x.dtype.str, x.shape, x.tobytes())
        if isinstance(x, (mi.Object, type)) or callable(x):
            return ("object", id(x))
        if hasattr(x, "_traverse_1_cb_ro"):
            return ("traversed", type(x).__name__)
        k = id(x)
        if k in memo:            # (a BVH's specs, in the shadow plan's lists too: met again)
            return memo[k]
        if k in open_ or depth > 12:
            return ("cycle", type(x).__name__)
        open_.add(k)
        if isinstance(x, dict):
            out = ("dict", tuple((walk(a, depth + 1), walk(v, depth + 1)) for a, v in x.items()))
        elif isinstance(x, (list, tuple)):
            out = (type(x).__name__, tuple(walk(v, depth + 1) for v in x))
        elif isinstance(x, (set, frozenset)):
            out = ("set", tuple(sorted((walk(v, depth + 1) for v in x), key=repr)))
        elif callable(getattr(x, "literals", None)) and callable(getattr(x, "tables", None)):
            out = (type(x).__name__, x.literals(), walk(x.tables(), depth + 1))
        elif dataclasses.is_dataclass(x) and not hasattr(x, "__dict__"):
            out = (type(x).__name__, tuple((f.name, walk(getattr(x, f.name, None), depth + 1))
                                           for f in dataclasses.fields(x)))
        elif hasattr(x, "__dict__"):
            out = (type(x).__name__, tuple((a, walk(v, depth + 1)) for a, v in vars(x).items()))
        else:
            out = ("object", id(x))
        open_.discard(k)
        memo[k] = out
        return out

    return walk(parts)


class Launches:
    """The launches of one engine: the frozen window and point launches (their recordings),
    the film's batch tables and the ray counters of the last render. Each call is given the
    camera view of the tables to render (``tables``, from ``Tables.prepare``), the scene and the
    frame's :class:`~.raytree.Tracer`; ``config`` (:class:`~.config.Config`) gives the defaults
    (seed, AOVs) and whether to freeze."""

    __slots__ = (
        "config",
        "window_launch",   # the frozen window launch (:meth:`_frozen_fn`), or None
        "point_launch",    # the frozen point launch (:meth:`_frozen_points_fn`), or None
        "stage_launches",  # the boundary term's frozen stages by function (:meth:`frozen_stage`)
        "batches",         # the film's batch tables by windows (film.cached_batch)
        "stats_now",       # ray counters of the last render, summed
        "stats_pending",   # ... or the launches' counters, summed when first read
    )

    def __init__(self, config: Config):
        self.config = config
        self.window_launch = self.point_launch = None
        self.stage_launches = {}
        self.batches = {}
        self.stats_now = self.stats_pending = None

    def forget(self):
        """Start both frozen launches anew: called by the tables (tables.py) when the ones
        recorded read tables that were replaced (their key names the tables by ``id``, and a
        new one may get a dead one's) or constants of their kernels changed (lights, camera;
        of the tables made from the links1 shapes' geometry, what :func:`literal_key` holds);
        the boundary term's stages with them."""
        self.window_launch = self.point_launch = None
        self.stage_launches = {}

    def recordings(self) -> tuple:
        """``(window, point)``: the recordings of the frozen launches (0 while there is none)."""
        return tuple(0 if f is None else f.n_recordings for f in (self.window_launch, self.point_launch))

    # -------------------------------------------------------------- ray counters
    def _counts(self, n, nsh1, cr=None, ct=None, nr=None, nt=None, nsh2=None):
        """Ray counters of one launch of ``n`` camera rays (rays by kind; ``cr``, ``ct``: which
        camera rays have a mirror and a refraction child, of every lane or of the compacted
        ones: ``Tracer.trace_tree``)."""
        tot = lambda a: 0 if a is None else int(np.sum(_lanes(a, dr.width(a)), dtype=np.int64))  # noqa: E731
        w = 0 if cr is None else max(dr.width(cr), dr.width(ct))
        return {"camera": int(n), "shadow": tot(nsh1) + tot(nsh2), "reflect": tot(cr) + tot(nr),
                "refract": tot(ct) + tot(nt),
                "secondary_lanes": int(np.count_nonzero(_lanes(cr, w) | _lanes(ct, w))) if cr is not None else 0}

    def _launch_counts(self, n, counters):
        """A launch's ray counters for :meth:`_set_stats`: the launch's arrays (outputs of its
        tracing kernels), summed only when ``stats`` is read: no reduction kernel a frame."""
        return (n, counters)

    def _device_counts(self, n, counters):
        """A launch's counters summed on the device at once (``dr.sum``, no read-back: ``stats``
        reads the sums)."""
        def tot(a):
            return 0 if a is None else dr.sum(mi.UInt64(dr.select(a, 1, 0)) if dr.is_mask_v(a) else mi.UInt64(a))
        c = {k: counters.get(k) for k in ("nsh1", "cr", "ct", "nr", "nt", "nsh2")}
        w = 0 if c["cr"] is None else max(dr.width(c["cr"]), dr.width(c["ct"]))
        sec = 0 if c["cr"] is None else tot(widen(c["cr"], w) | widen(c["ct"], w))
        return ("device", {"camera": int(n), "shadow": tot(c["nsh1"]) + tot(c["nsh2"]),
                           "reflect": tot(c["cr"]) + tot(c["nr"]), "refract": tot(c["ct"]) + tot(c["nt"]),
                           "secondary_lanes": sec})

    def _set_stats(self, counts):
        """``self.stats`` (read through :meth:`_read_stats`): the counters of the last
        render's launches (a list of :meth:`_launch_counts`) summed, and per camera ray; or
        the dict ``counts`` itself. The launches' arrays past ``LAZY_COUNT_LANES`` lanes of
        the render are summed on the device now (the memory kept after the frame)."""
        pending = isinstance(counts, list)
        if pending:
            lanes = 0
            for q, c in enumerate(counts):
                if isinstance(c, tuple) and c[0] != "device":
                    lanes += c[0]
                    if lanes > LAZY_COUNT_LANES:
                        counts[q] = self._device_counts(*c)
        self.stats_now = None if pending else counts
        self.stats_pending = counts if pending else None

    def _read_stats(self):
        pending = self.stats_pending
        if pending:
            counts = [c if not isinstance(c, tuple) else
                      {k: int(v if isinstance(v, int) else v[0]) for k, v in c[1].items()} if c[0] == "device"
                      else self._counts(c[0], **c[1]) for c in pending]
            c = {k: sum(x[k] for x in counts) for k in counts[0]}
            c["per_camera_ray"] = {k: c[k] / max(c["camera"], 1) for k in ("shadow", "reflect", "refract")}
            self.stats_now = c
            self.stats_pending = None
        return self.stats_now

    @property
    def stats(self):
        """Ray counters of the last render (:meth:`_read_stats`); set: :meth:`_set_stats`."""
        return self._read_stats()

    @stats.setter
    def stats(self, counts):
        self._set_stats(counts)

    # -------------------------------------------------------------- the frozen launches
    def _call_frozen(self, fn, tables, scene, tracer: Tracer, *args, **held):
        """Call a frozen launch with ``args``, the scene as :class:`SceneInputs` and, last, its
        caller: a :class:`~links1_mitsuba.util.Hidden` holding the frame's ``tracer``, the
        ``tables`` and the scene, which a recording's body reads (freeze walks nothing of a
        ``Hidden`` and keys it on its type alone: a new one each call replays the recording;
        the Dr.Jit arrays the body reads reach freeze as the table inputs and scene inputs). A
        recording that reads more of the scene than :class:`SceneInputs` holds is made again
        with the whole scene, which the launches of ``tables`` then keep passing. ``held``: more
        for the body, in the caller."""
        scene_input = getattr(tables, "scene_input", None)
        extra = _extra_scenes(tables)
        if scene_input is None:
            scene_input = tables.scene_input = SceneInputs(scene, extra, _unread_bsdfs(tables))
        elif scene_input is not _WHOLE_SCENE and scene_input.stale:
            scene_input = tables.scene_input = _WHOLE_SCENE   # freeze would update the scene's own
        caller = Hidden(tracer=tracer, tables=tables, scene=scene, **held)
        # no cyclic garbage collection while recording: freeing another renderer's Dr.Jit
        # state (its own recordings) in the middle of one aborts the process
        gc_on = gc.isenabled()
        gc.disable()
        try:
            whole = (scene, *extra) if extra else scene
            if scene_input is _WHOLE_SCENE:
                return fn(*args, whole, caller)
            try:
                return fn(*args, scene_input, caller)
            except Exception:
                pass
            # garbage scenes' registered instances (see below) fail a recording with these
            # inputs too: once they are freed, the scene's own variables may be enough
            gc.collect()
            try:
                return fn(*args, scene_input, caller)
            except Exception:
                tables.scene_input = _WHOLE_SCENE
                try:
                    return fn(*args, whole, caller)
                except Exception:
                    # a call through a pointer array reaches every registered instance of
                    # its class, also those of scenes that are garbage not yet collected
                    # (cycles through Python plugins), which are in no input: freeze fails
                    # to record ("... no such object instance was found in the function's
                    # inputs"). Those scenes freed, the same recording succeeds.
                    gc.collect()
                    return fn(*args, whole, caller)
        finally:
            if gc_on:
                gc.enable()

    def _frozen_fn(self):
        """The launch as a :func:`drjit.freeze` function of run-time inputs (sample ids,
        sample count, seeds: ``UInt32``; the per-scene tables): recorded once per
        configuration ``cfg`` (scene, AOVs, depth, weight threshold, the switches of
        :class:`~links1_mitsuba.tuning.Tuning` as one number, ``Tuning.key``: hashed Python
        values; a switch changed after a recording makes another one) and replayed without
        re-tracing for any pixel set, window or batch size and spp (freeze replays recorded
        kernels at the widths of the new inputs)."""
        if self.window_launch is None:
            def launch_kernels(sid, n_op, spp, seeds, cfg, table_inputs, scene_input, caller):
                # no closure: freeze would traverse it (the tracer, the scene ...); they come
                # in the caller (_call_frozen)
                tables = caller.tables
                want = cfg[2]
                o, d, tmin, tmax, key, sample = camera_rays(tables, sid, spp, seeds)
                total, cost, t0, s0, n0, counters = caller.tracer.trace_tree(
                    tables, caller.scene, o, d, tmin, tmax, key, want, sample, frozen=n_op,
                    rays=_rays_of(tables, sid, spp, seeds))
                return (total, cost, t0, s0, n0, counters) if want else (total, cost, counters)
            self.window_launch = dr.freeze(launch_kernels, warn_after=1000)
        return self.window_launch

    def _frozen_points_fn(self):
        """:meth:`trace_points` as a :func:`drjit.freeze` function (film positions and keys
        are run-time inputs): recorded once per configuration, replayed for any point count."""
        if self.point_launch is None:
            def launch_points(xf, yf, key, n_op, cfg, table_inputs, scene_input, caller):
                tables = caller.tables
                o, d, tmin, tmax = rays_at(tables, xf, yf, key)
                total, cost, _, _, _, counters = caller.tracer.trace_tree(
                    tables, caller.scene, o, d, tmin, tmax, key, False, None, frozen=n_op)
                return total, cost, counters
            self.point_launch = dr.freeze(launch_points, warn_after=1000)
        return self.point_launch

    def frozen_stage(self, tables, scene, tracer: Tracer, fn, *args, key=()):
        """``fn(tables, scene, *args)``, a stage of the boundary term (boundary.py: a module-level
        function of Dr.Jit arrays returning Dr.Jit arrays), as a :func:`drjit.freeze` function
        recorded once per configuration (the tables, the scene, ``fn``, the caller's ``key`` of
        the Python choices its trace makes; started anew with the launches, :meth:`forget`)
        and replayed for any lane count, as the point launch; traced each call without
        ``use_freeze``."""
        if not self.config.use_freeze:
            return fn(tables, scene, *args)
        frozen = self.stage_launches.get(fn)
        if frozen is None:
            def stage(*a):
                # (args, cfg, table inputs, scene input, caller: no closure, as _frozen_fn)
                caller = a[-1]
                return caller.stage(caller.tables, caller.scene, *a[:-4])
            frozen = self.stage_launches[fn] = dr.freeze(stage, warn_after=1000)
        cfg = self._key(tables, scene, tracer, fn.__module__, fn.__qualname__, key)
        return self._call_frozen(frozen, tables, scene, tracer, *args, cfg, frozen_inputs(tables), stage=fn)

    def _key(self, tables, scene, tracer: Tracer, *more) -> tuple:
        """A frozen launch's configuration (hashed by freeze): the tables and scene by id,
        ``more``, the depth and weight threshold, the frame's switches as one number."""
        return (id(tables), id(scene), *more, int(self.config.max_depth), float(self.config.min_weight),
                tracer.tuning.key())

    # -------------------------------------------------------------- launches
    @interruptible
    def trace_points(self, tables, scene, tracer: Tracer, xf, yf, keys):
        """Radiance and cost of the camera rays through film positions ``(xf, yf)`` (numpy,
        fractions of the film, row 0 at the top), ray-tree keys ``keys`` (uint32): the
        lattice points of adaptive anti-aliasing (:mod:`links1.tracing.adaptive`). Light samples at
        the primary hit follow the key alone, as in the core's ``trace(keys=...)``.
        Returns ``(L (n, 3) float64, cost (n,) float64)``; launches of at most
        ``LAUNCH_LANES`` points."""
        L, cost, counts = [np.zeros((0, 3))], [np.zeros(0)], []
        for a in range(0, len(xf), LAUNCH_LANES):
            b = min(a + LAUNCH_LANES, len(xf))
            x = mi.Float(aligned(xf[a:b], np.float32))
            y = mi.Float(aligned(yf[a:b], np.float32))
            key = mi.UInt32(aligned(keys[a:b], np.uint32))
            if self.config.use_freeze:
                cfg = self._key(tables, scene, tracer)
                total, c, counters = self._call_frozen(self._frozen_points_fn(), tables, scene, tracer, x, y, key,
                                                       dr.opaque(mi.UInt32, b - a), cfg,
                                                       frozen_inputs(tables))
            else:
                o, d, tmin, tmax = rays_at(tables, x, y, key)
                total, c, _, _, _, counters = tracer.trace_tree(tables, scene, o, d, tmin, tmax, key,
                                                                False, None)
            L.append(_columns(total, b - a).astype(np.float64))
            cost.append(_lanes(c, b - a).astype(np.float64))
            counts.append(self._launch_counts(b - a, counters))
            _between_launches()
        if counts:
            self._set_stats(counts)
        return np.concatenate(L), np.concatenate(cost)

    def _launch(self, tables, scene, tracer: Tracer, sid, spp_, seeds, want, mode=dr.ADMode.Primal, compact=False):
        """One launch over the sample ids ``sid`` (a ``UInt32`` array) -> (its device outputs
        ``total``, ``cost`` and with ``want`` ``t0``, ``s0``, ``n0``, each with one lane per
        sample; its ray counters). ``mode``: ``dr.ADMode.Primal`` (the frozen launch) or a
        derivative pass's (gradients.py); ``compact``: in a derivative pass that traces the
        seeing samples alone, their RGB and lanes as ``seeing`` instead of ``total``
        (``raytree_ad.trace_tree_ad``)."""
        n = dr.width(sid)
        if mode != dr.ADMode.Primal:   # a derivative pass (gradients.py): unfrozen, no AOVs
            o, d, tmin, tmax, key, sample = camera_rays(tables, sid, spp_, seeds)
            # (the samples' RGB evaluated in one kernel: the film's gather would evaluate each
            # channel alone, recomputing the shading of the ray tree three times)
            total = trace_tree_ad(tracer, tables, scene, o, d, tmin, tmax, key, sample,
                                  rays=lambda lanes: camera_rays(tables, dr.gather(mi.UInt32, sid, lanes), spp_, seeds),
                                  backward=mode == dr.ADMode.Backward, compact=compact)
            return ({"seeing": total} if isinstance(total, tuple) else {"total": total, "cost": dr.zeros(mi.UInt32, n)},
                    (n, dict(nsh1=None)))
        if self.config.use_freeze:
            cfg = self._key(tables, scene, tracer, want)
            out = self._call_frozen(self._frozen_fn(), tables, scene, tracer, sid, dr.opaque(mi.UInt32, n),
                                    spp_, seeds, cfg, frozen_inputs(tables))
            total, cost, counters = out[0], out[1], out[-1]
            t0, s0, n0 = out[2:5] if want else (None, None, None)
        else:
            o, d, tmin, tmax, key, sample = camera_rays(tables, sid, spp_, seeds)
            total, cost, t0, s0, n0, counters = tracer.trace_tree(tables, scene, o, d, tmin, tmax, key,
                                                                  want, sample, rays=_rays_of(tables, sid, spp_, seeds))
        part = {"total": widen(total, n), "cost": widen(cost, n)}
        if want:
            part.update(t0=widen(t0, n), s0=widen(s0, n), n0=widen(n0, n))
        return part, self._launch_counts(n, counters)

    def seeing_hits(self, tables, scene, window, spp, seed):
        """Where the camera rays of the film window ``window = (x0, y0, w, h)`` (its own samples:
        a box filter's) hit something: a ``Bool`` lane per sample, in the order of the window's
        launch (row by row), evaluated: what a derivative pass traces of it
        (``raytree_ad.trace_tree_ad``)."""
        W, _ = tables.film_size
        batch = (cached_batch(self.batches, [window], [window], int(spp)) if SEEING_BATCH_CACHED
                 else Batch([window], [window], int(spp)))
        sid = sample_ids(W, int(spp), batch)
        o, d, tmin, tmax, _, _ = camera_rays(tables, sid, *_ray_counts(spp, seed))
        hit = hits(tables, scene, o, d, tmin, tmax)
        dr.eval(hit)
        return hit

    def window_samples(self, tables, scene, tracer: Tracer, window=None, spp=1, seed=None, aovs=None):
        """The samples a window's pixels are made of, as numpy (for checks and debugging):
        ``(sample_window, {"total": (sh, sw, spp, 3), "cost": (sh, sw, spp)`` and with AOVs
        ``"t0", "s0", "n0"``: the launch's per-sample outputs, float32 / int32``})``."""
        W, H = tables.film_size
        win = (0, 0, W, H) if window is None else tuple(int(v) for v in window)
        swin = win if tables.rfilter.border == 0 else sample_window(tables.rfilter, win, (W, H))
        seed = self.config.seed if seed is None else int(seed)
        want = bool(self.config.aovs if aovs is None else parse_aovs(aovs))
        sid = sample_ids(W, int(spp), Batch([win], [swin], spp))
        part, _ = self._launch(tables, scene, tracer, sid, *_ray_counts(spp, seed), want)
        shape = (swin[3], swin[2], int(spp))
        out = {k: (np.stack([np.asarray(v[c]) for c in range(3)], axis=-1) if dr.size_v(v) == 3
                   else np.asarray(v)).reshape(shape + ((3,) if dr.size_v(v) == 3 else ()))
               for k, v in part.items()}
        return swin, out

    @interruptible
    def render_windows(self, tables, scene, tracer: Tracer, windows, spp=1, seed=None, aovs=None):
        """Render several windows of the film in one launch -> one float64 ndarray ``(h, w,
        3 + aov channels)`` per window, each exactly what ``Engine.render_window`` returns for
        it (pixels are independent lanes). The frame is made on the device
        (:meth:`render_windows_device`) and copied to numpy once, at the end."""
        flat, C, batch = self._render_flat(tables, scene, tracer, windows, spp, seed, aovs, mi.Float64,
                                           dr.ADMode.Primal)
        a = flat.numpy()
        return [a[p * C:(p + w * h) * C].reshape(h, w, C)
                for p, (_, _, w, h) in zip(batch.pixel_start, batch.wins)]

    @interruptible
    def render_windows_device(self, tables, scene, tracer: Tracer, windows, spp=1, seed=None, aovs=None,
                              dtype=None, mode=dr.ADMode.Primal):
        """:meth:`render_windows` on the device: one tensor ``(h, w, C)`` per window, of
        ``dtype`` (``mi.Float``: ``mi.TensorXf``; ``mi.Float64``: ``mi.TensorXf64``), never
        visiting numpy (:mod:`links1_mitsuba.film`: sample ids, the reconstruction filter, spp
        and AOVs in Dr.Jit).

        The pixel set reaches the kernels as a ``UInt32`` array of sample ids made on the
        device from the windows' tables (:class:`~links1_mitsuba.film.Batch`), so no window offset, window size, batch size or
        sample count enters the recorded kernels: one recording per configuration, then
        replays (:meth:`_frozen_fn`); the film's kernels are cached likewise. ``tables``: the
        camera view to render (``Tables.prepare``'s, or a derivative pass's, gradients.py);
        ``mode``: ``dr.ADMode.Primal``, or the derivative pass's mode (gradients.py: the ray
        tree traced level by level, the film's loops evaluated, no AOVs).
        """
        flat, C, batch = self._render_flat(tables, scene, tracer, windows, spp, seed, aovs,
                                           mi.Float if dtype is None else dtype, mode)
        Tensor = mi.TensorXf64 if type(flat) is mi.Float64 else mi.TensorXf
        if len(batch.wins) == 1:
            _, _, w, h = batch.wins[0]
            return [Tensor(flat, shape=(h, w, C))]
        return [Tensor(dr.gather(type(flat), flat, dr.arange(mi.UInt32, w * h * C) + dr.opaque(mi.UInt32, p * C)),
                       shape=(h, w, C)) for p, (_, _, w, h) in zip(batch.pixel_start, batch.wins)]

    def _render_flat(self, tables, scene, tracer: Tracer, windows, spp, seed, aovs, dtype, mode):
        """The windows' pixels as one flat ``dtype`` array, window after window, with their
        channel count and :class:`~links1_mitsuba.film.Batch` (for the callers above)."""
        W, H = tables.film_size
        wins = []
        for window in windows:
            x0, y0, w, h = (0, 0, W, H) if window is None else (int(v) for v in window)
            if not (0 <= x0 and 0 <= y0 and w > 0 and h > 0 and x0 + w <= W and y0 + h <= H):
                raise ValueError(f"window {window} is outside the {W}x{H} film")
            wins.append((x0, y0, w, h))
        spp = int(spp)
        if W * H * spp >= 2 ** 32:
            raise ValueError(f"{W}x{H} pixels x {spp} samples exceed the 32-bit sample ids")
        seed = self.config.seed if seed is None else int(seed)
        aovs = self.config.aovs if aovs is None else parse_aovs(aovs)
        ad = mode != dr.ADMode.Primal
        if ad:
            aovs = []   # a derivative pass differentiates the RGB channels
        want = bool(aovs)
        # each window traces the samples of its filter border too (clipped to the film)
        box = tables.rfilter.border == 0
        swins = wins if box else [sample_window(tables.rfilter, win, (W, H)) for win in wins]
        batch = cached_batch(self.batches, wins, swins, spp)
        n = batch.lanes
        sid = sample_ids(W, spp, batch)
        spp_, seeds = _ray_counts(spp, seed)
        # launches of at most LAUNCH_LANES samples (lanes are independent: the same bits as
        # one launch); one launch of W*H*spp lanes needs ~90 bytes each (512², 1024 spp: 24 GB)
        if n <= LAUNCH_LANES:
            # a box filter's window in a reverse-mode pass: its seeing samples summed into their
            # pixels (raytree_ad.SEEING_FILM)
            compact = (raytree_ad.SEEING_FILM and mode == dr.ADMode.Backward and len(wins) == 1 and box
                       and tables.rfilter.is_box)
            parts, counts = self._launch(tables, scene, tracer, sid, spp_, seeds, want, mode, compact)
            if "seeing" in parts:
                self._set_stats([counts])
                return raytree_ad.seeing_film(*parts["seeing"], spp_[0], batch.pixels), 3, batch
            counts = [counts]
        else:
            dr.eval(sid)
            lanes = lambda a: dr.arange(mi.UInt32, min(LAUNCH_LANES, n - a)) + dr.opaque(mi.UInt32, a)  # noqa: E731
            chunks = []
            for a in range(0, n, LAUNCH_LANES):
                chunks.append(self._launch(tables, scene, tracer, dr.gather(mi.UInt32, sid, lanes(a)), spp_, seeds,
                                           want, mode))
                _between_launches()
            counts = [c for _, c in chunks]
            parts = {}
            for key in chunks[0][0]:
                vals = [q[key] for q, _ in chunks]
                if dr.size_v(vals[0]) == 3:
                    parts[key] = type(vals[0])(*(concat([v[k] for v in vals], n, type(vals[0][k]))
                                                 for k in range(3)))
                else:
                    parts[key] = concat(vals, n, type(vals[0]))
        self._set_stats(counts)
        flat, C = reconstruct(tables.rfilter, (W, H), spp, seed, batch, parts, aovs, dtype,
                              mode="evaluated" if ad else None)
        return flat, C, batch
