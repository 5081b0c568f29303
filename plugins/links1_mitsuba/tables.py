"""The per-scene tables of ``links1_whitted`` (their one home): ``prepare`` turns a Mitsuba scene
into what the kernels read (slots in file order, ray offsets, materials, shadow transmittance,
emission, lights, camera, custom shapes, their BVH and light buffers), rebuilt only when the scene changes
(:class:`ParamWatch`: by the Dr.Jit variables of its parameters, nothing read back);
``_occluders`` decides which shadow rays a scene needs.

What a scene doesn't need is not traced (decided once per scene in ``prepare``): no
refraction code without transmissive surfaces, no reflection without reflective ones, no loop
at all without either, no custom-shape code without custom shapes, no blob solver without
blobs, no shadow ray toward a light from a hit that no shape can shadow (``_occluders``: a
lone convex shape, a floor below every other shape and the light, ...).

:class:`Tables` is a base class of the ``Engine`` (engine.py); its methods name
``mi.Float``, ``mi.Ray3f``, ... when called, so the class serves every Mitsuba variant.
"""
from __future__ import annotations

import copy
import warnings
from dataclasses import dataclass, field

import numpy as np

from links1.maths.halfspace import box_side, point_side
from links1.scene.params import MAX_EXTENT
from links1.sensor.filters import Filter
from links1.shading.lights import ENV_LIGHT_ID, number_area_lights

import drjit as dr
import mitsuba as mi

from . import lightbuffer, proxies, tuning
from .bvh import QuadricBVH
from .registered import plugin_class
from .lights import _emitted_rgb
from .util import Hidden, checked_index, kind_of

#: Relative ray-origin offset on shapes whose float32 hits are accurate to a few ulps
#: (meshes, rectangles, disks, links1 quadrics): a small offset keeps shadow rays that graze
#: an object on the same side as the float64 core. Mitsuba's sphere/cylinder and links1
#: blobs (iterative roots) use Mitsuba's RayEpsilon (self-shadowing otherwise).
OFFSET_EPS = 2.0 ** -19
_PRECISE_MITSUBA = ("Mesh", "OBJMesh", "PLYMesh", "Rectangle", "Disk", "Links1Bicubic", "SerializedMesh")

#: Shadow rays toward a light that at most this many Mitsuba shapes can occlude first test the
#: segment against those shapes' bounding boxes and call Embree only where one is met
#: (``Intersect._shadow_mitsuba``); above it Embree's own BVH culls better
BOX_CULL_MAX = 8

#: Scenes with at most this many transparent Mitsuba shapes test shadow rays with one any-hit
#: query per transparent shape and one over the opaque ones (``shadow_split``) instead of
#: walking the crossings nearest first
SPLIT_MAX = 8


def shadow_split(mi, shapes, slot_list, trans):
    """Shadow rays through few transparent Mitsuba shapes (3-3-3: T = 0 behind an opaque shape,
    else the product of the shadow transmittances of the shapes met, each once, in any order):
    a Mitsuba scene of the opaque shapes (None if there are none) for one any-hit query, and
    one scene per transparent shape, ``{"opaque", "opaque_slots", "trans": [(scene, slot,
    transmittance)]}``. The scenes share the shapes (no copy). None above SPLIT_MAX, on the
    CUDA variants (untried there: OptiX traces a kernel's rays through one pipeline), or if
    Mitsuba refuses a sub-scene (then the crossings are walked)."""
    if not mi.variant().startswith("llvm"):
        # OptiX: one kernel traces through one pipeline, so no second scene in the launch
        return None
    tr = [(s, sl) for s, sl in zip(shapes, slot_list) if trans[sl].max() > 0]
    op = [(s, sl) for s, sl in zip(shapes, slot_list) if not trans[sl].max() > 0]
    if not tr or len(tr) > SPLIT_MAX:
        return None

    def scene_of(group):
        # load_dict names each object after its key: keyed by slot, the shapes' own ids
        # (empty for a plain mi.load_file without ids) given back afterwards
        ids = [s.id() for s, _ in group]
        try:
            return mi.load_dict({"type": "scene", **{f"_links1_slot_{sl}": s for s, sl in group}})
        finally:
            for (s, _), i in zip(group, ids):
                s.set_id(i)

    try:
        return {"opaque": scene_of(op) if op else None, "opaque_slots": frozenset(sl for _, sl in op),
                "trans": [(scene_of([(s, sl)]), sl, trans[sl].copy()) for s, sl in tr]}
    except Exception as exc:    # noqa: BLE001 - any refusal: the general path
        warnings.warn(f"links1_whitted: transparent shadows walk their crossings ({exc})", stacklevel=2)
        return None


def occluder_boxes(occ, lo, hi, convex):
    """The bounding boxes of the Mitsuba shapes ``occ`` (per slot) for the shadow rays' cull:
    ``[(lo, hi, slot, convex)]`` as Python floats, or None when there are more than
    BOX_CULL_MAX or one is unbounded. Each axis is widened by 2^-20 of the box's extent plus
    its largest coordinate there (Mitsuba's and Embree's own float32 tests accept hits a few
    ulps outside a shape: a rectangle's corner), and rounded outward to float32; a box flat
    along an axis (a floor) stays flat there, so rays leaving it are culled."""
    slots = np.flatnonzero(occ)
    if slots.size > BOX_CULL_MAX:
        return None
    boxes = []
    for sl in slots:
        a, b = np.asarray(lo[sl], dtype=np.float64), np.asarray(hi[sl], dtype=np.float64)
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            return None
        m = 2.0 ** -20 * ((b - a) + np.maximum(np.abs(a), np.abs(b)))
        a, b = a - m, b + m
        a32, b32 = np.float32(a), np.float32(b)   # outward rounding to float32
        a32 = np.where(a32 > a, np.nextafter(a32, np.float32(-np.inf)), a32)
        b32 = np.where(b32 < b, np.nextafter(b32, np.float32(np.inf)), b32)
        boxes.append(([float(v) for v in a32], [float(v) for v in b32], int(sl), bool(convex[sl])))
    return boxes


def _textured(bsdf) -> bool:
    """Whether a Mitsuba BSDF has a texture (bitmap and checkerboard expose ``to_uv``)."""
    import mitsuba as mi
    return bsdf is not None and any(k.endswith("to_uv") for k in mi.traverse(bsdf).keys())


def _token(value):
    """A value that ``mi.traverse`` hands out without Dr.Jit variables (a Python number, a
    scalar vector or transform: the film's size, a clip distance), as something ``==`` compares
    by value (a NaN equals itself)."""
    t = type(value)
    if t is float:
        return value if value == value else "nan"
    if t in (bool, int, str) or value is None:
        return value
    try:                                    # a scalar Dr.Jit vector: its numbers
        tup = tuple(value)
        if all(type(e) in (int, float, bool) for e in tup):
            return tuple(_token(e) for e in tup)
    except Exception:  # noqa: BLE001 - not iterable: as numpy reads it
        pass
    try:
        a = np.asarray(value.matrix if hasattr(value, "matrix") else value)
    except Exception:  # noqa: BLE001 - a value numpy cannot read: its text
        return ("repr", repr(value))
    return (a.dtype.str, a.shape, np.ascontiguousarray(a).tobytes())


#: :class:`ParamWatch`'s stand-in for the watched scene's integrator (not held: its tables hold the watch)
_INTEGRATOR = object()


class _Entries:
    """Some parameters' entries as ``mi.traverse`` holds them (``properties``: key -> (value,
    cpptype, node, flags); ``get_property``): what :meth:`ParamWatch.changed` found changed
    without a whole traversal, for :meth:`ParamWatch.renewed` to read again."""

    __slots__ = ("properties", "get_property")

    def __init__(self, mi, entries):
        self.properties = {k: (v, ct, node, None) for k, (v, ct, node) in entries}
        self.get_property = mi.get_property


