"""The film of ``links1_whitted`` on the device (issue 22, item 1): sample ids, the
reconstruction filter, spp accumulation and the AOVs in Dr.Jit, so a frame never visits numpy.

Everything here is a per-output-pixel *gather* in one fixed order, never a scatter with atomics:

* sample ids ``pixel * spp + i`` of a window's sample window (the window plus the filter's
  border, clipped to the film), window after window (:func:`sample_ids`);
* box filter (Mitsuba's fast path): the mean of the pixel's ``spp`` samples, summed in float64
  in sample order and divided by ``spp`` (numpy's ``mean`` of ``launch.render_windows`` before);
* any other filter: the pixel is ``Σ w·s / Σ w`` over its ``spp`` samples and those of its
  ``(2b+1)²`` neighbours on the film, summed in float64 in the order of
  :meth:`links1.sensor.filters.FilterGather.add` (sample index, then neighbour row, then neighbour
  column), with the 1-D weights of :meth:`links1.sensor.filters.Filter.eval` evaluated in float64 at
  the sample offsets of :mod:`links1.maths.sampling` (recomputed from the same integer hash, in
  float64 as :func:`links1.maths.sampling.sample_offsets`; the kernels' own camera rays use the
  float32 rounding of the same offsets);
* AOVs: ``depth``/``normal``/``id`` of the pixel's sample 0, ``cost`` summed over its samples,
  ``samples`` = spp.

What depends only on the windows (the :class:`Batch` tables, the sample ids, the filter's
weight tables) is kept with the batch while the same windows are rendered again
(:func:`cached_batch`); each neighbour's RGB is read as one packet of four floats, and the
divisions by run-time values go through :func:`links1_mitsuba.util.udiv` (exact).

So a pixel depends only on its own samples and those of its neighbours, never on the window:
a window or a batch of windows equals the full frame bit for bit. Every size (film width,
spp, seeds) enters the kernels as an opaque value and the windows' origins, sizes and offsets
as tables (:class:`Batch`): new windows and batch sizes replay the cached kernels (one kernel
per filter type and AOV list), and a batch of hundreds of windows is still one kernel.

Agreement with the numpy path (:func:`links1.sensor.filters.filter_samples`): bit for bit for box,
tent, mitchell and catmullrom; gaussian and lanczos differ where Dr.Jit's float64 ``exp`` /
``sin`` differ from libm's by an ulp (about one evaluation in six), i.e. a relative 1e-15 in
float64 and, after the float32 rounding of ``mi.render``, almost always nothing. A division
by a Python float would become a reciprocal multiply in Dr.Jit: divisors are opaque.
"""
from __future__ import annotations

import functools
import math
import sys

import drjit as dr
import mitsuba as mi
import numpy as np

from .util import mix32, table, udiv

#: Largest tables of 1-D filter weights of a batch (bytes: 16 per sample and neighbour offset);
#: bigger windows evaluate the weights in the gather itself ((2b+1) times as many evaluations,
#: the same values).
FILM_TABLE_BYTES = 1 << 30

#: A batch of at most this many sample lanes keeps what depends only on its windows (sample
#: ids, the filter's weight tables) evaluated between frames (:func:`cached_batch`): 4 bytes a
#: lane for the ids (at most 32 MiB) ...
KEEP_LANES = 1 << 23
#: ... and its weight tables when they take at most this many bytes (512², spp 12, a gaussian)
KEEP_TABLE_BYTES = 1 << 28

#: Batches kept by :func:`cached_batch` (per integrator: the last few window sets).
KEEP_BATCHES = 2


def sample_window(rfilter, window, film_size):
    """The pixels whose samples a window needs: ``window`` plus ``rfilter.border`` on each
    side, clipped to the film (:attr:`links1.sensor.filters.FilterGather.sample_window`)."""
    W, H = film_size
    x0, y0, w, h = window
    b = rfilter.border
    sx0, sy0 = max(0, x0 - b), max(0, y0 - b)
    return sx0, sy0, min(W, x0 + w + b) - sx0, min(H, y0 + h + b) - sy0


def op_u(v):
    return dr.opaque(mi.UInt32, int(v) & 0xFFFFFFFF)


def op_i(v):
    return dr.opaque(mi.Int32, int(v))


