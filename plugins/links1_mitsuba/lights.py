"""The lights of ``links1_whitted`` (their one home): analytic lights evaluated at the hits
(:func:`light_at`: links1 point and spot lights, Mitsuba point, spot and directional emitters),
area emitters and environment maps as the core's :mod:`links1.shading.lights` tables
(:func:`area_table`, :func:`envmap_table`) sampled in float32 (:func:`sample_area`,
:func:`sample_env`) at the core's light-sample points (:func:`light_uv`), and the RGB of
Mitsuba emitters (``_emitted_rgb``, read by the tables).

Plain functions of their arguments (no state): the tables (``tables.py``) make the records,
the ray tree (``raytree.py``) evaluates and samples them. They name ``mi.Float``,
``mi.Ray3f``, ... when called, so they serve every Mitsuba variant.
"""
from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import numpy as np

from links1.maths.sampling import BSDF_SAMPLE_ID, light_tag

import drjit as dr
import mitsuba as mi

from .util import INF, color3, kind_of, mix32, spread, unit_float, vector3


def _emitted_rgb(prm, key: str, kind: str, where: str = "links1_whitted") -> np.ndarray:
    """An emitter's RGB ``key`` from ``mi.traverse``: its value, or for a ``blackbody`` spectrum
    (which Mitsuba's RGB variants cannot evaluate) the colour the core uses
    (:func:`links1.shading.spectra.blackbody_to_rgb`, with a warning)."""
    if f"{key}.value" in prm:
        v = np.array(prm[f"{key}.value"], dtype=np.float64).ravel()
        return np.broadcast_to(v, (3,)).copy() if v.size == 1 else v
    if f"{key}.temperature" in prm:
        from links1.shading.spectra import blackbody_to_rgb
        t = float(np.array(prm[f"{key}.temperature"]).ravel()[0])
        rgb = blackbody_to_rgb(t)
        warnings.warn(f"{where}: {kind} {key} is a blackbody ({t:g} K), which Mitsuba's RGB "
                      f"variants cannot evaluate; using the colour its spectral variants integrate "
                      f"to, {np.round(rgb, 6).tolist()}", stacklevel=3)
        return rgb
    raise ValueError(f"links1_whitted: {kind} '{key}' must be an RGB value or a blackbody spectrum "
                     "(textured emitters are not supported)")


# -------------------------------------------------------------- the light records
# One record per kind of light in the tables (``Prepared.lights``, ``Prepared.consts``): named
# tuples, so that the walk gathering the frozen launch's inputs (launch.py: ``_frozen_inputs``)
# meets their arrays as it met the tuples' before. Each field holds a numpy value or, in a
# derivative pass, an attached Dr.Jit value (gradients.py: ``_replace``).

class PointRecord(NamedTuple):
    """A point light: a ``links1_point`` (eq. 3.10: ``L1 + L2 max(cos, 0)`` about ``axis``) or a
    Mitsuba ``point`` (``L2`` zero, inverse-square falloff)."""
    position: object
    axis: object
    L1: object
    L2: object
    inverse_square: bool


class CylinderSpotRecord(NamedTuple):
    """A ``links1_spot``: a parallel beam of ``radius`` about the axis from ``origin`` along
    ``direction``."""
    origin: object
    direction: object
    radius: object
    intensity: object


class MitsubaSpotRecord(NamedTuple):
    """A Mitsuba ``spot`` (untextured): cutoff and beam angles in degrees."""
    position: object
    axis: object
    intensity: object
    cutoff: float
    beam: float


class DirectionalRecord(NamedTuple):
    """A Mitsuba ``directional`` emitter: light travels along ``direction``."""
    direction: object
    irradiance: object


class MitsubaEmitterRecord(NamedTuple):
    """A Mitsuba delta emitter evaluated by Mitsuba itself (textured spot, projector)."""
    position: object
    emitter: object


class ConstantEnvRecord(NamedTuple):
    """A ``constant`` environment: its radiance (RGB) and light id (sampling)."""
    radiance: object
    light_id: int


class EnvMapRecord(NamedTuple):
    """An ``envmap``: its table (:func:`envmap_table`) and light id (sampling)."""
    table: object
    light_id: int