class ParamWatch(Hidden):
    """Whether a Mitsuba object's parameters (every one ``mi.traverse(obj)`` exposes: a
    scene's shapes, BSDFs, textures, emitters, sensors, ...) changed since the watch was made,
    without reading them back.

    A Dr.Jit value is compared by its variables' indices (``dr.detail.collect_indices``, the
    JIT and AD indices that ``mi.SceneParameters.update`` itself compares): Dr.Jit variables
    are immutable, and an assignment (``params[k] = v``), an in-place operation or a
    ``dr.scatter`` gives the value another variable. The watch keeps a reference to each
    variable it saw (``_pins``), so that no freed index is handed to a new value and a
    ``dr.scatter`` into a variable (in place only while nothing else holds it) must copy it
    (the values replaced stay in memory until the tables are built again, at the next frame).
    A value without variables (a Python number, the film's scalar size) is compared by value:
    they are tiny.

    The traversal is made once: Mitsuba's C++ objects hand ``mi.traverse`` the addresses of
    their fields, which show what ``params.update()`` writes there later. ``obj``'s own fields
    are traversed again at each check (one level, not its children): the watch does not keep
    ``obj``, so a scene's tables, which its integrator keeps, do not keep the scene alive. A
    value that a Python plugin hands out as an object (``parameters_changed`` may replace the
    object), or the scene's integrator's, is read again by traversing its node (one level,
    :meth:`_own_values`); another ``obj`` (a scene with the same shapes, emitters and
    sensors) makes the check a whole ``mi.traverse`` (~0.15 ms), as a node whose values
    cannot be matched to their keys does.

    A :class:`~links1_mitsuba.util.Hidden`: neither ``dr.freeze`` nor the walk that gathers
    the frozen launch's inputs from the tables (``Launches._frozen_inputs``) takes the pins
    (old values) for inputs."""

    class _Shallow:
        """A ``TraversalCallback`` that keeps the values put (not the objects): the class is
        made once per Mitsuba variant."""
        classes: dict = {}

        @classmethod
        def make(cls, mi):
            c = cls.classes.get(mi.variant())
            if c is None:
                class Shallow(mi.TraversalCallback):
                    def put(self, name, value, flags, cpptype=None):
                        if not isinstance(value, mi.Object):
                            self.out.append((name, value, cpptype))
                c = cls.classes[mi.variant()] = Shallow
            return c()

    def __init__(self, obj, params=None, renew=None, keys=()):
        import drjit as dr
        import mitsuba as mi
        self._mi, self._collect = mi, dr.detail.collect_indices
        params = mi.traverse(obj) if params is None else params   # (changed()'s, just read)
        self._obj_id = id(obj)
        self.traversed = self.changed_keys = None
        if renew is not None:
            # the watch ``renew`` with the ``keys`` its :meth:`changed` found read again (the
            # others' variables are the ones it pinned, and the traversal's structure its own),
            # unless a value changed kind (variables or not): then a whole new watch
            state, pins = self._read_all(params, pin=True, keys=keys)
            if any(state[k][0] != renew.state[k][0] for k in keys):
                renew = None
                if isinstance(params, _Entries):     # (only the changed ones: all of them now)
                    params = mi.traverse(obj)
        if renew is not None:
            self.state, self._pins = dict(renew.state), dict(renew._pins)
            self.state.update(state)
            for k in keys:
                self._pins.pop(k, None)
            self._pins.update(pins)
            for name in ("_own", "_retraverse", "_jit", "_jit_keys", "_scalar", "_scalar_keys", "_root_keys"):
                setattr(self, name, getattr(renew, name, None))
        else:
            self.state, self._pins = self._read_all(params, pin=True)
            # values a Python plugin (or the scene's integrator) hands out as objects: their
            # nodes traversed again at each check, one level each (:meth:`_own_values`)
            self._own = self._own_values(obj, params)
            self._retraverse = self._own is None
            if not self._retraverse:
                kids = [(k, v, ct, node) for k, (v, ct, node, _) in params.properties.items()
                        if node is not obj and ct is not None and not isinstance(node, mi.Integrator)]
                self._jit = [(v, ct, node) for k, v, ct, node in kids if self.state[k][0] == "ids"]
                self._jit_keys = [k for k, *_ in kids if self.state[k][0] == "ids"]
                self._scalar = [(v, ct, node) for k, v, ct, node in kids if self.state[k][0] == "value"]
                self._scalar_keys = [k for k, *_ in kids if self.state[k][0] == "value"]
                self._root_keys = sorted(k for k, (_, _, node, _) in params.properties.items() if node is obj)
        if not self._retraverse:
            self._jit_ids = [i for k in self._jit_keys for i in self.state[k][1]]
            self._scalar_tokens = [self.state[k][1] for k in self._scalar_keys]

    def renewed(self, obj):
        """A watch of ``obj``'s parameters now, made from this one after :meth:`changed` found
        which differ (only those read again: a rebuild's watch of the blob scene's 90
        parameters took ~0.5 ms); a whole new watch where the keys changed."""
        keys, params = self.changed_keys, self.traversed
        # the traversal let go: it holds the scene, and this watch lives in the scene's tables
        # (and in their camera views): kept, it would keep every scene alive (a cycle through
        # C++ objects), whose registered objects then break freeze's recordings of others
        self.changed_keys = self.traversed = None
        if keys is None or params is None or id(obj) != self._obj_id:
            return ParamWatch(obj)
        return ParamWatch(obj, params, renew=self, keys=keys)

    def _own_values(self, obj, params):
        """``[(node, keys)]``: each node whose values ``mi.traverse`` took as they were (a
        Python plugin's: ``cpptype`` None; the scene's integrator's, held as
        :data:`_INTEGRATOR` and asked of the scene at each check, since the watch lives in
        its tables), with the keys of its values in the order its ``traverse`` puts them.
        None where that order cannot be matched to the keys (then every check traverses
        ``obj`` whole)."""
        mi = self._mi
        groups = {}
        for k, (v, ct, node, _) in params.properties.items():
            if node is not obj and (ct is None or isinstance(node, mi.Integrator)):
                groups.setdefault(id(node), (node, []))[1].append(k)
        out = []
        for node, keys in groups.values():
            ref = node
            if isinstance(node, mi.Integrator):
                if not (isinstance(obj, mi.Scene) and obj.integrator() is node):
                    return None
                ref = _INTEGRATOR
            names = [n for n, _, _ in self._shallow(node)]
            if len(names) != len(keys) or not all(k == n or k.endswith("." + n) for k, n in zip(keys, names)):
                return None
            out.append((ref, keys))
        return out

    def _shallow(self, node):
        """``(name, value, cpptype)`` of the values ``node`` itself puts (one level)."""
        cb = self._Shallow.make(self._mi)
        cb.out = []
        node.traverse(cb)
        return cb.out

    def _read_all(self, params, pin=False, keys=None):
        """``{key: ("ids", indices) or ("value", token)}`` of every parameter (or of ``keys``),
        and with ``pin`` the pins (``{key: pin}``)."""
        collect = self._collect
        state, pins = {}, {}
        props = params.properties
        for k in (props.keys() if keys is None else keys):
            v, ct, node, _ = props[k]
            value = v if ct is None else params.get_property(v, ct, node)
            ids = tuple(collect(value))
            if ids and pin:
                try:
                    p = type(value)(value)      # another reference to the same variables
                except Exception:  # noqa: BLE001 - a type that cannot be copied so
                    p = None
                if p is not None and tuple(collect(p)) == ids:
                    pins[k] = p
                    state[k] = ("ids", ids)
                    continue
                if p is not None and any(i >> 32 for i in ids):
                    # an attached value (an optimiser's, ``params.update(opt)``: an AD index in
                    # the upper 32 bits): its copy (under ``suspend_grad``, as ``prepare`` runs)
                    # has none, so the value itself is pinned (it holds its JIT and
                    # AD variables; a later assignment puts another object there). Compared
                    # by value instead, each check read it back to the host (a device sync)
                    pins[k] = value
                    state[k] = ("ids", ids)
                    continue
            elif ids:
                state[k] = ("ids", ids)
                continue
            state[k] = ("value", _token(value))
        return state, pins

    def unchanged(self, obj) -> bool:
        """Whether ``obj`` (the object watched, or one with the same children: the same
        shapes, emitters and sensors) has the parameters the watch saw."""
        mi = self._mi
        if self._retraverse or id(obj) != self._obj_id:
            params = mi.traverse(obj)
            if params.properties.keys() != self.state.keys():
                return False
            return all(self._read_one(v if ct is None else params.get_property(v, ct, node), self.state[k][0])
                       == self.state[k] for k, (v, ct, node, _) in params.properties.items())
        get = mi.get_property
        # the Dr.Jit values, one list of indices (their types, so their index counts, are fixed)
        if self._collect([get(*e) for e in self._jit]) != self._jit_ids:
            return False
        if [_token(get(*e)) for e in self._scalar] != self._scalar_tokens:
            return False
        entries = self._node_entries(obj)
        return entries is not None and not any(self._differs(k, e) for k, e in entries)

    def _node_entries(self, obj):
        """``[(key, (value, cpptype, node))]`` of ``obj``'s own values and those the Python
        plugins (and the scene's integrator) hand out, their nodes traversed one level, in the
        watch's keys; None where they are not the watched ones (keys added or gone)."""
        own = self._shallow(obj)
        if sorted(name for name, _, _ in own) != self._root_keys:
            return None
        out = [(name, (v, ct, obj)) for name, v, ct in own]
        for ref, keys in self._own:
            node = obj.integrator() if ref is _INTEGRATOR else ref
            vals = self._shallow(node)
            if len(vals) != len(keys) or not all(k == n or k.endswith("." + n) for (n, _, _), k in zip(vals, keys)):
                return None
            out += [(k, (v, ct, node)) for (_, v, ct), k in zip(vals, keys)]
        return out

    def _differs(self, k, entry):
        """Whether parameter ``k`` (its ``entry``: value, cpptype, node) is not what the watch saw."""
        v, ct, node = entry
        s = self.state[k]
        return self._read_one(v if ct is None else self._mi.get_property(v, ct, node), s[0]) != s

    def changed(self, obj):
        """The parameters of ``obj`` that differ from the watch's, as ``(name, object)``: the
        parameter's last name (``diffuse.value``'s ``diffuse``; ``exponent``) and the Mitsuba
        object that holds it; None when the parameters are other ones (keys added or gone).
        Read the way :meth:`unchanged` reads them where it can (:meth:`_changed_entries`: no
        whole ``mi.traverse``, ~0.1 ms an update), else from a traversal."""
        self.changed_keys = None
        entries = None if self._retraverse or id(obj) != self._obj_id else self._changed_entries(obj)
        if entries is not None:
            params = self.traversed = _Entries(self._mi, entries)   # (for the next watch: renewed())
            found = [(k, node) for k, (_, _, node) in entries]
        else:
            params = self.traversed = self._mi.traverse(obj)
            if params.properties.keys() != self.state.keys():
                return None
            found = [(k, node) for k, (v, ct, node, _) in params.properties.items()
                     if self._read_one(v if ct is None else params.get_property(v, ct, node),
                                       self.state[k][0]) != self.state[k]]
        out = []
        for k, node in found:
            parts = k.split(".")
            out.append((parts[-2] if parts[-1] == "value" and len(parts) > 1 else parts[-1], node))
        self.changed_keys = [k for k, _ in found]
        return out

    def _changed_entries(self, obj):
        """``[(key, (value, cpptype, node))]`` of the parameters that differ, read as
        :meth:`unchanged` reads them (the C++ objects' fields by address, ``obj``'s own and the
        Python plugins' values by traversing their nodes one level); None where the structure
        is not the watched one (keys added or gone: the caller traverses)."""
        entries = self._node_entries(obj)
        if entries is None:
            return None
        return [(k, e) for k, e in [*zip(self._jit_keys, self._jit), *zip(self._scalar_keys, self._scalar), *entries]
                if self._differs(k, e)]

    def attached(self) -> bool:
        """Whether a parameter had gradients enabled when the watch read it (an AD index in
        the upper 32 bits of one of its variables): with :meth:`unchanged`, whether one has now,
        without reading the parameters again."""
        return any(how == "ids" and any(i >> 32 for i in v) for how, v in self.state.values())

    def _read_one(self, value, how):
        """One value as the state has it (``how``: "ids" or "value")."""
        return (how, tuple(self._collect(value)) if how == "ids" else _token(value))