def op_f(v):
    return dr.opaque(mi.Float64, float(v))


def concat(parts, n, tp):
    """``parts`` (flat arrays) one after another in one array of width ``n``; the offsets are
    opaque (``dr.concat`` bakes them into its kernels)."""
    if len(parts) == 1:
        return parts[0]
    out = dr.empty(tp, n)
    at = 0
    for p in parts:
        m = dr.width(p)
        dr.scatter(out, p, dr.arange(mi.UInt32, m) + op_u(at))
        at += m
    return out


class Batch:
    """The windows of one launch, laid one after another: their samples in the launch's lanes
    (each window's sample window, row-major, ``spp`` samples innermost) and their output pixels
    in the film's result (each window row-major). The per-window values reach the kernels as
    ``UInt32`` tables, gathered by the window an entry belongs to (:meth:`window_of`), so one
    kernel makes the sample ids or the pixels of every window of a batch, whatever their number,
    sizes and places: no recompilation, no per-window kernel or Python work (a scanline
    partition hands a node hundreds of windows)."""

    def __init__(self, wins, swins, spp):
        self.wins, self.swins, self.spp = [tuple(w) for w in wins], [tuple(s) for s in swins], int(spp)
        m = np.array([w * h for _, _, w, h in self.wins], dtype=np.int64)
        ns = np.array([sw * sh for _, _, sw, sh in self.swins], dtype=np.int64) * self.spp
        #: first output pixel / first sample lane of each window; their totals
        self.pixel_start = np.concatenate([[0], np.cumsum(m)[:-1]])
        self.lane_start = np.concatenate([[0], np.cumsum(ns)[:-1]])
        self.pixels, self.lanes = int(m.sum()), int(ns.sum())
        if self.lanes >= 2 ** 32 or self.pixels >= 2 ** 32:
            raise ValueError(f"{self.lanes} samples in one batch exceed the 32-bit lane indices")
        u = lambda v: table(mi.UInt32, np.asarray(v, dtype=np.uint32))  # noqa: E731
        w, s = np.array(self.wins, dtype=np.int64), np.array(self.swins, dtype=np.int64)
        self.x0, self.y0, self.w = u(w[:, 0]), u(w[:, 1]), u(w[:, 2])
        self.sx0, self.sy0, self.sw = u(s[:, 0]), u(s[:, 1]), u(s[:, 2])
        self.first_lane, self.first_pixel = u(self.lane_start), u(self.pixel_start)
        #: whether the values below are kept evaluated with the batch (:data:`KEEP_LANES`)
        self.keep = self.lanes <= KEEP_LANES
        self._kept = {}

    def kept(self, key, make):
        """``make()`` (a tuple of Dr.Jit arrays), evaluated and kept with the batch under
        ``key`` when the batch keeps values (one value a kind: ``key[0]``), else made anew."""
        if not self.keep:
            return make()
        hit = self._kept.get(key[0])
        if hit is not None and hit[0] == key:
            return hit[1]
        vals = make()
        dr.eval(*vals)
        self._kept[key[0]] = (key, vals)
        return vals

    @functools.cached_property
    def lane_window(self):
        """The window of each sample lane (:meth:`window_of`), made once a batch: the sample
        ids and the filter's weight tables both read it."""
        return self.window_of(self.lane_start, self.lanes)

    def window_of(self, starts, n, scale=1):
        """The window (``UInt32``) of each of ``n`` entries laid out window after window from
        ``starts * scale``: a mark at each window's first entry, summed (one prefix sum)."""
        if len(starts) == 1:
            return dr.zeros(mi.UInt32, n)
        marks = dr.zeros(mi.UInt32, n)
        # at least two indices (the last repeated: a second write of the same 1): Dr.Jit makes a
        # one-entry array a scalar of the kernel, which would be another kernel for two windows
        at = np.asarray(starts[1:] * scale, dtype=np.uint32)
        dr.scatter(marks, mi.UInt32(1), table(mi.UInt32, np.append(at, at[-1]) if at.size == 1 else at))
        return dr.cumsum(marks)


def _divisor(v):
    """A gathered ``UInt32`` divisor (a window's width, always >= 1) kept >= 1 in the lanes a
    kernel computes past the array's end: a masked gather gives 0 there, and the LLVM backend's
    per-lane integer division traps on 0 (SIGFPE) even in lanes it then discards."""
    return dr.maximum(v, 1)


