r"""``whitted_reference``: Mitsuba's own sampling restricted to Whitted's light paths.

The reference the corpus is judged against (tests/plugins/test_corpus.py, compare/corpus.py).
It is written with nothing but Mitsuba's own machinery (``Scene.sample_emitter_direction``,
``BSDF.sample``/``eval_pdf``, ``Emitter.eval``), so it shares no code with either links1
renderer.

Light paths: in Heckbert's notation, ``E S* (D L | L)``: at every surface hit, direct light
by emitter sampling and BSDF sampling combined with multiple importance sampling (power
heuristic, as Mitsuba's ``direct`` and ``path``), plus emission seen directly; the path goes on
only through a *delta* lobe (mirror, glass, the straight-through ``Null`` lobe of ``mask`` and
``thindielectric``). A BSDF sample of a non-delta lobe is traced one segment, for the emission
it finds (the BSDF half of the MIS estimate), and ends there. A BSDF with both kinds of lobe
(``plastic``, ``blendbsdf``, ``principled``'s clear coat) picks one per sample, as ``BSDF.sample``
does, with its weight.

So on a scene whose BSDFs have no delta lobe it computes what ``direct`` computes, and where
Mitsuba's ``path`` finds no light path with two non-delta vertices within ``max_depth`` it
computes what ``path`` computes (tests/plugins/test_whitted_reference.py checks both).

==========  =======  ===============================================================  =======
Parameter   Type     Meaning                                                          Default
==========  =======  ===============================================================  =======
max_depth   integer  longest path, counted as Mitsuba's ``path`` counts: 1 = emitters     6
                     seen directly, 2 = direct light. links1_whitted's ``max_depth``
                     m (surface interactions, 1 = direct light) is ``m + 1`` here.
==========  =======  ===============================================================  =======

Example::

    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    from tests.corpus.whitted_reference import register
    register()
    img = mi.render(scene, integrator=mi.load_dict({"type": "whitted_reference", "max_depth": 6}))
"""
from __future__ import annotations

#: links1_whitted's default max_depth (5 surface interactions), in Mitsuba's counting
DEFAULT_MAX_DEPTH = 6

_registered: set = set()


def register() -> None:
    """Register ``whitted_reference`` for the active Mitsuba variant (idempotent)."""
    import mitsuba as mi
    variant = mi.variant()
    if variant in _registered:
        return
    cls = _define()
    mi.register_integrator("whitted_reference", lambda props: cls(props))
    _registered.add(variant)


def _define():
    import drjit as dr
    import mitsuba as mi

    class WhittedReference(mi.SamplingIntegrator):
        def __init__(self, props):
            super().__init__(props)
            self.max_depth = int(props.get("max_depth", DEFAULT_MAX_DEPTH))
            if self.max_depth < 1:
                raise ValueError(f"whitted_reference: max_depth must be >= 1, got {self.max_depth}")

        def aov_names(self):
            return []

        def to_string(self):
            return f"WhittedReference[max_depth={self.max_depth}]"

        @dr.syntax
        def sample(self, scene, sampler, ray, medium=None, active=True):
            # (dr.syntax re-compiles this method without the enclosing function's names)
            import drjit as dr
            import mitsuba as mi
            mis_weight = mi.ad.integrators.common.mis_weight   # power heuristic, as prb.py and path
            bsdf_ctx = mi.BSDFContext()

            ray = mi.Ray3f(ray)                      # current ray
            depth = mi.UInt32(0)                     # vertices so far
            L = mi.Spectrum(0)                       # radiance
            beta = mi.Spectrum(1)                    # throughput of the delta chain
            active = mi.Bool(active)                 # lanes still tracing
            si_prev = dr.zeros(mi.SurfaceInteraction3f)
            bsdf_pdf_prev = mi.Float(1)              # pdf of the BSDF sample that made `ray`
            bsdf_delta_prev = mi.Bool(True)          # ... and whether its lobe was delta

            while active:
                si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=depth == 0,
                                         active=active)
                bsdf = si.bsdf(ray)

                # ---------------- emission found by the ray (MIS with the previous
                # vertex's emitter sample, weight 1 after a delta lobe or the camera)
                ds = mi.DirectionSample3f(scene, si=si, ref=si_prev)
                em_pdf = scene.pdf_emitter_direction(si_prev, ds, active & ~bsdf_delta_prev)
                L += beta * mis_weight(bsdf_pdf_prev, em_pdf) * ds.emitter.eval(si, active)

                # A vertex reached through a non-delta lobe only gathers emission.
                active_next = active & bsdf_delta_prev & si.is_valid() & (depth + 1 < self.max_depth)

                # ---------------- emitter sampling
                active_em = active_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
                ds, em_weight = scene.sample_emitter_direction(si, sampler.next_2d(), True, active_em)
                active_em &= ds.pdf != 0
                bsdf_val, bsdf_pdf = bsdf.eval_pdf(bsdf_ctx, si, si.to_local(ds.d), active_em)
                mis_em = dr.select(ds.delta, 1, mis_weight(ds.pdf, bsdf_pdf))
                L[active_em] += beta * mis_em * bsdf_val * em_weight

                # ---------------- BSDF sampling: any lobe; only a delta one recurses
                bs, bsdf_weight = bsdf.sample(bsdf_ctx, si, sampler.next_1d(), sampler.next_2d(),
                                              active_next)
                # (lanes without active_next stop here, so their state need not be kept)
                beta *= bsdf_weight
                ray = si.spawn_ray(si.to_world(bs.wo))
                si_prev = si
                bsdf_pdf_prev = bs.pdf
                bsdf_delta_prev = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)

                # ---------------- stopping criterion
                depth += 1
                active = active_next & (dr.max(mi.unpolarized_spectrum(beta)) != 0)

            return L, mi.Bool(True), []

    return WhittedReference


def render_reference(path, spp: int, seed: int, width=None, height=None, params=None,
                     max_depth: int = DEFAULT_MAX_DEPTH):
    """``whitted_reference`` on the scene file ``path`` loaded by plain ``mi.load_file`` (the
    active variant; ``params``: its ``$name`` values), its film resized as the links1
    renderers resize it (``width`` x ``height``, ``x_fov`` kept; ``height`` None: the file's
    aspect) -> (h, w, 3) float64."""
    import mitsuba as mi
    import numpy as np
    from links1_mitsuba.renderer import resize_film
    register()
    scene = mi.load_file(str(path), **{k: str(v) for k, v in (params or {}).items()})
    sensor = scene.sensors()[0]
    if width is not None:
        W, H = (int(v) for v in sensor.film().size())
        resize_film(sensor, width, height or max(1, round(width * H / W)))
    integrator = mi.load_dict({"type": "whitted_reference", "max_depth": max_depth})
    img = mi.render(scene, integrator=integrator, sensor=sensor, spp=spp, seed=seed)
    return np.array(img, dtype=np.float64)[..., :3]
