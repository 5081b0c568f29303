"""Which shadow rays a scene needs, planned once per scene on the host (numpy): which shapes can
lie between a lit point and each light (:func:`plan_occluders`, the same rules as
:mod:`links1.tracing.occluders`, the side of a plane from :mod:`links1.maths.halfspace`), the
boxes of the few Mitsuba shapes a shadow ray is first tested against (:func:`occluder_boxes`),
the sub-scenes of the transparent ones (:func:`shadow_split`) and the lights at a pinhole
camera's eye, toward which its rays' hits need no shadow ray (:func:`eye_lights`).
"""
from __future__ import annotations

import math
import warnings

import drjit as dr
import mitsuba as mi
import numpy as np

from links1.geometry.shapes import TriangleMesh
from links1.maths.halfspace import box_side, point_side
from links1.tracing.occluders import _plane_of, lights_at_eye, near_reach

from .lights import POSITIONED, DirectionalRecord, CylinderSpotRecord
from .paramwatch import own_param
from .util import PLAIN_MESHES, kind_of

#: Shadow rays toward a light that at most this many Mitsuba shapes can occlude first test the
#: segment against those shapes' bounding boxes and call Embree only where one is met
#: (``intersect.shadow_mitsuba``); above it Embree's own BVH culls better
BOX_CULL_MAX = 8

#: Scenes with at most this many transparent Mitsuba shapes test shadow rays with one any-hit
#: query per transparent shape and one over the opaque ones (``shadow_split``) instead of
#: walking the crossings nearest first
SPLIT_MAX = 8

#: Mitsuba meshes of at most this many faces are tested for the core's planar and convex
#: rules (:func:`_mesh_rules`); larger ones are taken as neither (conservative)
MESH_RULES_MAX = 256


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




def _side_of_box(nrm, c, a, b, tol):
    """-1 / +1 if the box ``a``-``b`` is in the closed half-space below / above the plane
    ``x · nrm = c`` (within ``tol``), else 0 (an unbounded box: 0): the core's rule
    (:func:`links1.maths.halfspace.box_side`) with the plugin's plane form and tolerance."""
    return box_side(a, b, lambda corners: corners @ nrm - c, tol)


def plan_occluders(P, custom, shapes, slot_list, reuse=False):
    """Which shapes can lie between a lit point and each light (skip what can't).

    A convex shape (sphere, capped quadric, rectangle, disk) never shadows its own
    points toward a light on the outer side of the surface there; a closed one (sphere,
    capped quadric) does where the light is on the inner side (``P.shadow_inner``, same
    rule as links1.tracing.occluders). A planar shape shadows nothing when the light and every
    other shape lie on the same side of its plane. ``P.shadow_need[j]``: per slot,
    whether hits on that slot need a shadow ray toward light ``j``; ``P.occ_custom[j]``
    / ``P.occ_mitsuba[j]``: the links1 shapes / whether any Mitsuba shape can occlude
    it. Conservative. What the shapes alone decide (``P.occ_shapes``:
    :func:`occluder_shapes`) is made once per build, and a light's update reuses it (``reuse``)."""
    if not reuse:
        # (a geometry update: the Mitsuba shapes' part of the last planning kept)
        P.occ_shapes = occluder_shapes(P, custom, shapes, slot_list, getattr(P, "occ_shapes", None))
    G = P.occ_shapes
    nslots, convex, plane, tol = P.nslots, G["convex"], G["plane"], G["tol"]
    lights = []   # (position or None, direction toward the light or None, emitter slot or None)
    for L in P.lights:
        if isinstance(L, (DirectionalRecord, CylinderSpotRecord)):
            lights.append(("dir", -np.asarray(L.direction, dtype=np.float64)))
        else:
            lights.append(("pos", np.asarray(L.position, dtype=np.float64)))
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
        P.occ_custom.append([spec for spec in custom if occ[spec.slot]])
        msl = occ & G["mitsuba_slot"]
        P.occ_mitsuba.append(bool(np.any(msl)))
        P.occ_boxes.append(occluder_boxes(msl, G["lo"], G["hi"], convex))
        P.occ_mslots.append(frozenset(int(v) for v in np.flatnonzero(msl)))


def eye_lights(tables) -> tuple:
    """Per analytic light of ``tables`` (a camera view, ``tables.lights``): whether the hits of
    its camera's rays need no shadow ray toward it, the light at the eye of a pinhole
    perspective camera and no shape's box within the near plane's reach
    (:func:`links1.tracing.occluders.lights_at_eye`, the core's rule; the shapes inside
    instances by the instances' boxes). All False for another
    camera, a light without a position or one whose position is a Dr.Jit value (a derivative
    pass's), and before the shapes are planned."""
    lights = tables.lights
    G = getattr(tables, "occ_shapes", None)
    if not tables.perspective or tables.lens is not None or G is None:
        return (False,) * len(lights)
    W, H = tables.film_size
    tn = math.tan(math.radians(tables.x_fov) / 2.0)
    positions = [L.position if isinstance(L, POSITIONED) and not dr.is_array_v(L.position) else None
                 for L in lights]
    eye = np.asarray(tables.cam, dtype=np.float64)[:3, 3]
    # a shapegroup's members are bounded by their instances' world boxes (their own: unbounded)
    keep = [sl for sl in range(len(G["lo"])) if sl not in tables.member_slots]
    return tuple(lights_at_eye(eye, near_reach(tables.near, tn, tn * H / W), positions,
                               zip(G["lo"][keep], G["hi"][keep])))


def _mesh_rules(s_):
    """``(convex, closed, plane)`` of a small Mitsuba mesh by the core's planar rule
    (:mod:`links1.tracing.occluders`): a planar mesh is convex, with its plane (unit normal,
    offset); else neither. The core's other rule, a closed convex mesh never shadowing its own
    points toward a light outside it, is not taken: with it the cull skips a cube's own box
    where its shadow rays leave it, and pixels of ``scenes/mitsuba_direct.xml``'s cube changed."""
    v = np.array(s_.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3)
    f = np.array(s_.faces_buffer(), dtype=np.int64).reshape(-1, 3)
    if v.size == 0 or f.size == 0 or not np.all(np.isfinite(v)):
        return False, False, None
    pl = _plane_of(TriangleMesh(v, f))
    if pl is None:
        return False, False, None
    nrm, p0 = pl
    return True, False, (nrm, float(nrm @ p0))


def occluder_shapes(P, custom, shapes, slot_list, last=None):
    """What :func:`plan_occluders` needs of the shapes, whatever the lights: per slot its box
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
        elif s_.is_mesh() and kind in PLAIN_MESHES and int(s_.face_count()) <= MESH_RULES_MAX:
            convex[sl], closed[sl], plane[sl] = _mesh_rules(s_)
    for spec in custom:
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