def cached_batch(cache, wins, swins, spp):
    """The :class:`Batch` of ``wins``/``swins``/``spp`` from ``cache`` (a dict the caller
    keeps: the last :data:`KEEP_BATCHES` batches), or a new one put in it: a frame of the same
    windows reuses its tables, sample ids and weight tables (the same values: they depend
    only on the windows, the film and the sample pattern) instead of making them again."""
    key = (tuple(map(tuple, wins)), tuple(map(tuple, swins)), int(spp))
    b = cache.pop(key, None)
    if b is None:
        b = Batch(wins, swins, spp)
    cache[key] = b                    # the most recent last
    while len(cache) > KEEP_BATCHES:
        cache.pop(next(iter(cache)))
    return b


def sample_ids(film_width, spp, batch):
    """UInt32 sample ids ``(py * W + px) * spp + i`` of the sample windows of ``batch``
    (:class:`Batch`: row-major, ``i`` innermost), one window after another; kept with the
    batch (:meth:`Batch.kept`)."""
    return batch.kept(("sid", int(film_width), int(spp)), lambda: (_sample_ids(film_width, spp, batch),))[0]


def _sample_ids(film_width, spp, batch):
    W, s = op_u(film_width), op_u(spp)
    k = batch.lane_window
    j = dr.arange(mi.UInt32, batch.lanes) - dr.gather(mi.UInt32, batch.first_lane, k)
    pix = udiv(j, s)
    i = j - pix * s
    sw = _divisor(dr.gather(mi.UInt32, batch.sw, k))
    ly = udiv(pix, sw)
    lx = pix - ly * sw
    return ((ly + dr.gather(mi.UInt32, batch.sy0, k)) * W + lx + dr.gather(mi.UInt32, batch.sx0, k)) * s + i


def filter_eval(f, x):
    """:meth:`links1.sensor.filters.Filter.eval` in float64, the same operations in the same order."""
    x = dr.abs(x)
    p, r = f.params, f.radius
    if f.name == "tent":
        return dr.maximum(0.0, 1.0 - x / op_f(r))
    if f.name == "gaussian":
        a = -1.0 / (2.0 * p["stddev"] ** 2)
        return dr.maximum(0.0, dr.exp(a * x * x) - math.exp(a * r * r))
    if f.name == "lanczos":
        tiny = x < 2.0 ** -23   # np.finfo(np.float32).eps
        x1 = math.pi * dr.select(tiny, 1.0, x)
        x2 = x1 / op_f(r)
        v = dr.sin(x1) * dr.sin(x2) / (x1 * x2)
        return dr.select(tiny, 1.0, dr.select(x > r, 0.0, v))
    if f.name in ("mitchell", "catmullrom"):
        b, c = (p["B"], p["C"]) if f.name == "mitchell" else (0.0, 0.5)
        x2, x3 = x * x, x * x * x
        near = (12 - 9 * b - 6 * c) * x3 + (-18 + 12 * b + 6 * c) * x2 + (6 - 2 * b)
        far = (-b - 6 * c) * x3 + (6 * b + 30 * c) * x2 + (-12 * b - 48 * c) * x + (8 * b + 24 * c)
        return dr.select(x < 2.0, dr.select(x < 1.0, near, far) / op_f(6.0), 0.0)
    raise ValueError(f"links1_whitted: no device film for filter {f.name!r}")


def offsets(pix, i, spp, k, seed):
    """Float64 offsets in the pixel of sample ``i`` of pixel ``pix`` (UInt32s):
    :func:`links1.maths.sampling.sample_offsets` with run-time ``spp``, strata ``k``, ``seed``."""
    base = mix32(mix32(seed) ^ pix)
    ux = mi.Float64(mix32(base ^ (2 * i)) >> 8) * 2.0 ** -24
    uy = mi.Float64(mix32(base ^ (2 * i + 1)) >> 8) * 2.0 ** -24
    sy = udiv(i, k)
    sx = i - sy * k
    kf = mi.Float64(k)
    one = spp == 1
    return dr.select(one, 0.5, (mi.Float64(sx) + ux) / kf), dr.select(one, 0.5, (mi.Float64(sy) + uy) / kf)