#: the records of lights at a position (light buffers, shadow planning)
POSITIONED = (PointRecord, MitsubaSpotRecord, MitsubaEmitterRecord)
#: the records of lights along one direction (``direction``: the way light travels)
DIRECTED = (DirectionalRecord, CylinderSpotRecord)


# -------------------------------------------------------------- the tables' entries


def params_of(tables, obj):
    """``mi.traverse(obj)`` of a native Mitsuba object, made once for ``tables`` (a
    :class:`~.prepared.Prepared` or camera view: their base's): it reads each parameter when
    asked (``mi.get_property``), so it gives the current values after ``params.update()``, and
    a traversal is not free."""
    base = tables.base if tables.base is not None else tables
    prm = base.obj_params.get(id(obj))
    if prm is None:
        prm = base.obj_params[id(obj)] = mi.traverse(obj)
    return prm


def analytic_light(e, kind, point_class, spot_class, tables, place):
    """The ``tables.lights`` record (:class:`PointRecord`, ...) of the emitter ``e`` (its
    ``kind``: :func:`~.util.kind_of`) when it is an analytic light: a ``links1_point``
    (``point_class``) or ``links1_spot`` (``spot_class``), a Mitsuba point, spot, projector
    (these two with an image: ``memitter``) or directional emitter; else None. ``tables``: the
    tables it is for (:func:`params_of`); ``place(obj)``: where ``obj`` is in the file, for
    warnings (``SceneShapes.place``)."""
    if isinstance(e, point_class):
        p = e.params
        return PointRecord(p["position"], p["direction"], p["L1"], p["L2"],
                           p["falloff"] == "inverse_square")
    if isinstance(e, spot_class):
        p = e.params
        return CylinderSpotRecord(p["origin"], p["direction"], p["radius"], p["intensity"])
    if kind not in ("PointLight", "SpotLight", "DirectionalEmitter", "Projector"):
        return None
    prm = params_of(tables, e)
    if kind == "PointLight":
        pos = np.array(prm["position"], dtype=np.float64).ravel()
        I = _emitted_rgb(prm, "intensity", kind, place(e))
        return PointRecord(pos, np.array([0, 0, 1.0]), I, np.zeros(3), True)
    m = np.array(prm["to_world"].matrix, dtype=np.float64).reshape(4, 4)
    if kind == "Projector":   # a delta light projecting an image: Mitsuba's own evaluation
        return MitsubaEmitterRecord(m[:3, 3], e)
    if kind == "DirectionalEmitter":
        E = _emitted_rgb(prm, "irradiance", kind, place(e))
        return DirectionalRecord(m[:3, 2] / np.linalg.norm(m[:3, 2]), E)
    if any(k.startswith("texture.") and k != "texture.value" for k in prm.keys()):
        # a projector (its texture varies): Mitsuba's own evaluation of the emitter
        return MitsubaEmitterRecord(m[:3, 3], e)
    I = _emitted_rgb(prm, "intensity", kind, place(e))
    if "texture.value" in prm.keys():   # a constant texture scales the intensity
        I = I * _emitted_rgb(prm, "texture", kind, place(e))
    cutoff = float(np.array(prm["cutoff_angle"]).ravel()[0])
    beam = float(np.array(prm["beam_width"]).ravel()[0])
    return MitsubaSpotRecord(m[:3, 3].copy(), m[:3, 2] / np.linalg.norm(m[:3, 2]), I, cutoff, beam)


def _toward(pos, axis, p):
    """Unit direction from ``p`` to the point light at ``pos``, the distance, and the
    cosine between the light's ``axis`` and the direction from the light to ``p``."""
    to_light = vector3(pos) - p
    dist = dr.norm(to_light)
    wi = to_light / dr.maximum(dist, 1e-30)
    return wi, dist, -dr.dot(wi, vector3(axis))


