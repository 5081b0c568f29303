"""``links1_whitted``: the LINKS-1 method (digest §2–4) as a Mitsuba 3 integrator in Dr.Jit.

Recursion design (``_trace_tree``): two kernels per frame, whatever the depth.

1. The camera level: every sample's ray is intersected (Mitsuba shapes through
   ``scene.ray_intersect``, links1 quadrics and blobs in Dr.Jit, nearest wins) and shaded
   (eq. 3.11 under every light, shadow rays with transmittance); its mirror and refraction
   children are computed.
2. The samples that spawn children are compacted (``dr.compress``, order kept) and one
   symbolic ``dr.while_loop`` traces the rest of their ray trees, one ray per iteration: the
   mirror child (eq. 3.12) is followed next, a refraction child (eq. 3.14-3.15) with a mirror
   sibling waits on a small per-lane stack (Dr.Jit local memory). ``I = I_o + r I_r + t I_t``
   (eq. 3.16) is accumulated as the sum of ``weight · I_o`` over the tree (weight = product of
   the factors down the branch), then scattered back to its sample (one writer per sample).

A branch stops when its weight falls to ``min_weight`` (default 1/255, as the core). Lanes
never interact, so a window renders the same bits as the same pixels of the full frame, and
every run-time input (window offset and width, seed) is an opaque value: the kernels compile
once per scene and are reused for every window and frame. Many links1 quadrics go under a BVH
(:mod:`links1_mitsuba.bvh`).

What a scene doesn't need is not traced (decided once per scene in ``prepare``): no
refraction code without transmissive surfaces, no reflection without reflective ones, no loop
at all without either, no custom-shape code without custom shapes, no blob solver without
blobs, no shadow ray toward a light from a hit that no shape can shadow (``_occluders``: a
lone convex shape, a floor below every other shape and the light, ...). ``stats`` holds the
ray counts of the last render by kind.
"""
from __future__ import annotations

import hashlib
import math
import warnings

import numpy as np

from links1.filters import Filter
from links1.lights import ENV_LIGHT_ID
from links1.render import AOVS, DEFAULT_ADAPTIVE_DEPTH, channel_names
from links1.sampling import light_tag

from .launch import _CAM_SAMPLE, define_launches

INF = float("inf")
#: Relative ray-origin offset on shapes whose float32 hits are accurate to a few ulps
#: (meshes, rectangles, disks, links1 quadrics): a small offset keeps shadow rays that graze
#: an object on the same side as the float64 core. Mitsuba's sphere/cylinder and links1
#: blobs (iterative roots) use Mitsuba's RayEpsilon (self-shadowing otherwise).
OFFSET_EPS = 2.0 ** -19
_PRECISE_MITSUBA = ("Mesh", "OBJMesh", "PLYMesh", "Rectangle", "Disk", "Links1Bicubic", "SerializedMesh")
#: Default weight below which a branch of the ray tree is not traced (POV-Ray's adc_bailout;
#: the same default as links1.integrator.DEFAULT_MIN_WEIGHT).
DEFAULT_MIN_WEIGHT = 1.0 / 255.0
#: Custom quadrics with finite bounds go under a BVH (bvh.py) from this many on.
BVH_MIN = 8
_M1 = 0x7FEB352D
_M2 = 0x846CA68B


def _emitted_rgb(prm, key: str, kind: str) -> np.ndarray:
    """An emitter's RGB ``key`` from ``mi.traverse``: its value, or for a ``blackbody`` spectrum
    (which Mitsuba's RGB variants cannot evaluate) the colour the core uses
    (:func:`links1.spectra.blackbody_to_rgb`, with a warning)."""
    if f"{key}.value" in prm:
        v = np.array(prm[f"{key}.value"], dtype=np.float64).ravel()
        return np.broadcast_to(v, (3,)).copy() if v.size == 1 else v
    if f"{key}.temperature" in prm:
        from links1.spectra import blackbody_to_rgb
        t = float(np.array(prm[f"{key}.temperature"]).ravel()[0])
        rgb = blackbody_to_rgb(t)
        warnings.warn(f"links1_whitted: {kind} {key} is a blackbody ({t:g} K), which Mitsuba's RGB "
                      f"variants cannot evaluate; using the colour its spectral variants integrate "
                      f"to, {np.round(rgb, 6).tolist()}", stacklevel=3)
        return rgb
    raise ValueError(f"links1_whitted: {kind} '{key}' must be an RGB value or a blackbody spectrum "
                     "(textured emitters are not supported)")


def parse_aovs(value) -> list:
    if value is None:
        return []
    if isinstance(value, str):
        items = [s.strip() for s in value.replace(";", ",").split(",") if s.strip()]
    else:
        items = [str(s).strip() for s in value]
    for a in items:
        if a not in AOVS:  # one naming for both renderers (links1.render)
            raise ValueError(f"unknown AOV '{a}': allowed are {sorted(AOVS)}")
    return items


def _textured(bsdf) -> bool:
    """Whether a Mitsuba BSDF has a texture (bitmap and checkerboard expose ``to_uv``)."""
    import mitsuba as mi
    return bsdf is not None and any(k.endswith("to_uv") for k in mi.traverse(bsdf).keys())