def _set_later():
    """A field :meth:`Tables._prepare_scene` (or the camera view, :meth:`Tables._set_camera`)
    always sets: no default, so reading it before it is set is an AttributeError."""
    return field(init=False, repr=False)


def _default(value=None):
    """A field the code reads before (or without) setting it: ``value`` until set."""
    return field(init=False, repr=False, default=value)


@dataclass(slots=True, eq=False)
class Prepared:
    """The per-scene tables the kernels read (:meth:`Tables.prepare`): slots (the shapes in
    file order: Mitsuba's first, then the links1 shapes), materials, shadow rays, emission,
    lights, and in a camera view (a shallow copy per sensor) the camera and film.

    Every field is declared here (``slots``: assigning an undeclared name is an
    AttributeError). The Dr.Jit arrays among them reach the frozen launches as their
    ``tables`` input (``Launches._frozen_inputs`` walks the fields). Per-slot tables have
    ``nslots`` rows; the RGB ones are flat Floats of 3 values per slot. ``eq=False``: tables are
    compared (and hashed) by identity."""

    # -- scene identity and bookkeeping
    #: the scene's shapes, emitters and sensors as object ids (:func:`scene_identity`)
    ident: tuple = _set_later()
    #: the tuning the tables were built with (``tuning.Tuning.tables_key``)
    tuning: tuning.Tuning = _set_later()
    #: the scene's parameters as last seen (:class:`ParamWatch`)
    watch: ParamWatch = _set_later()
    #: (shapes, emitters, sensors, BSDF per slot): the objects whose ids ``ident`` and the
    #: BSDF pointer tables hold, kept alive with the tables
    keep_alive: tuple = _set_later()
    #: Mitsuba's shapes (top-level, then shapegroup members), their slots, the members' slots
    shape_list: list = _set_later()
    slot_list: list = _set_later()
    member_slots: frozenset = _set_later()
    #: the camera views of these tables, by ``id(sensor)`` (:meth:`Tables._camera_view`)
    views: dict = _set_later()
    #: ``mi.traverse`` of objects the tables read again on updates (:meth:`Tables._params_of`)
    obj_params: dict = _set_later()
    #: number of slots (Mitsuba shapes and links1 shapes)
    nslots: int = _set_later()
    #: the links1 shapes (``QuadricSpec`` / ``BlobSpec``), the integrator's list
    custom: list = _set_later()
    #: the tables of the links1 shapes traced in their own code (``QuadricSpec.tables`` /
    #: ``BlobSpec.tables``: the constants an update may change, a blob's candidate search)
    blob_tables: list = _set_later()
    #: the links1 quadrics under a BVH (``bvh.QuadricBVH``), or None (fewer than ``bvh_min``)
    bvh: object = _set_later()
    #: the links1 shapes intersected one code block each (those not under the BVH)
    custom_unrolled: list = _set_later()
    #: the slots of the quadrics under the BVH
    bvh_slots: frozenset = _default(frozenset())
    #: Mitsuba's shape registry id -> slot (-1: none), Int32
    reg_to_slot: object = _set_later()
    #: whether the scene has Mitsuba shapes (else no ``scene.ray_intersect``)
    any_mitsuba_shapes: bool = _set_later()
    #: relative ray-origin offset per slot (``OFFSET_EPS`` or Mitsuba's RayEpsilon), Float
    eps_table: object = _set_later()

    # -- materials (links1_phong: eq. 3.11; other Mitsuba BSDFs through bsdf.eval / sample)
    #: per slot: a links1_phong surface (numpy bool)
    is_phong_np: object = _set_later()
    #: the material tables' values as numpy ({"amb": (nslots, 3), ..., "ior": (nslots,)}):
    #: what a value update (:meth:`Tables._update_values`) compares with
    phong_np: object = _set_later()
    #: every slot / some slot is links1_phong
    all_phong: bool = _set_later()
    any_phong: bool = _set_later()
    #: ``is_phong_np`` as a Bool table
    is_phong: object = _set_later()
    #: eq. 3.11's dic, drc, src (ambient, diffuse, specular) and eq. 3.16's r, t per slot (RGB)
    amb: object = _set_later()
    dif: object = _set_later()
    spe: object = _set_later()
    refl: object = _set_later()
    trans: object = _set_later()
    #: the highlight exponent n and the index of refraction per slot, Float
    expo: object = _set_later()
    ior: object = _set_later()
    #: some slot has an ambient term
    any_ambient: bool = _set_later()
    #: per slot: the Mitsuba BSDF has a delta reflection / delta transmission / Null lobe, Bool
    has_dr: object = _set_later()
    has_dt: object = _set_later()
    has_null: object = _set_later()
    #: some Mitsuba BSDF has a delta reflection / transmission / Null lobe / any delta lobe
    any_mitsuba_dr: bool = _set_later()
    any_mitsuba_dt: bool = _set_later()
    any_mitsuba_null: bool = _set_later()
    any_mitsuba_delta: bool = _set_later()
    #: per delta lobe ("r", "t"): the components of the slots' samplers that have it, with the
    #: slots whose sampler has it there: [(component, Bool per slot)]
    delta_components: dict = _set_later()
    #: some slot's BSDF is a ``mask``; then the BSDFs masks wrap, per slot (BSDFPtr), else None
    any_mask: bool = _set_later()
    inner_ptr: object = _set_later()
    #: some links1_phong slot reflects / transmits; some slot spawns a mirror or refraction ray
    any_phong_r: bool = _set_later()
    any_phong_t: bool = _set_later()
    any_specular: bool = _set_later()
    #: per slot: the Mitsuba BSDF has a diffuse or glossy lobe (Bool); direct light from the
    #: sampled lights at such hits adds a BSDF sample, combined by multiple importance sampling
    #: (``any_mis``: some such slot and some area or environment light); links1_phong keeps
    #: the paper's light samples alone
    glossy: object = _set_later()
    any_mis: bool = _set_later()
    #: the links1 quadric slots whose Mitsuba BSDF has a texture (they get the core's uv)
    uv_slots: set = _set_later()
    #: the BSDF of each slot (BSDFPtr), None when every slot is links1_phong
    bsdf_ptr: object = _set_later()

    # -- shadow rays (3-3-3)
    #: shadow transmittance per slot ((nslots, 3) numpy; a derivative pass: a list of rows)
    shadow_t_np: object = _set_later()
    #: the same as a flat Float
    shadow_t: object = _set_later()
    #: a transparent Mitsuba shape's bit and word in a lane's "seen" set, per slot (UInt32)
    trans_bits: object = _set_later()
    trans_words: object = _set_later()
    #: words of that set
    trans_nwords: int = _set_later()
    #: most crossings of transparent Mitsuba shapes one shadow segment can make
    max_crossings: int = _set_later()
    any_transparent_mitsuba: bool = _set_later()
    #: the sub-scenes of :func:`shadow_split`, or None (the crossings are walked)
    shadow_split: object = _default(None)

    # -- emission
    #: the links1 shapes' emission per slot (RGB); some slot emits
    custom_emission: object = _set_later()
    any_custom_emission: bool = _set_later()
    #: per slot: a Mitsuba shape with an area emitter (Bool); some slot has one
    any_mitsuba_emission: bool = _set_later()
    mitsuba_emits: object = _set_later()

    # -- lights (docs/method.md §4.1; lights.py)
    #: the analytic lights: ("point", pos, axis, L1, L2, inverse_square), ("cspot", origin,
    #: direction, radius, I), ("mspot", pos, axis, I, cutoff, beam), ("dir", direction, E),
    #: ("memitter", pos, emitter)
    lights: list = _set_later()
    #: the sampled area emitters and their tables (``Lights._area_table``)
    area: list = _set_later()
    area_tab: list = _set_later()
    #: the environment emitter seen by escaping rays, or None
    env: object = _set_later()
    #: the environment lights: ("const", rgb, light id) or ("envmap", table, light id)
    consts: list = _set_later()
    #: per light (analytic, then area, then environment; :meth:`Tables._occluders`): the slots
    #: whose hits need a shadow ray (Bool, None: all), the closed shapes that shadow their own
    #: points from the inside (Bool or None), whether any shadow ray is traced, the links1
    #: shapes / whether any Mitsuba shape can occlude it, the Mitsuba occluders' boxes
    #: (:func:`occluder_boxes`) and slots
    shadow_need: list = _set_later()
    shadow_inner: list = _set_later()
    any_shadow: list = _set_later()
    occ_custom: list = _set_later()
    occ_mitsuba: list = _set_later()
    occ_boxes: list = _set_later()
    occ_mslots: list = _set_later()
    #: what the shapes alone decide of those (``Tables._occluder_shapes``)
    occ_shapes: dict = _set_later()
    #: per analytic light: its light buffer (lightbuffer.plan) or None
    lbuf: list = _set_later()

    # -- the camera view (:meth:`Tables._camera_view`; None / unset on the scene's tables)
    #: the scene's tables this view copies
    base: Prepared | None = _default(None)
    #: a sensor that is not the scene's, watched (:class:`ParamWatch`) while verify_scene
    sensor_watch: ParamWatch | None = _default(None)
    #: the Dr.Jit arrays of these tables (``Launches._frozen_inputs``), once gathered
    frozen_inputs: list | None = _default(None)
    #: the scene as the frozen launches' input (``launch.SceneInputs`` or "whole scene")
    scene_input: object = _default(None)
    sensor: object = _set_later()
    #: the film's full size (W, H) and reconstruction filter (links1.sensor.filters.Filter)
    film_size: tuple = _set_later()
    rfilter: Filter = _set_later()
    #: "perspective" or "orthographic"; perspective; its horizontal field of view (degrees)
    projection: str = _set_later()
    perspective: bool = _default(False)
    x_fov: float | None = _default(None)
    #: a thin lens's (aperture radius, focus distance), or None: a pinhole
    lens: tuple | None = _default(None)
    #: the camera-to-world matrix (4x4 float64) and the clip distances
    cam: object = _set_later()
    near: float = _set_later()
    far: float = _set_later()
    #: the light buffer around a pinhole camera's eye (lightbuffer.plan_eye), or None
    eye_buf: object = _default(None)

    # -- a derivative pass (gradients.py: a copy with attached values)
    #: the attached geometry of the links1 shapes, or None
    geo_ad: object = _default(None)
    #: whether no moving surface (``geo_ad``) can spawn a mirror or refraction ray: the
    #: children's rays then carry no derivative (``_trace_tree_ad`` detaches them)
    fixed_children: bool = _default(True)
    #: what one derivative pass makes once for all its levels (``geometry.surface_ad``'s memo)
    ad_memo: object = _default(None)
    #: whether any parameter the pass reads has gradients enabled
    attached_any: bool = _default(False)


