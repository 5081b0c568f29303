"""``links1_whitted``: the LINKS-1 method (docs/method.md §2–4) as a Mitsuba 3 integrator in Dr.Jit.

The integrator class is composed here from one part per concept, each a module-level class in
its own module (their methods name ``mi.Float``, ``mi.Ray3f``, ... when called, so one part
serves every variant):

- :class:`~links1_mitsuba.tables.Tables`: the per-scene tables (``prepare``) and which shadow
  rays a scene needs (``_occluders``);
- :class:`~links1_mitsuba.lights.Lights`: analytic lights, area and environment lights
  (tables, samples);
- :class:`~links1_mitsuba.intersect.Intersect`: nearest hits over Mitsuba and links1 shapes,
  shadow transmittance (3-3-3);
- :class:`~links1_mitsuba.raytree.RayTree`: one level traced and shaded, the ray trees
  (eq. 3.11-3.16; the recursion design is described there);
- :class:`~links1_mitsuba.launch.Launches`: camera rays, the frozen launches, read-back, ``stats``;
- :class:`~links1_mitsuba.gradients.Gradients`: ``render_forward``/``render_backward``;
- :mod:`~links1_mitsuba.util`: Dr.Jit helpers (hashes, literals, gathers), module functions.

``Links1Whitted`` itself subclasses ``mi.SamplingIntegrator``, a class of the variant in use,
so it is made per variant by :func:`define_integrator` (``_registry.register``). Nanobind
classes take one base, so it takes the parts' methods as its own rather than inheriting them;
a name defined twice is an error.
"""
from __future__ import annotations

import numpy as np

from links1.tracing.adaptive import DEFAULT_ADAPTIVE_DEPTH
from links1.tracing.aovs import channel_names
from links1.tracing.aovs import check_aovs as parse_aovs  # the one AOV table and checker (links1/tracing/aovs.py)
from links1.scene.params import default as l1_default
from links1.scene.params import read as l1_read

from . import geometry, proxies
from .gradients import Gradients
from .intersect import Intersect
from .launch import Launches
from .lights import Lights
from .raytree import RayTree
from .registered import check_properties, unsupported_variant
from .tables import Tables
from .util import Hidden, hidden_attr, place_of

#: Default weight below which a branch of the ray tree is not traced (POV-Ray's adc_bailout;
#: the same default as links1.tracing.integrator.DEFAULT_MIN_WEIGHT).
DEFAULT_MIN_WEIGHT = l1_default("links1_whitted", "min_weight")
# Custom quadrics with finite bounds go under a BVH (bvh.py) from tuning.Tuning.bvh_min on.

#: the parts whose methods Links1Whitted takes
PARTS = (Tables, Lights, Intersect, RayTree, Launches, Gradients)


