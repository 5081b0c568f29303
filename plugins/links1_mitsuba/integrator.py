"""``links1_whitted``: the LINKS-1 method (docs/method.md §2–4) as a Mitsuba 3 integrator in Dr.Jit.

``Links1Whitted`` is thin: it reads its properties into a :class:`~links1_mitsuba.config.Config`
and hands every entry point to one :class:`~links1_mitsuba.engine.Engine` (engine.py: the
tables, lights, intersection, ray tree, launches and gradients as its parts; its state declared
there), held out of :func:`drjit.freeze`'s walk of the scene (:class:`~links1_mitsuba.util.Hidden`).

It subclasses ``mi.SamplingIntegrator``, a class of the variant in use, so it is made per variant
by :func:`define_integrator` (``_registry.register``); the engine is one class for every variant.
"""
from __future__ import annotations

from links1.scene.params import default as l1_default

from .config import Config
from .engine import Engine
from .registered import check_properties, unsupported_variant
from .util import Hidden

#: Default weight below which a branch of the ray tree is not traced (POV-Ray's adc_bailout;
#: the same default as links1.tracing.integrator.DEFAULT_MIN_WEIGHT).
DEFAULT_MIN_WEIGHT = l1_default("links1_whitted", "min_weight")
# Custom quadrics with finite bounds go under a BVH (bvh.py) from tuning.Tuning.bvh_min on.

#: the integrator's parameters, read and set through it (config.Config)
CONFIG_FIELDS = ("max_depth", "seed", "min_weight", "light_samples", "aovs", "adaptive",
                 "adaptive_depth", "verify_scene", "use_freeze", "projective")


def _delegate(name):
    def call(self, *args, **kwargs):
        return getattr(self._hidden.engine, name)(*args, **kwargs)
    call.__name__ = name
    call.__doc__ = f"See :meth:`links1_mitsuba.engine.Engine.{name}`."
    return call


def _config(name):
    return property(lambda self: getattr(self._hidden.engine.config, name),
                    lambda self, v: setattr(self._hidden.engine.config, name, v))


def define_integrator():
    """``Links1Whitted`` for the variant in use: a subclass of its ``mi.SamplingIntegrator``
    (hence made per variant) over an :class:`~links1_mitsuba.engine.Engine`."""
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
        projective  boolean  derivatives add the visibility term: outlines moving under   false
                             the camera rays (boundary.py; box filter)
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

        def __init__(self, props):
            why = unsupported_variant(mi.variant())
            if why:   # registered for one variant, built under another
                raise ValueError(why)
            check_properties("integrator", "links1_whitted", props)
            super().__init__(props)
            config = Config.from_props(props)
            custom_bsdfs = {int(k[len("_l1_bsdf_"):]): props[k] for k in props.keys()
                            if k.startswith("_l1_bsdf_")}
            #: custom slots whose BSDF is a top-level object of the file (traverse leaves it out)
            shared = {int(k[len("_l1_topbsdf_"):]) for k in props.keys()
                      if k.startswith("_l1_topbsdf_") and props[k]}
            self._hidden = Hidden(engine=Engine(config, custom_bsdfs, shared))

        @property
        def engine(self) -> Engine:
            """The engine that renders (engine.py); what it made is read through :meth:`info`
            (:meth:`links1_mitsuba.engine.Engine.info`)."""
            return self._hidden.engine

        # -------------------------------------------------------------- Mitsuba entry points
        def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
            """``mi.render(scene, sensor=...)``: ``sensor`` (an index into ``scene.sensors()`` or
            a sensor object, the scene's or one made apart) gives the camera, the film (size,
            crop window, reconstruction filter) and, unless ``spp`` is given, the sample count.
            ``develop=False`` (a film left to the caller) is refused, as Mitsuba's
            ``ADIntegrator`` refuses it; the frame is evaluated whatever ``evaluate`` says
            (``mi.render`` passes False: may be left unevaluated)."""
            if not develop:
                raise RuntimeError("links1_whitted.render(): develop=False is not supported (the film "
                                   "is made on the device and returned developed)")
            return self._hidden.engine.render(scene, sensor, seed, spp)

        def render_forward(self, scene, params, sensor=0, seed=0, spp=0):
            """See :meth:`links1_mitsuba.gradients.Gradients.render_forward`."""
            return self._hidden.engine.render_forward(scene, params, sensor, seed, spp)

        def render_backward(self, scene, params, grad_in, sensor=0, seed=0, spp=0):
            """See :meth:`links1_mitsuba.gradients.Gradients.render_backward`."""
            return self._hidden.engine.render_backward(scene, params, grad_in, sensor, seed, spp)

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
            flags = mi.ParamFlags.Differentiable
            self._hidden.engine.traverse(callback, (flags, flags | mi.ParamFlags.Discontinuous))

        def parameters_changed(self, keys):
            """``params.update()``: the links1 shapes whose geometry changed get a new spec
            (checked as the loader checks a file: ValueError otherwise), and the next frame
            makes their tables again (BVH, blob tables: ``Tables._update_values``). ``keys`` holds only the last part
            of each key (``to_world``, not which shape's), so a value changed is one whose Dr.Jit
            variables are not those seen last (:func:`geometry.changed`)."""
            self._hidden.engine.parameters_changed(keys)

        def aov_names(self):
            return self._hidden.engine.channels()[3:]

        def to_string(self):
            e = self._hidden.engine
            c = e.config
            return (f"Links1Whitted[max_depth={c.max_depth}, seed={c.seed}, aovs={c.aovs}, "
                    f"custom_shapes={len(e.shapes.custom)}]")

        # -------------------------------------------------------------- the engine's API
        @property
        def tuning(self):
            """The switches of the accelerations this integrator renders with
            (:class:`links1_mitsuba.tuning.Tuning`): its own where one was set, else the
            module-wide ones. Setting a ``Tuning`` makes it this integrator's alone (None: back
            to the module-wide ones); it takes effect at the next frame."""
            return self._hidden.engine.current_tuning()

        @tuning.setter
        def tuning(self, value):
            self._hidden.engine.set_tuning(value)

        @property
        def stats(self):
            """Ray counters of the last render (camera, shadow, reflect, refract rays)."""
            return self._hidden.engine.stats

        info = _delegate("info")
        attach = _delegate("attach")
        adopt = _delegate("adopt")
        place = _delegate("place")
        channels = _delegate("channels")
        prepare = _delegate("prepare")
        render_window = _delegate("render_window")
        render_windows = _delegate("render_windows")
        render_windows_device = _delegate("render_windows_device")
        render_adaptive = _delegate("render_adaptive")
        trace_points = _delegate("trace_points")
        window_samples = _delegate("window_samples")

    for name in CONFIG_FIELDS:
        setattr(Links1Whitted, name, _config(name))
    return Links1Whitted