def _unmask(mi, b):
    """The BSDF a Mitsuba ``mask`` (nested masks too) wraps; ``b`` itself if it is no mask."""
    while kind_of(b) == "Mask":
        kids = [k for k, (parent, depth) in mi.traverse(b).hierarchy.items()
                if depth == 1 and isinstance(k, mi.BSDF)]
        if len(kids) != 1:
            break
        b = kids[0]
    return b


def group_members(scene) -> list:
    """The shapes inside the scene's ``shapegroup``s (drawn by its ``instance``s: a hit on one
    names the member, ``si.instance`` the instance), each once, in the scene's order."""
    found, seen = [], set()

    class Collect(mi.TraversalCallback):
        def put(self, name, value, flags, cpptype=None):
            if isinstance(value, mi.Shape) and id(value) not in seen:
                seen.add(id(value))
                found.append(value)

    scene.traverse(Collect())
    groups = [s for s in found if s.class_name() == "ShapeGroupPlugin"]
    members = []
    for g in groups:
        found.clear()
        g.traverse(Collect())
        members += [s for s in found if s.class_name() not in ("ShapeGroupPlugin", "Instance")]
    return members


def own_param(obj, name):
    """``mi.traverse(obj)[name]`` for a parameter of ``obj`` itself (not of a child object),
    read through one ``obj.traverse`` with :class:`ParamWatch`'s callback class: Mitsuba's
    ``mi.traverse`` defines its callback class anew at every call (~0.2 ms, most of a rebuild's
    five calls on a small scene). KeyError as ``mi.traverse`` when ``obj`` has no such one."""
    cb = ParamWatch._Shallow.make(mi)
    cb.out = []
    obj.traverse(cb)
    for n, v, ct in cb.out:
        if n == name:
            return v if ct is None else mi.get_property(v, ct, obj)
    raise KeyError(name)


def scene_identity(scene):
    """The scene's shapes, emitters and sensors as object identities (cheap: no parameters).
    Prepared tables keep those objects alive, so another scene's objects cannot take the
    same identities while the tables are kept."""
    ids = []
    for objs in (scene.shapes(), scene.emitters(), scene.sensors()):
        ids.append(len(objs))
        ids += [id(o) for o in objs]
    return tuple(ids)


def _side_of_box(nrm, c, a, b, tol):
    """-1 / +1 if the box ``a``-``b`` is in the closed half-space below / above the plane
    ``x · nrm = c`` (within ``tol``), else 0 (an unbounded box: 0): the core's rule
    (:func:`links1.maths.halfspace.box_side`) with the plugin's plane form and tolerance."""
    return box_side(a, b, lambda corners: corners @ nrm - c, tol)


#: The ``links1_phong`` coefficients as the tables hold them: table field -> (the BSDF's parameter
#: name, values a slot). ``trans`` is also the shadow transmittance (``shadow_t_np``); the
#: derivative pass differentiates all but ``ior`` (``Gradients._ad_tables``: the refracted
#: direction is held fixed).
PHONG_TABLES = {"amb": ("ambient", 3), "dif": ("diffuse", 3), "spe": ("specular", 3),
                "refl": ("reflectance", 3), "trans": ("transmittance", 3), "expo": ("exponent", 1),
                "ior": ("ior", 1)}

#: The fields of the tables planned from the analytic lights' places (``Tables._shadow_tables``),
#: with the lights themselves: what a light's update (``Tables._update_values``) makes anew.
LIGHT_FIELDS = ("lights", "shadow_need", "occ_custom", "occ_mitsuba", "any_shadow", "shadow_inner",
                "occ_boxes", "occ_mslots", "occ_shapes", "lbuf")
#: The fields of the tables made from the links1 shapes' geometry (``Tables._shape_tables``): with
#: the light tables (planned from the shapes' bounds too), what a geometry update makes anew.
SHAPE_FIELDS = ("custom", "custom_unrolled", "bvh_slots", "bvh", "blob_tables")


