"""The device film of ``links1_whitted``
against the numpy film it replaced: the same samples (``window_samples``) assembled by the old
numpy code (kept below as the reference: the box mean, the AOVs, and
:func:`links1.sensor.filters.filter_samples` for the other filters) give the same pixels.

The non-box film computes in float32 (``filter_samples(..., np.float32)``: the same float32
operations in the same order). Tolerance: box (float64), tent, mitchell and catmullrom are
bit-identical. Gaussian and lanczos weights are float64 ``exp`` / ``sin`` (Dr.Jit's differ from
libm's by an ulp in about one call in six) rounded to float32, which an ulp of float64 changes
about once in 2^29: bit-identical here, checked within :data:`ULPS` (a float32 ``exp`` instead:
Dr.Jit's and numpy's differ on ~40 % of the weights, and the pixels by up to 5 ulps).
"""
from __future__ import annotations

import numpy as np
import pytest

from links1.sensor.filters import filter_samples

from tests.scenes import perspective, scene, whitted

from .test_filters_vs_mitsuba import RFILTERS
from .test_vs_mitsuba_integrators import DIFFUSE

pytestmark = pytest.mark.mitsuba

W, H = 24, 18
EXACT = ("box", "tent", "mitchell", "catmullrom")
#: float32 ulps (of the pixel, at least of 1e-3) between the device film and the numpy film
#: where a weight comes from ``exp`` / ``sin`` (measured: 0)
ULPS = 1
AOVS = "depth,normal,id,cost,samples"
MIRROR = """<shape type="sphere"><point name="center" x="0.9" y="0.5" z="-0.8"/><float name="radius" value="0.5"/>
    <bsdf type="conductor"/></shape>"""


def load(tmp_path, rfilter):
    import links1_mitsuba as lm
    import mitsuba as mi
    path = tmp_path / "film.xml"
    camera = perspective("0, 2.5, 6", "0, 0.7, 0", fov=40, width=W, height=H, spp=None, rfilter=RFILTERS[rfilter])
    path.write_text(scene(whitted(3), camera, DIFFUSE, MIRROR))
    return lm.load_file(str(path), variant=mi.variant())


def numpy_film(integ, scene, window, spp, seed, aovs):
    """The numpy film that ``render_windows`` used (the reference)."""
    P = integ.prepare(scene)
    (sx0, sy0, sw, sh), s = integ.window_samples(scene, window, spp=spp, seed=seed, aovs=aovs)
    samples = s["total"].astype(np.float64)
    npix = sw * sh
    if P.rfilter.border == 0:
        rgb = samples.reshape(npix, spp, 3).mean(axis=1) if spp > 1 else samples.reshape(npix, 3)
    else:
        rgb = filter_samples(P.rfilter, window, P.film_size, samples, (sx0, sy0), spp, seed,
                             np.float32).reshape(-1, 3).astype(np.float64)
    chans = []
    if aovs:
        t0 = s["t0"].reshape(npix, spp)[:, 0].astype(np.float64)
        s0 = s["s0"].reshape(npix, spp)[:, 0].astype(np.int64)
        n0 = s["n0"].reshape(npix, spp, 3)[:, 0].astype(np.float64)
        hit0 = s0 >= 0
        for a in aovs.split(","):
            chans.append({"depth": lambda: np.where(hit0, t0, 0.0)[:, None],
                          "normal": lambda: np.where(hit0[:, None], n0, 0.0),
                          "id": lambda: s0.astype(np.float64)[:, None],
                          "cost": lambda: s["cost"].astype(np.float64).reshape(npix, spp).sum(axis=1)[:, None],
                          "samples": lambda: np.full((npix, 1), float(spp))}[a]())
    x0, y0, w, h = window
    aov = np.concatenate(chans, axis=1).reshape(sh, sw, -1)[y0 - sy0:y0 - sy0 + h, x0 - sx0:x0 - sx0 + w] \
        if chans else np.zeros((h, w, 0))
    return np.concatenate([rgb.reshape(h, w, 3), aov], axis=2)


