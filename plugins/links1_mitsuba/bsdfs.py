"""``links1_phong``: the paper's shading model (eq. 3.11) as a Mitsuba BSDF."""
from __future__ import annotations

import numpy as np

from .registered import check_properties
from .util import Hidden, place_in, read_rgb


def _rgb(props, name, default):
    v = read_rgb(props, name, default, emitter=False)   # one reader of colours and spectra
    return None if v is None else [float(c) for c in v]


def phong_params(props) -> dict:
    """Read and check the ``links1_phong`` parameters from Mitsuba ``Properties`` (defaults and
    ranges: :data:`links1.scene.params.PLUGINS`, the table the core's reader uses too)."""
    from links1.scene.params import PLUGINS, read
    check_properties("bsdf", "links1_phong", props)
    v = {}
    for name, prm in PLUGINS[("bsdf", "links1_phong")].items():
        raw = _rgb(props, name, None) if prm.kind == "rgb" else (float(props[name]) if name in props else None)
        v[name] = read("links1_phong", name, raw)
        if prm.kind == "rgb" and v[name] is not None:
            v[name] = [float(c) for c in v[name]]
    if v["reflectance"] is None:
        v["reflectance"] = list(v["specular"])
    return v


#: the colours of links1_phong (``traverse``: ``<name>.value``)
_PHONG_RGB = ("ambient", "diffuse", "specular", "reflectance", "transmittance")


