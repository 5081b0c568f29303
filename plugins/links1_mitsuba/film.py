"""The film of ``links1_whitted`` on the device: sample ids, the
reconstruction filter, spp accumulation and the AOVs in Dr.Jit, so a frame never visits numpy.

Everything here is a per-output-pixel *gather* in one fixed order, never a scatter with atomics:

* sample ids ``pixel * spp + i`` of a window's sample window (the window plus the filter's
  border, clipped to the film), window after window (:func:`sample_ids`);
* box filter (Mitsuba's fast path): the mean of the pixel's ``spp`` samples, summed in float64
  in sample order and divided by ``spp`` (numpy's ``mean`` of ``launch.render_windows`` before);
  at spp a multiple of 4, four consecutive samples a packet gather (:data:`BOX_PACKETS`);
* any other filter: the pixel is ``Σ w·s / Σ w`` over its ``spp`` samples and those of its
  ``(2b+1)²`` neighbours on the film, in float32 (the output's precision: twice the SIMD lanes
  and half the bytes of float64): the 1-D weights of :meth:`links1.sensor.filters.Filter.eval`
  evaluated in float64 at the sample offsets of :mod:`links1.maths.sampling` rounded to float32
  (recomputed from the same integer hash as :func:`links1.maths.sampling.sample_offsets`: the
  positions of the kernels' own camera rays) and rounded to float32, summed in float32 in the
  order of :class:`links1.sensor.filters.FilterGather` with ``dtype=np.float32``: per neighbour
  row, then column, the neighbour's own samples in sample order summed apart, then added to
  the pixel. Against the float64 film at the same positions a pixel moves by a few float32 ulps
  where the weights are positive (gaussian, tent: measured ≤ 10), more only relative to a pixel
  that nearly cancels (mitchell, lanczos: negative lobes); ``compare/results/film_precision.md``;
* AOVs: ``depth``/``normal``/``id`` of the pixel's sample 0, ``cost`` summed over its samples,
  ``samples`` = spp.

The non-box filters, in two passes at spp > 1 (each sample is read once with its ``2(2b+1)``
weights, made once a batch, :func:`_sample_weights`; kept as ``2 · 2b`` where the filter's
radius allows it: a sample's two outermost weights are never both nonzero):

1. a lane a pixel ``q`` of a sample window (:func:`_filter_partials`): over ``q``'s samples, for
   each neighbour offset ``(dy, dx)``, the record ``(Σ w·r, Σ w·g, Σ w·b, Σ w)`` of the terms
   ``q`` gives the pixel ``(dy, dx)`` away (a table a offset, ``(2b+1)²`` of them; RGB records
   of 5 neighbours a row a table a row, 64 bytes a pixel: :func:`_row_tables`);
2. a lane an output pixel (:func:`_filter_sum`): its neighbours' records for it, added in
   ascending ``dy``, then ``dx``, over the weight sum.

The weight sums depend only on the samples' places: where the batch keeps the samples' weights,
the first frame's pass 2 keeps them (:func:`_keeps_weights`) and later frames' records carry the
RGB sums alone; a pixel whose samples are all zero (a black background, a hard
shadow) then has records of +0 and skips pass 1's loop over its samples, and an output pixel
none of whose neighbours has a nonzero sample skips pass 2's reads (in a primal frame).

A record depends only on its pixel's samples, so the pass-2 sums are a pixel's own whatever the
window. At spp 1 every sample lies at its pixel's centre and the weights are ``2b+1``
constants (:func:`_centre_weights`): the order above is then the one of the terms themselves,
and one kernel computes a strip of :data:`STRIP` pixels of a window row a lane, reading each
neighbour sample once for the strip (:func:`_filter_gather`). Up to :data:`STRIPS_SPP`, where
writing and reading the records costs more than the few samples, one kernel makes them and adds
them, a strip of :data:`STRIPS_P` pixels a lane (:func:`_filter_strips`; a derivative pass takes
the two passes, whose unrolled loops LLVM compiles in a fraction of the strips' time); a film whose pass-1
table would pass :data:`FILM_TABLE_BYTES`, one kernel a pixel (:func:`_filter_direct`): the same
operations in the same order, the same bits.

What depends only on the windows (the :class:`Batch` tables, the sample ids, the samples'
weights) is kept with the batch while the same windows are rendered again
(:func:`cached_batch`), and the divisions by
run-time values go through :func:`links1_mitsuba.util.udiv` (exact).

So a pixel depends only on its own samples and those of its neighbours, never on the window:
a window or a batch of windows equals the full frame bit for bit. Every size (film width,
spp, seeds) enters the kernels as an opaque value and the windows' origins, sizes and offsets
as tables (:class:`Batch`): new windows and batch sizes replay the cached kernels (one kernel
per filter type and AOV list), and a batch of hundreds of windows is still one kernel.

Agreement with the numpy path (:func:`links1.sensor.filters.filter_samples`, float64 for box,
``dtype=np.float32`` for the others): bit for bit for box, tent, mitchell and catmullrom;
gaussian and lanczos weights differ where Dr.Jit's float64 ``exp`` / ``sin`` differ from libm's
by an ulp (about one evaluation in six) and that ulp survives the rounding to float32 (about
once in 2^29): bit for bit on every scene measured. A division by a Python float would become
a reciprocal multiply in Dr.Jit: divisors are opaque.
"""
from __future__ import annotations

import functools
import math
import sys

import drjit as dr
import mitsuba as mi
import numpy as np

from .util import mix32, table, udiv

#: Largest table of the filter's pass 1 (:func:`_filter_partials`: ``(2b+1)²`` records of four
#: float32 a pixel of the sample windows; 105 MB at 512² for a gaussian, 830 MB at
#: 1920 × 1080); a bigger film makes each pixel's records in pass 2 itself
#: (:func:`_filter_direct`: the same values, the weights made ``(2b+1)²`` times).
FILM_TABLE_BYTES = 1 << 31

#: A batch of at most this many sample lanes keeps what depends only on its windows (the
#: sample ids: 4 bytes a lane, at most 32 MiB) evaluated between frames (:func:`cached_batch`).
KEEP_LANES = 1 << 23

