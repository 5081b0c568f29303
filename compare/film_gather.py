"""The filter gather of ``links1_whitted``'s device film alone (``film.reconstruct``), timed
against a reference copy of ``film.py`` in the same process.

    python -m compare.film_gather --ref FILM.py|REV [--res 512] [--spp 1 2 4 16]
                                  [--filter gaussian] [--repeats 9] [--variant llvm_ad_rgb]

Per filter and spp: one full-frame window of a ``res``² film, ``spp`` samples a pixel, random
sample values (the gather's cost does not depend on them), what the film keeps with the batch
made (as a second frame of the same windows has it): each round times ``reconstruct`` of this
tree and of ``--ref`` once each, alternating (``dr.eval`` + ``dr.sync_thread``, warm; wall and
the process's CPU time), and checks that both give the same float32 bits. ``--ref``: a
``film.py``, or a git revision whose ``plugins/links1_mitsuba/film.py`` is used. Prints the
medians and their ratio (on a shared
machine only the ratio measured in one run means something) and writes
``compare/results/film_gather.{json,md}``.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

from compare.common import command_line, machine_info, machine_markdown

RESULTS = Path(__file__).resolve().parent / "results"


def load_ref(path):
    """``path`` (a ``film.py``, or a git revision of this repository's) as a module inside the
    ``links1_mitsuba`` package (its relative imports resolve to this tree's helpers)."""
    if not Path(path).is_file():
        src = subprocess.run(["git", "show", f"{path}:plugins/links1_mitsuba/film.py"], check=True,
                             capture_output=True, text=True, cwd=Path(__file__).resolve().parent).stdout
        tmp = tempfile.NamedTemporaryFile("w", suffix="_film.py", delete=False)
        tmp.write(src)
        tmp.close()
        path = tmp.name
    spec = importlib.util.spec_from_file_location("links1_mitsuba._film_ref", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def measure(mods, rfilter, res, spp, repeats):
    import drjit as dr
    import mitsuba as mi
    import numpy as np
    W = H = res
    win = (0, 0, W, H)
    swin = mods["this"].sample_window(rfilter, win, (W, H))
    batches = {k: m.Batch([win], [swin], spp) for k, m in mods.items()}
    n = batches["this"].lanes
    rng = np.random.default_rng(1)
    total = mi.Color3f(*(mi.Float(rng.random(n, dtype=np.float32)) for _ in range(3)))
    data = {"total": total, "cost": mi.Float(rng.random(n, dtype=np.float32))}
    dr.eval(data)

    def run(k):
        c, t = time.process_time(), time.perf_counter()
        out, _ = mods[k].reconstruct(rfilter, (W, H), spp, 7, batches[k], data, [], mi.Float)
        dr.eval(out)
        dr.sync_thread()
        return time.perf_counter() - t, out, time.process_time() - c

    outs = {k: run(k)[1] for k in mods}            # compile, make what the batch keeps
    same = bool(dr.all(outs["this"] == outs["ref"]))
    times, cpu = {k: [] for k in mods}, {k: [] for k in mods}
    for r in range(repeats):
        for k in (mods if r % 2 == 0 else reversed(list(mods))):
            wall, _, c = run(k)
            times[k].append(wall * 1e3)
            cpu[k].append(c * 1e3)
    med = {k: statistics.median(v) for k, v in times.items()}
    low = {k: min(v) for k, v in times.items()}   # the least disturbed frame of each
    cmed = {k: statistics.median(v) for k, v in cpu.items()}
    return dict(filter=rfilter.name, spp=spp, res=res, median_ms=med, min_ms=low, runs_ms=times, same_bits=same,
                ratio=med["this"] / med["ref"], ratio_min=low["this"] / low["ref"], cpu_median_ms=cmed,
                cpu_runs_ms=cpu, ratio_cpu=cmed["this"] / cmed["ref"])


def markdown(rows, info, cmd, ref) -> str:
    out = ["# The non-box film alone: this tree's `film.reconstruct` against another `film.py`\n",
           machine_markdown(info, cmd),
           f"\nReference: `{ref}`. Rounds alternate the two films in one process; the machine was shared "
           "with other jobs (2 cores): only the ratios of one run mean something.\n",
           "\n| filter | spp | this ms (median / min) | reference ms (median / min) | this / reference (medians) | "
           "(minima) | CPU ms this / reference (medians) | (CPU ratio) | same float32 bits |",
           "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        m, lo, c = r["median_ms"], r["min_ms"], r["cpu_median_ms"]
        out.append(f"| {r['filter']} | {r['spp']} | {m['this']:.1f} / {lo['this']:.1f} | {m['ref']:.1f} / "
                   f"{lo['ref']:.1f} | **{r['ratio']:.2f}** | {r['ratio_min']:.2f} | {c['this']:.1f} / {c['ref']:.1f} | "
                   f"**{r['ratio_cpu']:.2f}** | {r['same_bits']} |")
    return "\n".join(out) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m compare.film_gather", description=__doc__.split("\n\n")[0])
    ap.add_argument("--ref", required=True, help="the film.py to compare with, or a git revision")
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--spp", type=int, nargs="+", default=[16])
    ap.add_argument("--filter", nargs="+", default=["gaussian"])
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--out", default=str(RESULTS / "film_gather"))
    a = ap.parse_args(argv)

    import mitsuba as mi
    mi.set_variant(a.variant)
    from links1.sensor.filters import Filter
    from links1_mitsuba import film
    info, cmd = machine_info(), command_line()
    mods = {"this": film, "ref": load_ref(a.ref)}
    rows = []
    for name in a.filter:
        for spp in a.spp:
            r = measure(mods, Filter(name), a.res, spp, a.repeats)
            rows.append(r)
            m, lo = r["median_ms"], r["min_ms"]
            print(f"{a.res}², spp {spp}, {name}, {a.variant}, {a.repeats} rounds: this {m['this']:.1f} ms, "
                  f"ref {m['ref']:.1f} ms, this/ref {r['ratio']:.2f} (minima {lo['this']:.1f} / {lo['ref']:.1f} ms: "
                  f"{r['ratio_min']:.2f}), CPU this/ref {r['ratio_cpu']:.2f}, same bits: {r['same_bits']}", flush=True)
    out = Path(a.out)
    out.with_suffix(".json").write_text(json.dumps(dict(machine=info, command=cmd, args=vars(a), rows=rows), indent=1))
    out.with_suffix(".md").write_text(markdown(rows, info, cmd, a.ref))
    print(f"wrote {out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
