"""The schema of ``links1_whitted``'s per-scene tables: :class:`Prepared`, one slotted dataclass
(every field named, typed and commented; an undeclared name is an AttributeError), a sensor's
:class:`CameraView` of it (its own :class:`ViewFields`, the rest read through the scene's
tables), and the groups of its fields that an in-place update makes anew (:data:`LIGHT_FIELDS`,
:data:`SHAPE_FIELDS`) or that hold the ``links1_phong`` coefficients (:data:`PHONG_TABLES`).
Made by ``tables.Tables.prepare``.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING

from . import tuning

if TYPE_CHECKING:   # the fields' types (annotations only)
    from links1.sensor.filters import Filter

    from .paramwatch import ParamWatch


def _set_later():
    """A field :meth:`Tables._prepare_scene` (or the camera view, :func:`views.set_camera`)
    always sets: no default, so reading it before it is set is an AttributeError."""
    return field(init=False, repr=False)


def _default(value=None):
    """A field the code reads before (or without) setting it: ``value`` until set."""
    return field(init=False, repr=False, default=value)


@dataclass(slots=True, eq=False)
class ViewFields:
    """The fields of a sensor's view of the tables (:func:`views.camera_view`): those
    of a :class:`CameraView` and of :class:`Prepared` (None / unset on the scene's tables)."""

    #: the scene's tables (None: these are the scene's tables)
    base: Prepared | None = _default(None)
    #: a sensor that is not the scene's, watched (:class:`ParamWatch`) while verify_scene
    sensor_watch: ParamWatch | None = _default(None)
    #: the Dr.Jit arrays of these tables (``launch.frozen_inputs``), once gathered
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


@dataclass(slots=True, eq=False)
class Prepared(ViewFields):
    """The per-scene tables the kernels read (:meth:`Tables.prepare`): slots (the shapes in
    file order: Mitsuba's first, then the links1 shapes), materials, shadow rays, emission,
    lights, and in a derivative pass's copy of a camera view (:meth:`CameraView.tables`) the
    camera and film (a view itself is a :class:`CameraView`: its own fields, the rest read
    through the scene's tables).

    Every field is declared here (``slots``: assigning an undeclared name is an
    AttributeError). The Dr.Jit arrays among them reach the frozen launches as their
    ``tables`` input (``launch.frozen_inputs`` walks the fields). Per-slot tables have
    ``nslots`` rows; the RGB ones are flat Floats of 3 values per slot. ``eq=False``: tables are
    compared (and hashed) by identity."""

    # -- scene identity and bookkeeping
    #: the scene's shapes, emitters and sensors as object ids (:func:`tables.scene_identity`)
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
    #: the camera views of these tables, by ``id(sensor)`` (:func:`views.camera_view`)
    views: dict = _set_later()
    #: ``mi.traverse`` of objects the tables read again on updates (:func:`lights.params_of`)
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
    #: Embree's geometry id (a preliminary hit's ``shape_index``: the shape's index in
    #: ``scene.shapes()``) -> slot (-1: none), Int32; None where the scene has instances (there
    #: ``shape_index`` is the member's index in its group)
    geom_to_slot: object = _default(None)
    #: ``geom_to_slot`` is the identity (every shape of ``scene.shapes()`` the slot of its index)
    geom_slot_identity: bool = _default(False)
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
    #: has_dr | has_dt | has_null as numpy (nslots,) bool
    mitsuba_delta_np: object = _set_later()
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
    #: per slot: a hit there can spawn a child (a links1_phong slot that reflects or transmits,
    #: a Mitsuba BSDF with a delta or Null lobe), Bool: the lobes are computed under a
    #: symbolic branch on it (raytree.Tracer._secondary)
    spawns: object = _set_later()
    #: per slot: the Mitsuba BSDF has a diffuse or glossy lobe (Bool); direct light from the
    #: sampled lights at such hits adds a BSDF sample, combined by multiple importance sampling
    #: (``any_mis``: some such slot and some area or environment light); links1_phong keeps
    #: the paper's light samples alone
    glossy: object = _set_later()
    any_mis: bool = _set_later()
    #: the links1 quadric slots whose Mitsuba BSDF has a texture (they get the core's uv)
    uv_slots: set = _set_later()
    #: per slot: direct light can reach the eye from a hit there (a links1_phong slot, a Mitsuba
    #: BSDF with a smooth lobe), Bool: the direct light is computed under a symbolic branch on
    #: it (raytree.Tracer.level); every slot is such a slot
    shaded: object = _set_later()
    all_shaded: bool = _set_later()
    #: the BSDF of each slot (BSDFPtr), None when every slot is links1_phong
    bsdf_ptr: object = _set_later()
    #: where every Mitsuba shape is a mesh, rectangle, sphere or disk, or an instance of them,
    #: their buffers and transforms from which the kernel makes the nearest hit's surface record
    #: itself (``tables.MeshRecord``: ``intersect.mesh_surface``), else None
    mesh_record: object = _default(None)
    # -- Mitsuba ``diffuse`` BSDFs of one reflectance value (``rgb`` or a float, no texture),
    #    alone or as a ``twosided``'s one BSDF: evaluated in the kernel (raytree.Hit.f_eval) with
    #    the float operations of Mitsuba's SmoothDiffuse::eval, without a BSDF call
    #: per slot: such a BSDF (Bool); in a ``twosided`` (Bool); its reflectance (flat Float, RGB)
    lam: object = _set_later()
    lam_two: object = _set_later()
    lam_rgb: object = _set_later()
    #: the reflectances as numpy ((nslots, 3) float32) and their spectrum objects ({slot:
    #: object}): what a value update (``Tables._update_values``) reads and compares with
    #: (a derivative pass calls the BSDFs: Mitsuba differentiates the reflectance)
    lam_np: object = _set_later()
    lam_src: dict = _set_later()
    #: some slot is such a diffuse BSDF / in a twosided; every Mitsuba BSDF's slot is one
    any_lam: bool = _set_later()
    any_lam_two: bool = _set_later()
    all_lam: bool = _set_later()

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
    #: the analytic lights, one record each (lights.py): ``PointRecord`` (links1 and Mitsuba point
    #: lights), ``CylinderSpotRecord`` (links1_spot), ``MitsubaSpotRecord``, ``DirectionalRecord``,
    #: ``MitsubaEmitterRecord`` (a textured spot, a projector)
    lights: list = _set_later()
    #: the sampled area emitters and their tables (``lights.area_table``)
    area: list = _set_later()
    area_tab: list = _set_later()
    #: the environment emitter seen by escaping rays, or None
    env: object = _set_later()
    #: the environment lights: ``ConstantEnvRecord`` or ``EnvMapRecord`` (lights.py)
    consts: list = _set_later()
    #: per light (analytic, then area, then environment; :func:`shadow_plan.plan_occluders`): the slots
    #: whose hits need a shadow ray (Bool, None: all), the closed shapes that shadow their own
    #: points from the inside (Bool or None), whether any shadow ray is traced, the links1
    #: shapes / whether any Mitsuba shape can occlude it, the Mitsuba occluders' boxes
    #: (:func:`shadow_plan.occluder_boxes`) and slots
    shadow_need: list = _set_later()
    shadow_inner: list = _set_later()
    any_shadow: list = _set_later()
    occ_custom: list = _set_later()
    occ_mitsuba: list = _set_later()
    occ_boxes: list = _set_later()
    occ_mslots: list = _set_later()
    #: what the shapes alone decide of those (``shadow_plan.occluder_shapes``)
    occ_shapes: dict = _set_later()
    #: per analytic light: its light buffer (lightbuffer.plan) or None
    lbuf: list = _set_later()

    # -- a derivative pass (gradients.py: a copy with attached values)
    #: the attached geometry of the links1 shapes, or None
    geo_ad: object = _default(None)
    #: whether no moving surface (``geo_ad``) can spawn a mirror or refraction ray: the
    #: children's rays then carry no derivative (``raytree_ad.trace_tree_ad`` detaches them)
    fixed_children: bool = _default(True)
    #: what one derivative pass makes once for all its levels (``geometry.surface_ad``'s memo)
    ad_memo: object = _default(None)
    #: whether any parameter the pass reads has gradients enabled
    attached_any: bool = _default(False)




@dataclass(slots=True, eq=False)
class CameraView(ViewFields):
    """A sensor's view of the scene's tables ``base`` (:func:`views.camera_view`):
    it holds only its own fields, the sensor's camera, film, filter and eye buffer and the
    launches' inputs gathered for it, and reads every other field of :class:`Prepared` through
    ``base``, so an in-place update of the scene's tables (``Tables._update_values``) is what
    each view sees. ``launch.frozen_inputs`` walks its fields, ``base`` among them."""

    def __getattr__(self, name):
        # (called only for a name that is not one of the view's set fields)
        if name in _VIEW_FIELDS or name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.base, name)

    def tables(self) -> Prepared:
        """A :class:`Prepared` holding the base's fields and this view's (a shallow copy: the
        tables' values are shared), ``base`` the scene's tables: what a derivative pass puts
        its attached values in (``Gradients._ad_tables``)."""
        Q = copy.copy(self.base)
        for f in _VIEW_FIELDS:
            if hasattr(self, f):
                setattr(Q, f, getattr(self, f))
        return Q


_VIEW_FIELDS = frozenset(f.name for f in fields(ViewFields))


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