def assert_near_numpy(got, ref):
    """The device film's pixels ``got`` against the numpy film's ``ref`` (float32 arithmetic
    in the same order) where the filter evaluates ``exp`` / ``sin``: within ULPS float32 ulps
    of the pixel's magnitude; the AOVs (no filter) the same bits."""
    scale = np.spacing(np.maximum(np.abs(ref[..., :3]), 1e-3).astype(np.float32)).astype(np.float64)
    err = np.abs(got[..., :3] - ref[..., :3]) / scale
    assert err.max() <= ULPS, f"device film off the numpy film by {err.max():.1f} float32 ulps"
    assert np.array_equal(got[..., 3:], ref[..., 3:])


@pytest.mark.slow
@pytest.mark.parametrize("aovs", ["", AOVS])
@pytest.mark.parametrize("spp", [1, 4])
@pytest.mark.parametrize("rfilter", list(RFILTERS))
def test_device_film_equals_numpy_film(variant, tmp_path, rfilter, spp, aovs):
    import drjit as dr
    import mitsuba as mi
    scene = load(tmp_path, rfilter)
    integ = scene.integrator()
    for window in [(0, 0, W, H), (3, 2, 11, 7)]:
        ref = numpy_film(integ, scene, window, spp, 7, aovs)
        dev = integ.render_windows_device(scene, [window], spp=spp, seed=7, aovs=aovs, dtype=mi.Float64)[0]
        assert type(dev) is mi.TensorXf64
        got = np.asarray(dev)
        assert got.shape == ref.shape == (window[3], window[2], 3 + {"": 0, AOVS: 7}[aovs])
        assert ref[..., :3].max() > 0.05          # not a black frame
        if rfilter in EXACT:
            assert np.array_equal(got, ref)
        else:
            assert_near_numpy(got, ref)
        # render_window (float64 numpy) and mi.render's float32 tensor are the same pixels
        assert np.array_equal(integ.render_window(scene, window, spp=spp, seed=7, aovs=aovs), got)
    integ.aovs = aovs.split(",") if aovs else []
    t = mi.render(scene, spp=spp, seed=0)
    assert type(t) is mi.TensorXf and t.shape == (H, W, len(integ.channels()))
    assert np.array_equal(np.asarray(t), integ.render_window(scene, None, spp=spp, seed=integ.seed,
                                                             aovs=aovs).astype(np.float32))


def test_box_mean_in_packets_equals_numpy_mean(variant, tmp_path, monkeypatch):
    """At spp a multiple of 4 the box film reads a pixel's samples four at a time (packet
    gathers): its pixels equal numpy's float64 mean of the same samples and the film read one
    sample at a time, bit for bit, in a window and in a batch of windows (spp 4 and 8; spp 6
    reads one at a time)."""
    import mitsuba as mi
    from links1_mitsuba import film
    scene = load(tmp_path, "box")
    integ = scene.integrator()
    wins = [(0, 0, W, H), (3, 2, 11, 7), (20, 9, 4, 9)]
    for spp in (4, 6, 8):
        for flag in (True, False):
            monkeypatch.setattr(film, "BOX_PACKETS", flag)
            got = [np.asarray(a) for a in integ.render_windows_device(scene, wins, spp=spp, seed=3, aovs="",
                                                                      dtype=mi.Float64)]
            for window, g in zip(wins, got):
                assert np.array_equal(g, numpy_film(integ, scene, window, spp, 3, ""))
            if flag:
                packets = got
            else:
                assert all(np.array_equal(a, b) for a, b in zip(packets, got))


