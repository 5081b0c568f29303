"""How far links1_whitted's float32 non-box film lies from the float64 film, on real samples.

    python -m compare.film_precision [--res 128] [--spp 4 16] [--filter gaussian tent mitchell lanczos]

Per ``scenes/*.xml`` (``res`` wide) and spp: the samples of the full frame traced once
(``window_samples``, seed 0), then reconstructed per filter by the device film
(``film.reconstruct``, float32 arithmetic) and by :func:`links1.sensor.filters.filter_samples`
in float64 (the film's former arithmetic: the same pixel definition, the same order; the former
device film equalled it to ~1e-15) and in float32 (the device film's numpy mirror). Errors are
in float32 ulps of the output pixel (``np.spacing`` of the float64 reference rounded to
float32; exact zeros left out): ``max`` and the 99.9th percentile over the RGB values, the
device film against float64 (the rounding of the float64 film's output alone is ≤ 0.5) and
against its float32 mirror. Writes ``compare/results/film_precision.{json,md}``.
"""
from __future__ import annotations

import argparse
import glob
import os
import warnings

import numpy as np

from compare.common import SCENES, command_line, machine_info, machine_markdown, write_results


def ulps(got, ref64):
    """|got - ref64| in float32 ulps of ref64 (its nonzero values)."""
    nz = ref64 != 0.0
    return np.abs(got[nz].astype(np.float64) - ref64[nz]) / np.spacing(np.abs(ref64[nz]).astype(np.float32))


def float64_at_float32_offsets(rf, W, H, samples, spp):
    """:func:`filter_samples` in float64 at the float32 rounding of the sample offsets (where
    the camera rays were traced): the float64 film's arithmetic with the device film's positions."""
    from links1.maths.sampling import sample_offsets
    from links1.sensor.filters import FilterGather
    g = FilterGather(rf, (0, 0, W, H), (W, H))
    py, px = np.mgrid[0:H, 0:W]
    for i in range(spp):
        ox, oy = (o.astype(np.float32).astype(np.float64) for o in sample_offsets(px, py, i, spp, 0, W))
        g.add(samples[:, :, i].astype(np.float64), ox, oy)
    return g.result()


def measure(path, res, spps, filters):
    import drjit as dr
    import mitsuba as mi
    from links1.sensor.filters import Filter, filter_samples
    from links1_mitsuba import MitsubaRenderer, film
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = MitsubaRenderer(path, params={"res": res})
    integ, scene = r.integrator, r.scene
    W, H = integ.prepare(scene).film_size
    rows = []
    for spp in spps:
        (sx0, sy0, sw, sh), s = integ.window_samples(scene, None, spp=spp, seed=0, aovs="")
        assert (sx0, sy0, sw, sh) == (0, 0, W, H)
        samples = s["total"]                                      # (H, W, spp, 3) float32
        flat = samples.reshape(-1, 3)
        data = {"total": mi.Color3f(*(mi.Float(np.ascontiguousarray(flat[:, c])) for c in range(3)))}
        for name in filters:
            rf = Filter(name)
            win = (0, 0, W, H)
            batch = film.Batch([win], [film.sample_window(rf, win, (W, H))], spp)
            out, C = film.reconstruct(rf, (W, H), spp, 0, batch, data, [], mi.Float)
            dev = np.asarray(out).reshape(H, W, C)
            ref64 = filter_samples(rf, win, (W, H), samples.astype(np.float64), (0, 0), spp, 0)
            ref32 = filter_samples(rf, win, (W, H), samples, (0, 0), spp, 0, np.float32)
            e64, e32 = ulps(dev, ref64), ulps(dev, ref32.astype(np.float64))
            pos = float64_at_float32_offsets(rf, W, H, samples, spp)
            ep = ulps(dev, pos)
            old = ulps(ref64.astype(np.float32), ref64)
            rows.append(dict(scene=os.path.basename(path), res=[W, H], spp=spp, filter=name,
                             max_ulps=float(e64.max()), p999_ulps=float(np.percentile(e64, 99.9)),
                             mean_ulps=float(e64.mean()), float64_rounded_max_ulps=float(old.max()),
                             same_pos_max_ulps=float(ep.max()), same_pos_p999_ulps=float(np.percentile(ep, 99.9)),
                             mirror_max_ulps=float(e32.max()), mirror_p999_ulps=float(np.percentile(e32, 99.9)),
                             mirror_same_frac=float(np.mean(dev == ref32)), values=int(e64.size)))
            print(f"{rows[-1]['scene']:18s} spp {spp:2d} {name:9s}: vs float64 max {e64.max():.2f} "
                  f"p99.9 {np.percentile(e64, 99.9):.2f} mean {e64.mean():.3f} ulps | at float32 positions max "
                  f"{ep.max():.2f} p99.9 {np.percentile(ep, 99.9):.2f} | vs float32 mirror "
                  f"max {e32.max():.2f}, same bits {np.mean(dev == ref32):.4f}", flush=True)
            dr.flush_malloc_cache()
    return rows


def markdown(rows, info, cmd) -> str:
    out = ["# The float32 non-box film against the float64 film\n", machine_markdown(info, cmd),
           "\nErrors in float32 ulps of each output value (RGB, exact zeros left out); the float64 film's "
           "own output rounded to float32 is within 0.5.\n",
           "\n| scene | size | spp | filter | vs float64: max | p99.9 | mean | vs float64 at the float32 positions: "
           "max | p99.9 | vs float32 numpy mirror: max | p99.9 | same bits |",
           "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        out.append(f"| `{r['scene']}` | {r['res'][0]}×{r['res'][1]} | {r['spp']} | {r['filter']} | "
                   f"{r['max_ulps']:.2f} | {r['p999_ulps']:.2f} | {r['mean_ulps']:.3f} | {r['same_pos_max_ulps']:.2f} | "
                   f"{r['same_pos_p999_ulps']:.2f} | {r['mirror_max_ulps']:.2f} | "
                   f"{r['mirror_p999_ulps']:.2f} | {r['mirror_same_frac']:.4f} |")
    worst = {}
    for r in rows:
        w = worst.setdefault(r["filter"], [0.0] * 5)
        for j, k in enumerate(("max_ulps", "p999_ulps", "same_pos_max_ulps", "same_pos_p999_ulps", "mirror_max_ulps")):
            w[j] = max(w[j], r[k])
    out += ["", "Over all scenes and spp, worst max / worst p99.9 against the float64 film, the same at the float32 "
            "positions, worst max against the float32 mirror (ulps):", ""]
    out += [f"* {k}: {v[0]:.1f} / {v[1]:.1f}; {v[2]:.1f} / {v[3]:.1f}; {v[4]:.1f}" for k, v in worst.items()]
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m compare.film_precision", description=__doc__.split("\n\n")[0])
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, nargs="+", default=[4, 16])
    ap.add_argument("--filter", nargs="+", default=["gaussian", "tent", "mitchell", "lanczos"])
    ap.add_argument("--variant", default="llvm_ad_rgb")
    a = ap.parse_args(argv)
    import mitsuba as mi
    mi.set_variant(a.variant)
    info, cmd = machine_info(), command_line()
    rows = []
    for path in sorted(glob.glob(str(SCENES / "*.xml"))):
        rows += measure(path, a.res, a.spp, a.filter)
    paths = write_results("film_precision", dict(machine=info, command=cmd, args=vars(a), rows=rows),
                          markdown(rows, info, cmd))
    print("wrote", *paths)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