def reconstruct(rfilter, film_size, spp, seed, batch, data, aovs, dtype=None, mode=None):
    """The pixels of every window of ``batch`` (:class:`Batch`) as one flat ``dtype`` array,
    window after window, each ``(h * w * C)`` (row-major, channels innermost: RGB, then
    ``aovs``), from ``data``: the launch's device outputs over all its lanes (``total``
    Color3f, ``cost`` Float, and for AOVs ``t0``, ``s0``, ``n0``) laid out as
    :func:`sample_ids`. A pixel is computed from its own window's values only, in the same
    operations whatever the batch, so it has the same bits in any batch. ``mode``: of the loops
    (``"evaluated"`` in a derivative pass: reverse-mode AD needs it). ``dtype``: of the result
    (None: ``mi.Float64``). Returns ``(flat, C)``."""
    F64, U32, I32 = mi.Float64, mi.UInt32, mi.Int32   # of the variant in use
    dtype = F64 if dtype is None else dtype
    W, H = film_size
    m = batch.pixels
    n_s = op_u(spp)
    kw = batch.window_of(batch.pixel_start, m)
    g = lambda t: dr.gather(U32, t, kw)  # noqa: E731  (this pixel's window's value)
    x0, y0, sx0, sy0, sw = g(batch.x0), g(batch.y0), g(batch.sx0), g(batch.sy0), g(batch.sw)
    start = g(batch.first_lane)
    q = dr.arange(U32, m) - g(batch.first_pixel)
    w = _divisor(g(batch.w))
    ly = udiv(q, w)
    lx = q - ly * w
    # the pixel's sample 0 in the launch
    first = start + ((ly + (y0 - sy0)) * sw + lx + (x0 - sx0)) * n_s
    total = data["total"]
    want_cost = "cost" in aovs
    box = rfilter.border == 0 and rfilter.is_box
    chans = []
    if box or want_cost:
        # the pixel's own samples in order: the box mean, the cost sum
        def body(i, r, g, b, c):
            v = dr.gather(type(total), total, first + i) if box else None
            if box:
                r, g, b = r + F64(v[0]), g + F64(v[1]), b + F64(v[2])
            if want_cost:
                c = c + F64(dr.gather(type(data["cost"]), data["cost"], first + i))
            return i + 1, r, g, b, c
        z = dr.zeros(F64, m)
        _, r, g, b, c = dr.while_loop((dr.zeros(U32, m), z, z, z, z), lambda i, *_: i < n_s, body, mode=mode)
        if box:
            s = F64(n_s)
            chans += [r / s, g / s, b / s]
    if not box:
        nb = 2 * rfilter.border + 1
        k, sd = op_u(math.ceil(math.sqrt(spp)) if spp > 1 else 1), op_u(seed)
        x, y = I32(lx + x0), I32(ly + y0)
        Wi, Hi = op_i(W), op_i(H)

        ns = batch.lanes
        # the samples' RGB as packets of four floats (r, g, b, 0): each neighbour is then one
        # 16-byte gather instead of three 4-byte ones (~2.6x cheaper for scattered lanes on
        # LLVM); the same values
        Vec4 = mi.Vector4f
        packed = dr.zeros(type(total[0]), 4 * ns)
        dr.scatter(packed, Vec4(total[0], total[1], total[2], 0.0), dr.arange(U32, ns))
        tables = ns * nb * 16 <= FILM_TABLE_BYTES
        if tables:
            make = lambda: _weight_tables(rfilter, W, n_s, k, sd, batch, nb)  # noqa: E731
            wx_t, wy_t = (batch.kept(("weights", rfilter, W, int(spp), int(seed)), make)
                          if ns * nb * 16 <= KEEP_TABLE_BYTES else make())

        def body(j, r, g, b, den):
            # one neighbour row of one sample a step, its nb columns unrolled: the order of the
            # sum is the same (sample, row, column), with the loop's overhead once per row
            i = j // nb
            dyi = j - i * nb
            dy = I32(dyi) - rfilter.border
            yy = y + dy
            on_y = (yy >= 0) & (yy < Hi)
            yu = U32(dr.select(on_y, yy, 0))
            row = (yu - sy0) * sw
            for dxi in range(nb):
                dx = dxi - rfilter.border
                xx = x + dx
                on = on_y & (xx >= 0) & (xx < Wi)
                xu = U32(dr.select(on, xx, 0))
                lane = start + (row + xu - sx0) * n_s + i
                v = dr.gather(Vec4, packed, lane, on)
                if tables:
                    wgt = dr.gather(F64, wy_t, lane * nb + dyi, on) * dr.gather(F64, wx_t, lane * nb + dxi, on)
                else:
                    ox, oy = offsets(yu * op_u(W) + xu, i, n_s, k, sd)
                    wgt = filter_eval(rfilter, (0.5 - F64(dy)) - oy) * filter_eval(rfilter, (0.5 - float(dx)) - ox)
                r = dr.select(on, r + wgt * F64(v[0]), r)
                g = dr.select(on, g + wgt * F64(v[1]), g)
                b = dr.select(on, b + wgt * F64(v[2]), b)
                den = dr.select(on, den + wgt, den)
            return j + 1, r, g, b, den
        z = dr.zeros(F64, m)
        _, r, g, b, den = dr.while_loop((dr.zeros(U32, m), z, z, z, z),
                                        lambda j, *_: j < n_s * nb, body, mode=mode)
        den = dr.select(den == 0.0, 1.0, den)
        chans += [r / den, g / den, b / den]
    if aovs:
        t0 = dr.gather(type(data["t0"]), data["t0"], first)
        s0 = I32(dr.gather(type(data["s0"]), data["s0"], first))
        n0 = dr.gather(type(data["n0"]), data["n0"], first)
        hit = s0 >= 0
        for a in aovs:
            if a == "depth":
                chans.append(dr.select(hit, F64(t0), 0.0))
            elif a == "normal":
                chans += [dr.select(hit, F64(n0[kk]), 0.0) for kk in range(3)]
            elif a == "id":
                chans.append(F64(s0))
            elif a == "cost":
                chans.append(c)
            elif a == "samples":
                chans.append(F64(n_s) + dr.zeros(F64, m))
    # the channels interleaved by one scatter of a nested array (index p -> p * C + channel):
    # one kernel with the channels' own (separate scatters into one array would each
    # evaluate the ones before: a kernel per channel)
    chans = [dtype(ch) for ch in chans]
    C = len(chans)
    ArrayX = getattr(sys.modules[dtype.__module__], "ArrayXf64" if dtype is F64 else "ArrayXf")
    out = dr.empty(dtype, m * C)
    dr.scatter(out, ArrayX(*chans), dr.arange(U32, m))
    return out, C