@pytest.mark.slow
@pytest.mark.parametrize("rfilter", ["box", "gaussian", "lanczos"])
def test_windows_and_batches_equal_full_frame_on_device(variant, tmp_path, rfilter):
    """A window, or a batch of windows (one launch), equals the same pixels of the full frame
    bit for bit, as device tensors (float32 and float64) and through render_windows."""
    import mitsuba as mi
    scene = load(tmp_path, rfilter)
    integ = scene.integrator()
    wins = [(0, 0, 8, 8), (8, 0, 8, 8), (12, 9, 12, 9), (1, 3, 22, 5), (23, 17, 1, 1)]
    for dtype in (mi.Float, mi.Float64):
        full = np.asarray(integ.render_windows_device(scene, [None], spp=4, seed=3, aovs=AOVS, dtype=dtype)[0])
        batch = integ.render_windows_device(scene, wins, spp=4, seed=3, aovs=AOVS, dtype=dtype)
        for (x0, y0, w, h), b in zip(wins, batch):
            one = integ.render_windows_device(scene, [(x0, y0, w, h)], spp=4, seed=3, aovs=AOVS, dtype=dtype)[0]
            assert np.array_equal(np.asarray(one), full[y0:y0 + h, x0:x0 + w])
            assert np.array_equal(np.asarray(b), full[y0:y0 + h, x0:x0 + w])
    for (x0, y0, w, h), b in zip(wins, integ.render_windows(scene, wins, spp=4, seed=3, aovs=AOVS)):
        assert b.dtype == np.float64 and np.array_equal(b, full[y0:y0 + h, x0:x0 + w])


@pytest.mark.slow
@pytest.mark.parametrize("rfilter", [f for f in RFILTERS if f != "box"])
def test_filter_windows_at_film_edges_in_two_passes_and_in_one(variant, tmp_path, monkeypatch, rfilter):
    """The non-box film at spp > 1 sums each sample-window pixel's records in pass 1 and a
    pixel's neighbours' records in pass 2 (film._filter_partials, film._filter_sum); up to
    film.STRIPS_SPP in one kernel of strips (film._filter_strips), and where the table would be
    too big in one kernel a pixel (film._filter_direct, FILM_TABLE_BYTES = 0): windows at each
    film edge, narrower than the border and than a strip, alone and in one batch, give the numpy
    film's pixels (bit for bit for the filters without exp/sin) and the full frame's bits, the
    same whichever way (at spp 2, straight code, and 3, a loop over the samples, the strips
    against the two passes; above STRIPS_SPP the two passes against the one kernel, and pass 1
    with the samples' weights from the kept table against made in the kernel,
    KEEP_TABLE_BYTES = 0)."""
    import mitsuba as mi
    from links1_mitsuba import film
    assert 3 <= film.STRIPS_SPP
    scene = load(tmp_path, rfilter)
    integ = scene.integrator()
    wins = [(W - 13, 0, 13, 5), (0, H - 3, 5, 3), (W - 3, H - 7, 3, 7), (10, 4, 1, 9), (1, 1, W - 1, 2)]
    for spp, other in ((2, "STRIPS_SPP"), (3, "STRIPS_SPP"), (film.STRIPS_SPP + 1, "FILM_TABLE_BYTES"),
                       (film.STRIPS_SPP + 1, "KEEP_TABLE_BYTES")):
        full = np.asarray(integ.render_windows_device(scene, [None], spp=spp, seed=5, aovs=AOVS, dtype=mi.Float64)[0])
        for default in (True, False):
            if not default:
                monkeypatch.setattr(film, other, 0)
            batch = integ.render_windows_device(scene, wins, spp=spp, seed=5, aovs=AOVS, dtype=mi.Float64)
            for (x0, y0, w, h), b in zip(wins, batch):
                one = integ.render_windows_device(scene, [(x0, y0, w, h)], spp=spp, seed=5, aovs=AOVS,
                                                  dtype=mi.Float64)[0]
                assert np.array_equal(np.asarray(one), full[y0:y0 + h, x0:x0 + w])
                assert np.array_equal(np.asarray(b), full[y0:y0 + h, x0:x0 + w])
                if default:
                    ref = numpy_film(integ, scene, (x0, y0, w, h), spp, 5, AOVS)
                    got = np.asarray(b)
                    if rfilter in EXACT:
                        assert np.array_equal(got, ref)
                    else:
                        assert_near_numpy(got, ref)
        monkeypatch.undo()