def light_at(L, p):
    """(wi, dist, L_s) of one analytic light at points p (docs/method.md §4.1)."""
    L = L._make(spread(x, dr.width(p)) for x in L)   # attached values at the lanes (util.spread)
    if isinstance(L, PointRecord):
        wi, dist, cos_theta = _toward(L.position, L.axis, p)
        Ls = color3(L.L1)
        if dr.is_array_v(L.L2) or np.any(L.L2 != 0):   # an attached L2 (gradients.py)
            Ls = Ls + color3(L.L2) * dr.maximum(cos_theta, 0.0)  # eq. (3.10)
        if L.inverse_square:
            Ls = Ls / dr.square(dist)
        return wi, dist, dr.select(dist > 0, Ls, 0.0)
    if isinstance(L, DirectionalRecord):
        n = dr.width(p)
        wi = dr.zeros(mi.Vector3f, n) - vector3(L.direction)
        return wi, dr.full(mi.Float, INF, n), dr.zeros(mi.Color3f, n) + color3(L.irradiance)
    if isinstance(L, CylinderSpotRecord):
        axis = vector3(L.direction)
        rel = p - vector3(L.origin)
        s = dr.dot(rel, axis)
        radial = rel - axis * s
        inside = (s > 0) & (dr.squared_norm(radial) <= L.radius * L.radius)
        return -axis + mi.Vector3f(dr.zeros(mi.Float, dr.width(p))), dr.select(inside, s, 0.0), \
            dr.select(inside, color3(L.intensity), 0.0)
    if isinstance(L, MitsubaSpotRecord):
        wi, dist, cos_theta = _toward(L.position, L.axis, p)
        co, cb = math.radians(L.cutoff), math.radians(L.beam)
        ramp = dr.select(cos_theta >= math.cos(cb), 1.0,
                         (co - dr.acos(dr.clip(cos_theta, -1.0, 1.0))) / max(co - cb, 1e-30))
        ramp = dr.select(cos_theta > math.cos(co), ramp, 0.0)
        return wi, dist, color3(L.intensity) * (ramp / dr.maximum(dr.square(dist), 1e-30))
    if isinstance(L, MitsubaEmitterRecord):   # evaluated by Mitsuba (textured spot, projector)
        it = dr.zeros(mi.Interaction3f, dr.width(p))
        it.p = p
        ds, spec = L.emitter.sample_direction(it, mi.Point2f(0.5, 0.5), True)
        return ds.d, ds.dist, mi.Color3f(spec)
    raise AssertionError(type(L).__name__)


# -------------------------------------------------------------- area lights, environments


