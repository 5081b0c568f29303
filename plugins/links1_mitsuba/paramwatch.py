"""Whether a Mitsuba object's parameters changed (:class:`ParamWatch`: by the Dr.Jit variables
of every parameter ``mi.traverse`` exposes, nothing read back from the device), and one
parameter of an object itself read cheaply (:func:`own_param`). The per-scene tables
(tables.py) keep a watch of their scene, each camera view of a sensor made apart.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from .util import Hidden


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


#: :class:`ParamWatch` reads the own values of a watched object of Mitsuba's C++ classes by their
#: fields' addresses, as a child's (False: it traverses the object one level at each check)
ROOT_BY_ADDRESS = True

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
    the frozen launch's inputs from the tables (``launch.frozen_inputs``) takes the pins
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
            for name in ("_own", "_retraverse", "_jit", "_jit_keys", "_scalar", "_scalar_keys", "_root_keys",
                         "_root"):
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
                self._root = self._fixed_root(obj, params)
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
                    # another reference to the same variables, the AD one too (an attached
                    # value, ``params.update(opt)``: an AD index in the upper 32 bits; under
                    # ``suspend_grad``, as ``prepare`` runs, a copy would drop it). Never
                    # ``value`` itself: a C++ object's parameter is a view of its field, which
                    # the next ``params.update()`` overwrites; the old variables freed, a new
                    # value may get their indices and the change go unseen (the frozen
                    # launch's scene input then hands freeze freed variables: an abort)
                    with dr.resume_grad():
                        p = type(value)(value)
                except Exception:  # noqa: BLE001 - a type that cannot be copied so
                    p = None
                if p is not None and tuple(collect(p)) == ids:
                    pins[k] = p
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

    @staticmethod
    def _fixed_root(obj, params):
        """``(class, [(key, field, cpptype)])``: ``obj``'s own values where a C++ class of
        Mitsuba's puts them all as fields (its keys fixed by the class; read by address at each
        check of an object of that class, with it as their node, as a child's are), else None (a
        Python plugin, a value put by value: ``obj`` traversed one level at each check)."""
        if not ROOT_BY_ADDRESS or not type(obj).__module__.startswith("mitsuba"):
            return None
        own = [(k, v, ct) for k, (v, ct, node, _) in params.properties.items() if node is obj]
        return (type(obj), own) if all(ct is not None for _, _, ct in own) else None

    def _node_entries(self, obj):
        """``[(key, (value, cpptype, node))]`` of ``obj``'s own values and those the Python
        plugins (and the scene's integrator) hand out, their nodes traversed one level, in the
        watch's keys; None where they are not the watched ones (keys added or gone)."""
        if self._root is not None and type(obj) is self._root[0] and ROOT_BY_ADDRESS:
            out = [(k, (v, ct, obj)) for k, v, ct in self._root[1]]
        else:
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




def _own_entry(obj, name):
    """``(value, cpptype)`` of ``obj``'s own parameter ``name`` as its ``traverse`` puts it (a
    C++ field's address and type; a Python plugin's value and None); KeyError as
    ``mi.traverse`` when ``obj`` has no such one."""
    cb = ParamWatch._Shallow.make(mi)
    cb.out = []
    obj.traverse(cb)
    for n, v, ct in cb.out:
        if n == name:
            return v, ct
    raise KeyError(name)


def own_param(obj, name):
    """``mi.traverse(obj)[name]`` for a parameter of ``obj`` itself (not of a child object),
    read through one ``obj.traverse`` with :class:`ParamWatch`'s callback class: Mitsuba's
    ``mi.traverse`` defines its callback class anew at every call (~0.2 ms, most of a rebuild's
    five calls on a small scene). KeyError as ``mi.traverse`` when ``obj`` has no such one."""
    v, ct = _own_entry(obj, name)
    return v if ct is None else mi.get_property(v, ct, obj)


def set_own_param(obj, name, value) -> None:
    """``obj``'s own parameter ``name``, a C++ object's field, set to ``value`` as
    ``mi.traverse(obj)[name] = value`` sets it, without ``parameters_changed``: for a value
    the object had (normals.settle_moved). KeyError as :func:`own_param`."""
    v, ct = _own_entry(obj, name)
    if ct is None:
        raise KeyError(f"{name}: not a C++ field of {obj.class_name()}")
    mi.set_property(v, ct, value)