@pytest.mark.parametrize("rfilter", [f for f in RFILTERS if f != "box"])
def test_filter_at_spp_1_from_centre_weights(variant, tmp_path, monkeypatch, rfilter):
    """At spp 1 every sample lies at its pixel's centre and the non-box gather takes its
    weights from film._centre_weights (2b+1 numbers), STRIP pixels of a row a lane: windows at
    the film's edges, narrower than a strip, give the full frame's bits, the numpy film's pixels
    (bit for bit for the filters without exp/sin) and the bits of the two passes of spp > 1
    (with one sample a pixel their order is the gather's)."""
    import mitsuba as mi
    from links1_mitsuba import film
    scene = load(tmp_path, rfilter)
    integ = scene.integrator()
    wins = [(W - 13, 0, 13, 5), (0, H - 3, 5, 3), (10, 4, 1, 9)]

    def frame(ws):
        return [np.asarray(a) for a in integ.render_windows_device(scene, ws, spp=1, seed=5, aovs=AOVS,
                                                                      dtype=mi.Float64)]
    full = frame([None])[0]
    for (x0, y0, w, h), b in zip(wins, frame(wins)):
        assert np.array_equal(b, full[y0:y0 + h, x0:x0 + w])
        ref = numpy_film(integ, scene, (x0, y0, w, h), 1, 5, AOVS)
        if rfilter in EXACT:
            assert np.array_equal(b, ref)
        else:
            assert_near_numpy(b, ref)
    monkeypatch.setattr(film, "_centre_weights", lambda *a: None)     # the two passes
    assert np.array_equal(frame([None])[0], full)


@pytest.mark.parametrize("name, params, compact", [
    ("gaussian", {}, True), ("tent", {}, True), ("mitchell", {}, True), ("catmullrom", {}, True),
    ("gaussian", {"stddev": 0.3}, False), ("tent", {"radius": 1.3}, False), ("lanczos", {}, False)])
def test_compact_sample_weights_are_the_full_records_weights(variant, name, params, compact):
    """The compact weight record (film._sample_weights: the inner weights and the outermost one
    on the sample's side of its pixel's middle, film._sides) expands (film._expand) to the full
    record's weights bit for bit, at odd and even strata (spp 2, 8, 16); where a filter's
    radius passes its border (both outermost weights of a sample nonzero) the batch keeps the
    full record, and lanczos (no fewer floats) too."""
    import drjit as dr
    import mitsuba as mi
    from links1.sensor.filters import Filter
    from links1_mitsuba import film
    from links1_mitsuba.util import mix32, udiv
    rf = Filter(name, params)
    nb = 2 * rf.border + 1
    win = (0, 0, W, H)
    for spp in (2, 8, 16):
        batch = film.Batch([win], [film.sample_window(rf, win, (W, H))], spp)
        full, is_compact = film._sample_weights(rf, W, 5, batch)
        assert not is_compact
        table, is_compact = film._sample_weights(rf, W, 5, batch, compact=True)
        assert is_compact == compact
        if not compact:
            assert np.array_equal(np.asarray(table), np.asarray(full))
            continue
        n, pad = batch.lanes, film._pad(nb)
        sid = film.sample_ids(W, spp, batch)
        pix = udiv(sid, film.op_u(spp))
        k = film._strata(spp)
        sides = film._sides(mix32(mix32(film.op_u(5)) ^ pix), sid - pix * film.op_u(spp), k, mi.Float64(k) * 0.5)
        rec = dr.gather(mi.ArrayXf, table, dr.arange(mi.UInt32, n), shape=(film._compact_pad(nb), n))
        got = np.array([np.asarray(w) for ws in film._expand(rec, nb, sides) for w in ws])
        want = np.asarray(full).reshape(n, 2, pad)[:, :, :nb].transpose(1, 2, 0).reshape(2 * nb, n)
        assert np.array_equal(got.view(np.uint32), want.view(np.uint32))
        assert np.count_nonzero(want[[0, nb - 1, nb, 2 * nb - 1]]) > n   # the outermost weights matter


#: a tent wider than its border: both outermost weights of a sample can be nonzero
WIDE_TENT = '<rfilter type="tent"><float name="radius" value="1.3"/></rfilter>'