#: Largest spp whose non-box filter is one kernel of strips (:func:`_filter_strips`) rather than
#: two passes (the same bits), as a batch's first frame (the weights made, four-channel records),
#: which a single render is, has it: the film kernels of the strips / the two passes at 512²,
#: gaussian, spp 2 0.47, 4 0.76, 6 0.85 (``compare/results/film_frame_strips_first.md``); in later
#: frames of the same windows (RGB records a neighbour row, :func:`_row_tables`) the two passes
#: are the faster from spp 3 (``compare/results/film_frame_strips.md``, docs/benchmarks.md)
STRIPS_SPP = 7
#: Pixels of a row a lane of :func:`_filter_strips` computes (each column's samples are read
#: by ``(P + 2b) / P`` lanes a neighbour row)
STRIPS_P = 8
#: Largest table of the samples' weights (:func:`_sample_weights`: 32 bytes a sample for a
#: gaussian, 134 MB at 512², spp 16; the strips' full record 64) kept with a batch between frames
KEEP_TABLE_BYTES = 3 << 27

#: Share of a batch's sample-window pixels whose samples are all zero above which the filter's
#: passes skip them (:meth:`Batch.skips_zeros`): the film of spp 16, gaussian, 512², with and
#: without (the same bits): no such pixel 1.13x (the first read of the samples), the teapot's
#: 79 % 0.55x, ``cbox_point``'s 22 % 0.98x
SKIP_ZEROS = 0.2

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