def area_table(e, shapes, slot_list, place):
    """The core's :class:`links1.shading.lights.AreaLight` for a Mitsuba area emitter (same triangles,
    CDF, sphere, disk), as Dr.Jit tables; None (with a warning) when it cannot be sampled."""
    from links1.geometry import meshes
    from links1.shading.lights import AreaLight
    from links1.geometry.shapes import Disk, Quadric, TriangleMesh
    sh = e.get_shape()
    kind = kind_of(sh)
    slot = next((sl for s_, sl in zip(shapes, slot_list) if s_ is sh), None)
    eprm = mi.traverse(e)
    # a textured radiance (bitmap, checkerboard, ...) is Mitsuba's to evaluate at each light
    # sample's uv (_area_radiance); the tables then hold the triangles' uv
    textured = "radiance.value" not in eprm
    rad = np.ones(3) if textured else np.array(eprm["radiance.value"], dtype=np.float64).ravel()
    uv = None
    try:
        prm = mi.traverse(sh)
        if kind not in ("Rectangle", "Sphere", "Disk") and sh.is_mesh():
            # (Mitsuba's flip_normals is in the faces' winding already)
            v = np.array(sh.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3)
            f = np.array(sh.faces_buffer(), dtype=np.int64).reshape(-1, 3)
            vn = (np.array(sh.vertex_normals_buffer(), dtype=np.float64).reshape(-1, 3)
                  if sh.has_vertex_normals() else None)
            core = TriangleMesh(v, f, vn)
            if textured:
                if not sh.has_vertex_texcoords():
                    raise ValueError("a textured radiance needs the mesh's texture coordinates, "
                                     "which it has not (Mitsuba refuses it too)")
                uv = np.array(sh.vertex_texcoords_buffer(), dtype=np.float64).reshape(-1, 2)[f]
                # Mitsuba's own sampling of this emitter (its direct, path, and any symbolic
                # call that traces every registered emitter) builds the mesh's uv
                # parameterization on first use, a scene of its own, with the GIL released;
                # the Python references taken here then make that unsafe (a segfault):
                # build it now, while the GIL is held
                sh.eval_parameterization(mi.Point2f(0.5, 0.5))
        else:
            m = np.array(prm["to_world"].matrix, dtype=np.float64).reshape(4, 4)
            # flip_normals of an analytic shape: Mitsuba's own sampled normal says it
            ps = sh.sample_position(0.0, mi.Point2f(0.3, 0.4))
            n_mi = np.array(ps.n, dtype=np.float64).ravel()
            if kind == "Rectangle":
                v, f, nrm, tc = meshes.rectangle_mesh(uv=True)
                v, nrm = meshes.transform_mesh(m, v, nrm)
                if float(np.dot(n_mi, nrm[0])) < 0:
                    f, nrm = meshes.flip(f, nrm)
                core = TriangleMesh(v, f)
                uv = tc[f] if textured else None
            elif kind == "Sphere":
                core = Quadric("sphere", m)
                if textured:
                    raise ValueError("a textured radiance on a sphere is not sampled (meshes, rectangles "
                                     "and disks are)")
            elif kind == "Disk":
                core = Disk(m)
                if float(np.dot(n_mi, core._normal)) < 0:
                    core = Disk(m, flip=True)
            else:
                raise ValueError(f"the plugin cannot sample an area emitter on a {kind}")
            if kind == "Sphere" and float(np.dot(n_mi, np.array(ps.p, dtype=np.float64).ravel() - m[:3, 3])) < 0:
                raise ValueError("a sphere with flip_normals emits inward, which is not sampled")
        core.index = -1 if slot is None else slot
        L = AreaLight(core, np.broadcast_to(rad, (3,)))
    except (ValueError, KeyError) as exc:
        warnings.warn(f"{place(e, f'links1_whitted: area emitter on {sh.id()!r}')}: "
                      f"it lights nothing: {exc}",
                      stacklevel=3)
        return None
    # id: the sample streams' tag, set once every area light is known (number_area_lights)
    tab = dict(kind=L.kind, id=None, light=L, slot=slot, L=L.radiance, emitter=e if textured else None)
    if L.kind == "mesh":
        tab.update(cdf=mi.Float(L.cdf), v0=mi.Float(L.v0.ravel()), v1=mi.Float(L.v1.ravel()),
                   v2=mi.Float(L.v2.ravel()), nrm=mi.Float(L.normals.ravel()), n=len(L.cdf),
                   area=float(L.area))
        if uv is not None:
            tab.update(**{f"uv{k}": mi.Float(np.ascontiguousarray(uv[:, k]).ravel()) for k in range(3)})
    elif L.kind == "sphere":
        tab.update(c=L.center, r=float(L.r))
    else:
        tab.update(m=L.m.tolist(), nrm_d=L.normal, area=float(L.area))
    return tab


def _area_radiance(tab, uv):
    """The radiance of an area light at light samples of surface coordinates ``uv``: its
    constant, or Mitsuba's evaluation of its texture (``emitter.eval`` on the front side)."""
    e = tab.get("emitter")
    if e is None:
        return color3(tab["L"])
    si = dr.zeros(mi.SurfaceInteraction3f, dr.width(uv))
    si.uv = uv
    si.wi = mi.Vector3f(0.0, 0.0, 1.0)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
    return mi.Color3f(e.eval(si))


def envmap_table(e):
    """The core's :class:`links1.shading.lights.EnvironmentMap` from Mitsuba's own data (its periodic
    columns dropped), to_world and scale, with its CDFs as Dr.Jit tables."""
    from links1.shading.lights import EnvironmentMap
    prm = mi.traverse(e)
    data = np.array(prm["data"], dtype=np.float64)
    m = np.array(prm["to_world"].matrix, dtype=np.float64).reshape(4, 4)
    scale = float(np.array(prm["scale"]).ravel()[0])
    # Mitsuba 3.9.1 pads a periodic column on each side (its eval matches the core's, tested)
    E = EnvironmentMap(data[:, 1:-1], to_world=m, scale=scale)
    return dict(E=E, nodes=mi.Float(E.nodes.ravel()), row=mi.Float(E.row_cdf),
                col=mi.Float(E.col_cdf.ravel()), pcell=mi.Float(E.p_cell.ravel()))