def define_integrator():
    import drjit as dr
    import mitsuba as mi

    from ._registry import plugin_class

    def mix32(x):
        """lowbias32 on UInt32 (wrapping), as links1.sampling.mix32."""
        x = x ^ (x >> 16)
        x = x * _M1
        x = x ^ (x >> 15)
        x = x * _M2
        x = x ^ (x >> 16)
        return x

    def u24(x):
        return mi.Float(x >> 8) * (2.0 ** -24)

    def c3(v):
        return mi.Color3f(float(v[0]), float(v[1]), float(v[2]))

    def v3(v):
        return mi.Vector3f(float(v[0]), float(v[1]), float(v[2]))

    def gl(src, idx, active=True):
        """Gather from an array of the same type as ``src``."""
        return dr.gather(type(src), src, idx, active)

    def gather3(table, idx, active=True):
        return dr.gather(mi.Color3f, table, idx, active)

    class _Untraversed:
        """Attributes that :func:`drjit.freeze` does not walk. It traverses the scene (an input
        of the frozen window function) and with it this integrator's ``__dict__``; the Dr.Jit
        arrays of the per-scene tables reach the frozen function through
        ``Links1Whitted._frozen_inputs``, and walking the shape specs (thousands in big scenes)
        on every call would cost more than rendering a small window."""

        def _traverse_1_cb_ro(self, fn):
            pass

        def _traverse_1_cb_rw(self, fn):
            pass

    def _hidden_attr(name):
        return property(lambda self: getattr(self._hidden, name, None),
                        lambda self, v: setattr(self._hidden, name, v))

    def next_up(x):
        """The next float32 above positive ``x`` (infinity stays): a strict ``t < limit`` test
        against ``next_up(t)`` accepts a tie at ``t``."""
        return dr.select(dr.isfinite(x) & (x >= 0), dr.reinterpret_array(
            mi.Float, dr.reinterpret_array(mi.UInt32, x) + 1), x)

    def scene_identity(scene):
        """The scene's shapes, emitters and sensors as object identities (cheap: no parameters).
        Prepared tables keep those objects alive, so another scene's objects cannot take the
        same identities while the tables are kept."""
        ids = []
        for objs in (scene.shapes(), scene.emitters(), scene.sensors()):
            ids.append(len(objs))
            ids += [id(o) for o in objs]
        return tuple(ids)

    def scene_digest(scene) -> bytes:
        """A digest of every parameter ``mi.traverse(scene)`` exposes, by value."""
        h = hashlib.blake2b(digest_size=16)
        params = mi.traverse(scene)
        for k in sorted(params.keys()):
            v = params[k]
            h.update(k.encode())
            try:
                a = np.asarray(v.matrix if hasattr(v, "matrix") else v)
            except Exception:  # noqa: BLE001 - a value numpy cannot read: its text
                h.update(repr(v).encode())
                continue
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(np.ascontiguousarray(a).tobytes())
        return h.digest()

    class Prepared:
        """Per-scene tables: slots (shapes in file order), materials, lights, camera."""

    Launches = define_launches(mi, dr, mix32, u24)

    class Links1Whitted(mi.SamplingIntegrator):
        r"""LINKS-1 Whitted ray tracer (``links1_whitted``), paper 3-1 and 3-3, eq. (3.11)–(3.16).

        ==========  =======  ==========================================================  =======
        Parameter   Type     Meaning                                                     Default
        ==========  =======  ==========================================================  =======
        max_depth   integer  surface interactions along one branch of the ray tree       5
                             (primary hit = 1; 1 = direct light only)
        seed        integer  seed of the sample pattern (links1.sampling)                0
        aovs        string   comma-separated extra channels: depth, normal, id, cost     ""
        min_weight  float    a secondary ray is traced only if the largest RGB component  1/255
                             of its weight in the pixel (product of the r / t factors
                             down the tree) exceeds this; 0 traces every branch
        light_samples int    shadow rays per sampled light (environment) per hit        1
        adaptive    float    adaptive anti-aliasing threshold (links1.adaptive) instead  none
                             of the sampler's count; ``mi.render`` and render_window
        adaptive_depth int   most refinement levels of ``adaptive``                     2
        ==========  =======  ==========================================================  =======

        Shading: ``links1_phong`` surfaces use eq. (3.11) (ambient + diffuse + highlight),
        other Mitsuba BSDFs are evaluated through Mitsuba (``bsdf.eval``) for delta lights
        and their delta lobes (mirror, glass) are recursed with their own weights; rough
        BSDFs get direct light only (warning). Lights: ``links1_point``, ``links1_spot``,
        Mitsuba ``point``, ``spot``, ``directional`` (evaluated analytically, shadow rays
        scaled by the transmittance of every object crossed, once per object); ``area``
        emitters (mesh, rectangle, cube, sphere, disk), ``constant`` and ``envmap`` are sampled
        with ``light_samples`` shadow rays each on the core's light-sample points
        (:mod:`links1.lights`, :func:`links1.sampling.light_samples_uv`) and are also the
        radiance of escaping rays (``constant``/``envmap``). Custom shapes (``links1_quadric``, ``links1_blob``) come
        from :func:`links1_mitsuba.load_file`.

        ``mi.render(scene)`` renders the film's crop window; :meth:`render_window` renders any
        window ``(x0, y0, w, h)`` of the full film without recompiling kernels.
        """

        custom = _hidden_attr("custom")
        custom_bsdfs = _hidden_attr("custom_bsdfs")
        slot_of_id = _hidden_attr("slot_of_id")
        shape_names = _hidden_attr("shape_names")
        _prep = _hidden_attr("prep")
        _freeze = _hidden_attr("freeze")
        _freeze_points = _hidden_attr("freeze_points")
        stats = _hidden_attr("stats")

        def __init__(self, props):
            super().__init__(props)
            self._hidden = _Untraversed()
            md = int(props.get("max_depth", 5))
            if md == -1:
                md = 5
            if md < 1:
                raise ValueError(f"links1_whitted: max_depth must be >= 1 (or -1), got {md}")
            self.max_depth = md
            self.seed = int(props.get("seed", 0))
            self.min_weight = float(props.get("min_weight", DEFAULT_MIN_WEIGHT))
            self.light_samples = int(props.get("light_samples", 1))
            if self.light_samples < 1:
                raise ValueError(f"links1_whitted: light_samples must be >= 1, got {self.light_samples}")
            if not self.min_weight >= 0:
                raise ValueError(f"links1_whitted: min_weight must be >= 0, got {self.min_weight}")
            self.aovs = parse_aovs(props.get("aovs", ""))
            self.adaptive = None
            if "adaptive" in props:
                from links1.adaptive import check_options
                try:
                    self.adaptive, self.adaptive_depth = check_options(
                        props.get("adaptive"), props.get("adaptive_depth", DEFAULT_ADAPTIVE_DEPTH))
                except Exception as e:
                    raise ValueError(f"links1_whitted: {e}") from None
            elif "adaptive_depth" in props:
                raise ValueError("links1_whitted: adaptive_depth needs adaptive")
            self.custom_bsdfs = {}
            for key in props.keys():
                if key.startswith("_l1_bsdf_"):
                    self.custom_bsdfs[int(key[len("_l1_bsdf_"):])] = props[key]
            self.custom = []          # QuadricSpec / BlobSpec, set by the loader
            self.slot_of_id = None    # Mitsuba shape id -> slot (file order), set by the loader
            self.shape_names = None
            self._prep = None
            #: check the scene's parameters (mi.traverse) before reusing the prepared tables;
            #: MitsubaRenderer, whose scene is its own, turns it off for its launches
            self.verify_scene = True
            self.stats = {}
            #: render windows through a frozen function (:meth:`_frozen_fn`): no re-tracing
            self.use_freeze = True
            self._freeze = None

        # -------------------------------------------------------------- set-up
        def attach(self, custom, slot_of_id, shape_names=None):
            """Called by the loader: the custom shapes and the file order of all shapes."""
            self.custom = list(custom)
            self.slot_of_id = dict(slot_of_id)
            self.shape_names = shape_names
            self._prep = None

        def prepare(self, scene):
            """The per-scene tables, rebuilt when the scene is another one or was changed.

            Keyed on what they are built from, never on ``id(scene)``: the registry ids of
            the scene's shapes, emitters and sensors (P keeps those objects alive, so no other
            scene can reuse the ids), and, while ``verify_scene``, a digest of every parameter
            ``mi.traverse`` exposes (a ``params.update()`` after a render is seen)."""
            ident = scene_identity(scene)
            P = self._prep
            if P is not None and P.ident == ident and (not self.verify_scene or P.content == scene_digest(scene)):
                return P
            P = Prepared()
            P.ident = ident
            P.content = scene_digest(scene)
            P.keep_alive = (list(scene.shapes()), list(scene.emitters()), list(scene.sensors()))  # see scene_identity
            self._freeze = None       # recordings hold the previous tables
            shapes = list(scene.shapes())
            slot_of_id = self.slot_of_id
            if slot_of_id is None:
                slot_of_id = {s.id(): i for i, s in enumerate(shapes)}
                nslots = len(shapes)
                slot_list = [slot_of_id[s.id()] for s in shapes]
            else:
                slot_list = []
                for s in shapes:
                    if s.id() not in slot_of_id:
                        raise RuntimeError(f"links1_whitted: shape '{s.id()}' is unknown to the loader")
                    slot_list.append(slot_of_id[s.id()])
                nslots = len(slot_of_id) + len(self.custom)
            P.nslots = nslots
            P.custom = self.custom
            # blobs' candidate-search tables, built before any trace (frozen inputs)
            P.blob_tables = [sp.tables() for sp in self.custom if hasattr(sp, "tables")]
            # many bounded quadrics: tables under a BVH (bvh.py) instead of one code block each
            quad = [sp for sp in self.custom if sp.__class__.__name__ == "QuadricSpec"
                    and np.all(np.isfinite(np.concatenate(sp.bounds())))]
            P.bvh = None
            P.custom_unrolled = list(self.custom)
            if len(quad) >= BVH_MIN:
                bvh_ids = {id(sp) for sp in quad}
                P.custom_unrolled = [sp for sp in self.custom if id(sp) not in bvh_ids]
                P.bvh_slots = {sp.slot for sp in quad}
            # registry id -> slot
            reg = [int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(s))[0]) for s in shapes]
            table = np.full(max(reg + [0]) + 1, -1, dtype=np.int32)
            for r, sl in zip(reg, slot_list):
                table[r] = sl
            P.reg_to_slot = mi.Int32(table)
            P.any_mitsuba_shapes = len(shapes) > 0
            eps_np = np.full(max(nslots, 1), float(mi.math.RayEpsilon), dtype=np.float32)
            for s_, sl in zip(shapes, slot_list):
                if s_.is_mesh() or str(s_).split("[")[0] in _PRECISE_MITSUBA:
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
                    if fl & int(mi.BSDFFlags.Glossy):
                        name = str(b).split("[")[0]
                        if name not in warned:
                            warned.add(name)
                            warnings.warn(f"links1_whitted: BSDF {name} has glossy lobes; it gets direct "
                                          "light from delta lights only (no glossy indirect light)",
                                          stacklevel=2)
            P.is_phong_np = is_phong
            P.all_phong = bool(is_phong.all())
            P.any_phong = bool(is_phong.any())
            P.is_phong = mi.Bool(is_phong)
            P.amb, P.dif, P.spe = (mi.Float(a.ravel()) for a in (amb, dif, spe))
            P.refl, P.trans = mi.Float(refl.ravel()), mi.Float(trans.ravel())
            P.expo, P.ior = mi.Float(expo), mi.Float(ior)
            P.any_ambient = bool(np.any(amb > 0))
            P.has_dr, P.has_dt = mi.Bool(has_dr), mi.Bool(has_dt)
            P.any_mitsuba_dr, P.any_mitsuba_dt = bool(has_dr.any()), bool(has_dt.any())
            P.any_mitsuba_delta = bool(np.any(has_dr | has_dt))
            P.any_phong_r = bool(np.any(refl.max(1) > 0))
            P.any_phong_t = bool(np.any(trans.max(1) > 0))
            P.any_specular = P.any_mitsuba_delta or P.any_phong_r or P.any_phong_t
            # links1_quadric shapes whose Mitsuba BSDF has a texture get the core's uv
            P.uv_slots = {sp.slot for sp in self.custom if sp.__class__.__name__ == "QuadricSpec"
                          and not is_phong[sp.slot] and _textured(bsdfs[sp.slot])}
            P.bsdf_ptr = mi.BSDFPtr([b if b is not None else default_bsdf for b in bsdfs]) \
                if not P.all_phong else None
            # shadow transmittance (3-3-3): Phong t; Mitsuba BSDFs are opaque
            P.shadow_t_np = trans.copy()
            if len(P.custom_unrolled) != len(self.custom):
                from .bvh import define_bvh
                P.bvh = define_bvh()([sp for sp in self.custom if sp.slot in P.bvh_slots], P.shadow_t_np)
                s2q = np.full(max(nslots, 1), -1, dtype=np.int32)
                for i, sp in enumerate(P.bvh.specs):
                    s2q[sp.slot] = i
                P.bvh.slot_to_q = mi.Int32(s2q)
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
            # emission
            emis = np.zeros((nslots, 3))
            for spec in self.custom:
                if spec.emission is not None:
                    emis[spec.slot] = spec.emission
            P.custom_emission = mi.Float(emis.ravel())
            P.any_custom_emission = bool(np.any(emis > 0))
            P.any_mitsuba_emission = any(s.emitter() is not None for s in shapes)
            # lights
            P.lights, P.area, P.env, P.consts, P.area_tab = [], [], None, [], []
            n_env = 0
            Pt, Sp = plugin_class("links1_point"), plugin_class("links1_spot")
            for e in scene.emitters():
                kind = str(e).split("[")[0]
                if isinstance(e, Pt):
                    p = e.params
                    P.lights.append(("point", p["position"], p["direction"], p["L1"], p["L2"],
                                     p["falloff"] == "inverse_square"))
                elif isinstance(e, Sp):
                    p = e.params
                    P.lights.append(("cspot", p["origin"], p["direction"], p["radius"], p["intensity"]))
                elif kind == "PointLight":
                    prm = mi.traverse(e)
                    pos = np.array(prm["position"], dtype=np.float64).ravel()
                    I = _emitted_rgb(prm, "intensity", kind)
                    P.lights.append(("point", pos, np.array([0, 0, 1.0]), I, np.zeros(3), True))
                elif kind == "SpotLight":
                    prm = mi.traverse(e)
                    m = np.array(prm["to_world"].matrix, dtype=np.float64).reshape(4, 4)
                    I = _emitted_rgb(prm, "intensity", kind)
                    cutoff = float(np.array(prm["cutoff_angle"]).ravel()[0])
                    beam = float(np.array(prm["beam_width"]).ravel()[0])
                    P.lights.append(("mspot", m[:3, 3].copy(), m[:3, 2] / np.linalg.norm(m[:3, 2]),
                                     I, cutoff, beam))
                elif kind == "DirectionalEmitter":
                    prm = mi.traverse(e)
                    m = np.array(prm["to_world"].matrix, dtype=np.float64).reshape(4, 4)
                    E = _emitted_rgb(prm, "irradiance", kind)
                    P.lights.append(("dir", m[:3, 2] / np.linalg.norm(m[:3, 2]), E))
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
                    warnings.warn(f"links1_whitted: emitter {kind} is seen as the background but "
                                  "lights nothing", stacklevel=2)
                    n_env += 1
                    P.env = e
                elif int(e.flags()) & int(mi.EmitterFlags.Surface):
                    tab = self._area_table(e, shapes, slot_list)
                    if tab is not None:
                        P.area.append(e)
                        P.area_tab.append(tab)
                else:
                    warnings.warn(f"links1_whitted: emitter {kind} is not supported and is ignored",
                                  stacklevel=2)
            # camera
            sensor = scene.sensors()[0]
            film = sensor.film()
            P.sensor = sensor
            P.film_size = (int(film.size()[0]), int(film.size()[1]))
            P.rfilter = Filter.from_mitsuba(film.rfilter())
            P.perspective = str(sensor).startswith("PerspectiveCamera")
            if P.perspective:
                prm = mi.traverse(sensor)
                P.x_fov = float(np.array(prm["x_fov"]).ravel()[0])
                P.cam = np.array(sensor.world_transform().matrix, dtype=np.float64).reshape(4, 4)
                P.near, P.far = float(sensor.near_clip()), float(sensor.far_clip())
            else:
                warnings.warn("links1_whitted: non-perspective sensor: rays from sensor.sample_ray",
                              stacklevel=2)
            self._occluders(P, shapes, slot_list)
            self._prep = P
            return P

        def _occluders(self, P, shapes, slot_list):
            """Which shapes can lie between a lit point and each light (skip what can't).

            A convex shape (sphere, capped quadric, rectangle, disk) never shadows its own
            points toward a light on the outer side of the surface there; a closed one (sphere,
            capped quadric) does where the light is on the inner side (``P.shadow_inner``, same
            rule as links1.occluders). A planar shape shadows nothing when the light and every
            other shape lie on the same side of its plane. ``P.shadow_need[j]``: per slot,
            whether hits on that slot need a shadow ray toward light ``j``; ``P.occ_custom[j]``
            / ``P.occ_mitsuba[j]``: the links1 shapes / whether any Mitsuba shape can occlude
            it. Conservative."""
            nslots = P.nslots
            lo = np.full((nslots, 3), -np.inf)
            hi = np.full((nslots, 3), np.inf)
            convex = np.zeros(nslots, dtype=bool)
            closed = np.zeros(nslots, dtype=bool)   # convex and enclosing a volume
            plane = [None] * nslots
            mitsuba_slot = np.zeros(nslots, dtype=bool)
            for s_, sl in zip(shapes, slot_list):
                mitsuba_slot[sl] = True
                b = s_.bbox()
                lo[sl] = [b.min[0], b.min[1], b.min[2]]
                hi[sl] = [b.max[0], b.max[1], b.max[2]]
                kind = str(s_).split("[")[0]
                if kind in ("Sphere", "Rectangle", "Disk"):
                    convex[sl] = True
                    closed[sl] = kind == "Sphere"
                if kind in ("Rectangle", "Disk"):
                    try:
                        m = np.array(mi.traverse(s_)["to_world"].matrix, dtype=np.float64).reshape(4, 4)
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

            def side_of_box(nrm, c, a, b):
                """-1 / +1 if the box is in the closed half-space below / above the plane, else 0."""
                if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
                    return 0
                corners = np.array([[x, y, z] for x in (a[0], b[0]) for y in (a[1], b[1]) for z in (a[2], b[2])])
                dist = corners @ nrm - c
                if np.all(dist >= -tol):
                    return 1
                if np.all(dist <= tol):
                    return -1
                return 0

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
            P.shadow_inner = []
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
                        lside = side_of_box(nrm, c, np.array([bb.min[0], bb.min[1], bb.min[2]]),
                                            np.array([bb.max[0], bb.max[1], bb.max[2]]))
                    elif light[0] == "dir":
                        v = float(light[1] @ nrm)
                        lside = 1 if v > 0 else (-1 if v < 0 else 0)
                    else:
                        v = float(light[1] @ nrm - c)
                        lside = 1 if v > tol else (-1 if v < -tol else 0)
                    if lside == 0:
                        continue
                    if all(side_of_box(nrm, c, lo[o], hi[o]) == lside for o in range(nslots) if o != sl):
                        occ[sl] = False
                if light[0] == "area":      # a convex emitter never hides its own sampled points
                    own = P.area_tab[P.area.index(light[1])]["slot"]
                    if own is not None and convex[own]:
                        occ[own] = False
                need = np.array([bool(np.any(occ & ~((np.arange(nslots) == sl) & convex[sl])))
                                 for sl in range(nslots)], dtype=bool)
                inner = occ & closed & ~need
                P.shadow_need.append(None if need.all() else mi.Bool(need))
                P.shadow_inner.append(mi.Bool(inner) if inner.any() else None)
                P.any_shadow.append(bool(need.any() or inner.any()))
                P.occ_custom.append([spec for spec in self.custom if occ[spec.slot]])
                P.occ_mitsuba.append(bool(np.any(occ & mitsuba_slot)))

        # -------------------------------------------------------------- geometry
        def _nearest(self, P, scene, o, d, tmin, tmax, active, cost):
            """Nearest hit over Mitsuba shapes and custom shapes: (t, slot, si, prim, custom_won)."""
            if P.any_mitsuba_shapes:
                ray = mi.Ray3f(o + d * tmin, d, tmax - tmin)
                si = scene.ray_intersect(ray, active=active)
                valid = active & si.is_valid()
                t = dr.select(valid, si.t + tmin, INF)
                reg = dr.reinterpret_array(mi.UInt32, si.shape)
                slot = dr.select(valid, dr.gather(mi.Int32, P.reg_to_slot, reg, valid), -1)
                cost += dr.select(active, mi.UInt32(1), 0)
            else:
                si = dr.zeros(mi.SurfaceInteraction3f, dr.width(o))
                t = dr.full(mi.Float, INF, dr.width(o))
                slot = dr.full(mi.Int32, -1, dr.width(o))
            prim = dr.zeros(mi.UInt32, dr.width(o))
            # ties at the same distance go to the lower slot (file order), as in the core
            # (links1.accel): a shape after the current best may not tie, one before it may
            for spec in P.custom_unrolled:
                tt = dr.minimum(t, tmax)
                tt = dr.select(slot > spec.slot, next_up(tt), tt)
                if spec.__class__.__name__ == "BlobSpec":
                    tc, pc = spec.intersect(o, d, tmin, tt, active, cost)
                else:
                    tc, pc = spec.intersect(o, d, tmin, tt, active)
                    cost += dr.select(active, mi.UInt32(1), 0)
                better = (tc < t) | ((tc == t) & (slot > spec.slot))
                t = dr.select(better, tc, t)
                slot = dr.select(better, spec.slot, slot)
                prim = dr.select(better, pc, prim)
            if P.bvh is not None:
                tq, q, part, found = P.bvh.nearest(o, d, tmin, next_up(dr.minimum(t, tmax)), active, cost)
                sq = mi.Int32(dr.gather(mi.UInt32, P.bvh.slot, q, found))
                better = found & ((tq < t) | ((tq == t) & ((slot < 0) | (sq < slot))))
                t = dr.select(better, tq, t)
                slot = dr.select(better, sq, slot)
                prim = dr.select(better, part, prim)
            return t, slot, si, prim

        def _shadow_custom(self, P, o, d, smax, active, cost, specs=None):
            """Transmittance (3-3-3) through the links1 shapes: product of shadow_t over the
            shapes the segment hits, once per shape."""
            T = dr.select(active, mi.Color3f(1.0), mi.Color3f(0.0))
            specs = P.custom if specs is None else specs
            if P.bvh is not None:
                if any(sp.slot in P.bvh_slots for sp in specs):
                    T = P.bvh.transmittance(o, d, smax, active, cost)
                specs = [sp for sp in specs if sp.slot not in P.bvh_slots]
            for spec in specs:
                st = P.shadow_t_np[spec.slot]
                act = active & (dr.max(T) > 0)
                if spec.__class__.__name__ == "BlobSpec":
                    tc, _ = spec.intersect(o, d, 0.0, smax, act, cost, any_hit=True)
                else:
                    tc, _ = spec.intersect(o, d, 0.0, smax, act)
                    cost += dr.select(act, mi.UInt32(1), 0)
                hit = act & (tc < INF)
                T = dr.select(hit, T * c3(st), T)
            return T

        def _shadow_mitsuba(self, P, scene, o, d, smax, active, T, cost):
            """Continue the transmittance ``T`` through Mitsuba's shapes (once per shape)."""
            if not P.any_mitsuba_shapes:
                return T
            act = active & (dr.max(T) > 0)
            if not P.any_transparent_mitsuba:
                occluded = scene.ray_test(mi.Ray3f(o, d, smax, 0.0, mi.Color0f()), active=act)  # (o, d, x) would set time, not maxt
                cost += dr.select(act, mi.UInt32(1), 0)
                return dr.select(occluded, 0.0, T)
            reg_to_slot, bits_t, words_t, sh_t = P.reg_to_slot, P.trans_bits, P.trans_words, P.shadow_t
            nwords, max_crossings = P.trans_nwords, P.max_crossings

            def cond(o, tleft, T, seen, run, it, cost):
                return run

            def body(o, tleft, T, seen, run, it, cost):
                si = scene.ray_intersect(mi.Ray3f(o, d, tleft, 0.0, mi.Color0f()), active=run)
                cost += dr.select(run, mi.UInt32(1), 0)
                hit = run & si.is_valid()
                reg = dr.reinterpret_array(mi.UInt32, si.shape)
                slot = dr.gather(mi.Int32, reg_to_slot, reg, hit)
                bit = dr.gather(mi.UInt32, bits_t, mi.UInt32(slot), hit)
                word = dr.gather(mi.UInt32, words_t, mi.UInt32(slot), hit)
                opaque = hit & (bit == 0)
                mine = [hit & (bit != 0) & (word == k) for k in range(nwords)]
                new = hit & mi.Bool(False)
                for k in range(nwords):
                    new = new | (mine[k] & ((seen[k] & bit) == 0))
                T = dr.select(opaque, 0.0, T)
                T = dr.select(new, T * gather3(sh_t, mi.UInt32(slot), new), T)
                seen = [dr.select(new & mine[k], seen[k] | bit, seen[k]) for k in range(nwords)]
                nxt = si.spawn_ray(d)
                tleft = dr.select(hit, tleft - si.t, tleft)
                o = dr.select(hit, nxt.o, o)
                it += 1
                run = hit & ~opaque & (it < max_crossings) & (tleft > 0)
                return o, tleft, T, seen, run, it, cost

            n = dr.width(o)
            state = (mi.Point3f(o), mi.Float(smax), T, [dr.zeros(mi.UInt32, n) for _ in range(nwords)], mi.Bool(act),
                     dr.zeros(mi.UInt32, n), dr.zeros(mi.UInt32, n))
            o, tleft, T, seen, run, it, c_loop = dr.while_loop(state, cond, body)
            cost += c_loop
            return T

        # -------------------------------------------------------------- lights
        def _light(self, L, p):
            """(wi, dist, L_s) of one analytic light at points p (digest §4.1)."""
            kind = L[0]
            if kind == "point":
                _, pos, direction, L1, L2, inv_sq = L
                to_light = v3(pos) - p
                dist = dr.norm(to_light)
                wi = to_light / dr.maximum(dist, 1e-30)
                cos_theta = -dr.dot(wi, v3(direction))
                Ls = c3(L1)
                if np.any(L2 != 0):
                    Ls = Ls + c3(L2) * dr.maximum(cos_theta, 0.0)  # eq. (3.10)
                if inv_sq:
                    Ls = Ls / dr.square(dist)
                return wi, dist, dr.select(dist > 0, Ls, 0.0)
            if kind == "dir":
                _, direction, E = L
                n = dr.width(p)
                wi = dr.zeros(mi.Vector3f, n) - v3(direction)
                return wi, dr.full(mi.Float, INF, n), dr.zeros(mi.Color3f, n) + c3(E)
            if kind == "cspot":
                _, origin, direction, radius, I = L
                axis = v3(direction)
                rel = p - v3(origin)
                s = dr.dot(rel, axis)
                radial = rel - axis * s
                inside = (s > 0) & (dr.squared_norm(radial) <= radius * radius)
                return -axis + mi.Vector3f(dr.zeros(mi.Float, dr.width(p))), dr.select(inside, s, 0.0), \
                    dr.select(inside, c3(I), 0.0)
            if kind == "mspot":
                _, pos, axis, I, cutoff, beam = L
                to_light = v3(pos) - p
                dist = dr.norm(to_light)
                wi = to_light / dr.maximum(dist, 1e-30)
                cos_theta = -dr.dot(wi, v3(axis))
                co, cb = math.radians(cutoff), math.radians(beam)
                ramp = dr.select(cos_theta >= math.cos(cb), 1.0,
                                 (co - dr.acos(dr.clip(cos_theta, -1.0, 1.0))) / max(co - cb, 1e-30))
                ramp = dr.select(cos_theta > math.cos(co), ramp, 0.0)
                return wi, dist, c3(I) * (ramp / dr.maximum(dr.square(dist), 1e-30))
            raise AssertionError(kind)

        # -------------------------------------------------------------- one level
        def _area_table(self, e, shapes, slot_list):
            """The core's :class:`links1.lights.AreaLight` for a Mitsuba area emitter (same triangles,
            CDF, sphere, disk), as Dr.Jit tables; None (with a warning) when it cannot be sampled."""
            from links1 import meshes
            from links1.lights import AreaLight
            from links1.shapes import Disk, Quadric, TriangleMesh
            sh = e.get_shape()
            kind = str(sh).split("[")[0]
            slot = next((sl for s_, sl in zip(shapes, slot_list) if s_.id() == sh.id()), None)
            rad = np.array(mi.traverse(e)["radiance.value"], dtype=np.float64).ravel()
            try:
                prm = mi.traverse(sh)
                if kind not in ("Rectangle", "Sphere", "Disk") and sh.is_mesh():
                    v = np.array(sh.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3)
                    f = np.array(sh.faces_buffer(), dtype=np.int64).reshape(-1, 3)
                    core = TriangleMesh(v, f)
                else:
                    m = np.array(prm["to_world"].matrix, dtype=np.float64).reshape(4, 4)
                    if kind == "Rectangle":
                        v, f, nrm = meshes.rectangle_mesh()
                        v, nrm = meshes.transform_mesh(m, v, nrm)
                        core = TriangleMesh(v, f)
                    elif kind == "Sphere":
                        core = Quadric("sphere", m)
                    elif kind == "Disk":
                        core = Disk(m)
                    else:
                        raise ValueError(f"the plugin cannot sample an area emitter on a {kind}")
                core.index = -1 if slot is None else slot
                L = AreaLight(core, np.broadcast_to(rad, (3,)))
            except (ValueError, KeyError) as exc:
                warnings.warn(f"links1_whitted: area emitter on '{sh.id()}' lights nothing: {exc}",
                              stacklevel=3)
                return None
            tab = dict(kind=L.kind, id=L.light_id, slot=slot, L=L.radiance)
            if L.kind == "mesh":
                tab.update(cdf=mi.Float(L.cdf), v0=mi.Float(L.v0.ravel()), v1=mi.Float(L.v1.ravel()),
                           v2=mi.Float(L.v2.ravel()), nrm=mi.Float(L.normals.ravel()), n=len(L.cdf),
                           area=float(L.area))
            elif L.kind == "sphere":
                tab.update(c=L.center, r=float(L.r))
            else:
                tab.update(m=L.m.tolist(), nrm_d=L.normal, area=float(L.area))
            return tab

        def _envmap_table(self, e):
            """The core's :class:`links1.lights.EnvironmentMap` from Mitsuba's own data (its periodic
            columns dropped), to_world and scale, with its CDFs as Dr.Jit tables."""
            from links1.lights import EnvironmentMap
            prm = mi.traverse(e)
            data = np.array(prm["data"], dtype=np.float64)
            m = np.array(prm["to_world"].matrix, dtype=np.float64).reshape(4, 4)
            scale = float(np.array(prm["scale"]).ravel()[0])
            # Mitsuba 3.9.1 pads a periodic column on each side (its eval matches the core's, tested)
            E = EnvironmentMap(data[:, 1:-1], to_world=m, scale=scale)
            return dict(E=E, nodes=mi.Float(E.nodes.ravel()), row=mi.Float(E.row_cdf),
                        col=mi.Float(E.col_cdf.ravel()), pcell=mi.Float(E.p_cell.ravel()))

        def _sample_area(self, tab, p, u, v):
            """``AreaLight.sample`` of the core in float32: (wi, dist, L_e / pdf)."""
            Le = c3(tab["L"])
            if tab["kind"] == "sphere":
                c, r = v3(tab["c"]), float(tab["r"])
                to_c = c - p
                dc2 = dr.squared_norm(to_c)
                dc = dr.sqrt(dc2)
                outside = dc > r
                axis = to_c / dr.select(dc > 0, dc, 1.0)
                sin2 = dr.minimum(r * r / dr.select(outside, dc2, 1.0), 1.0)
                cos_max = dr.sqrt(1.0 - sin2)
                one_minus = sin2 / (1.0 + cos_max)
                cos_t = 1.0 - u * one_minus
                sin_t = dr.safe_sqrt(1.0 - cos_t * cos_t)
                sp_, cp_ = dr.sincos(2.0 * math.pi * v)
                fr = mi.Frame3f(axis)
                wi = fr.s * (sin_t * cp_) + fr.t * (sin_t * sp_) + axis * cos_t
                dist = dc * cos_t - dr.safe_sqrt(r * r - dc2 * sin_t * sin_t)
                w = dr.select(outside, 2.0 * math.pi * one_minus, 0.0)
                return wi, dr.select(outside, dist, 0.0), Le * w
            if tab["kind"] == "mesh":
                cdf, nt = tab["cdf"], tab["n"]
                k = dr.binary_search(0, nt - 1, lambda i: dr.gather(mi.Float, cdf, i) <= u)
                hi = dr.gather(mi.Float, cdf, k)
                lo = dr.select(k > 0, dr.gather(mi.Float, cdf, dr.maximum(k, 1) - 1), 0.0)
                u2 = dr.clip((u - lo) / dr.maximum(hi - lo, 1e-30), 0.0, 1.0)
                su = dr.sqrt(u2)
                b0 = 1.0 - su
                b1 = v * su
                q = (dr.gather(mi.Vector3f, tab["v0"], k) * b0 + dr.gather(mi.Vector3f, tab["v1"], k) * b1
                     + dr.gather(mi.Vector3f, tab["v2"], k) * (1.0 - b0 - b1))
                nl = dr.gather(mi.Vector3f, tab["nrm"], k)
            else:
                m = tab["m"]
                rr = dr.sqrt(u)
                sp_, cp_ = dr.sincos(2.0 * math.pi * v)
                x, y = rr * cp_, rr * sp_
                q = mi.Vector3f(*[m[i][0] * x + m[i][1] * y + m[i][3] for i in range(3)])
                nl = v3(tab["nrm_d"])
            to = q - p
            d2 = dr.squared_norm(to)
            dist = dr.sqrt(d2)
            wi = to / dr.select(dist > 0, dist, 1.0)
            cos_l = -dr.dot(nl, wi)
            w = dr.select((cos_l > 0) & (d2 > 0), tab["area"] * cos_l / dr.select(d2 > 0, d2, 1.0), 0.0)
            return wi, dist, Le * w

        def _sample_env(self, env, nf, u, v):
            """``ConstantEnvironment.sample`` / ``EnvironmentMap.sample`` of the core in float32:
            (wi, L / pdf)."""
            if env[0] == "const":
                fr = mi.Frame3f(nf)
                r_ = dr.sqrt(u)
                z = dr.sqrt(dr.maximum(0.0, 1.0 - u))
                sp_, cp_ = dr.sincos(2.0 * math.pi * v)
                wi = fr.s * (r_ * cp_) + fr.t * (r_ * sp_) + fr.n * z
                return wi, c3(env[1]) * dr.select(z > 0, math.pi / z, 0.0)
            T = env[1]
            E, H, W = T["E"], T["E"].H, T["E"].W
            if E.dark:
                return mi.Vector3f(nf), dr.zeros(mi.Color3f, dr.width(u))
            row, col = T["row"], T["col"]
            iy = dr.binary_search(0, H - 2, lambda i: dr.gather(mi.Float, row, i) <= v)
            hi = dr.gather(mi.Float, row, iy)
            lo = dr.select(iy > 0, dr.gather(mi.Float, row, dr.maximum(iy, 1) - 1), 0.0)
            fy = dr.clip((v - lo) / dr.maximum(hi - lo, 1e-30), 0.0, 1.0)
            base = iy * W
            ix = dr.binary_search(0, W - 1, lambda i: dr.gather(mi.Float, col, base + i) <= u)
            hi = dr.gather(mi.Float, col, base + ix)
            lo = dr.select(ix > 0, dr.gather(mi.Float, col, base + dr.maximum(ix, 1) - 1), 0.0)
            fx = dr.clip((u - lo) / dr.maximum(hi - lo, 1e-30), 0.0, 1.0)
            x, y = mi.Float(ix) + fx, mi.Float(iy) + fy
            theta = y * (math.pi / (H - 1))
            phi = (x + 0.5) * (2.0 * math.pi / W)
            st, ct = dr.sincos(theta)
            sp_, cp_ = dr.sincos(phi)
            mw = E.to_world.tolist()
            lx, ly, lz = sp_ * st, ct, -cp_ * st
            wi = dr.normalize(mi.Vector3f(*[mw[i][0] * lx + mw[i][1] * ly + mw[i][2] * lz for i in range(3)]))
            pdf = dr.gather(mi.Float, T["pcell"], iy * W + ix) * (W * (H - 1)) / \
                (2.0 * math.pi * math.pi * dr.maximum(st, 1e-30))
            # bilinear radiance at (x, y) between the nodes (links1.lights.EnvironmentMap._bilinear)
            ixn = dr.minimum(mi.UInt32(x), W - 1)
            iyn = dr.minimum(mi.UInt32(y), H - 2)
            gx, gy = x - mi.Float(ixn), y - mi.Float(iyn)
            nodes, W1 = T["nodes"], W + 1
            g = lambda yy, xx: dr.gather(mi.Color3f, nodes, yy * W1 + xx)  # noqa: E731
            L = ((g(iyn, ixn) * (1 - gx) + g(iyn, ixn + 1) * gx) * (1 - gy)
                 + (g(iyn + 1, ixn) * (1 - gx) + g(iyn + 1, ixn + 1) * gx) * gy)
            w = dr.select((pdf > 0) & (st > 0), 1.0 / dr.select(pdf > 0, pdf, 1.0), 0.0)
            return wi, L * w

        def _light_uv(self, key, sample, light_id, j):
            """Light sample ``j`` of light ``light_id``: :func:`links1.sampling.light_samples_uv`
            in float32 (``sample = (pixel key, i, spp)`` at a primary hit, else None)."""
            m = self.light_samples
            if sample is not None:
                shift, i, spp = sample
                s_, n_ = i * m + j, mi.Float(spp * m)
            else:
                shift, s_, n_ = key, dr.zeros(mi.UInt32, dr.width(key)) + j, float(m)
            h = mix32(shift ^ mi.UInt32(light_tag(light_id)))
            a, b = u24(mix32(h ^ 1)), u24(mix32(h ^ 2))
            x = mi.UInt32(s_)
            for sh, mask in ((1, 0x55555555), (2, 0x33333333), (4, 0x0F0F0F0F), (8, 0x00FF00FF)):
                x = ((x >> sh) & mask) | ((x & mask) << sh)
            x = (x >> 16) | (x << 16)
            u = mi.Float(s_) / n_ + a
            v = u24(x) + b
            return u - dr.floor(u), v - dr.floor(v)

        def _level(self, P, scene, o, d, tmin, tmax, key, depth, spawn, active=None, symbolic=True,
                   sample=None):
            """Trace and shade one ray per lane (inside the megakernel's loop when ``symbolic``).
            ``sample``: the camera sample of a primary hit (see :meth:`_light_uv`).
            Returns a dict of Dr.Jit arrays."""
            n = dr.width(o)
            if active is None:
                active = dr.full(mi.Bool, True, n)
            cost = dr.zeros(mi.UInt32, n)
            n_shadow = dr.zeros(mi.UInt32, n)
            if P.any_mitsuba_shapes and not symbolic:
                dr.eval(o, d, tmin, tmax)
            t, slot, si, prim = self._nearest(P, scene, o, d, tmin, tmax, active, cost)
            hit = slot >= 0
            uslot = mi.UInt32(dr.maximum(slot, 0))
            # ---- surface record of the winner
            p = o + d * t
            if P.any_mitsuba_shapes:
                ng, ns = mi.Vector3f(si.n), mi.Vector3f(si.sh_frame.n)
                mits = hit & si.is_valid() & (dr.abs(si.t + tmin - t) <= 0.0)
                p = dr.select(mits, si.p, p)
            else:
                ng = dr.zeros(mi.Vector3f, n)
                ns = dr.zeros(mi.Vector3f, n)
                mits = dr.full(mi.Bool, False, n)
            for spec in P.custom_unrolled:
                m = slot == spec.slot
                nc = spec.normal(o, d, t, prim)
                ng = dr.select(m, nc, ng)
                ns = dr.select(m, nc, ns)
            if P.bvh is not None:
                qi = dr.gather(mi.Int32, P.bvh.slot_to_q, uslot, hit)
                m = hit & (qi >= 0)
                nc = P.bvh.normal(mi.UInt32(dr.maximum(qi, 0)), o, d, t, prim, m)
                ng = dr.select(m, nc, ng)
                ns = dr.select(m, nc, ns)
            wo = -d
            front = dr.dot(ng, wo) > 0
            nf = dr.select(front, ns, -ns)
            if P.any_mitsuba_shapes and not symbolic:
                dr.eval(t, slot, prim, p, ng, ns, nf, cost)
            out = dr.zeros(mi.Color3f, n)
            # ---- escaping rays: background (Mitsuba constant / envmap)
            if P.env is not None:
                sim = dr.zeros(mi.SurfaceInteraction3f, n)
                sim.wi = wo
                sim.t = mi.Float(INF)
                out = dr.select(hit, out, P.env.eval(sim, ~hit))
            # ---- ambient (eq. 3.11, dic) and emission
            if P.any_ambient:
                out += dr.select(hit, gather3(P.amb, uslot, hit), 0.0)
            if P.any_custom_emission:
                out += dr.select(hit & front & ~mits, gather3(P.custom_emission, uslot, hit), 0.0)
            # Mitsuba-side interaction record for BSDF calls (custom winners filled in)
            need_si = not P.all_phong or P.any_mitsuba_emission
            if need_si:
                sif = mi.SurfaceInteraction3f(si)
                cw = hit & ~mits
                sif.p = dr.select(cw, p, si.p)
                sif.n = dr.select(cw, mi.Normal3f(ng), si.n)
                frame_c = mi.Frame3f(ns)
                sif.sh_frame = mi.Frame3f(dr.select(cw, frame_c.s, si.sh_frame.s),
                                          dr.select(cw, frame_c.t, si.sh_frame.t),
                                          dr.select(cw, frame_c.n, si.sh_frame.n))
                sif.t = dr.select(hit, t, INF)
                sif.uv = dr.select(cw, self._custom_uv(P, o, d, t, prim, slot, uslot, hit), si.uv)
                sif.wi = sif.to_local(wo)
                if P.any_mitsuba_emission:
                    em = si.emitter(scene, mits)
                    out += dr.select(mits, em.eval(sif, mits), 0.0)
                bsdf = dr.gather(mi.BSDFPtr, P.bsdf_ptr, uslot, hit)
                is_ph = dr.gather(mi.Bool, P.is_phong, uslot, hit)
                mb = hit & ~is_ph
                ctx = mi.BSDFContext()
            # Phong parameters
            if P.any_phong:
                ph = hit if P.all_phong else hit & is_ph
                dif = gather3(P.dif, uslot, ph)
                spe = gather3(P.spe, uslot, ph)
                expo = dr.gather(mi.Float, P.expo, uslot, ph)

            def f_eval(wi):
                """Factor multiplying L_s for light direction wi (eq. 3.11 / Mitsuba BSDF)."""
                f = dr.zeros(mi.Color3f, n)
                if P.any_phong:
                    cos_theta = dr.dot(nf, wi)
                    mirror = nf * (2.0 * cos_theta) - wi
                    cos_phi = dr.maximum(dr.dot(mirror, wo), 0.0)
                    sp = dr.select(expo > 0, dr.power(cos_phi, expo), 1.0)
                    fp = dif * dr.maximum(cos_theta, 0.0) + spe * sp
                    f = dr.select(ph & (cos_theta > 0), fp, f)
                if not P.all_phong:
                    fm = bsdf.eval(ctx, sif, sif.to_local(wi), mb)
                    f = dr.select(mb, fm, f)
                return f

            # ray offsets (relative to 1 + max|p|), per shape: see OFFSET_EPS
            eps_scale = dr.gather(mi.Float, P.eps_table, uslot, hit)
            eps = (1.0 + dr.max(dr.abs(p))) * eps_scale

            def offset(direction):
                side = dr.select(dr.dot(ng, direction) >= 0, 1.0, -1.0)
                return p + ng * (side * eps)

            # ---- direct light with shadows (eq. 3.11, 3-3-3). Shadow rays of all lights are
            # built and evaluated together, then handed to Mitsuba's ray tests (each test
            # evaluates its inputs: building them first avoids recomputing shared work).
            pending = []

            def need_of(j, lit, wi):
                """Lanes that need a shadow ray toward light j (P.shadow_need, _occluders)."""
                if not P.any_shadow[j]:
                    return dr.zeros(mi.Bool, n)
                if P.shadow_need[j] is None:
                    return lit
                need = dr.gather(mi.Bool, P.shadow_need[j], uslot, lit)
                if P.shadow_inner[j] is not None:  # light on the inner side of a closed convex shape
                    need |= dr.gather(mi.Bool, P.shadow_inner[j], uslot, lit) & (dr.dot(ng, wi) <= 0)
                return lit & need

            def shadow(j, so, wi, smax, lit, contrib):
                nonlocal n_shadow
                if not P.any_shadow[j]:
                    return None, lit, None
                need = need_of(j, lit, wi)
                n_shadow = n_shadow + dr.select(need, mi.UInt32(1), 0)
                T = self._shadow_custom(P, so, wi, smax, need, cost, P.occ_custom[j])
                return T, need, P.occ_mitsuba[j]

            for jl, L in enumerate(P.lights):
                wi, dist, Ls = self._light(L, p)
                contrib = f_eval(wi) * Ls
                lit = hit & (dr.max(contrib) > 0)
                so, smax = offset(wi), dist - 2.0 * eps
                T, need, occ_m = shadow(jl, so, wi, smax, lit, contrib)
                pending.append((contrib, so, wi, smax, lit, need, T, occ_m))
            m_inv = 1.0 / self.light_samples
            sampled = [(len(P.lights) + j, tab, tab["id"]) for j, tab in enumerate(P.area_tab)]
            sampled += [(len(P.lights) + len(P.area) + k, env, lid) for k, env in enumerate(P.consts)
                        for lid in [env[2]]]
            for jsh, tab, lid in sampled:          # area lights and environments (links1.lights)
                for js in range(self.light_samples):
                    u, v = self._light_uv(key, sample, lid, js)
                    if isinstance(tab, dict):
                        wi, dist, Lw = self._sample_area(tab, p, u, v)
                        # Mitsuba's ray tests include the emitter: stop short of it as Mitsuba does
                        smax = dist * (1.0 - mi.math.ShadowEpsilon) - 2.0 * eps
                    else:
                        wi, Lw = self._sample_env(tab, nf, u, v)
                        smax = dr.full(mi.Float, INF, n)
                    contrib = f_eval(wi) * Lw * m_inv
                    lit = hit & (dr.max(contrib) > 0)
                    so = offset(wi)
                    T, need, occ_m = shadow(jsh, so, wi, smax, lit, contrib)
                    pending.append((contrib, so, wi, smax, lit, need, T, occ_m))
            if P.any_mitsuba_shapes and pending and not symbolic:
                dr.eval(out, cost, *[x for tup in pending for x in tup[:6]])
            for contrib, so, wi, smax, lit, need, T, occ_m in pending:
                if T is None:               # nothing can shadow this light
                    out += dr.select(lit, contrib, 0.0)
                    continue
                if P.any_mitsuba_shapes and occ_m:
                    T = self._shadow_mitsuba(P, scene, so, wi, smax, need, T, cost)
                out += dr.select(lit, contrib * dr.select(need, T, 1.0), 0.0)
            res = {"L": out, "cost": cost, "t": t, "slot": slot, "ns": ns, "hit": hit}
            res["n_shadow"] = n_shadow
            if not spawn:
                return res
            # ---- secondary rays, eq. (3.12)-(3.16)
            r = dr.zeros(mi.Color3f, n)
            tw = dr.zeros(mi.Color3f, n)
            dir_r = dr.zeros(mi.Vector3f, n)
            dir_t = dr.zeros(mi.Vector3f, n)
            if P.any_phong_r or P.any_phong_t:
                cos_i = -dr.dot(d, nf)
                dir_r = d + nf * (2.0 * cos_i)                                  # eq. (3.12)
                r = dr.select(ph, gather3(P.refl, uslot, ph), r)
                if P.any_phong_t:
                    tt = gather3(P.trans, uslot, ph)
                    ior = dr.gather(mi.Float, P.ior, uslot, ph)
                    eta = dr.select(front, 1.0 / ior, ior)                        # η = η_i/η_t
                    S = (d + nf * cos_i) * eta                                     # eq. (3.14)
                    s2 = dr.squared_norm(S)
                    has_t = ph & (dr.max(tt) > 0)
                    tir = has_t & (s2 > 1.0)
                    r = dr.select(tir, r + tt, r)
                    tw = dr.select(has_t & ~tir, tt, 0.0)
                    dir_t = S - nf * dr.safe_sqrt(1.0 - s2)                       # eq. (3.15)
            if P.any_mitsuba_delta:
                lobes = [(mi.BSDFFlags.DeltaReflection, "r")] if P.any_mitsuba_dr else []
                if P.any_mitsuba_dt:
                    lobes.append((mi.BSDFFlags.DeltaTransmission, "t"))
                for flag, which in lobes:   # only the delta lobes some BSDF of the scene has
                    table = P.has_dr if which == "r" else P.has_dt
                    act = mb & dr.gather(mi.Bool, table, uslot, mb)
                    cx = mi.BSDFContext()
                    cx.type_mask = +flag
                    bs, w = bsdf.sample(cx, sif, mi.Float(0.5), mi.Point2f(0.5, 0.5), act)
                    ok = act & (bs.pdf > 0) & (dr.max(w) > 0)
                    dw = sif.to_world(bs.wo)
                    if which == "r":
                        r = dr.select(ok, w, r)
                        dir_r = dr.select(ok, dw, dir_r)
                    else:
                        tw = dr.select(ok, w, tw)
                        dir_t = dr.select(ok, dw, dir_t)
            has_r = hit & (dr.max(r) > 0)
            has_tt = hit & (dr.max(tw) > 0)
            dir_r = dr.normalize(dir_r)
            dir_t = dr.normalize(dir_t)
            res.update(r=r, tw=tw, has_r=has_r, has_t=has_tt, dir_r=dir_r, dir_t=dir_t,
                       o_r=offset(dir_r), o_t=offset(dir_t))
            return res

        def _custom_uv(self, P, o, d, t, prim, slot, uslot, hit):
            """uv of the hits on links1_quadric shapes with textured BSDFs (0 elsewhere)."""
            uv = mi.Point2f(0.0)
            if not P.uv_slots:
                return uv
            for spec in P.custom_unrolled:
                if spec.slot in P.uv_slots:
                    uv = dr.select(slot == spec.slot, spec.uv(o, d, t, prim), uv)
            if P.bvh is not None and P.uv_slots & P.bvh_slots:
                qi = dr.gather(mi.Int32, P.bvh.slot_to_q, uslot, hit)
                m = hit & (qi >= 0)
                uv = dr.select(m, P.bvh.uv(mi.UInt32(dr.maximum(qi, 0)), o, d, t, m), uv)
            return uv

        # -------------------------------------------------------------- the tree
        def _children(self, res, act, wgt, depth):
            """Which children a hit spawns (eq. 3.12-3.16, ``max_depth``, weight threshold as
            the core) and their weights in the pixel."""
            md, mw = self.max_depth, float(self.min_weight)
            deeper = act & (depth < md)
            w_r, w_t = wgt * res["r"], wgt * res["tw"]
            cr = deeper & res["has_r"]
            ct = deeper & res["has_t"]
            if mw > 0:
                cr &= dr.max(w_r) > mw
                ct &= dr.max(w_t) > mw
            return cr, ct, w_r, w_t

        def _trace_tree(self, P, scene, o, d, tmin, tmax, key, want_aovs, frozen=None):
            """All ray trees: the camera level in one kernel, the rest in a "megakernel".

            Level 1 (every sample) is straight-line code. The samples whose hit spawns a
            mirror or refraction ray are compacted (``dr.compress``), and one symbolic
            ``dr.while_loop`` traces the rest of their trees, one ray per iteration: the mirror
            child (eq. 3.12) is followed next, a refraction child (eq. 3.14-3.15) with a mirror
            sibling waits on a small per-lane stack (Dr.Jit local memory, at most
            ``max_depth - 1`` entries). ``I = I_o + r I_r + t I_t`` (eq. 3.16) is accumulated as
            ``Σ weight · I_o`` with the weight the product of the factors down the tree (the
            core's sum in another order). Lanes never interact and the compaction keeps the
            order of samples, so a window renders the same bits as the full frame; the window
            is a run-time value (no recompilation). Returns ``(RGB, cost, t0, slot0, ns0,
            counters)`` with ``counters`` the arrays :meth:`_counts` sums (no read-back here).

            ``frozen``: the sample count as an opaque ``UInt32`` when traced inside
            :func:`drjit.freeze` (:meth:`_frozen_fn`), so no Python decision may depend on data:
            the compaction always keeps the last two samples too (a lane without children starts
            inactive and adds exact zeros, the same bits as no lane), so the loop exists whatever
            the recorded pixels held (two lanes: a recording with one would treat the loop's
            arrays as scalars and replay wrongly).
            """
            n = dr.width(o)
            md = self.max_depth
            spawn = md > 1 and P.any_specular
            one = mi.UInt32(1)
            res = self._level(P, scene, o, d, tmin, tmax, key, 1, spawn, sample=_CAM_SAMPLE.pop(id(self), None))
            aov = (res["t"], res["slot"], res["ns"]) if want_aovs else ()
            if not spawn:
                rgb = mi.Color3f(res["L"])
                dr.eval(rgb, res["cost"], res["n_shadow"], *aov)
                return rgb, res["cost"], res["t"], res["slot"], res["ns"], dict(nsh1=res["n_shadow"])
            act = res["hit"]
            cr, ct, w_r, w_t = self._children(res, act, mi.Color3f(1.0), mi.UInt32(1))
            key_r = mix32(key ^ mi.UInt32(0x63D83595))
            key_t = mix32(key ^ mi.UInt32(0xA511E9B3))
            has_t = P.any_phong_t or P.any_mitsuba_dt
            if has_t:
                kids = (res["o_r"], res["dir_r"], w_r, key_r, res["o_t"], res["dir_t"], w_t, key_t)
            else:       # no refraction anywhere: no refraction children to store
                kids = (res["o_r"], res["dir_r"], w_r, key_r)
            L1, cost1, nsh1 = res["L"], res["cost"], res["n_shadow"]
            dr.eval(L1, cost1, nsh1, cr, ct, *aov, *kids)                  # kernel 1: level 1
            if frozen is not None:  # the last two samples always: a width of 1 would record as a scalar
                ar = dr.arange(mi.UInt32, n)
                idx = dr.compress(cr | ct | (ar + 2 >= frozen))  # n: an input, not a literal
            else:
                idx = dr.compress(cr | ct)
            m = dr.width(idx)
            counters = dict(nsh1=nsh1, cr=cr, ct=ct)
            if m == 0:
                return L1, cost1, res["t"], res["slot"], res["ns"], counters
            g = lambda x: dr.gather(type(x), x, idx)  # noqa: E731
            if has_t:
                o_r, d_r, wr, kr, o_t, d_t, wt, kt = (g(x) for x in kids)
            else:
                o_r, d_r, wr, kr = (g(x) for x in kids)
                o_t, d_t, wt, kt = o_r, d_r, wr, kr
            gr, gt = g(cr), g(ct)
            push = gr & gt
            K = md - 1
            stk_f = dr.alloc_local(mi.Float, 9 * K, mi.Float(0.0))   # o, d, weight per entry
            stk_u = dr.alloc_local(mi.UInt32, 2 * K, mi.UInt32(0))   # depth, key per entry
            if has_t:
                for k_, val in enumerate((o_t.x, o_t.y, o_t.z, d_t.x, d_t.y, d_t.z, wt.x, wt.y, wt.z)):
                    stk_f.write(val, mi.UInt32(k_), push)
                stk_u.write(dr.full(mi.UInt32, 2, m), mi.UInt32(0), push)
                stk_u.write(kt, mi.UInt32(1), push)
            zu = dr.zeros(mi.UInt32, m)
            state = dict(o=mi.Point3f(dr.select(gr, o_r, o_t)), d=mi.Vector3f(dr.select(gr, d_r, d_t)),
                         wgt=mi.Color3f(dr.select(gr, wr, wt)),
                         depth=zu + 2, key=dr.select(gr, kr, kt), L=dr.zeros(mi.Color3f, m),
                         cost=mi.UInt32(zu), sp=dr.select(push, one, 0), active=gr | gt,
                         nsh=mi.UInt32(zu), nr=mi.UInt32(zu), nt=mi.UInt32(zu))
            names = list(state)

            def cond(stk_f, stk_u, *vals):
                return vals[names.index("active")]

            def body(stk_f, stk_u, *vals):
                v = dict(zip(names, vals))
                act = v["active"]
                mm = dr.width(v["o"])
                res = self._level(P, scene, v["o"], v["d"], dr.zeros(mi.Float, mm), dr.full(mi.Float, INF, mm),
                                  v["key"], 0, True, active=act)
                wgt = v["wgt"]
                L = v["L"] + wgt * res["L"]
                cost = v["cost"] + res["cost"]
                cr, ct, w_r, w_t = self._children(res, act, wgt, v["depth"])
                key_r = mix32(v["key"] ^ mi.UInt32(0x63D83595))
                key_t = mix32(v["key"] ^ mi.UInt32(0xA511E9B3))
                sp = v["sp"]
                push = cr & ct
                if has_t:
                    base = sp * 9
                    o_t, d_t = res["o_t"], res["dir_t"]
                    for k, val in enumerate((o_t.x, o_t.y, o_t.z, d_t.x, d_t.y, d_t.z, w_t.x, w_t.y, w_t.z)):
                        stk_f.write(val, base + k, push)
                    stk_u.write(v["depth"] + 1, sp * 2, push)
                    stk_u.write(key_t, sp * 2 + 1, push)
                pop = act & ~cr & ~ct & (sp > 0)
                top = dr.select(pop, sp - 1, 0)
                fp = [stk_f.read(top * 9 + k, pop) for k in range(9)]
                dp = stk_u.read(top * 2, pop)
                kp = stk_u.read(top * 2 + 1, pop)
                o_n = dr.select(cr, res["o_r"], dr.select(ct, res["o_t"], mi.Point3f(fp[0], fp[1], fp[2])))
                d_n = dr.select(cr, res["dir_r"], dr.select(ct, res["dir_t"], mi.Vector3f(fp[3], fp[4], fp[5])))
                w_n = dr.select(cr, w_r, dr.select(ct, w_t, mi.Color3f(fp[6], fp[7], fp[8])))
                depth_n = dr.select(cr | ct, v["depth"] + 1, dp)
                key_n = dr.select(cr, key_r, dr.select(ct, key_t, kp))
                sp = dr.select(push, sp + 1, dr.select(pop, sp - 1, sp))
                out = dict(o=mi.Point3f(o_n), d=mi.Vector3f(d_n), wgt=mi.Color3f(w_n), depth=depth_n, key=key_n, L=L, cost=cost, sp=sp,
                           active=cr | ct | pop, nsh=v["nsh"] + res["n_shadow"],
                           nr=v["nr"] + dr.select(cr, one, 0), nt=v["nt"] + dr.select(ct, one, 0))
                return (stk_f, stk_u, *[out[k] for k in names])

            result = dr.while_loop((stk_f, stk_u, *[state[k] for k in names]), cond, body,
                                   label="links1_whitted")
            v = dict(zip(names, result[2:]))
            # materialise the loop's outputs in one kernel first: scatters into arrays of another
            # size are scheduled as their own kernel, which would re-run the loop
            dr.eval(v["L"], v["cost"], v["nsh"], v["nr"], v["nt"])          # kernel 2: the trees
            # one child forest per sample (idx is unique: no races). The scatter targets are
            # copies of level-1 arrays, whose width is the input's at every replay (a zeros(n)
            # target would keep the recorded width; a scatter_add would force freeze to dry-run)
            total = mi.Color3f(L1)
            dr.scatter(total, g(L1) + v["L"], idx)
            cost = mi.UInt32(cost1)
            dr.scatter(cost, g(cost1) + v["cost"], idx)
            dr.eval(total, cost)
            counters.update(nr=v["nr"], nt=v["nt"], nsh2=v["nsh"])
            return total, cost, res["t"], res["slot"], res["ns"], counters

        def channels(self):
            return channel_names(self.aovs)

        # -------------------------------------------------------------- Mitsuba entry points
        def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
            if isinstance(sensor, int):
                sensor = scene.sensors()[sensor]
            film = sensor.film()
            off, size = film.crop_offset(), film.crop_size()
            if spp == 0 or spp is None:
                spp = sensor.sampler().sample_count()
            s = int(seed) if not hasattr(seed, "__len__") else int(np.array(seed).ravel()[0])
            win = (int(off[0]), int(off[1]), int(size[0]), int(size[1]))
            if self.adaptive is not None:
                img = self.render_adaptive(scene, win, seed=self.seed + s)
            else:
                img = self.render_window(scene, win, spp=int(spp), seed=self.seed + s)
            return mi.TensorXf(img.astype(np.float32))

        def sample(self, scene, sampler, ray, medium=None, active=True):
            raise RuntimeError("links1_whitted renders whole ray trees in its own kernels; use mi.render() "
                               "or render_window(), not sample()")

        def aov_names(self):
            return channel_names(self.aovs)[3:]

        def to_string(self):
            return (f"Links1Whitted[max_depth={self.max_depth}, seed={self.seed}, aovs={self.aovs}, "
                    f"custom_shapes={len(self.custom)}]")

    # ray generation and launches have their home in launch.py (nanobind classes take one base,
    # so its methods are attached rather than inherited)
    for name, fn in vars(Launches).items():
        if callable(fn) and not name.startswith("__"):
            setattr(Links1Whitted, name, fn)
    return Links1Whitted