#: A box filter's frame at spp 1 without AOVs makes only the lanes' pixel indices
#: (:class:`_PixelLanes`; False: every table of :class:`_Lanes`, traced and unused)
PIXEL_LANES = True
#: The box filter's mean at spp a multiple of 4 reads a pixel's samples (consecutive in the
#: launch's output) four at a time, with packet gathers (False: one at a time)
BOX_PACKETS = True


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
        #: the sample windows' pixels (a lane of the filter's pass 1), window after window
        self.source_start, self.sources = self.lane_start // self.spp, self.lanes // self.spp
        self.first_source = u(self.source_start)
        #: whether the values below are kept evaluated with the batch (:data:`KEEP_LANES`)
        self.keep = self.lanes <= KEEP_LANES
        self._kept, self._strips = {}, {}
        #: the filter's pass 1 of the last frame: how many sample-window pixels up to each have
        #: a nonzero sample (:func:`_filter_partials`; an evaluated UInt32 array, or None)
        self.zero_probe = None

    def skips_zeros(self):
        """Whether the filter's passes skip the pixels of zero samples this frame: where the
        last frame of these windows had at least :data:`SKIP_ZEROS` of them, or none was made
        (finding them costs a read of the samples' RGB: ~0.1x of the film where none is)."""
        if self.zero_probe is None:
            return True
        return self.sources - int(self.zero_probe[self.sources - 1]) >= SKIP_ZEROS * self.sources

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

    def peek(self, key):
        """The values kept under ``key`` (:meth:`kept`, :meth:`keep_with_frame`), or None."""
        hit = self._kept.get(key[0])
        return hit[1] if hit is not None and hit[0] == key else None

    def keep_with_frame(self, key, value):
        """Keep ``value`` (a Dr.Jit array of this frame) under ``key``, evaluated with the frame's
        own kernel (``dr.schedule``: no kernel of its own). Kept detached: a value made in a
        derivative pass may be attached to its AD graph, and a later pass's backward would leave
        its gradient on the kept node for a forward pass after it to propagate as a tangent."""
        if self.keep:
            value = dr.detach(value)
            dr.schedule(value)
            self._kept[key[0]] = (key, value)

    def strips(self, P):
        """The lanes of a reconstruction kernel whose lane computes ``P`` consecutive pixels of
        a window row (:class:`_Lanes`): each window's first lane (numpy), their total and the
        first lanes as a ``UInt32`` table; ``P = 1``: the pixels themselves."""
        if P == 1:
            return self.pixel_start, self.pixels, self.first_pixel
        hit = self._strips.get(P)
        if hit is None:
            n = np.array([-(-w // P) * h for _, _, w, h in self.wins], dtype=np.int64)
            starts = np.concatenate([[0], np.cumsum(n)[:-1]])
            hit = self._strips[P] = (starts, int(n.sum()), table(mi.UInt32, np.asarray(starts, dtype=np.uint32)))
        return hit

    @functools.cached_property
    def lane_window(self):
        """The window of each sample lane (:meth:`window_of`), made once a batch (the sample
        ids read it)."""
        return self.window_of(self.lane_start, self.lanes)

    @functools.cached_property
    def source_window(self):
        """The window of each sample-window pixel (:meth:`window_of`), made once a batch (the
        filter's pass 1 reads it)."""
        return self.window_of(self.source_start, self.sources)

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
    windows reuses its tables and sample ids (the same values: they depend only on the
    windows, the film and the sample pattern) instead of making them again."""
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


#: A derivative pass (``mode="evaluated"``) runs a film loop of at most this many steps as
#: straight-line code: an evaluated loop launches a kernel and reads its condition back to the
#: host at every step; the same operations in the same order.
UNROLL_MAX = 8


def _loop(state, cond, body, mode, steps):
    """``dr.while_loop(state, cond, body, mode=mode)``, whose loop makes ``steps`` steps (a
    Python int); in a derivative pass (``mode="evaluated"``) with at most :data:`UNROLL_MAX`
    steps, ``body`` applied ``steps`` times instead (``cond`` is then true for exactly those)."""
    if mode == "evaluated" and steps <= UNROLL_MAX:
        for _ in range(steps):
            state = body(*state)
        return state
    return dr.while_loop(state, cond, body, mode=mode)


def reconstruct(rfilter, film_size, spp, seed, batch, data, aovs, dtype=None, mode=None):
    """The pixels of every window of ``batch`` (:class:`Batch`) as one flat ``dtype`` array,
    window after window, each ``(h * w * C)`` (row-major, channels innermost: RGB, then
    ``aovs``), from ``data``: the launch's device outputs over all its lanes (``total``
    Color3f, ``cost`` Float, and for AOVs ``t0``, ``s0``, ``n0``) laid out as
    :func:`sample_ids`. A pixel is computed from its own window's values only, in the same
    operations whatever the batch, so it has the same bits in any batch. ``mode``: of the loops
    (``"evaluated"`` in a derivative pass: reverse-mode AD needs it). ``dtype``: of the result
    (None: ``mi.Float64``). Returns ``(flat, C)``.

    A lane computes one output pixel, or with a non-box filter at spp 1 a strip of :data:`STRIP`
    consecutive pixels of one window row (:func:`_filter_gather`), up to :data:`STRIPS_SPP` one
    of :data:`STRIPS_P` (:func:`_filter_strips`); a strip's pixels past its row's end are
    masked."""
    F64, U32, I32 = mi.Float64, mi.UInt32, mi.Int32   # of the variant in use
    dtype = F64 if dtype is None else dtype
    W, H = film_size
    n_s = op_u(spp)
    box = rfilter.border == 0 and rfilter.is_box
    # spp 1: every sample at its pixel's centre, its weights nb constants (the strip gather)
    centred = _centre_weights(rfilter, 2 * rfilter.border + 1) if not box and int(spp) == 1 else None
    # (not in a derivative pass: there its loops are unrolled, UNROLL_MAX, and the strips' code
    # took LLVM 11 s (spp 2) and 25 s (spp 4) to compile against 1.6 s for the two passes, the
    # same bits)
    strips = not box and centred is None and int(spp) <= STRIPS_SPP and mode != "evaluated"
    P = STRIP if centred is not None else (STRIPS_P if strips else 1)
    if box and int(spp) == 1 and not aovs and PIXEL_LANES:
        L = _PixelLanes(batch)   # (reads no window table)
    else:
        L = _Lanes(batch, P, n_s)
    if box:
        # a box filter's sample windows are its windows (sample_window), laid out as the
        # pixels are (Batch): a pixel's sample 0 is pixel · spp, found without a division
        L.first = dr.arange(U32, L.n) * n_s
    # each sample is one pixel's (box): in a derivative pass a gather's reverse is then a
    # plain scatter (Permute), not a scatter-add with conflict checks (0.58 -> 0.27 ms at 256²)
    red = dr.ReduceMode.Permute if mode == "evaluated" else dr.ReduceMode.Auto
    want_cost = "cost" in aovs
    # the channels of each of the lane's P pixels
    chans = [[] for _ in range(P)]
    if box and int(spp) == 1 and not want_cost:
        # one sample a pixel: its value (the mean below, v / 1 in float64, is v itself)
        v = data["total"]
        if dr.width(v) != L.n:   # (as many lanes as pixels: sample q is pixel q, read in place)
            v = dr.gather(type(v), v, L.first, mode=red)
        chans[0] += [v[kk] for kk in range(3)]
    elif box and not want_cost and mode != "evaluated" and BOX_PACKETS and int(spp) % 4 == 0:
        # four samples a packet gather (a load and a transpose where gathers lane by lane read
        # a cache line a lane each), summed in sample order in float64 as below: the same bits
        total = data["total"]

        def body(j, *acc):
            acc = list(acc)
            for kk in range(3):
                v = dr.gather(mi.Array4f, total[kk], (L.first >> 2) + j)
                for e in range(4):
                    acc[kk] = acc[kk] + F64(v[e])
            return (j + 1, *acc)
        z = dr.zeros(F64, L.n)
        _, *acc = dr.while_loop((dr.zeros(U32, L.n), z, z, z), lambda j, *_: j < (n_s >> 2), body, mode=mode)
        s = F64(n_s)
        chans[0] += [a / s for a in acc]
    elif box or want_cost:
        total, cost = data["total"], data.get("cost")

        # the pixel's own samples in order: the box mean, the cost sum
        def body(i, *acc):
            acc = list(acc)
            if box:
                v = dr.gather(type(total), total, L.first + i, mode=red)
                acc[:3] = [a + F64(v[kk]) for kk, a in enumerate(acc[:3])]
            if want_cost:
                for p in range(P):
                    c = dr.gather(type(cost), cost, L.sample(p) + i, L.valid[p])
                    acc[-P + p] = acc[-P + p] + F64(c)
            return (i + 1, *acc)
        z = dr.zeros(F64, L.n)
        _, *acc = _loop((dr.zeros(U32, L.n), *[z] * ((3 if box else 0) + (P if want_cost else 0))),
                        lambda i, *_: i < n_s, body, mode, int(spp))
        if box:
            s = F64(n_s)
            chans[0] += [a / s for a in acc[:3]]
        cost_sum = acc[-P:] if want_cost else None
    if centred is not None:
        for p, rgb in enumerate(_filter_gather((W, H), batch, data, L, centred, mode)):
            chans[p] += rgb
    elif strips:
        for p, rgb in enumerate(_filter_strips(rfilter, (W, H), seed, batch, data, L, mode)):
            chans[p] += rgb
    elif not box and batch.sources * (2 * rfilter.border + 1) ** 2 * 16 <= FILM_TABLE_BYTES:
        # the weight sums kept by an earlier frame of these windows, else this frame's, kept
        key = ("den", rfilter, (W, H), int(seed))
        keeps = _keeps_weights(rfilter, batch)
        den = batch.peek(key) if keeps else None
        part, seen = _filter_partials(rfilter, (W, H), seed, batch, data, n_s, mode, channels=4 if den is None else 3)
        rgb, sums = _filter_sum(rfilter, (W, H), batch, part, L, den, seen)
        chans[0] += rgb
        if den is None and keeps:
            batch.keep_with_frame(key, sums)
    elif not box:
        chans[0] += _filter_direct(rfilter, (W, H), seed, batch, data, L, mode)
    if aovs:
        for p in range(P):
            first = L.sample(p)
            t0 = dr.gather(type(data["t0"]), data["t0"], first, L.valid[p])
            s0 = I32(dr.gather(type(data["s0"]), data["s0"], first, L.valid[p]))
            n0 = dr.gather(type(data["n0"]), data["n0"], first, L.valid[p])
            hit = s0 >= 0
            for a in aovs:
                if a == "depth":
                    chans[p].append(dr.select(hit, F64(t0), 0.0))
                elif a == "normal":
                    chans[p] += [dr.select(hit, F64(n0[kk]), 0.0) for kk in range(3)]
                elif a == "id":
                    chans[p].append(F64(s0))
                elif a == "cost":
                    chans[p].append(cost_sum[p])
                elif a == "samples":
                    chans[p].append(F64(n_s) + dr.zeros(F64, L.n))
    # the channels interleaved by one scatter of a nested array (index q -> q * C + channel):
    # one kernel with the channels' own (separate scatters into one array would each
    # evaluate the ones before: a kernel per channel, or per strip pixel)
    C = len(chans[0])
    ArrayX = getattr(sys.modules[dtype.__module__], "ArrayXf64" if dtype is F64 else "ArrayXf")
    out = dr.empty(dtype, batch.pixels * C)
    if P == 1:
        dr.scatter(out, ArrayX(*[dtype(ch) for ch in chans[0]]), L.pixel)
    else:
        # the strips' pixels (row ends padded to P pixels) in one scatter of P * C channels,
        # then each output pixel's C channels gathered from its strip (a kernel over pixels)
        strip = dr.empty(dtype, L.n * P * C)
        dr.scatter(strip, ArrayX(*[dtype(ch) for chp in chans for ch in chp]), dr.arange(U32, L.n))
        Q = _Lanes(batch, 1, n_s)
        _, _, first = batch.strips(P)
        row = ((_divisor(Q.w) + (P - 1)) // P) * P
        at = dr.gather(U32, first, Q.window) * P + Q.ly * row + Q.lx
        dr.scatter(out, dr.gather(ArrayX, strip, at, shape=(C, batch.pixels)), Q.pixel)
    return out, C


#: Output pixels a lane of the non-box filter at spp 1 computes: consecutive pixels of one
#: window row, which share all but ``2 * border`` of their neighbour columns, so each
#: neighbour sample (its RGB packet) is read once for the strip instead of once per pixel
#: (:func:`_filter_gather`). A Python constant: the kernels' shape, not a size.
STRIP = 8


class _PixelLanes:
    """The lanes of a box filter's frame at spp 1 without AOVs, the part of :class:`_Lanes` it
    reads: lane ``q`` is output pixel ``q`` (``n``, ``pixel``; ``first``, its sample, the
    caller's). The window tables' gathers that :class:`_Lanes` traces, which no kernel of such
    a frame uses, are left out: host time of a frame."""

    def __init__(self, batch):
        _, self.n, _ = batch.strips(1)
        self.pixel = dr.arange(mi.UInt32, self.n)


class _Lanes:
    """The lanes of a reconstruction kernel: lane ``t`` computes ``P`` consecutive output
    pixels of one row of one window (``P = 1``: one pixel), the lanes laid window after window,
    row-major. Per lane (Dr.Jit arrays): its window (``window``) and the window's tables
    (``x0 y0 sx0 sy0 sw w start``),
    its first pixel's place ``lx, ly`` in the window and index ``pixel`` in the result,
    ``first`` (that pixel's sample 0 in the launch) and ``valid[p]`` (pixel ``p`` is inside the
    row; ``True`` for ``P = 1``)."""

    def __init__(self, batch, P, n_s):
        U32 = mi.UInt32
        starts, self.n, first = batch.strips(P)
        kw = batch.window_of(starts, self.n)
        g = lambda t: dr.gather(U32, t, kw)  # noqa: E731  (this lane's window's value)
        self.x0, self.y0, self.sx0, self.sy0, self.sw = g(batch.x0), g(batch.y0), g(batch.sx0), g(batch.sy0), g(batch.sw)
        self.start = g(batch.first_lane)
        q = dr.arange(U32, self.n) - g(first)
        self.window, self.w = kw, g(batch.w)
        w = _divisor(self.w)
        if P == 1:
            self.ly = udiv(q, w)
            self.lx = q - self.ly * w
        else:
            per_row = (w + (P - 1)) // P   # strips a row (a literal divisor: a shift)
            self.ly = udiv(q, per_row)
            self.lx = (q - self.ly * per_row) * P
        self.pixel = dr.arange(U32, self.n) if P == 1 else g(batch.first_pixel) + self.ly * w + self.lx
        self.first = self.start + ((self.ly + (self.y0 - self.sy0)) * self.sw + self.lx + (self.x0 - self.sx0)) * n_s
        self.valid = [True] + [self.lx + p < w for p in range(1, P)]
        self.n_s = n_s

    def sample(self, p):
        """Sample 0 of the lane's pixel ``p`` in the launch."""
        return self.first + p * self.n_s if p else self.first


def _strata(spp):
    """The opaque strata a side ``k`` of :func:`offsets` for ``spp`` (a Python int)."""
    return op_u(math.ceil(math.sqrt(spp)) if spp > 1 else 1)


def _filter_gather(film_size, batch, data, L, centred, mode):
    """At spp 1 (every sample at its pixel's centre, so its 1-D weights are the ``nb``
    constants ``centred``, :func:`_centre_weights`): RGB (three float32 arrays) of each of the
    ``P`` pixels of the lanes ``L`` (:class:`_Lanes`), ``Σ w·s / Σ w`` over the pixel's
    ``(2b+1)²`` neighbours on the film in ascending neighbour row, then column: the order of
    :meth:`links1.sensor.filters.FilterGather.result` with one sample a pixel.

    A loop step is one neighbour row ``dy``: the strip's ``P`` pixels need the ``P + 2b``
    columns ``x - b .. x + P - 1 + b`` of that row, each read once (its RGB as a packet) and
    added, in ascending column order, to every pixel ``p`` it neighbours (column ``c`` is offset
    ``dx = c - p - b``), each pixel in its own accumulators: the same float32 sums, bit for bit,
    as a loop over one pixel's neighbours. A column is read where it lies in the window's sample
    window (the window plus the border, clipped to the film): for a pixel inside the row exactly
    "on the film", and never outside the window's own lanes for the pixels past the row's end."""
    FT, U32, I32 = mi.Float32, mi.UInt32, mi.Int32
    P, nb = len(L.valid), len(centred[0])
    b = nb // 2
    y = I32(L.ly + L.y0)
    Hi = op_i(film_size[1])
    # the column of the strip's first neighbour (c = 0) in the sample window (may be < 0)
    cx0 = I32(L.lx + L.x0) - I32(L.sx0) - b
    total = data["total"]
    # the samples' RGB as packets of four floats (r, g, b, 0): each neighbour is one 16-byte
    # gather instead of three 4-byte ones (~2.6x cheaper for scattered lanes on LLVM)
    packed = dr.empty(type(total[0]), 4 * batch.lanes)
    dr.scatter(packed, mi.Vector4f(total[0], total[1], total[2], 0.0), dr.arange(U32, batch.lanes))

    def body(dyi, *acc):
        r, g, bl, den = (list(acc[q * P:(q + 1) * P]) for q in range(4))
        yy = y + I32(dyi) - b
        on_y = (yy >= 0) & (yy < Hi)
        # the strip's first column's sample in the launch (c = 0; U32 arithmetic wraps)
        lane0 = L.start + (U32(dr.select(on_y, yy, 0)) - L.sy0) * L.sw + U32(cx0)
        w_row = dr.gather(FT, centred[1], dyi)   # the step's row weight (one for all lanes)
        for c in range(P + 2 * b):
            on = on_y & (U32(cx0 + c) < L.sw)
            lane = dr.select(on, lane0 + c if c else lane0, 0)
            v = dr.gather(mi.Vector4f, packed, lane, on)
            wy = dr.select(on, w_row, 0.0)   # off the film: zero weights
            for p in range(max(0, c - 2 * b), min(P, c + 1)):
                # off the film the weight and the term are zeros: a sum plus a zero is the sum
                # (never -0: it starts at +0), the same bits without a select
                wgt = wy * centred[0][c - p]
                r[p], g[p], bl[p] = r[p] + wgt * v[0], g[p] + wgt * v[1], bl[p] + wgt * v[2]
                den[p] = den[p] + wgt
        return (dyi + 1, *r, *g, *bl, *den)
    z = dr.zeros(FT, L.n)
    _, *acc = _loop((dr.zeros(U32, L.n), *[z] * (4 * P)), lambda j, *_: j < nb, body, mode, nb)
    return [_normalised(acc[p::P]) for p in range(P)]


def _normalised(acc):
    """RGB over the weight sum of ``acc = (Σ w·r, Σ w·g, Σ w·b, Σ w)`` (a zero weight divides by 1)."""
    den = dr.select(acc[3] == 0.0, 1.0, acc[3])
    return [acc[0] / den, acc[1] / den, acc[2] / den]


def _weights(rfilter, pix, i, n_s, k, sd, nb):
    """The 1-D weights ``wx[dx], wy[dy]`` (``nb`` each) of sample ``i`` of film pixel ``pix``
    towards the pixels ``dx - b`` columns and ``dy - b`` rows from its own (strata ``k``, seed
    ``sd``): :func:`weight32` at the float32 offsets of :func:`offsets`, made in the kernel (where
    the batch keeps no :func:`_sample_weights`), the values of
    :meth:`links1.sensor.filters.FilterGather.add` with ``dtype=np.float32``."""
    ox, oy = offsets(pix, i, n_s, k, sd)
    return _weights_at(rfilter, mi.Float32(ox), nb), _weights_at(rfilter, mi.Float32(oy), nb)


def _weights_at(rfilter, o, nb):
    """The ``nb`` 1-D weights of a sample at offset ``o`` in its pixel towards the pixels
    ``d - b`` away (``d = 0 .. nb - 1``)."""
    b = nb // 2
    return [weight32(rfilter, (0.5 - float(d - b)) - mi.Float64(o)) for d in range(nb)]


def weight32(f, x):
    """The film's weight at offset ``x`` (float64, exact from a float32 sample offset):
    :func:`filter_eval` in float64, rounded to float32 (:meth:`links1.sensor.filters.Filter.eval32`)."""
    return mi.Float32(filter_eval(f, x))


def _add_terms(acc, wy, wx, v, weight=True):
    """``acc = (Σ w·r, Σ w·g, Σ w·b, Σ w)`` plus one sample's term ``w = wy · wx``;
    ``weight=False``: ``acc`` without ``Σ w``."""
    wgt = wy * wx
    return [a + wgt * c for a, c in zip(acc, v)] + ([acc[len(v)] + wgt] if weight else [])


def _first_terms(wy, wx, v):
    """The record ``(w·r, w·g, w·b, w)`` of one sample's term ``w = wy · wx``: :func:`_add_terms`
    on a zero record but for the sign of a zero."""
    wgt = wy * wx
    return [wgt * v[0], wgt * v[1], wgt * v[2], wgt]


def _filter_partials(rfilter, film_size, seed, batch, data, n_s, mode, channels=4):
    """Pass 1 of the filter at spp > 1 (a lane: one pixel ``q`` of a sample window): for each
    neighbour offset ``(dy, dx)`` the record ``(Σ w·r, Σ w·g, Σ w·b, Σ w)`` of ``q``'s samples in
    sample order, ``w = wy(dy) · wx(dx)`` (read from :func:`_sample_weights` where the batch keeps
    them, else :func:`_weights`): the terms ``q`` gives the output pixel ``(dy - b, dx - b)`` away
    from it, as :meth:`links1.sensor.filters.FilterGather.add` sums them. Returns ``nb²`` Float32 tables, one
    a offset ``dy · nb + dx``, with pixel ``q``'s record at ``4q`` (where :func:`_row_tables`:
    ``nb`` tables, one a neighbour row, pixel ``q``'s at ``16q``); a record depends only on its
    pixel's samples. ``channels``: 4, the record; 3, its RGB sums (the fourth float +0: a packet),
    where the weight sums are kept (:func:`reconstruct`). Returns ``(tables, counts)``: where pixels of zero samples
    skipped the loop, ``counts`` (UInt32, the pixels up to each one that have a nonzero sample:
    a prefix sum), else None."""
    FT, U32 = mi.Float32, mi.UInt32
    nb = 2 * rfilter.border + 1
    nq = batch.sources
    q = dr.arange(U32, nq)
    kq = batch.source_window
    local = q - dr.gather(U32, batch.first_source, kq)
    sw = _divisor(dr.gather(U32, batch.sw, kq))
    py = udiv(local, sw)
    pix = (py + dr.gather(U32, batch.sy0, kq)) * op_u(film_size[0]) + local - py * sw + dr.gather(U32, batch.sx0, kq)
    first = q * n_s
    total = data["total"]
    k, sd = _strata(batch.spp), op_u(seed)
    ArrayX = getattr(sys.modules[FT.__module__], "ArrayXf")
    pad = _pad(nb)
    # the samples' weights from the table kept with the batch (the same values), in the
    # compact record where the batch's samples allow it
    kept = _keeps_weights(rfilter, batch)
    weights, compact = _sample_weights(rfilter, film_size[0], seed, batch, compact=True) if kept else (None, False)
    if compact:
        base, half = mix32(mix32(sd) ^ pix), mi.Float64(k) * 0.5

    C = channels

    def body(i, *acc):
        v = dr.gather(type(total), total, first + i)
        v = [v[0], v[1], v[2]]
        if compact:
            rec = dr.gather(ArrayX, weights, first + i, shape=(_compact_pad(nb), nq))
            wx, wy = _expand(rec, nb, _sides(base, i, k, half))
        elif kept:
            at = (first + i) * 2
            wx, wy = dr.gather(ArrayX, weights, at, shape=(pad, nq)), dr.gather(ArrayX, weights, at + 1, shape=(pad, nq))
        else:
            wx, wy = _weights(rfilter, pix, i, n_s, k, sd, nb)
        out = []
        for dy in range(nb):
            for dx in range(nb):
                at = C * (dy * nb + dx)
                out += _add_terms(acc[at:at + C], wy[dy], wx[dx], v, weight=C != 3)
        return (i + 1, *out)
    z = dr.zeros(FT, nq)
    acc, nz = [z] * (C * nb * nb), None

    def nonzero(i, nz):
        v = dr.gather(type(total), total, first + i)
        return nz | (v[0] != 0) | (v[1] != 0) | (v[2] != 0)
    # which pixels have a nonzero sample: a pixel whose samples are all zero (RGB: black
    # background, hard shadow) gives records of +0 (+0 plus w·0 = ±0 is +0), which the
    # tables' zeros are; where the batch's last frame had enough of them (Batch.skips_zeros)
    # such a lane skips the loop (found by a first loop over the samples' RGB, which a lane
    # leaves at its first nonzero sample), and a packet of them skips it at once; else the loop
    # notes them (for the next frame's choice)
    probe = C == 3 and mode != "evaluated" and not dr.grad_enabled(total)
    skip = probe and batch.skips_zeros()
    if skip:
        _, nz = _loop((dr.zeros(U32, nq), dr.zeros(mi.Bool, nq)), lambda i, nz: (i < n_s) & ~nz,
                      lambda i, nz: (i + 1, nonzero(i, nz)), mode, batch.spp)
        _, *acc = _loop((dr.zeros(U32, nq), *acc), lambda i, *_: (i < n_s) & nz, body, mode, batch.spp)
    elif probe:
        def noting(i, nz, *acc):
            j, *out = body(i, *acc)
            return (j, nonzero(i, nz), *out)
        _, nz, *acc = _loop((dr.zeros(U32, nq), dr.zeros(mi.Bool, nq), *acc), lambda i, *_: i < n_s, noting,
                            mode, batch.spp)
    else:
        _, *acc = _loop((dr.zeros(U32, nq), *acc), lambda i, *_: i < n_s, body, mode, batch.spp)
    # a table per offset, or per neighbour row (_row_tables; separate scatters into one array
    # would each evaluate the ones before: the loop once per record); adjacent lanes write
    # adjacent records
    if _row_tables(nb, C):
        parts = [dr.empty(FT, nq * 16) for _ in range(nb)]
        for dy, part in enumerate(parts):
            r = acc[3 * nb * dy:3 * nb * (dy + 1)]   # the row's records (dx = 0 .. 4), RGB each
            dr.scatter(part, ArrayX(*r[0:3], r[12], *r[3:6], r[13], *r[6:9], r[14], *r[9:12], FT(0.0)), q)
    else:
        parts = [dr.empty(FT, nq * 4) for _ in range(nb * nb)]
        for kk, part in enumerate(parts):
            dr.scatter(part, ArrayX(*acc[C * kk:C * kk + C], *[FT(0.0)] * (4 - C)), q)
    if nz is None:
        return parts, None
    seen = dr.empty(U32, nq)   # 1 where a pixel has a nonzero sample, written by the same kernel
    dr.scatter(seen, dr.select(nz, U32(1), U32(0)), q)
    counts = batch.zero_probe = dr.cumsum(seen)   # evaluated: the next frame reads its last count
    return parts, counts if skip else None


def _neighbours(rfilter, film_size, L):
    """``(dy, dx, on, q)`` for each neighbour of the lanes' pixels in ascending row, then
    column: ``on``, whether pixel ``(x + dx - b, y + dy - b)`` lies on the film, and ``q`` its
    place in the window's sample window (row-major; 0 where not ``on``)."""
    U32 = mi.UInt32
    W = film_size[0]
    b = rfilter.border
    for dy, x, on_y, row in _rows(rfilter, film_size, L):
        for dx in range(2 * b + 1):
            xx = x + (dx - b)
            on = on_y & (xx >= 0) & (xx < op_i(W))
            yield dy, dx, on, dr.select(on, row + U32(xx), 0)


def _rows(rfilter, film_size, L):
    """``(dy, x, on_y, row)`` for each neighbour row of the lanes' pixels (:func:`_neighbours`):
    the pixel's column ``x`` (Int32), whether row ``y + dy - b`` lies on the film and the place
    of its column 0 in the window's sample window (``row + x`` is column ``x``'s)."""
    I32, U32 = mi.Int32, mi.UInt32
    b = rfilter.border
    x, y = I32(L.lx + L.x0), I32(L.ly + L.y0)
    for dy in range(2 * b + 1):
        yy = y + (dy - b)
        yield dy, x, (yy >= 0) & (yy < op_i(film_size[1])), (U32(yy) - L.sy0) * L.sw - L.sx0


def _filter_sum(rfilter, film_size, batch, part, L, den=None, seen=None):
    """Pass 2 (a lane: one output pixel ``p``): ``Σ_dy Σ_dx`` of the record ``(dy, dx)`` of pixel
    ``p + (dy - b, dx - b)`` on the film (:func:`_filter_partials`) in ascending ``dy``, then
    ``dx``, as :meth:`links1.sensor.filters.FilterGather.result` sums them; RGB over the weight
    sum (``den`` where the batch keeps it: the records' RGB sums alone). Off the film a record
    is zeros (a masked read): a sum plus +0 is the sum (never -0: it starts at +0). Returns
    ``(RGB, the weight sums)``. With ``seen``
    (:func:`_filter_partials`' counts), a pixel none of whose neighbours has a nonzero sample
    (their records are +0: its RGB sums +0) reads no record: two reads of the counts give each
    neighbour row's, and the records' reads run in a loop of one step that such lanes skip (a
    packet of them at once)."""
    FT = mi.Float32
    ArrayX = getattr(sys.modules[FT.__module__], "ArrayXf")
    nb = 2 * rfilter.border + 1
    q0 = dr.gather(mi.UInt32, batch.first_source, L.window)
    C = 3 if den is not None else 4
    acc = [dr.zeros(FT, L.n)] * C

    rows = _row_tables(nb, C)

    def add(*acc):
        for dy, dx, on, q in _neighbours(rfilter, film_size, L):
            at = dr.select(on, q0 + q, 0)
            if not rows:
                rec = dr.gather(ArrayX, part[dy * nb + dx], at, on, shape=(4, L.n))
            elif dx < nb - 1:
                rec = dr.gather(ArrayX, part[dy], at * 4 + dx, on, shape=(4, L.n))
            else:
                rec = [dr.gather(FT, part[dy], at * 16 + (4 * c + 3), on) for c in range(3)]
            acc = [a + rec[c] for c, a in enumerate(acc)]
        return acc
    if seen is None:
        acc = add(*acc)
    else:
        U32 = mi.UInt32
        b = rfilter.border
        near = dr.zeros(mi.Bool, L.n)
        for _, x, on_y, row in _rows(rfilter, film_size, L):
            # the row's neighbours on the film: columns first .. last of the sample window
            first = q0 + row + U32(dr.maximum(x - b, 0))
            last = q0 + row + U32(dr.minimum(x + b, op_i(film_size[0]) - 1))
            before = dr.gather(U32, seen, first - 1, on_y & (first > 0))
            near |= on_y & (dr.gather(U32, seen, last, on_y) != before)
        _, *acc = dr.while_loop((dr.zeros(U32, L.n), *acc), lambda j, *_: (j < 1) & near,
                                lambda j, *a: (j + 1, *add(*a)))
    acc = acc if den is None else [*acc, den]
    return _normalised(acc), acc[3]


def _row_tables(nb, channels):
    """Whether the filter's pass 1 writes its records a table per neighbour row, 16 float32 a
    pixel (:func:`_filter_partials`, :func:`_filter_sum`): with RGB records (``channels`` 3)
    and ``nb`` 5, the row's records ``dx = 0 .. 3`` at floats ``4 dx .. 4 dx + 2`` (a packet
    of 4 each) and the channels of ``dx = 4`` at floats 3, 7 and 11: a cache line a row, 320
    bytes a pixel instead of the 400 of a table per offset (25 packets of 4, one float +0)."""
    return channels == 3 and nb == 5


def _keeps_weights(rfilter, batch):
    """Whether ``batch`` keeps the samples' weights (:func:`_sample_weights`) and so the pixels'
    weight sums: they depend only on the samples' places, so a frame of these windows keeps its
    pass 2's ``Σ w`` (the records' fourth channel) and later frames' records carry RGB alone
    (three sums a term instead of four), the same bits."""
    return batch.keep and batch.lanes * 2 * _pad(2 * rfilter.border + 1) * 4 <= KEEP_TABLE_BYTES


def _filter_direct(rfilter, film_size, seed, batch, data, L, mode):
    """Passes 1 and 2 in one kernel, without the table (a film whose table would take more
    than :data:`FILM_TABLE_BYTES`): each output pixel makes the record ``(dy, dx)`` of each
    neighbour from its samples (their weights made again for each output pixel) and adds it
    as :func:`_filter_sum` does: the same operations in the same order, the same bits."""
    FT, U32 = mi.Float32, mi.UInt32
    W = film_size[0]
    nb = 2 * rfilter.border + 1
    n_s = L.n_s
    total = data["total"]
    k, sd = _strata(batch.spp), op_u(seed)
    sw = _divisor(L.sw)
    acc = [dr.zeros(FT, L.n)] * 4
    for dy, dx, on, q in _neighbours(rfilter, film_size, L):
        first = L.start + q * n_s
        qy = udiv(q, sw)
        pix = (qy + L.sy0) * op_u(W) + q - qy * sw + L.sx0

        def body(i, *rec):
            v = dr.gather(type(total), total, first + i, on)
            wx, wy = _weights(rfilter, pix, i, n_s, k, sd, nb)
            return (i + 1, *_add_terms(rec, wy[dy], wx[dx], [v[0], v[1], v[2]]))
        z = dr.zeros(FT, L.n)
        _, *rec = _loop((dr.zeros(U32, L.n), *[z] * 4), lambda i, *_: i < n_s, body, mode, batch.spp)
        acc = [dr.select(on, a + r, a) for a, r in zip(acc, rec)]
    return _normalised(acc)


def _sample_weights(rfilter, film_width, seed, batch, compact=False):
    """Per sample lane of ``batch`` (:func:`sample_ids`' layout) the 1-D weights of
    :func:`_weights` (``wx``, ``wy``; a float64 ``exp`` / ``sin`` each), made in one kernel over
    the samples and kept with the batch (:meth:`Batch.kept`) up to :data:`KEEP_TABLE_BYTES`: a
    frame of the same windows reads them. Returns ``(table, is_compact)``:

    * the full record: two records of :func:`_pad` float32, the ``nb`` column weights, then the
      ``nb`` row weights;
    * with ``compact`` where it is smaller (:func:`_compact_pad`; not lanczos), the compact
      record of :func:`_expand`, if every sample of the batch allows it (checked on the device
      when the table is made: else the full record). The filter is zero at ``|x| >= r``; the
      outermost weights of a sample at offset ``o`` are at ``x = b + 1/2 - o`` and
      ``-(b - 1/2 + o)``, so with a radius ``r <= b`` (gaussian, tent, mitchell, catmullrom at
      their defaults) the first is nonzero only for ``o > 1/2``, the last only for ``o < 1/2``:
      the record keeps the ``nb - 2`` inner weights and the outermost one on the offset's side
      (:func:`_sides`), the other being +0. Half the bytes of the full record for a gaussian
      (32 against 64 a sample, one packet instead of two), the same values."""
    FT, U32 = mi.Float32, mi.UInt32
    nb = 2 * rfilter.border + 1
    pad = _pad(nb)
    compact = compact and _compact_pad(nb) < 2 * pad
    size = _compact_pad(nb) if compact else 2 * pad
    ArrayX = getattr(sys.modules[FT.__module__], "ArrayXf")

    def make():
        n_s = op_u(batch.spp)
        sl = dr.arange(U32, batch.lanes)
        sid = sample_ids(film_width, batch.spp, batch)     # pixel * spp + i, kept with the batch
        pix = udiv(sid, n_s)
        i = sid - pix * n_s
        k, sd = _strata(batch.spp), op_u(seed)
        ox, oy = (FT(o) for o in offsets(pix, i, n_s, k, sd))
        zero = dr.zeros(FT, batch.lanes)
        wx, wy = _weights_at(rfilter, ox, nb), _weights_at(rfilter, oy, nb)
        if compact:
            vals, dropped = [], mi.Bool(False)
            for w, hi in zip((wx, wy), _sides(mix32(mix32(sd) ^ pix), i, k, mi.Float64(k) * 0.5)):
                vals += [*w[1:-1], dr.select(hi, w[0], w[-1])]
                # the other outermost weight, which the record leaves out: +0 (all bits 0)?
                dropped |= dr.reinterpret_array(U32, dr.select(hi, w[-1], w[0])) != 0
            rec = dr.empty(FT, batch.lanes * size)
            dr.scatter(rec, ArrayX(*vals, *[zero] * (size - len(vals))), sl)
            n_dropped = dr.count(dropped)
            dr.eval(rec, n_dropped)
            if n_dropped[0] == 0:
                return rec, True
        vals = [*wx, *[zero] * (pad - nb), *wy, *[zero] * (pad - nb)]
        rec = dr.empty(FT, batch.lanes * 2 * pad)
        dr.scatter(rec, ArrayX(*vals), sl)
        return rec, False
    if batch.lanes * size * 4 > KEEP_TABLE_BYTES:
        return make()
    return batch.kept(("weights", rfilter, int(film_width), int(seed), compact), make)


def _sides(base, i, k, half):
    """Whether sample ``i`` of a pixel lies past the pixel's middle in x and in y
    (``sx + ux > k / 2``, ``sy + uy > k / 2``: exact in float64; an offset :func:`offsets`
    rounds to ``0.5`` lies on either side) from the pixel's hash ``base``
    (``mix32(mix32(seed) ^ pixel)``), strata ``k`` and ``half = k / 2`` (Float64)."""
    F64 = mi.Float64
    ux = F64(mix32(base ^ (2 * i)) >> 8) * 2.0 ** -24
    uy = F64(mix32(base ^ (2 * i + 1)) >> 8) * 2.0 ** -24
    sy = udiv(i, k)
    return F64(i - sy * k) + ux > half, F64(sy) + uy > half


def _expand(rec, nb, sides):
    """The weights ``wx``, ``wy`` (``nb`` each) of a compact record (:func:`_sample_weights`:
    per axis the ``nb - 2`` inner weights, then the outermost one on the sample's side) and the
    sample's ``sides`` (:func:`_sides`): the other outermost weight is +0."""
    zero, m = mi.Float32(0.0), nb - 2
    out = []
    for a, hi in enumerate(sides):
        w = rec[a * (m + 1):(a + 1) * (m + 1)]
        out.append([dr.select(hi, w[m], zero), *w[:m], dr.select(hi, zero, w[m])])
    return out


def _compact_pad(nb):
    """Float32s of a sample's compact weight record (:func:`_sample_weights`): ``2 (nb - 1)``,
    padded to a power of two (a packet)."""
    return 1 << (2 * nb - 3).bit_length()


def _pad(nb):
    """Float32s of a sample's weight record: ``nb``, padded to a power of two (a packet)."""
    return 1 << nb.bit_length()


def _filter_strips(rfilter, film_size, seed, batch, data, L, mode):
    """The sums of :func:`_filter_partials` and :func:`_filter_sum` in one kernel, for spp up to
    :data:`STRIPS_SPP` (the two passes' tables cost more there than the samples' layers), a lane
    :data:`STRIPS_P` pixels of a window row. A loop step is one neighbour row ``dy``; in it, column
    after column of the strip's ``P + 2b``, the column's samples are read once each (the RGB
    packet, its column weights and its row weight from :func:`_sample_weights`) and their
    terms summed, in sample order, into the record ``(dy, dx)`` the column gives each strip
    pixel it neighbours; each pixel then adds that record (its columns come in
    ascending ``dx``). So only one column's records are live at a time (a loop over samples
    ``1 .. spp - 1`` a column, straight code at spp 2). The same operations in the same order as
    the two passes, the same bits; a record starts at its first term instead of adding it to a
    zero (``0 + t`` is ``t`` but for ``t = -0``, and a pixel's sums, which start at ``+0``, add
    a ``-0`` record as a ``+0`` one)."""
    FT, U32, I32 = mi.Float32, mi.UInt32, mi.Int32
    W, H = film_size
    P, b = len(L.valid), rfilter.border
    nb = 2 * b + 1
    n_s = L.n_s
    pad = _pad(nb)
    ArrayX = getattr(sys.modules[FT.__module__], "ArrayXf")
    weights = _sample_weights(rfilter, W, seed, batch)[0]
    total = data["total"]
    packed = dr.empty(type(total[0]), 4 * batch.lanes)
    dr.scatter(packed, mi.Vector4f(total[0], total[1], total[2], 0.0), dr.arange(U32, batch.lanes))
    y = I32(L.ly + L.y0)
    cx0 = I32(L.lx + L.x0) - I32(L.sx0) - b

    def body(dyi, *acc):
        acc = list(acc)
        yy = y + I32(dyi) - b
        on_y = (yy >= 0) & (yy < op_i(H))
        lane0 = L.start + ((U32(dr.select(on_y, yy, 0)) - L.sy0) * L.sw + U32(cx0)) * n_s
        for c in range(P + 2 * b):
            on = on_y & (U32(cx0 + c) < L.sw)
            first = dr.select(on, lane0 + c * n_s if c else lane0, 0)
            pixels = range(max(0, c - 2 * b), min(P, c + 1))

            def visit(i, rec, first=first, on=on, pixels=pixels, c=c):
                # the column's records plus the terms of its sample i (rec None: i is its first)
                at = first if isinstance(i, int) and i == 0 else first + i
                v = dr.gather(mi.Vector4f, packed, at, on)
                w = dr.gather(ArrayX, weights, at * 2, on, shape=(pad, L.n))
                wy = dr.gather(FT, weights, at * (2 * pad) + pad + dyi, on)
                v = [v[0], v[1], v[2]]
                return {p: _add_terms(rec[p], wy, w[c - p], v) if rec else _first_terms(wy, w[c - p], v)
                        for p in pixels}
            rec = visit(0, None)
            if batch.spp == 2:
                rec = visit(1, rec)
            else:
                def step(i, *flat, visit=visit, pixels=pixels):
                    r = visit(i, {p: list(flat[4 * j:4 * j + 4]) for j, p in enumerate(pixels)})
                    return (i + 1, *[x for p in pixels for x in r[p]])
                _, *flat = _loop((dr.ones(U32, L.n), *[x for p in pixels for x in rec[p]]),
                                 lambda i, *_: i < n_s, step, mode, batch.spp - 1)
                rec = {p: flat[4 * j:4 * j + 4] for j, p in enumerate(pixels)}
            for p in pixels:
                for q in range(4):
                    acc[q * P + p] = acc[q * P + p] + rec[p][q]
        return (dyi + 1, *acc)
    z = dr.zeros(FT, L.n)
    _, *acc = _loop((dr.zeros(U32, L.n), *[z] * (4 * P)), lambda j, *_: j < nb, body, mode, nb)
    return [_normalised(acc[p::P]) for p in range(P)]


_CENTRE_WEIGHTS = {}


def _centre_weights(rfilter, nb):
    """The 1-D weights of a sample at its pixel's centre (spp 1) towards its ``nb`` neighbour
    columns or rows, as Python floats and a Float32 array, evaluated as :func:`_weights` does
    (:func:`filter_eval` on the device at ``(0.5 - d) - 0.5``): once per filter and variant."""
    key = (rfilter.name, tuple(sorted(rfilter.params.items())), rfilter.radius, nb, mi.variant())
    hit = _CENTRE_WEIGHTS.get(key)
    if hit is None:
        F64 = mi.Float64
        x = F64([0.5 - float(d - rfilter.border) for d in range(nb)]) - dr.opaque(F64, 0.5)
        w = weight32(rfilter, x)
        dr.eval(w)
        hit = _CENTRE_WEIGHTS[key] = ([float(v) for v in np.asarray(w)], w)
    return hit


def widen(v, n):
    """``v`` with ``n`` lanes: a frozen launch returns literals at their recorded width
    (their first lane, broadcast)."""
    return v if dr.width(v) == n else dr.gather(type(v), v, dr.zeros(mi.UInt32, n))