def sample_area(tab, p, u, v):
    """``AreaLight.sample`` of the core in float32: (wi, dist, L_e / pdf, pdf), the pdf in
    solid angle (0 where nothing is sampled)."""
    if tab["kind"] == "sphere":
        Le = color3(tab["L"])
        c, r = vector3(tab["c"]), float(tab["r"])
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
        return wi, dr.select(outside, dist, 0.0), Le * w, dr.select(w > 0, 1.0 / dr.select(w > 0, w, 1.0), 0.0)
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
        uv = None
        if "uv0" in tab:
            uv = (dr.gather(mi.Point2f, tab["uv0"], k) * b0 + dr.gather(mi.Point2f, tab["uv1"], k) * b1
                  + dr.gather(mi.Point2f, tab["uv2"], k) * (1.0 - b0 - b1))
    else:
        m = tab["m"]
        rr = dr.sqrt(u)
        sp_, cp_ = dr.sincos(2.0 * math.pi * v)
        x, y = rr * cp_, rr * sp_
        q = mi.Vector3f(*[m[i][0] * x + m[i][1] * y + m[i][3] for i in range(3)])
        nl = vector3(tab["nrm_d"])
        uv = mi.Point2f(rr, v)     # Mitsuba's disk: (r, φ / 2π)
    Le = _area_radiance(tab, uv)
    to = q - p
    d2 = dr.squared_norm(to)
    dist = dr.sqrt(d2)
    wi = to / dr.select(dist > 0, dist, 1.0)
    cos_l = -dr.dot(nl, wi)
    w = dr.select((cos_l > 0) & (d2 > 0), tab["area"] * cos_l / dr.select(d2 > 0, d2, 1.0), 0.0)
    return wi, dist, Le * w, dr.select(w > 0, 1.0 / dr.select(w > 0, w, 1.0), 0.0)


def area_pdf(tab, p, wi, dist, n_hit):
    """The solid-angle pdf with which :func:`sample_area` draws direction ``wi`` from ``p``,
    where it meets the light at distance ``dist`` with normal ``n_hit`` (a sphere's cone:
    ``1 / (2π (1 - cos θ_max))``; a mesh or disk: ``d² / (A |cos θ_light|)``)."""
    if tab["kind"] == "sphere":
        r = float(tab["r"])
        dc2 = dr.squared_norm(vector3(tab["c"]) - p)
        sin2 = dr.minimum(r * r / dr.select(dc2 > r * r, dc2, 1.0), 1.0)
        one_minus = sin2 / (1.0 + dr.sqrt(1.0 - sin2))
        return dr.select(dc2 > r * r, 1.0 / (2.0 * math.pi * dr.maximum(one_minus, 1e-30)), 0.0)
    cos_l = dr.abs(dr.dot(n_hit, wi))
    return dr.select(cos_l > 0, dr.square(dist) / (tab["area"] * dr.select(cos_l > 0, cos_l, 1.0)), 0.0)


def sample_env(env, nf, u, v):
    """``ConstantEnvironment.sample`` / ``EnvironmentMap.sample`` of the core in float32:
    (wi, L / pdf, pdf)."""
    if isinstance(env, ConstantEnvRecord):
        fr = mi.Frame3f(nf)
        r_ = dr.sqrt(u)
        z = dr.sqrt(dr.maximum(0.0, 1.0 - u))
        sp_, cp_ = dr.sincos(2.0 * math.pi * v)
        wi = fr.s * (r_ * cp_) + fr.t * (r_ * sp_) + fr.n * z
        return wi, color3(env.radiance) * dr.select(z > 0, math.pi / z, 0.0), z * (1.0 / math.pi)
    T = env.table
    E, H, W = T["E"], T["E"].H, T["E"].W
    if E.dark:
        return mi.Vector3f(nf), dr.zeros(mi.Color3f, dr.width(u)), dr.zeros(mi.Float, dr.width(u))
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
    pdf = _env_cell_pdf(T, ix, iy, st)
    L = _env_bilinear(T, x, y)
    ok = (pdf > 0) & (st > 0)
    w = dr.select(ok, 1.0 / dr.select(pdf > 0, pdf, 1.0), 0.0)
    return wi, L * w, dr.select(ok, pdf, 0.0)


def _env_cell_pdf(T, ix, iy, st):
    """The solid-angle pdf of an envmap's cell ``(ix, iy)`` at ``sin θ = st``."""
    E = T["E"]
    return dr.gather(mi.Float, T["pcell"], iy * E.W + ix) * (E.W * (E.H - 1)) / \
        (2.0 * math.pi * math.pi * dr.maximum(st, 1e-30))