@pytest.mark.parametrize("rfilter", ["gaussian", "tent", "lanczos", "wide tent"])
def test_later_frames_rgb_records_equal_numpy_film(variant, tmp_path, rfilter):
    """Above film.STRIPS_SPP the batch keeps the samples' weights (film._sample_weights), in the
    compact record where every left-out weight is +0 (else the full record: the wide tent;
    lanczos has no compact record), and frames after the first sum RGB records alone, with 5
    neighbours a row (gaussian) a table per neighbour row (film._row_tables: four packets and
    the fifth record in their fourth floats). Windows at each film edge, four frames: each
    equals the numpy film (bit for bit for the tents) and the first frame."""
    import links1_mitsuba as lm
    import mitsuba as mi
    from links1_mitsuba import film
    if rfilter == "wide tent":
        path = tmp_path / "film.xml"
        camera = perspective("0, 2.5, 6", "0, 0.7, 0", fov=40, width=W, height=H, spp=None, rfilter=WIDE_TENT)
        path.write_text(scene(whitted(3), camera, DIFFUSE, MIRROR))
        scn = lm.load_file(str(path), variant=mi.variant())
    else:
        scn = load(tmp_path, rfilter)
    integ = scn.integrator()
    rf = integ.prepare(scn).rfilter
    nb = 2 * rf.border + 1
    assert film._row_tables(nb, 3) == (rfilter == "gaussian")
    wins = [(W - 13, 0, 13, 5), (0, H - 3, 5, 3), (10, 4, 1, 9), (1, 1, W - 1, 2)]
    spp = film.STRIPS_SPP + 1
    frames = [integ.render_windows_device(scn, wins, spp=spp, seed=5, dtype=mi.Float64) for _ in range(4)]
    (batch,) = integ.engine.batches.values()
    kept = batch.peek(("weights", rf, W, 5, True)) or batch.peek(("weights", rf, W, 5, False))
    assert kept is not None and kept[1] == (rfilter in ("gaussian", "tent"))
    for k, win in enumerate(wins):
        ref = numpy_film(integ, scn, win, spp, 5, "")
        for frame in frames:
            got = np.asarray(frame[k])
            assert np.array_equal(got, np.asarray(frames[0][k]))
            if "tent" in rfilter:
                assert np.array_equal(got, ref)
            else:
                assert_near_numpy(got, ref)


def test_zero_pixels_skipped_or_not_give_the_same_bits(variant, tmp_path, monkeypatch):
    """A batch's first frame sums the records' four channels and keeps its weight sums; later
    frames sum RGB alone and skip the sample-window pixels whose samples are all zero (their
    records are +0) where the batch's last frame had at least film.SKIP_ZEROS of them (the
    test scene: about a third), else note them in pass 1's loop: frames each way, with AOVs,
    equal the frame of a film that keeps nothing (KEEP_TABLE_BYTES = 0) bit for bit."""
    import mitsuba as mi
    from links1_mitsuba import film
    scene = load(tmp_path, "gaussian")
    integ = scene.integrator()
    wins = [(0, 0, W, H), (3, 2, 11, 7)]

    def frames():
        return [np.asarray(a) for a in integ.render_windows_device(scene, wins, spp=9, seed=4, aovs=AOVS,
                                                                      dtype=mi.Float64)]
    first = frames()
    (batch,) = integ.engine.batches.values()
    assert batch.zero_probe is None and batch.peek(("den", integ.prepare(scene).rfilter, (W, H), 4)) is not None
    skip = frames()
    assert batch.skips_zeros() and batch.zero_probe is not None      # a third of the pixels
    monkeypatch.setattr(film, "SKIP_ZEROS", 2.0)      # never: the next frames note them instead
    noted = [frames(), frames()]
    assert not batch.skips_zeros() and batch.zero_probe is not None
    monkeypatch.setattr(film, "KEEP_TABLE_BYTES", 0)
    integ.engine.batches = {}
    plain = frames()
    for got in (first, skip, *noted):
        for g, r in zip(got, plain):
            assert np.array_equal(g, r)