def define_integrator():
    """``Links1Whitted`` for the variant in use: a subclass of its ``mi.SamplingIntegrator``
    (hence made per variant) with the methods of :data:`PARTS`."""
    import mitsuba as mi

    class Links1Whitted(mi.SamplingIntegrator):
        r"""LINKS-1 Whitted ray tracer (``links1_whitted``), paper 3-1 and 3-3, eq. (3.11)–(3.16).

        ==========  =======  ==========================================================  =======
        Parameter   Type     Meaning                                                     Default
        ==========  =======  ==========================================================  =======
        max_depth   integer  surface interactions along one branch of the ray tree       5
                             (primary hit = 1; 1 = direct light only)
        seed        integer  seed of the sample pattern (links1.maths.sampling)                0
        aovs        string   comma-separated extra channels: depth, normal, id, cost     ""
        min_weight  float    a secondary ray is traced only if the largest RGB component  1/255
                             of its weight in the pixel (product of the r / t factors
                             down the tree) exceeds this; 0 traces every branch
        light_samples int    shadow rays per sampled light (environment) per hit        1
        adaptive    float    adaptive anti-aliasing threshold (links1.tracing.adaptive) instead  none
                             of the sampler's count; ``mi.render`` and render_window
        adaptive_depth int   most refinement levels of ``adaptive``                     2
        ==========  =======  ==========================================================  =======

        Shading: ``links1_phong`` surfaces use eq. (3.11) (ambient + diffuse + highlight),
        other Mitsuba BSDFs are evaluated through Mitsuba (``bsdf.eval``) for delta lights
        and their delta lobes (mirror, glass, and the straight-through ``Null`` lobe of
        ``thindielectric``, ``mask`` and ``null``, weight ``eval_null_transmission``) are
        recursed with their own weights (a ``mask``'s: its nested BSDF's times the opacity); rough
        BSDFs get direct light only (warning). Lights: ``links1_point``, ``links1_spot``,
        Mitsuba ``point``, ``spot``, ``directional`` (evaluated analytically, shadow rays
        scaled by the transmittance of every object crossed, once per object); ``area``
        emitters (mesh, rectangle, cube, sphere, disk), ``constant`` and ``envmap`` are sampled
        with ``light_samples`` shadow rays each on the core's light-sample points
        (:mod:`links1.shading.lights`, :func:`links1.maths.sampling.light_samples_uv`) and are also the
        radiance of escaping rays (``constant``/``envmap``). Custom shapes (``links1_quadric``, ``links1_blob``) come
        from :func:`links1_mitsuba.load_file`.

        ``mi.render(scene)`` renders the film's crop window; :meth:`render_window` renders any
        window ``(x0, y0, w, h)`` of the full film without recompiling kernels.
        """

        custom = hidden_attr("custom")
        #: the Dr.Jit values of the links1 shapes' geometry, by slot (geometry.hold)
        geo = hidden_attr("geo")
        geo_seen = hidden_attr("geo_seen")
        custom_bsdfs = hidden_attr("custom_bsdfs")
        #: the scene's shapes (ids) whose proxies :meth:`adopt` made ``custom`` of, and their slots
        adopted = hidden_attr("adopted")
        proxy_slots = hidden_attr("proxy_slots")
        slot_of_id = hidden_attr("slot_of_id")
        shape_names = hidden_attr("shape_names")
        places = hidden_attr("places")
        _prep = hidden_attr("prep")
        _freeze = hidden_attr("freeze")
        _freeze_points = hidden_attr("freeze_points")
        #: the camera sample of the last camera rays (``Launches._take_cam_sample``)
        _cam_sample = hidden_attr("cam_sample")
        #: ray counters of the last render (``Launches._set_stats``: summed when first read)
        stats = property(lambda self: self._read_stats(), lambda self, v: self._set_stats(v))

        def __init__(self, props):
            why = unsupported_variant(mi.variant())
            if why:   # registered for one variant, built under another
                raise ValueError(why)
            check_properties("integrator", "links1_whitted", props)
            super().__init__(props)
            self._hidden = Hidden()
            def param(name, conv):   # links1.scene.params: the rules the core's reader applies too
                return l1_read("links1_whitted", name, conv(props[name]) if name in props else None)
            md = param("max_depth", int)
            if md == -1:
                md = l1_default("links1_whitted", "max_depth")
            if md < 1:
                raise ValueError(f"links1_whitted: max_depth must be >= 1 (or -1), got {md}")
            self.max_depth = md
            self.seed = param("seed", int)
            self.min_weight = param("min_weight", float)
            self.light_samples = param("light_samples", int)
            self.aovs = parse_aovs(props.get("aovs", ""))
            self.adaptive = None
            if "adaptive" in props:
                from links1.tracing.adaptive import check_options
                try:
                    self.adaptive, self.adaptive_depth = check_options(
                        props.get("adaptive"), props.get("adaptive_depth", DEFAULT_ADAPTIVE_DEPTH))
                except Exception as e:
                    raise ValueError(f"links1_whitted: {e}") from None
            elif "adaptive_depth" in props:
                raise ValueError("links1_whitted: adaptive_depth needs adaptive")
            self.custom_bsdfs = {}
            #: custom slots whose BSDF is a top-level object of the file (traverse leaves it out)
            self.shared_bsdfs = {int(k[len("_l1_topbsdf_"):]) for k in props.keys()
                                 if k.startswith("_l1_topbsdf_") and props[k]}
            for key in props.keys():
                if key.startswith("_l1_bsdf_"):
                    self.custom_bsdfs[int(key[len("_l1_bsdf_"):])] = props[key]
            self.custom = []          # QuadricSpec / BlobSpec, set by the loader
            self.slot_of_id = None    # Mitsuba shape id -> slot (file order), set by the loader
            self.shape_names = None
            self.places = None        # object id -> "FILE:LINE: <element>", set by the loader
            self._prep = None
            #: check the scene's parameters (mi.traverse) before reusing the prepared tables;
            #: MitsubaRenderer, whose scene is its own, turns it off for its launches
            self.verify_scene = True
            #: the scene tables and camera views built so far (tables.py: prepare)
            self.n_scene_builds = 0
            self.n_camera_views = 0
            self.n_value_updates = 0
            self.stats = {}
            #: render windows through a frozen function (:meth:`_frozen_fn`): no re-tracing
            self.use_freeze = True
            self._freeze = None

        # -------------------------------------------------------------- set-up
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

        # -------------------------------------------------------------- Mitsuba entry points
        def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
            """``mi.render(scene, sensor=...)``: ``sensor`` (an index into ``scene.sensors()`` or
            a sensor object, the scene's or one made apart) gives the camera, the film (size,
            crop window, reconstruction filter) and, unless ``spp`` is given, the sample count."""
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

        def sample(self, scene, sampler, ray, medium=None, active=True):
            raise RuntimeError("links1_whitted renders whole ray trees in its own kernels; use mi.render() "
                               "or render_window(), not sample()")

        def traverse(self, callback):
            """The links1 shapes (``links1_quadric``, ``links1_blob``: not Mitsuba shapes,
            links1_whitted holds them), named as Mitsuba names a shape's parameters under the
            integrator's id: their BSDFs, ``links1_whitted.<shape id>.bsdf.<parameter>``
            (a BSDF declared at the top of the file keeps its own name, ``<bsdf id>.<parameter>``),
            and their geometry (:mod:`links1_mitsuba.geometry`): ``<shape id>.to_world``, a
            quadric's ``clip_<k>_offset``, a blob's ``centers``, ``weights``, ``radii`` and
            ``threshold`` (differentiable and discontinuous, as a Mitsuba shape's ``to_world``:
            they move silhouettes, which the gradients leave out)."""
            names = self._shape_name_of()
            for sl, b in sorted(self.custom_bsdfs.items()):
                if sl in self.shared_bsdfs:   # named by its own id (a top-level BSDF of the file)
                    continue
                callback.put(f"{names(sl)}.bsdf", b, mi.ParamFlags.Differentiable)
            flags = mi.ParamFlags.Differentiable | mi.ParamFlags.Discontinuous
            for sp in self.custom:
                held = (self.geo or {}).get(sp.slot)
                for k in geometry.param_names(sp) if held is not None else []:
                    callback.put(f"{names(sp.slot)}.{k}", held[k], flags)

        def _shape_name_of(self):
            names = {sl: name for sl, name, _ in (self.shape_names or [])}
            return lambda sl: names.get(sl, f"_links1_slot_{sl}")

        def parameters_changed(self, keys):
            """``params.update()``: the links1 shapes whose geometry changed get a new spec
            (checked as the loader checks a file: ValueError otherwise), and the next frame
            makes their tables again (BVH, blob tables: ``Tables._update_values``). ``keys`` holds only the last part
            of each key (``to_world``, not which shape's), so a value changed is one whose Dr.Jit
            variables are not those seen last (:func:`geometry.changed`)."""
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

        def aov_names(self):
            return channel_names(self.aovs)[3:]

        def to_string(self):
            return (f"Links1Whitted[max_depth={self.max_depth}, seed={self.seed}, aovs={self.aovs}, "
                    f"custom_shapes={len(self.custom)}]")

    # the parts' methods (nanobind classes take one base: attached rather than inherited)
    for part in PARTS:
        for name, fn in vars(part).items():
            if callable(fn) and not name.startswith("__"):
                if name in vars(Links1Whitted):
                    raise AssertionError(f"links1_whitted: {name} is defined twice ({part.__name__})")
                setattr(Links1Whitted, name, fn)
    return Links1Whitted