def _env_bilinear(T, x, y):
    """Bilinear radiance at node coordinates ``(x, y)`` (links1.shading.lights.EnvironmentMap._bilinear)."""
    W, H = T["E"].W, T["E"].H
    ixn = dr.minimum(mi.UInt32(x), W - 1)
    iyn = dr.minimum(mi.UInt32(y), H - 2)
    gx, gy = x - mi.Float(ixn), y - mi.Float(iyn)
    nodes, W1 = T["nodes"], W + 1
    g = lambda yy, xx: dr.gather(mi.Color3f, nodes, yy * W1 + xx)  # noqa: E731
    return ((g(iyn, ixn) * (1 - gx) + g(iyn, ixn + 1) * gx) * (1 - gy)
            + (g(iyn + 1, ixn) * (1 - gx) + g(iyn + 1, ixn + 1) * gx) * gy)


def env_eval_pdf(env, nf, wi):
    """Radiance of an environment light toward ``-wi`` and the pdf with which
    :func:`sample_env` draws ``wi`` (constant: ``cos θ / π`` about ``nf``; envmap: its
    cell's, ``EnvironmentMap.eval``'s mapping)."""
    n = dr.width(wi)
    if isinstance(env, ConstantEnvRecord):
        return dr.zeros(mi.Color3f, n) + color3(env.radiance), dr.maximum(dr.dot(nf, wi), 0.0) * (1.0 / math.pi)
    T = env.table
    E = T["E"]
    if E.dark:
        return dr.zeros(mi.Color3f, n), dr.zeros(mi.Float, n)
    W, H = E.W, E.H
    inv = E.inv.tolist()
    lx, ly, lz = (inv[i][0] * wi.x + inv[i][1] * wi.y + inv[i][2] * wi.z for i in range(3))
    u = dr.atan2(lx, -lz) * (1.0 / (2.0 * math.pi)) - 0.5 / W
    u = u - dr.floor(u)
    ct = dr.clip(ly / dr.maximum(dr.sqrt(lx * lx + ly * ly + lz * lz), 1e-30), -1.0, 1.0)
    x, y = u * W, dr.acos(ct) * ((H - 1) / math.pi)
    ix = dr.minimum(mi.UInt32(x), W - 1)
    iy = dr.minimum(mi.UInt32(y), H - 2)
    st = dr.safe_sqrt(1.0 - ct * ct)
    pdf = _env_cell_pdf(T, ix, iy, st)
    return _env_bilinear(T, x, y), dr.select(st > 0, pdf, 0.0)


def light_uv(key, sample, light_id, j, m):
    """Light sample ``j`` of ``m`` of light ``light_id``:
    :func:`links1.maths.sampling.light_samples_uv` in float32 (``sample = (pixel key, i,
    spp)`` at a primary hit, else None)."""
    if sample is not None:
        shift, i, spp = sample
        s_, n_ = i * m + j, mi.Float(spp * m)
    else:
        shift, s_, n_ = key, dr.zeros(mi.UInt32, dr.width(key)) + j, float(m)
    h = mix32(shift ^ mi.UInt32(light_tag(light_id)))
    a, b = unit_float(mix32(h ^ 1)), unit_float(mix32(h ^ 2))
    x = mi.UInt32(s_)
    for sh, mask in ((1, 0x55555555), (2, 0x33333333), (4, 0x0F0F0F0F), (8, 0x00FF00FF)):
        x = ((x >> sh) & mask) | ((x & mask) << sh)
    x = (x >> 16) | (x << 16)
    u = mi.Float(s_) / n_ + a
    v = unit_float(x) + b
    return u - dr.floor(u), v - dr.floor(v)


def bsdf_uv(key, sample):
    """The hit's BSDF sample ``(u1, u, v)``: :func:`links1.maths.sampling.bsdf_samples_uv`
    in float32 (one per hit, keyed as :func:`light_at_uv`)."""
    u, v = light_uv(key, sample, BSDF_SAMPLE_ID, 0, m=1)
    if sample is not None:
        shift, s_ = sample[0], sample[1]
    else:
        shift, s_ = key, dr.zeros(mi.UInt32, dr.width(key))
    h = mix32(shift ^ mi.UInt32(light_tag(BSDF_SAMPLE_ID)))
    return unit_float(mix32(mix32(h ^ 3) ^ mi.UInt32(s_))), u, v
