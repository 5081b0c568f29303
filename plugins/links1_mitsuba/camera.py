"""Camera rays of ``links1_whitted`` (their one home): the rays of any set of samples
(:func:`camera_rays`: the sample pattern of :mod:`links1.maths.sampling`, its pixel set and
sample count run-time values) and of any film positions (:func:`rays_at`: perspective, thin lens,
orthographic, as Mitsuba's sensors make them), from a camera view of the tables
(:class:`~.prepared.CameraView`: ``film_size``, ``cam``, ``x_fov``, ``lens``, ``near``, ``far``).

Plain functions (no state), read by the launches (launch.py) and the derivatives' visibility
term; they name ``mi.Float``, ``mi.Ray3f``, ... when called, so they serve every Mitsuba variant.
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi

from links1.maths.sampling import KEY_LENS_U, KEY_LENS_V, KEY_PIXEL

from .util import mix32, udiv, unit_float


def camera_rays(tables, sid, spp, seed):
    """Camera rays of the samples ``sid = pixel * spp + i`` (``pixel = py * W + px``, ``i``
    the sample's index in its pixel): any set of pixels (one window or a batch of them)
    in one launch. ``sid``, ``spp = (spp, strata k)`` and ``seed = (pattern seed, key
    seed)`` are run-time values (``UInt32``), so neither the pixel set nor the sample count
    enters the kernels (see ``Launches.render_windows``). Returns ``o, d, tmin, tmax, key,
    sample``: ``sample = (pixel key, i, spp)``, the camera sample the ray tree's primary level
    takes its light samples from (``Tracer.trace_tree``)."""
    W, H = tables.film_size
    n_s, k_s = spp
    pix = udiv(sid, n_s)          # run-time divisors: util.udiv (exact, vectorised)
    i = sid - pix * n_s
    py = pix // W
    px = pix - py * W
    kf = mi.Float(k_s)
    row = udiv(i, k_s)
    sx = mi.Float(i - row * k_s)
    sy = mi.Float(row)
    base = mix32(mix32(seed[0]) ^ pix)
    ux = unit_float(mix32(base ^ (2 * i)))
    uy = unit_float(mix32(base ^ (2 * i + 1)))
    centre = n_s == 1   # one sample: the pixel centre (links1.maths.sampling)
    offx = dr.select(centre, mi.Float(0.5), (sx + ux) / kf)
    offy = dr.select(centre, mi.Float(0.5), (sy + uy) / kf)
    xf = (mi.Float(px) + offx) / W
    yf = (mi.Float(py) + offy) / H
    key = mix32(mix32(seed[1]) ^ sid)
    # light samples of a primary hit: one set over the pixel (links1.maths.sampling.pixel_keys)
    sample = (mix32(mix32(seed[1] ^ KEY_PIXEL) ^ pix), i, n_s)
    o, d, tmin, tmax = rays_at(tables, xf, yf, key)
    return o, d, tmin, tmax, key, sample


def rays_at(tables, xf, yf, key):
    """Camera rays through film positions ``(xf, yf)`` (fractions of the film's width and
    height, row 0 at the top) with keys ``key`` (a thin lens's aperture samples,
    links1.maths.sampling.lens_samples) -> ``o, d, tmin, tmax``."""
    n = dr.width(xf)
    W, H = tables.film_size
    if tables.perspective:
        tn = math.tan(math.radians(tables.x_fov) / 2.0)
        aspect = W / H
        dc = mi.Vector3f((1.0 - 2.0 * xf) * tn, (1.0 - 2.0 * yf) * (tn / aspect), 1.0)
        m = tables.cam.tolist()
        if tables.lens is not None:   # a thin lens (links1.sensor.camera): from the aperture point
            radius, focus = tables.lens
            disk = mi.warp.square_to_uniform_disk_concentric(
                mi.Point2f(unit_float(mix32(key ^ KEY_LENS_U)), unit_float(mix32(key ^ KEY_LENS_V))))
            a = mi.Vector3f(radius * disk.x, radius * disk.y, 0.0)
            dc = dr.normalize(dc * focus - a)
            o = mi.Point3f(*[m[r][0] * a.x + m[r][1] * a.y + m[r][3] for r in range(3)])
        else:
            dc = dr.normalize(dc)
            o = mi.Point3f(m[0][3], m[1][3], m[2][3]) + mi.Vector3f(dr.zeros(mi.Float, n))
        inv_z = 1.0 / dc.z
        d = dr.normalize(mi.Vector3f(*[m[r][0] * dc.x + m[r][1] * dc.y + m[r][2] * dc.z
                                       for r in range(3)]))
        return o, d, tables.near * inv_z, tables.far * inv_z
    # orthographic (links1.sensor.camera): the film on the near plane, rays along the view axis
    m = tables.cam.tolist()
    pc = (1.0 - 2.0 * xf, (1.0 - 2.0 * yf) * (H / W), tables.near)
    o = mi.Point3f(*[m[r][0] * pc[0] + m[r][1] * pc[1] + m[r][2] * pc[2] + m[r][3] for r in range(3)])
    d = dr.normalize(mi.Vector3f(m[0][2], m[1][2], m[2][2])) + mi.Vector3f(dr.zeros(mi.Float, n))
    return o, d, dr.zeros(mi.Float, n), mi.Float(tables.far - tables.near) + dr.zeros(mi.Float, n)