def test_split_launches_one_kernel_filter_and_device_counters(variant, tmp_path, monkeypatch):
    """Launches split at LAUNCH_LANES give the same bits as one launch, the filter in one kernel
    (windows over FILM_TABLE_BYTES) the same as in two passes, and the ray
    counters summed on the device (all launches, or those past LAZY_COUNT_LANES lanes) equal
    those summed on the host. A frame of one launch runs no reduction kernel for its counters."""
    import drjit as dr
    from links1_mitsuba import film, launch
    scene = load(tmp_path, "gaussian")
    integ = scene.integrator()
    integ.render_window(scene, None, spp=256)       # 110592 lanes: one launch
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()
    integ.render_window(scene, None, spp=256)
    kinds = {str(k["type"]) for k in dr.kernel_history()}
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert not [k for k in kinds if k.endswith((".Reduce", ".BlockReduce"))], kinds   # (compress: a prefix sum)
    assert integ.stats["camera"] == W * H * 256
    one = integ.render_window(scene, None, spp=4, seed=1, aovs=AOVS)
    host_stats = dict(integ.stats)
    assert host_stats["reflect"] > 0 and host_stats["shadow"] > 0
    monkeypatch.setattr(launch, "LAUNCH_LANES", 1000)
    monkeypatch.setattr(film, "FILM_TABLE_BYTES", 0)
    for lazy in (0, 2500):
        monkeypatch.setattr(launch, "LAZY_COUNT_LANES", lazy)
        assert np.array_equal(integ.render_window(scene, None, spp=4, seed=1, aovs=AOVS), one)
        assert integ.stats == host_stats


@pytest.mark.slow
@pytest.mark.parametrize("rfilter", ["box", "gaussian"])
def test_new_window_and_batch_sizes_compile_nothing(variant, tmp_path, rfilter):
    """Every kernel of a frame with new window sizes, origins, batch sizes and spp is one that
    earlier frames ran (the same hash): window and batch sizes and spp are run-time values (the
    non-box film has one set of kernels at spp 2, one up to film.STRIPS_SPP and one above)."""
    import drjit as dr
    scene = load(tmp_path, rfilter)
    integ = scene.integrator()

    def kernels(wins, spp):
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()
        integ.render_windows(scene, wins, spp=spp, seed=2, aovs="depth,cost")
        hist = dr.kernel_history()
        dr.set_flag(dr.JitFlag.KernelHistory, False)
        return {k["hash"] for k in hist if k.get("hash")}

    two = [(0, 0, 8, 8), (8, 8, 4, 4)]
    seen = kernels([(0, 0, 8, 8)], 4) | kernels(two, 4) | kernels(two, 2) | kernels([(0, 0, 8, 8)], 8)
    new = kernels([(3, 5, 13, 7)], 9) | kernels([(1, 1, 5, 6), (7, 2, 9, 9), (20, 0, 4, 18)], 3)
    # a scanline partition's batch: one window a row, the same kernels as two windows
    rows = kernels([(0, y, W, 1) for y in range(H)], 3)
    assert new and new <= seen, new - seen
    assert rows <= seen, rows - seen


@pytest.mark.parametrize("rfilter", ["box", "gaussian"])
def test_batch_film_work_does_not_grow_with_windows(variant, tmp_path, rfilter):
    """The film of a batch is made by the same number of kernels for 2 windows as for one a
    row (a scanline partition): no kernel or Python work per window, and each row
    equals the full frame bit for bit."""
    import drjit as dr
    scene = load(tmp_path, rfilter)
    integ = scene.integrator()
    full = integ.render_window(scene, None, spp=2, seed=5, aovs="depth,cost")

    def launched(wins):
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()
        out = integ.render_windows(scene, wins, spp=2, seed=5, aovs="depth,cost")
        n = len(dr.kernel_history())
        dr.set_flag(dr.JitFlag.KernelHistory, False)
        return out, n

    _, two = launched([(0, 0, W, 9), (0, 9, W, H - 9)])
    rows, many = launched([(0, y, W, 1) for y in range(H)])
    assert many <= two
    assert np.array_equal(np.concatenate(rows, axis=0), full)


def test_mi_render_never_visits_numpy(variant, tmp_path, monkeypatch):
    """``mi.render`` assembles the frame without numpy in the launch, film and integrator code."""
    import mitsuba as mi
    from links1_mitsuba import engine, launch
    scene = load(tmp_path, "gaussian")
    ref = np.asarray(mi.render(scene, spp=4))

    class NoNumpy:
        def __getattr__(self, name):
            raise AssertionError(f"numpy.{name} used while rendering")
    for mod in (launch, engine):
        monkeypatch.setattr(mod, "np", NoNumpy())
    t = mi.render(scene, spp=4)
    monkeypatch.undo()
    assert type(t) is mi.TensorXf and np.array_equal(np.asarray(t), ref)


