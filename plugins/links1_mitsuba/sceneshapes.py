"""The links1 shapes a ``links1_whitted`` renders (their one home in the engine): the
``links1_quadric`` and ``links1_blob`` specs of its scene, given by the loader
(:meth:`SceneShapes.attach`) or found among a plainly loaded scene's shapes
(:meth:`SceneShapes.adopt`: the proxies, :mod:`links1_mitsuba.proxies`), their BSDFs, their
geometry as ``mi.traverse`` parameters (:mod:`links1_mitsuba.geometry`) and the slots of every
shape (file order). The tables (tables.py) read them; the derivative pass reads their attached
geometry (gradients.py).
"""
from __future__ import annotations

from . import geometry, proxies
from .util import place_of


class SceneShapes:
    """The links1 shapes of the engine's scene, their BSDFs and geometry, and where each
    object of the file is (for warnings)."""

    __slots__ = (
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
    )

    def __init__(self, custom_bsdfs=None, shared_bsdfs=()):
        self.custom = []
        self.geo = self.geo_seen = None
        self.custom_bsdfs = dict(custom_bsdfs or {})
        self.shared_bsdfs = set(shared_bsdfs)
        self.adopted = self.proxy_slots = None
        self.slot_of_id = self.shape_names = self.places = None

    def attach(self, custom, slot_of_id, shape_names=None, places=None):
        """Called by the loader: the custom shapes, the file order of all shapes and where
        each object is in the file (for warnings)."""
        self._hold(list(custom))
        self.slot_of_id = dict(slot_of_id)
        self.shape_names = shape_names
        self.places = places

    def adopt(self, scene) -> bool:
        """A scene the loader did not attach (``mi.load_file``, ``mi.load_string``,
        ``mi.load_dict``): its links1 shapes are the proxies among its shapes
        (:mod:`links1_mitsuba.proxies`), each shape's slot its place in ``scene.shapes()``,
        and each proxy's BSDF its own (matched by object, never by id). Made again only
        for another scene (or other shapes): whether it was (the tables then start anew)."""
        if self.slot_of_id is not None:      # the loader's scene: attach() said it all
            return False
        shapes = list(scene.shapes())
        key = tuple(id(s) for s in shapes)
        if self.adopted == key:
            return False
        found = proxies.specs_of(shapes)
        self._hold([sp for _, sp in found])
        self.custom_bsdfs = {sl: shapes[sl].bsdf() for sl, _ in found}
        self.shared_bsdfs = set(self.custom_bsdfs)    # each proxy's BSDF is named under its shape
        self.proxy_slots = frozenset(sl for sl, _ in found)
        self.adopted = key
        return True

    def _hold(self, custom):
        """``custom`` the shapes, their geometry held as Dr.Jit values (and seen)."""
        self.custom = custom
        self.geo = {sp.slot: geometry.hold(sp) for sp in custom}
        self.geo_seen = {sl: geometry.seen(h) for sl, h in self.geo.items()}

    def place(self, obj, what: str = "links1_whitted") -> str:
        """``FILE:LINE: <element>`` of a scene object for a warning, else ``what``."""
        return place_of(obj, self.places or {}) or what

    def slots(self, shapes):
        """``(slot_list, nslots)``: the slot of each of the Mitsuba ``shapes`` (file order, or the
        loader's ``slot_of_id``) and the number of slots (links1 shapes included)."""
        slot_of_id = self.slot_of_id
        if slot_of_id is None:
            # a scene the loader did not see (mi.load_file / load_string / load_dict): each
            # shape's slot is its place in the scene's shapes (links1 proxies included:
            # adopt), whatever its id (none, or shared)
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

    def parameters_changed(self) -> bool:
        """``params.update()``: each links1 shape whose geometry's Dr.Jit variables are not
        those seen last gets a new spec (:func:`geometry.updated`, checked as the loader checks
        a file); whether any did."""
        changed = False
        for i, sp in enumerate(self.custom):
            held = (self.geo or {}).get(sp.slot)
            mine = geometry.changed(held, self.geo_seen[sp.slot]) if held is not None else []
            if mine:
                self.custom[i] = geometry.updated(sp, held, mine)
                self.geo_seen[sp.slot] = geometry.seen(held)
                changed = True
        return changed