class Tables:
    """``prepare``: the per-scene tables; ``_occluders``: which shadow rays they need."""

    __slots__ = ()

    def prepare(self, scene, sensor=None):
        """The tables of ``scene`` seen from ``sensor`` (a sensor object, an index into
        ``scene.sensors()``, or None: the scene's first sensor), rebuilt when the scene is
        another one or was changed.

        The scene's tables (shapes, materials, lights, shadow rays) are keyed on what they
        are built from, never on ``id(scene)``: the registry ids of the scene's shapes,
        emitters and sensors (P keeps those objects alive, so no other scene can reuse the
        ids), the part of the tuning they are built from (``tuning.Tuning.tables_key``: light
        buffers, BVH), and, while ``verify_scene``, every parameter ``mi.traverse`` exposes, watched
        by its Dr.Jit variables (:class:`ParamWatch`: a ``params.update()`` after a render
        is seen, and nothing is read back from the device). ``n_scene_builds`` and
        ``n_camera_views`` count the tables built. Each sensor gets its own
        view of them (:meth:`_camera_view`: camera, film, filter, eye buffer) as a distinct
        object, so a frozen launch recorded for one sensor's camera (``cfg`` holds the
        view's id) is never replayed for another."""
        self.adopt(scene)
        ident = scene_identity(scene)
        V = self._prep
        B = getattr(V, "base", None)
        same = B is not None and B.ident == ident and B.tuning.tables_key() == tuning.current().tables_key()
        if same and (not self.verify_scene or B.watch.unchanged(scene)):
            pass
        elif not (same and self._update_values(B, scene)):
            # (after _update_values, B's watch knows which parameters changed: the new watch
            # reads only those again)
            B = self._prepare_scene(scene, ident, B.watch if same else None)
        V = self._camera_view(B, scene, self._sensor_of(scene, sensor))
        self._prep = V
        return V

    def _update_values(self, B, scene) -> bool:
        """The tables ``B`` brought up to a change of ``links1_phong`` coefficients, analytic
        lights or links1 shapes' geometry only (``params.update()``
        re-prepares what the change touches), in place:

        - coefficients: the material rows re-read from the BSDFs; the frozen launch is kept
          (the rows are its inputs);
        - a light's values (a ``links1_point``'s or ``links1_spot``'s, a Mitsuba point, spot or
          directional emitter's own parameters): its ``P.lights`` entry and the tables planned
          from the lights' places (:meth:`_shadow_tables`: shadow rays, light buffers); the
          frozen launches start anew (the lights are constants in their kernels);
        - the links1 shapes' geometry (the integrator's parameters: a quadric's ``to_world``
          or clip offsets, a blob's centres, weights, radii, threshold; their specs already
          made anew by ``parameters_changed``): the shapes' tables (:meth:`_shape_tables`: the
          BVH built again over the same quadrics, the blob and quadric tables), the light
          tables (planned from the shapes' bounds too) and each camera view's eye buffer; the
          frozen launches start anew.

        Every other table (Mitsuba shapes, materials, emission, area and environment lights)
        is kept. False (the caller rebuilds all) for another scene or tuning, or any other
        change: a Mitsuba shape's or other object's (a light's texture too), a quadric that
        leaves or joins the BVH (its bounds become infinite or finite), or a Phong change that
        alters what the other tables are built from (the transmittance: shadow rays; which
        slots reflect or have ambient light: the kernels traced). ``n_value_updates`` counts
        the updates. Called by :meth:`prepare` only for tables of this scene and
        tuning, while ``verify_scene``, whose watch saw a change."""
        changed = B.watch.changed(scene)
        Phong = plugin_class("links1_phong")
        Pt, Sp = plugin_class("links1_point"), plugin_class("links1_spot")
        if not changed:
            return False
        phong = any(isinstance(node, Phong) for _, node in changed)
        light = geo = False
        for _, node in changed:
            if isinstance(node, Phong):
                continue
            if node is scene.integrator():    # the links1 shapes' geometry (integrator.traverse)
                geo = True
                continue
            if not (isinstance(node, (Pt, Sp)) or isinstance(node, mi.Emitter)
                    and kind_of(node) in ("PointLight", "SpotLight", "DirectionalEmitter")):
                return False
            light = True
        quad = None
        if geo:
            quad = self._bvh_quadrics(B)
            if frozenset(sp.slot for sp in quad) != B.bvh_slots:
                return False      # another split of the quadrics (one became unbounded)
        new, now = {}, None
        if phong:
            names = {k: PHONG_TABLES[k][0] for k in B.phong_np}   # (the transmittance: below)
            now = {k: np.zeros_like(v) for k, v in B.phong_np.items()}
            trans = np.zeros((B.nslots, 3))
            for sl, b in enumerate(B.keep_alive[3]):
                if isinstance(b, Phong):
                    p = b.params
                    for k, name in names.items():
                        now[k][sl] = p[name]
                    trans[sl] = p["transmittance"]
            if not (np.array_equal(trans, B.shadow_t_np) and bool(np.any(now["amb"] > 0)) == B.any_ambient
                    and bool(np.any(now["refl"].max(1) > 0)) == B.any_phong_r):
                return False
            # the tables whose values changed, made as _prepare_scene makes them (the same bits)
            new = {k: mi.Float(v.ravel()) for k, v in now.items() if not np.array_equal(v, B.phong_np[k])}
        if light:
            lights = [L for e in scene.emitters()
                      for L in [self._analytic_light(e, kind_of(e), Pt, Sp, B)] if L is not None]
            if len(lights) != len(B.lights):
                return False
            B.lights = lights
        if geo:
            self._shape_tables(B, quad)
        if light or geo:
            self._shadow_tables(B, scene, B.shape_list, B.slot_list, reuse=not geo)
            self._freeze = self._freeze_points = None
        for P in (B, *B.views.values()):
            for k, v in new.items():
                setattr(P, k, v)
            if now is not None:
                P.phong_np = now
            if (light or geo) and P is not B:
                for f in LIGHT_FIELDS + (SHAPE_FIELDS if geo else ()):
                    setattr(P, f, getattr(B, f))
                if geo:   # the camera rays' buffer around the eye (_camera_view)
                    P.eye_buf = lightbuffer.plan_eye(P, scene) if B.tuning.light_buffer else None
            P.frozen_inputs = None       # gathered again: the new arrays are the launch's inputs
            if light or geo or not B.all_phong or B.any_mitsuba_emission:
                P.scene_input = None     # the scene's variables (the BSDFs' new values) too
            # (all links1_phong: the launch's scene input leaves them out, launch._unread_bsdfs)
        B.watch = B.watch.renewed(scene)
        self.n_value_updates += 1
        return True

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
        """The tables ``B`` with ``sensor``'s camera, film and filter (a shallow copy of
        ``B``: the Dr.Jit tables are shared), one per sensor and kept with ``B``. A sensor
        that is not one of the scene's is watched (:class:`ParamWatch`) while
        ``verify_scene``, as the scene is."""
        own = any(sensor is s for s in B.keep_alive[2])
        check = self.verify_scene and not own
        V = B.views.get(id(sensor))
        if (V is not None and V.sensor is sensor and (V.sensor_watch is not None) == check
                and (not check or V.sensor_watch.unchanged(sensor))):
            return V
        V = copy.copy(B)
        V.base = B
        V.sensor_watch = ParamWatch(sensor) if check else None
        V.frozen_inputs = None
        V.scene_input = None
        self.n_camera_views += 1
        self._set_camera(V, sensor)
        # light buffer around a pinhole camera's eye for the camera rays' nearest quadric
        V.eye_buf = lightbuffer.plan_eye(V, scene) if B.tuning.light_buffer else None
        B.views[id(sensor)] = V     # V keeps the sensor alive: its id is not reused
        return V

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

    def _prepare_scene(self, scene, ident, watch=None):
        """The tables of ``scene`` that do not depend on the sensor (:meth:`prepare`); ``watch``:
        the last tables' (:meth:`ParamWatch.renewed`), or None."""
        P = Prepared()
        P.ident = ident
        P.tuning = tuning.current()     # what the tables are built with (tables_key)
        # before the tables read the parameters
        P.watch = ParamWatch(scene) if watch is None else watch.renewed(scene)
        self.n_scene_builds += 1
        P.keep_alive = (list(scene.shapes()), list(scene.emitters()), list(scene.sensors()))  # see scene_identity
        P.views, P.obj_params = {}, {}
        # recordings hold the previous tables, and their key names the tables by id(P): a new
        # P may get a dead one's id, so both frozen launches start anew
        self._freeze = self._freeze_points = None
        shapes, slot_list, nslots, P.member_slots = self._mitsuba_shapes(scene)
        P.shape_list, P.slot_list = shapes, slot_list
        P.nslots = nslots
        P.custom = self.custom
        # registry id -> slot
        reg = [int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(s))[0]) for s in shapes]
        table = np.full(max(reg + [0]) + 1, -1, dtype=np.int32)
        for r, sl in zip(reg, slot_list):
            table[r] = sl
        P.reg_to_slot = mi.Int32(checked_index(table, nslots, "reg_to_slot", sentinel=-1))
        P.any_mitsuba_shapes = len(shapes) > 0
        eps_np = np.full(max(nslots, 1), float(mi.math.RayEpsilon), dtype=np.float32)
        for s_, sl in zip(shapes, slot_list):
            if s_.is_mesh() or kind_of(s_) in _PRECISE_MITSUBA:
                eps_np[sl] = OFFSET_EPS
        for spec in self.custom:
            if spec.__class__.__name__ == "QuadricSpec":
                eps_np[spec.slot] = OFFSET_EPS
        P.eps_table = mi.Float(eps_np)
        # materials
        default_bsdf = None
        bsdfs = [None] * nslots
        for s, sl in zip(shapes, slot_list):
            bsdfs[sl] = s.bsdf()
        for spec in self.custom:
            b = self.custom_bsdfs.get(spec.slot)
            if b is None:
                if default_bsdf is None:
                    default_bsdf = mi.load_dict({"type": "diffuse"})
                b = default_bsdf
            bsdfs[spec.slot] = b
        Phong = plugin_class("links1_phong")
        is_phong = np.zeros(nslots, dtype=bool)
        amb = np.zeros((nslots, 3)); dif = np.zeros((nslots, 3)); spe = np.zeros((nslots, 3))
        refl = np.zeros((nslots, 3)); trans = np.zeros((nslots, 3))
        expo = np.zeros(nslots); ior = np.ones(nslots)
        has_dr = np.zeros(nslots, dtype=bool); has_dt = np.zeros(nslots, dtype=bool)
        has_null = np.zeros(nslots, dtype=bool)
        glossy = np.zeros(nslots, dtype=bool)
        inner = list(bsdfs)   # the BSDF whose delta lobes a slot samples (a mask's nested one)
        warned = set()
        for sl, b in enumerate(bsdfs):
            if b is None:
                continue
            if isinstance(b, Phong):
                p = b.params
                is_phong[sl] = True
                amb[sl], dif[sl], spe[sl] = p["ambient"], p["diffuse"], p["specular"]
                refl[sl], trans[sl] = p["reflectance"], p["transmittance"]
                expo[sl], ior[sl] = p["exponent"], p["ior"]
            else:
                fl = int(b.flags())
                has_dr[sl] = bool(fl & int(mi.BSDFFlags.DeltaReflection))
                has_dt[sl] = bool(fl & int(mi.BSDFFlags.DeltaTransmission))
                # Null: a straight-through delta lobe (thindielectric's transmission, mask's
                # transparency, null); its weight is eval_null_transmission
                has_null[sl] = bool(fl & int(mi.BSDFFlags.Null))
                inner[sl] = _unmask(mi, b)
                if has_null[sl] and has_dt[sl]:
                    name = kind_of(b)
                    if ("null+dt", name) not in warned:
                        warned.add(("null+dt", name))
                        warnings.warn(f"links1_whitted: BSDF {name} has both a refracted and a "
                                      "straight-through transmission (a mask around a "
                                      "dielectric); the straight-through part is dropped",
                                      stacklevel=2)
                    has_null[sl] = False
                if fl & int(mi.BSDFFlags.Diffuse):
                    glossy[sl] = True    # (a BSDF sample as for glossy lobes: Mitsuba's direct)
                if fl & int(mi.BSDFFlags.Glossy):
                    glossy[sl] = True
                    name = kind_of(b)
                    where = self.place(b)
                    if (where, name) not in warned:     # once per element
                        warned.add((where, name))
                        warnings.warn(f"{where}: BSDF {name} has glossy lobes; it gets direct "
                                      "light only (its glossy interreflections are not Whitted's light paths)",
                                      stacklevel=2)
        P.is_phong_np = is_phong
        P.all_phong = bool(is_phong.all())
        P.any_phong = bool(is_phong.any())
        P.is_phong = mi.Bool(is_phong)
        P.amb, P.dif, P.spe = (mi.Float(a.ravel()) for a in (amb, dif, spe))
        P.refl, P.trans = mi.Float(refl.ravel()), mi.Float(trans.ravel())
        P.expo, P.ior = mi.Float(expo), mi.Float(ior)
        P.phong_np = dict(amb=amb, dif=dif, spe=spe, refl=refl, expo=expo, ior=ior)
        P.any_ambient = bool(np.any(amb > 0))
        P.has_dr, P.has_dt, P.has_null = mi.Bool(has_dr), mi.Bool(has_dt), mi.Bool(has_null)
        P.any_mitsuba_dr, P.any_mitsuba_dt = bool(has_dr.any()), bool(has_dt.any())
        P.any_mitsuba_null = bool(has_null.any())
        P.any_mitsuba_delta = bool(np.any(has_dr | has_dt | has_null))
        # masks: their delta lobes are sampled on the nested BSDF and scaled by the opacity
        # (Mitsuba's mask.sample cannot sample one lobe alone: it returns its null lobe)
        # the delta lobes by component: each component of a slot's sampler (a mask's nested BSDF)
        # with a delta lobe is sampled on its own (BSDFContext.component): a blendbsdf weighs its
        # nested components by its weight there, where sampling the whole BSDF would pick one
        # nested BSDF by the sample; every smooth reflection has one direction, so the
        # components' weights add up (delta_components: lobe -> [(component, Bool per slot)])
        comp = {"r": {}, "t": {}}
        for sl, b in enumerate(bsdfs):
            if b is None or is_phong[sl] or not (has_dr[sl] or has_dt[sl]):
                continue
            s = inner[sl]
            for c in range(s.component_count()):
                fc = int(s.flags(c))
                for which, flag in (("r", mi.BSDFFlags.DeltaReflection), ("t", mi.BSDFFlags.DeltaTransmission)):
                    if fc & int(flag):
                        comp[which].setdefault(c, np.zeros(nslots, dtype=bool))[sl] = True
        P.delta_components = {k: [(c, mi.Bool(v)) for c, v in sorted(d.items())] for k, d in comp.items()}
        is_mask = np.array([b is not None and i is not b for b, i in zip(bsdfs, inner)], dtype=bool)
        P.any_mask = bool(is_mask.any())
        P.inner_ptr = mi.BSDFPtr([i if i is not None else default_bsdf for i in inner]) \
            if P.any_mask else None
        P.any_phong_r = bool(np.any(refl.max(1) > 0))
        P.any_phong_t = bool(np.any(trans.max(1) > 0))
        P.any_specular = P.any_mitsuba_delta or P.any_phong_r or P.any_phong_t
        P.glossy = mi.Bool(glossy)
        # links1_quadric shapes whose Mitsuba BSDF has a texture get the core's uv
        P.uv_slots = {sp.slot for sp in self.custom if sp.__class__.__name__ == "QuadricSpec"
                      and not is_phong[sp.slot] and _textured(bsdfs[sp.slot])}
        if default_bsdf is None and any(b is None for b in bsdfs):
            default_bsdf = mi.load_dict({"type": "diffuse"})
        bsdfs = [b if b is not None else default_bsdf for b in bsdfs]
        # a BSDFPtr array holds registry ids, not references: the BSDF objects (the default
        # made here above all) must live as long as the tables, or a vcall through a freed
        # id crashes the process
        P.keep_alive = P.keep_alive + (bsdfs,)
        if len(bsdfs) != nslots or any(b is None for b in bsdfs):
            raise RuntimeError("links1_whitted: the BSDF table has a hole (an internal inconsistency)")
        for spec in self.custom:
            checked_index([spec.slot], nslots, "custom shape slot")
        P.bsdf_ptr = mi.BSDFPtr(bsdfs) if not P.all_phong else None
        # shadow transmittance (3-3-3): Phong t; Mitsuba BSDFs are opaque
        P.shadow_t_np = trans.copy()
        self._shape_tables(P, self._bvh_quadrics(P))
        P.shadow_t = mi.Float(trans.ravel())
        # transparent Mitsuba shapes, each counted once per shadow segment (3-3-3): shape j
        # owns bit j % 32 of word j // 32 of a per-lane "seen" set (as many words as needed)
        transparent_mitsuba = [(s, sl) for s, sl in zip(shapes, slot_list) if trans[sl].max() > 0]
        bits = np.zeros(nslots, dtype=np.uint32)
        words = np.zeros(nslots, dtype=np.uint32)
        for j, (_, sl) in enumerate(transparent_mitsuba):
            bits[sl], words[sl] = np.uint32(1 << (j % 32)), np.uint32(j // 32)
        P.trans_bits, P.trans_words = mi.UInt32(bits), mi.UInt32(words)
        P.trans_nwords = max(1, -(-len(transparent_mitsuba) // 32))
        # a segment crosses each triangle at most once and an analytic shape at most twice,
        # and stops at the first opaque one: no arbitrary cap on crossings
        P.max_crossings = 1 + sum(int(s.face_count()) if s.is_mesh() else 2 for s, _ in transparent_mitsuba)
        P.any_transparent_mitsuba = bool(transparent_mitsuba)
        # (sub-scenes hold top-level shapes: a transparent shape inside an instance walks its crossings)
        P.shadow_split = shadow_split(mi, shapes, slot_list, trans) \
            if transparent_mitsuba and not any(sl in P.member_slots for _, sl in transparent_mitsuba) else None
        # emission
        emis = np.zeros((nslots, 3))
        for spec in self.custom:
            if spec.emission is not None:
                emis[spec.slot] = spec.emission
        P.custom_emission = mi.Float(emis.ravel())
        P.any_custom_emission = bool(np.any(emis > 0))
        # Mitsuba shapes that emit: area emitters only (a directionalarea is ignored, as the
        # emitter loop below says, so its shape shows no emission either)
        emits = np.zeros(max(nslots, 1), dtype=bool)
        for s, sl in zip(shapes, slot_list):
            if s.emitter() is not None and kind_of(s.emitter()) == "AreaLight":
                emits[sl] = True
        P.any_mitsuba_emission = bool(emits.any())
        P.mitsuba_emits = mi.Bool(emits)
        for s in shapes:
            if s.interior_medium() is not None or s.exterior_medium() is not None:
                warnings.warn(f"{self.place(s)}: its medium is not supported by links1_whitted and "
                              "is ignored", stacklevel=2)
        # lights
        P.lights, P.area, P.env, P.consts, P.area_tab = [], [], None, [], []
        n_env = 0
        Pt, Sp = plugin_class("links1_point"), plugin_class("links1_spot")
        for e in scene.emitters():
            kind = kind_of(e)
            L = self._analytic_light(e, kind, Pt, Sp, P)
            if L is not None:
                P.lights.append(L)
            elif kind == "ConstantBackgroundEmitter":
                rad = np.array(mi.traverse(e)["radiance.value"], dtype=np.float64).ravel()
                P.consts.append(("const", np.broadcast_to(rad, (3,)).copy(), ENV_LIGHT_ID + n_env))
                n_env += 1
                P.env = e
            elif kind == "EnvironmentMapEmitter":
                P.consts.append(("envmap", self._envmap_table(e), ENV_LIGHT_ID + n_env))
                n_env += 1
                P.env = e
            elif e.is_environment() or (int(e.flags()) & int(mi.EmitterFlags.Infinite)):
                warnings.warn(f"{self.place(e)}: emitter {kind} is seen as the background but "
                              "lights nothing", stacklevel=2)
                n_env += 1
                P.env = e
            elif kind == "AreaLight":   # a directionalarea (also Surface) is ignored, as in the core
                tab = self._area_table(e, shapes, slot_list)
                if tab is not None:
                    P.area.append(e)
                    P.area_tab.append(tab)
            else:
                warnings.warn(f"{self.place(e)}: emitter {kind} is not supported and is ignored",
                              stacklevel=2)
        # sample streams by place (as the core numbers them, whichever order Mitsuba gives the
        # shapes), and the area lights in that order
        order = number_area_lights([tab["light"] for tab in P.area_tab])
        P.area, P.area_tab = [P.area[i] for i in order], [P.area_tab[i] for i in order]
        for tab in P.area_tab:
            tab["id"] = tab["light"].light_id
        P.any_mis = bool(np.any(glossy)) and bool(P.area_tab or P.consts)
        self._shadow_tables(P, scene, shapes, slot_list)
        return P

    def _bvh_quadrics(self, P):
        """The links1 quadrics to put under a BVH (bvh.py) instead of one code block each:
        the bounded ones, when there are ``bvh_min`` of them; else none."""
        quad = [sp for sp in self.custom if sp.__class__.__name__ == "QuadricSpec"
                and np.all(np.isfinite(np.concatenate(sp.bounds())))]
        return quad if len(quad) >= P.tuning.bvh_min else []

    def _shape_tables(self, P, quad):
        """The tables made from the links1 shapes' geometry (what a ``params.update()`` of it
        redoes, :meth:`_update_values`): the quadrics ``quad`` under a BVH (its slots, the
        tree, each slot's place in it), the others traced in their own code
        (``custom_unrolled``) with their tables (shapes.py ``tables()``: their constants, a
        blob's candidate search), built before any trace (frozen inputs)."""
        in_bvh = {id(sp) for sp in quad}
        P.custom = self.custom
        P.custom_unrolled = [sp for sp in self.custom if id(sp) not in in_bvh]
        P.bvh_slots = frozenset(sp.slot for sp in quad)
        P.bvh = None
        if quad:
            P.bvh = QuadricBVH(quad, P.shadow_t_np)
            s2q = np.full(max(P.nslots, 1), -1, dtype=np.int32)
            for i, sp in enumerate(P.bvh.specs):
                s2q[sp.slot] = i
            P.bvh.slot_to_q = mi.Int32(checked_index(s2q, P.bvh.n, "slot_to_q", sentinel=-1))
        P.blob_tables = [sp.tables() for sp in P.custom_unrolled]

    def _shadow_tables(self, P, scene, shapes, slot_list, reuse=False):
        """The tables planned from the analytic lights' places (:data:`LIGHT_FIELDS`): what
        each light's shadow rays test (:meth:`_occluders`, ``reuse``: of the shapes' part
        made before) and the light buffers."""
        self._occluders(P, shapes, slot_list, reuse)
        # light buffers for the quadric shadow rays toward analytic lights (where they pay)
        P.lbuf = lightbuffer.plan(P, scene) if P.tuning.light_buffer else [None] * len(P.lights)

    def _mitsuba_shapes(self, scene):
        """``(shapes, slot_list, nslots, member_slots)``: Mitsuba's own shapes of ``scene``
        (links1 proxies left out) with their slots (:meth:`_slots`), then the shapes inside its
        shapegroups (:func:`group_members`), each a slot of its own after all others: a hit
        on an instance names the member, whose BSDF it takes (shared by every instance)."""
        shapes = [s for s in scene.shapes() if not proxies.is_proxy(s)]
        slot_list, nslots = self._slots(shapes)
        members = group_members(scene) if any(s.class_name() == "Instance" for s in shapes) else []
        member_slots = frozenset(range(nslots, nslots + len(members)))
        return shapes + members, slot_list + sorted(member_slots), nslots + len(members), member_slots

    def _slots(self, shapes):
        """``(slot_list, nslots)``: the slot of each of the Mitsuba ``shapes`` (file order, or the
        loader's ``slot_of_id``) and the number of slots (links1 shapes included)."""
        slot_of_id = self.slot_of_id
        if slot_of_id is None:
            # a scene the loader did not see (mi.load_file / load_string / load_dict): each
            # shape's slot is its place in the scene's shapes (links1 proxies included:
            # Integrator.adopt), whatever its id (none, or shared)
            order = self.adopted
            if order is None:
                return list(range(len(shapes))), len(shapes)
            pos = {k: i for i, k in enumerate(order)}
            return [pos[id(s)] for s in shapes], len(order)
        else:
            slot_list = []
            for s in shapes:
                if s.id() not in slot_of_id:
                    raise RuntimeError(f"links1_whitted: shape '{s.id()}' is unknown to the loader")
                slot_list.append(slot_of_id[s.id()])
            nslots = len(slot_of_id) + len(self.custom)
        return slot_list, nslots

    @staticmethod
    def _params_of(P, obj):
        """``mi.traverse(obj)`` of a native Mitsuba object, made once for the tables ``P`` (their
        base's): it reads each parameter when asked (``mi.get_property``), so it gives the
        current values after ``params.update()``, and a traversal costs ~0.15 ms a call."""
        B = P.base if P.base is not None else P
        prm = B.obj_params.get(id(obj))
        if prm is None:
            prm = B.obj_params[id(obj)] = mi.traverse(obj)
        return prm

    def _analytic_light(self, e, kind, Pt, Sp, P):
        """The ``P.lights`` entry of the emitter ``e`` (its ``kind``: :func:`~.util.kind_of`) when
        it is an analytic light: a ``links1_point`` (``Pt``) or ``links1_spot`` (``Sp``), a
        Mitsuba point, spot, projector (these two with an image: ``memitter``) or directional
        emitter; else None.
        ``P``: the tables it is for (:meth:`_params_of`)."""
        if isinstance(e, Pt):
            p = e.params
            return ("point", p["position"], p["direction"], p["L1"], p["L2"],
                    p["falloff"] == "inverse_square")
        if isinstance(e, Sp):
            p = e.params
            return ("cspot", p["origin"], p["direction"], p["radius"], p["intensity"])
        if kind not in ("PointLight", "SpotLight", "DirectionalEmitter", "Projector"):
            return None
        prm = self._params_of(P, e)
        if kind == "PointLight":
            pos = np.array(prm["position"], dtype=np.float64).ravel()
            I = _emitted_rgb(prm, "intensity", kind, self.place(e))
            return ("point", pos, np.array([0, 0, 1.0]), I, np.zeros(3), True)
        m = np.array(prm["to_world"].matrix, dtype=np.float64).reshape(4, 4)
        if kind == "Projector":   # a delta light projecting an image: Mitsuba's own evaluation
            return ("memitter", m[:3, 3], e)
        if kind == "DirectionalEmitter":
            E = _emitted_rgb(prm, "irradiance", kind, self.place(e))
            return ("dir", m[:3, 2] / np.linalg.norm(m[:3, 2]), E)
        if any(k.startswith("texture.") and k != "texture.value" for k in prm.keys()):
            # a projector (its texture varies): Mitsuba's own evaluation of the emitter
            return ("memitter", m[:3, 3], e)
        I = _emitted_rgb(prm, "intensity", kind, self.place(e))
        if "texture.value" in prm.keys():   # a constant texture scales the intensity
            I = I * _emitted_rgb(prm, "texture", kind, self.place(e))
        cutoff = float(np.array(prm["cutoff_angle"]).ravel()[0])
        beam = float(np.array(prm["beam_width"]).ravel()[0])
        return ("mspot", m[:3, 3].copy(), m[:3, 2] / np.linalg.norm(m[:3, 2]), I, cutoff, beam)

    def _occluders(self, P, shapes, slot_list, reuse=False):
        """Which shapes can lie between a lit point and each light (skip what can't).

        A convex shape (sphere, capped quadric, rectangle, disk) never shadows its own
        points toward a light on the outer side of the surface there; a closed one (sphere,
        capped quadric) does where the light is on the inner side (``P.shadow_inner``, same
        rule as links1.tracing.occluders). A planar shape shadows nothing when the light and every
        other shape lie on the same side of its plane. ``P.shadow_need[j]``: per slot,
        whether hits on that slot need a shadow ray toward light ``j``; ``P.occ_custom[j]``
        / ``P.occ_mitsuba[j]``: the links1 shapes / whether any Mitsuba shape can occlude
        it. Conservative. What the shapes alone decide (``P.occ_shapes``:
        :meth:`_occluder_shapes`) is made once per build, and a light's update reuses it (``reuse``)."""
        if not reuse:
            # (a geometry update: the Mitsuba shapes' part of the last planning kept)
            P.occ_shapes = self._occluder_shapes(P, shapes, slot_list, getattr(P, "occ_shapes", None))
        G = P.occ_shapes
        nslots, convex, plane, tol = P.nslots, G["convex"], G["plane"], G["tol"]
        lights = []   # (position or None, direction toward the light or None, emitter slot or None)
        for L in P.lights:
            if L[0] == "dir":
                lights.append(("dir", -np.asarray(L[1], dtype=np.float64)))
            elif L[0] == "cspot":
                lights.append(("dir", -np.asarray(L[2], dtype=np.float64)))
            else:
                lights.append(("pos", np.asarray(L[1], dtype=np.float64)))
        for e in P.area:
            lights.append(("area", e))
        for _ in P.consts:
            lights.append(("env", None))
        P.shadow_need, P.occ_custom, P.occ_mitsuba, P.any_shadow = [], [], [], []
        P.shadow_inner, P.occ_boxes, P.occ_mslots = [], [], []
        for light in lights:
            occ = np.ones(nslots, dtype=bool)
            for sl in range(nslots):
                if plane[sl] is None or light[0] == "env":   # environments: every direction
                    continue
                nrm, c = plane[sl]
                if light[0] == "area":
                    sh = light[1].get_shape()
                    bb = sh.bbox() if sh is not None else None
                    if bb is None:
                        continue
                    lside = _side_of_box(nrm, c, np.array([bb.min[0], bb.min[1], bb.min[2]]),
                                         np.array([bb.max[0], bb.max[1], bb.max[2]]), tol)
                elif light[0] == "dir":
                    lside = point_side(float(light[1] @ nrm), 0.0)
                else:
                    lside = point_side(float(light[1] @ nrm - c), tol)
                if lside != 0 and G["others"][sl] in (lside, None):   # None: no other shape
                    occ[sl] = False
            if light[0] == "area":      # a convex emitter never hides its own sampled points
                own = P.area_tab[P.area.index(light[1])]["slot"]
                if own is not None and convex[own]:
                    occ[own] = False
            # a hit needs a shadow ray if any shape but itself (when convex) can occlude
            need = np.count_nonzero(occ) - (occ & convex) > 0
            inner = occ & G["closed"] & ~need
            P.shadow_need.append(None if need.all() else mi.Bool(need))
            P.shadow_inner.append(mi.Bool(inner) if inner.any() else None)
            P.any_shadow.append(bool(need.any() or inner.any()))
            P.occ_custom.append([spec for spec in self.custom if occ[spec.slot]])
            msl = occ & G["mitsuba_slot"]
            P.occ_mitsuba.append(bool(np.any(msl)))
            P.occ_boxes.append(occluder_boxes(msl, G["lo"], G["hi"], convex))
            P.occ_mslots.append(frozenset(int(v) for v in np.flatnonzero(msl)))

    def _occluder_shapes(self, P, shapes, slot_list, last=None):
        """What :meth:`_occluders` needs of the shapes, whatever the lights: per slot its box
        (``lo``, ``hi``), whether it is ``convex`` / ``closed`` / a Mitsuba shape, a planar
        shape's ``plane`` (unit normal, offset) and the side of that plane every other
        shape's box lies on (``others``: +1, -1, 0 for neither, None for no other shape),
        and the tolerance ``tol`` of those tests. ``last``: the planning of the same tables
        before a change of the links1 shapes' geometry only, whose Mitsuba shapes' part (their
        boxes, kinds, planes: ~0.1 ms of device reads an update) is taken as it is."""
        nslots = P.nslots
        if last is not None and len(last["plane"]) == nslots:
            m = last["mitsuba_slot"]
            lo, hi = np.where(m[:, None], last["lo"], -np.inf), np.where(m[:, None], last["hi"], np.inf)
            convex, closed = last["convex"] & m, last["closed"] & m
            plane, mitsuba_slot = list(last["plane"]), m.copy()
            shapes = ()                          # (their part is the last one)
        else:
            lo = np.full((nslots, 3), -np.inf)
            hi = np.full((nslots, 3), np.inf)
            convex = np.zeros(nslots, dtype=bool)
            closed = np.zeros(nslots, dtype=bool)   # convex and enclosing a volume
            plane = [None] * nslots
            mitsuba_slot = np.zeros(nslots, dtype=bool)
        for s_, sl in zip(shapes, slot_list):
            mitsuba_slot[sl] = True
            if sl in P.member_slots:     # its box is the group's, not the world's: unbounded
                continue
            b = s_.bbox()
            lo[sl] = [b.min[0], b.min[1], b.min[2]]
            hi[sl] = [b.max[0], b.max[1], b.max[2]]
            kind = kind_of(s_)
            if kind in ("Sphere", "Rectangle", "Disk"):
                convex[sl] = True
                closed[sl] = kind == "Sphere"
            if kind in ("Rectangle", "Disk"):
                try:
                    m = np.array(own_param(s_, "to_world").matrix, dtype=np.float64).reshape(4, 4)
                    nrm = np.cross(m[:3, 0], m[:3, 1])
                    if np.linalg.norm(nrm) > 0:
                        nrm = nrm / np.linalg.norm(nrm)
                        plane[sl] = (nrm, float(nrm @ m[:3, 3]))
                except Exception:
                    pass
        for spec in self.custom:
            a, b = spec.bounds()
            lo[spec.slot], hi[spec.slot] = a, b
            if spec.__class__.__name__ == "QuadricSpec":
                convex[spec.slot] = (spec.kind == "sphere" and (not spec.clips or spec.capped)) or \
                    (spec.kind == "cylinder" and spec.capped and len(spec.clips) >= 2)
                closed[spec.slot] = convex[spec.slot]
        scale = 1.0 + float(np.max(np.abs(np.where(np.isfinite(lo), lo, 0.0)))) + \
            float(np.max(np.abs(np.where(np.isfinite(hi), hi, 0.0))))
        tol = 1e-6 * scale
        others = [None] * nslots
        for sl in range(nslots):
            if plane[sl] is not None:
                sides = {_side_of_box(*plane[sl], lo[o], hi[o], tol) for o in range(nslots) if o != sl}
                others[sl] = None if not sides else (sides.pop() if len(sides) == 1 else 0)
        return dict(lo=lo, hi=hi, convex=convex, closed=closed, plane=plane,
                    mitsuba_slot=mitsuba_slot, others=others, tol=tol)