@pytest.mark.parametrize("rfilter", ["box", "gaussian"])
def test_frames_of_the_same_windows_reuse_the_batch(variant, tmp_path, monkeypatch, rfilter):
    """A second frame of the same windows reuses the batch's sample ids (film.cached_batch,
    KEEP_LANES), window tables and the strips' sample weights (film._sample_weights): its kernels
    are the first frame's less those, its pixels the same bits, and the same as a frame that
    keeps nothing (KEEP_LANES = 0). The
    channels are interleaved in the pixel kernel: no kernel runs over pixels x channels."""
    import drjit as dr
    from links1_mitsuba import film
    scene = load(tmp_path, rfilter)
    integ = scene.integrator()
    wins = [(0, 0, W, 7), (2, 7, 15, 11)]

    def frame():
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()
        out = integ.render_windows(scene, wins, spp=4, seed=3, aovs=AOVS)
        hist = [k for k in dr.kernel_history() if str(k["type"]).endswith("JIT")]
        dr.set_flag(dr.JitFlag.KernelHistory, False)
        return out, hist

    integ.render_windows(scene, [(0, 0, 5, 5)], spp=4, seed=3, aovs=AOVS)   # the scene's tables
    first, k1 = frame()
    again, k2 = frame()
    pixels = sum(w * h for *_, w, h in wins)
    C = 3 + 1 + 3 + 1 + 1 + 1
    monkeypatch.setattr(film, "KEEP_LANES", 0)
    integ.engine.batches = {}
    none, k3 = frame()
    for a, b, c in zip(first, again, none):
        assert np.array_equal(a, b) and np.array_equal(a, c)
    # kept: the lanes' windows (a scatter of marks), the sample ids and, for the strips of a
    # non-box filter (spp 4 <= film.STRIPS_SPP), the samples' weights (made in the first
    # frame only); the launch and the pixels' kernels run again
    lanes = [b.lanes for b in integ.engine.batches.values()][-1]
    sizes1, sizes2 = [k["size"] for k in k1], [k["size"] for k in k2]
    kept = 1 if rfilter == "box" else 2
    assert len(k2) < len(k1) and sizes2.count(lanes) == sizes1.count(lanes) - kept, (sizes1, sizes2)
    # kept nothing: the samples' weights are written by the kernel that packs the samples
    assert len(k3) == len(k1) - (kept - 1)
    assert not [k for k in k1 if k["size"] == pixels * C]


def test_udiv_is_exact_integer_division(variant):
    """util.udiv (float64 quotient on LLVM, ``//`` elsewhere) equals numpy's ``//`` on random
    32-bit operands, the extremes, exact multiples and their neighbours (the cases where a
    rounded float64 quotient could land on the wrong side of an integer)."""
    import mitsuba as mi
    from links1_mitsuba.util import udiv
    rng = np.random.default_rng(7)
    a = np.concatenate([rng.integers(0, 2**32, 200_000, dtype=np.uint64), [2**32 - 1, 2**32 - 2, 0, 1]])
    b = np.concatenate([rng.integers(1, 2**32, 100_000, dtype=np.uint64),
                        rng.integers(1, 70_000, 100_000, dtype=np.uint64), [1, 2**32 - 1, 3, 2**32 - 1]])
    bm = rng.integers(1, 2**16, 100_000, dtype=np.int64)
    km = rng.integers(0, 2**16, 100_000, dtype=np.int64)
    for d in (-1, 0, 1):
        a = np.concatenate([a, (bm * km + d).clip(0, 2**32 - 1)])
        b = np.concatenate([b, bm])
    a, b = a.astype(np.uint32), b.astype(np.uint32)
    assert np.array_equal(np.asarray(udiv(mi.UInt32(a), mi.UInt32(b))), a // b)
    # a literal divisor keeps ``//`` (a float64 reciprocal multiply would not be exact)
    assert np.array_equal(np.asarray(udiv(mi.UInt32(a), mi.UInt32(3))), a // 3)
