"""The filter gather of ``links1_whitted``'s device film alone (``film.reconstruct``), timed
against a reference copy of ``film.py`` in the same process.

    python -m compare.film_gather --ref /path/to/other/film.py [--res 512] [--spp 16]
                                  [--filter gaussian] [--repeats 9] [--variant llvm_ad_rgb]

One full-frame window of a ``res``² film, ``spp`` samples a pixel, random sample values (the
gather's cost does not depend on them), the filter's weight tables kept with the batch (as a
second frame of the same windows has them): each round times ``reconstruct`` of this tree and
of ``--ref`` once each, alternating (``dr.eval`` + ``dr.sync_thread``, warm), and checks that
both give the same bits. Prints the medians and their ratio: on a shared machine only the ratio
measured in one run means something.
"""
from __future__ import annotations

import argparse
import importlib.util
import statistics
import time


def load_ref(path):
    """``path`` (a ``film.py``) as a module inside the ``links1_mitsuba`` package (its relative
    imports resolve to this tree's helpers)."""
    spec = importlib.util.spec_from_file_location("links1_mitsuba._film_ref", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ref", required=True, help="the film.py to compare with (e.g. main's)")
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--filter", default="gaussian")
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    a = ap.parse_args(argv)

    import drjit as dr
    import mitsuba as mi
    import numpy as np
    mi.set_variant(a.variant)
    from links1.sensor.filters import Filter
    from links1_mitsuba import film
    ref = load_ref(a.ref)

    f = Filter(a.filter)
    W = H = a.res
    win = (0, 0, W, H)
    swin = film.sample_window(f, win, (W, H))
    mods = {"this": film, "ref": ref}
    batches = {k: m.Batch([win], [swin], a.spp) for k, m in mods.items()}
    n = batches["this"].lanes
    rng = np.random.default_rng(1)
    total = mi.Color3f(*(mi.Float(rng.random(n, dtype=np.float32)) for _ in range(3)))
    data = {"total": total, "cost": mi.Float(rng.random(n, dtype=np.float32))}
    dr.eval(data)

    def run(k):
        t = time.perf_counter()
        out, _ = mods[k].reconstruct(f, (W, H), a.spp, 7, batches[k], data, [], mi.Float)
        dr.eval(out)
        dr.sync_thread()
        return time.perf_counter() - t, out

    outs = {k: run(k)[1] for k in mods}            # compile, make the weight tables
    same = bool(dr.all(outs["this"] == outs["ref"]))
    times = {k: [] for k in mods}
    for r in range(a.repeats):
        for k in (mods if r % 2 == 0 else reversed(list(mods))):
            times[k].append(run(k)[0])
    med = {k: statistics.median(v) * 1e3 for k, v in times.items()}
    low = {k: min(v) * 1e3 for k, v in times.items()}   # the least disturbed frame of each
    print(f"{a.res}², spp {a.spp}, {a.filter}, {a.variant}, {a.repeats} rounds: "
          f"this {med['this']:.1f} ms, ref {med['ref']:.1f} ms, this/ref {med['this'] / med['ref']:.2f} "
          f"(minima {low['this']:.1f} / {low['ref']:.1f} ms: {low['this'] / low['ref']:.2f}), same bits: {same}")
    for k, v in times.items():
        print(f"  {k}: " + " ".join(f"{t * 1e3:.1f}" for t in v))
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