def define_phong():
    """``Links1Phong`` for the variant in use: a subclass of that variant's ``mi.BSDF``, so it
    is made per variant (``_registry.register``), unlike the integrator's mixins."""
    import drjit as dr
    import mitsuba as mi

    class Links1Phong(mi.BSDF):
        r"""LINKS-1 Phong surface (``links1_phong``), eq. (3.11) in the paper's units.

        ``I_o = dic + drc Σ L cos θ + src Σ L (cos φ)^n``, plus ``r I_r + t I_t`` (eq. 3.16).

        ===============  =======  ==============================================  =========
        Parameter        Type     Meaning                                         Default
        ===============  =======  ==============================================  =========
        ambient          rgb      ``dic``: constant term (links1_whitted only)    0
        diffuse          rgb      ``drc``: multiplies ``L cos θ`` (no 1/π)        0.5
        specular         rgb      ``src``: multiplies ``L (cos φ)^n``             0
        exponent         float    ``n``: sharpness of the highlight               20
        reflectance      rgb      ``r``: weight of the mirror ray                 = specular
        transmittance    rgb      ``t``: weight of the refracted ray; shadow      0
                                  rays through the object are scaled by it
        ior              float    index of refraction inside (η = η_i/η_t)        1
        ===============  =======  ==============================================  =========

        Two-sided: the normal is turned toward the viewer. ``eval`` returns the local term's
        factor (it already contains ``cos θ``), so Mitsuba's ``direct``/``path`` lit by
        ``links1_point`` (``falloff=none``) give eq. (3.11) without the ambient term.
        ``sample`` draws only the delta lobes (mirror ray with weight ``r``, refraction with
        ``t``, total internal reflection folding ``t`` into ``r``): like the paper, the
        diffuse and highlight terms take no indirect light, so ``path`` converges to
        Whitted's ray tree. The constant ``ambient`` cannot be expressed in Mitsuba's BSDF
        interface; ``links1_whitted`` adds it.

        Example::

            {'type': 'links1_phong', 'diffuse': {'type': 'rgb', 'value': [0.8, 0.2, 0.2]},
             'specular': {'type': 'rgb', 'value': 0.5}, 'exponent': 40.0}
        """

        def __init__(self, props):
            super().__init__(props)
            self._held = Hidden()
            self._held.where = place_in(props)   # FILE:LINE: <bsdf ...> from the loader
            self._set_params(phong_params(props))

        def _set_params(self, p):
            """Hold the checked parameters ``p`` (Python values, what ``links1_whitted``'s tables
            read) and their Dr.Jit values (what ``traverse`` exposes and ``eval`` uses)."""
            # Plain Python values behind one attribute: dr.freeze traverses a Python BSDF's
            # attributes (dicts and lists item by item) on every call of a frozen launch, once
            # per shape that uses it; one opaque holder keeps that out of every launch
            # (with thousands of Mitsuba spheres that walk cost more than the frame). The primal launches of
            # links1_whitted read their own tables (made from ``params``); its gradient launches
            # read these Dr.Jit values (links1_mitsuba.gradients), which ``mi.traverse`` hands out.
            h = self._held
            h.params = p
            for name in _PHONG_RGB:
                setattr(h, name, mi.Color3f(*p[name]))
            h.t_exponent, h.t_ior = mi.Float(p["exponent"]), mi.Float(p["ior"])
            self._set_flags()

        def _set_flags(self):
            p, h = self.params, self._held
            h.has_r, h.has_t = max(p["reflectance"]) > 0, max(p["transmittance"]) > 0
            both = mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
            flags = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.GlossyReflection | both
            comps = [mi.BSDFFlags.DiffuseReflection | both]
            if self.has_r:
                flags = flags | mi.BSDFFlags.DeltaReflection
                comps.append(mi.BSDFFlags.DeltaReflection | both)
            if self.has_t:
                flags = flags | mi.BSDFFlags.DeltaTransmission
                comps.append(mi.BSDFFlags.DeltaTransmission | both)
            self.m_flags = flags
            self.m_components = comps

        params = property(lambda self: self._held.params)
        m_diffuse = property(lambda self: self._held.diffuse)
        m_specular = property(lambda self: self._held.specular)
        m_reflectance = property(lambda self: self._held.reflectance)
        m_transmittance = property(lambda self: self._held.transmittance)
        m_exponent = property(lambda self: self.params["exponent"])
        m_ior = property(lambda self: self.params["ior"])
        has_r = property(lambda self: self._held.has_r)
        has_t = property(lambda self: self._held.has_t)

        # -- local term, eq. (3.11)
        def _local(self, si, wo):
            wi = si.wi
            flip = mi.Frame3f.cos_theta(wi) < 0  # two-sided: turn the normal to the viewer
            wi = mi.Vector3f(wi.x, wi.y, dr.select(flip, -wi.z, wi.z))
            wo = mi.Vector3f(wo.x, wo.y, dr.select(flip, -wo.z, wo.z))
            cos_theta = mi.Frame3f.cos_theta(wo)          # toward the light
            mirror = mi.Vector3f(-wo.x, -wo.y, wo.z)       # mirror direction of the light
            cos_phi = dr.maximum(dr.dot(mirror, wi), 0.0)  # φ: mirror vs viewer
            if self.m_exponent > 0:
                spec = dr.power(cos_phi, self.m_exponent)
            else:
                spec = dr.ones(mi.Float, dr.width(cos_phi))
            f = self.m_diffuse * dr.maximum(cos_theta, 0.0) + self.m_specular * spec
            return dr.select(cos_theta > 0, f, 0.0)

        def eval(self, ctx, si, wo, active=True):
            if not ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, 0):
                return mi.Color3f(0.0)
            return dr.select(active, self._local(si, wo), 0.0)

        def pdf(self, ctx, si, wo, active=True):
            return mi.Float(0.0)

        def eval_pdf(self, ctx, si, wo, active=True):
            return self.eval(ctx, si, wo, active), mi.Float(0.0)

        def sample(self, ctx, si, sample1, sample2, active=True):
            wi = si.wi
            cos_i = mi.Frame3f.cos_theta(wi)
            entering = cos_i > 0
            eta = dr.select(entering, 1.0 / self.m_ior, self.m_ior)  # η = η_i/η_t
            # S = η(e - (e·n)n) with e = -wi, n toward the viewer: its length is η sinθ_i
            s2 = dr.square(eta) * (1.0 - dr.square(cos_i))
            use_r = self.has_r and ctx.is_enabled(mi.BSDFFlags.DeltaReflection, 1)
            use_t = self.has_t and ctx.is_enabled(mi.BSDFFlags.DeltaTransmission, 2)
            r = self.m_reflectance if use_r else mi.Color3f(0.0)
            t = self.m_transmittance if use_t else mi.Color3f(0.0)
            tir = s2 > 1.0
            if use_t:
                r = dr.select(tir, r + self.m_transmittance, r)  # TIR: t moves to the mirror ray
                t = dr.select(tir, 0.0, t)
            pr = dr.max(r)
            pt = dr.max(t)
            total = pr + pt
            prob_r = dr.select(total > 0, pr / dr.maximum(total, 1e-30), 0.0)
            pick_r = sample1 < prob_r
            bs = dr.zeros(mi.BSDFSample3f)
            refl = mi.Vector3f(-wi.x, -wi.y, wi.z)                      # eq. (3.12)
            cos_t = dr.safe_sqrt(1.0 - s2)
            trans = mi.Vector3f(-eta * wi.x, -eta * wi.y,
                                dr.select(entering, -cos_t, cos_t))       # eq. (3.14)-(3.15)
            bs.wo = dr.select(pick_r, refl, trans)
            bs.pdf = dr.select(pick_r, prob_r, 1.0 - prob_r)
            bs.eta = dr.select(pick_r, 1.0, 1.0 / eta)
            bs.sampled_type = dr.select(pick_r, mi.UInt32(+mi.BSDFFlags.DeltaReflection),
                                        mi.UInt32(+mi.BSDFFlags.DeltaTransmission))
            bs.sampled_component = dr.select(pick_r, mi.UInt32(1), mi.UInt32(2))
            ok = active & (total > 0) & (bs.pdf > 0)
            weight = dr.select(pick_r, r, t) / dr.maximum(bs.pdf, 1e-30)
            bs.pdf = dr.select(ok, bs.pdf, 0.0)
            return bs, dr.select(ok, weight, 0.0)

        def traverse(self, callback):
            """Every coefficient of eq. (3.11)/(3.16), named as Mitsuba names a BSDF's colours
            (``<id>.diffuse.value``, as ``diffuse``'s ``reflectance.value``) and floats
            (``<id>.exponent``; ``<id>.ior``, which bends rays: not differentiable, as
            ``dielectric``'s ``eta``)."""
            D = mi.ParamFlags.Differentiable
            for name in _PHONG_RGB:
                callback.put(f"{name}.value", getattr(self._held, name), D)
            callback.put("exponent", self._held.t_exponent, D)
            callback.put("ior", self._held.t_ior, mi.ParamFlags.NonDifferentiable)

        def parameters_changed(self, keys):
            """``params.update()``: the Python values (checked as the loader checks them, ranges
            of links1.scene.params) follow the Dr.Jit values; links1_whitted's tables are rebuilt at
            the next frame (its scene digest sees the change), in place when only coefficients
            change (tables.Tables._update_values)."""
            from links1.scene.params import check
            h, p = self._held, dict(self.params)
            ident = self.id()
            what = h.where or (f"links1_phong '{ident}'" if ident and not ident.startswith("_")
                               else "links1_phong")
            for name, key, want in ([(n, f"{n}.value", 3) for n in _PHONG_RGB]
                                    + [("exponent", "exponent", 1), ("ior", "ior", 1)]):
                v = np.array(getattr(h, name if want == 3 else f"t_{name}"), dtype=np.float64)
                if v.size != want:   # one value for the whole surface: width 1
                    kind = "Color3f" if want == 3 else "Float"
                    raise ValueError(f"{what}: '{key}' must be one {kind} (width 1), got width "
                                     f"{v.size // want}")
                try:
                    v = check("links1_phong", name, v.ravel() if want == 3 else float(v.ravel()[0]))
                except ValueError as exc:
                    raise ValueError(f"{what}: {exc}") from None
                p[name] = [float(c) for c in v] if want == 3 else float(v)
            h.params = p
            self._set_flags()

        def to_string(self):
            p = self.params
            return ("Links1Phong[ambient=%s, diffuse=%s, specular=%s, exponent=%g, reflectance=%s, "
                    "transmittance=%s, ior=%g]" % (p["ambient"], p["diffuse"], p["specular"],
                                                   p["exponent"], p["reflectance"],
                                                   p["transmittance"], p["ior"]))

    return Links1Phong