def _weight_tables(rfilter, W, n_s, k, sd, batch, nb):
    """The 1-D filter weights of every sample of ``batch`` towards its ``nb`` neighbour
    columns and rows (``(wx, wy)``, float64, ``nb`` per sample), once per sample (the gather
    would evaluate each ``nb`` times), from the sample's offsets made once (hashes and integer
    divisions, which the LLVM backend does lane by lane, not once per weight): the same values."""
    U32, I32, F64 = mi.UInt32, mi.Int32, mi.Float64
    ns = batch.lanes
    sl = dr.arange(U32, ns)
    kl = batch.lane_window
    local = sl - dr.gather(U32, batch.first_lane, kl)
    pl = udiv(local, n_s)
    i = local - pl * n_s
    swl = _divisor(dr.gather(U32, batch.sw, kl))
    py = udiv(pl, swl)
    ox, oy = offsets((py + dr.gather(U32, batch.sy0, kl)) * op_u(W) + pl - py * swl
                     + dr.gather(U32, batch.sx0, kl), i, n_s, k, sd)
    dr.eval(ox, oy)
    t = dr.arange(U32, ns * nb)
    sl = t // nb
    d = I32(t - sl * nb) - rfilter.border
    ox, oy = dr.gather(F64, ox, sl), dr.gather(F64, oy, sl)
    wx, wy = filter_eval(rfilter, (0.5 - F64(d)) - ox), filter_eval(rfilter, (0.5 - F64(d)) - oy)
    dr.eval(wx, wy)
    return wx, wy


def widen(v, n):
    """``v`` with ``n`` lanes: a frozen launch returns literals at their recorded width
    (their first lane, broadcast)."""
    return v if dr.width(v) == n else dr.gather(type(v), v, dr.zeros(mi.UInt32, n))
