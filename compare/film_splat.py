"""What a reconstruction filter costs a frame: links1_whitted's film against Mitsuba's splat.

    python -m compare.film_splat [--only teapot cbox_point] [--filter gaussian] [--spp 1 16]
                                 [--repeats 7] [--width 512] [--variant llvm_ad_rgb]

Per scene of ``compare.ray_floor`` (its delta-light cases, 512 px wide) and spp, four frames
interleaved in one process, ``repeats`` times each after a warm-up: links1_whitted and Mitsuba
``direct`` (emitter_samples 1, bsdf_samples 0), each with the box filter and with ``--filter``
on the same scene. The difference ``filter − box`` of a renderer's medians is what the filter
costs it: for ``direct`` the splat of every sample into the (2b+1)² pixels it reaches (inside its
ray kernel, float32 atomics) and the develop; for links1 its film's float32 sums in a fixed
order (``plugins/links1_mitsuba/film.py``) against the box mean. The rays traced are the same
with either filter. Also the medians of the process's CPU time a frame (all threads), which the
other jobs of a shared machine disturb less. Writes ``compare/results/film_splat.{json,md}``.
"""
from __future__ import annotations

import argparse
import json
import statistics

from compare.common import command_line, machine_info, machine_markdown
from compare.ray_floor import RESULTS, _frame, interleaved, load_case, mitsuba_integrator


def measure(cid, rfilter, spp, width, variant, repeats) -> dict:
    scenes = {rf: load_case(cid, rf, width, variant)[0] for rf in ("box", rfilter)}
    direct = mitsuba_integrator("direct", 1)
    runs = {}
    for rf, s in scenes.items():
        runs[f"links1/{rf}"] = lambda s=s: _frame(s, None, spp)
        runs[f"direct/{rf}"] = lambda s=s: _frame(s, direct, spp)
    for f in runs.values():
        f()                                   # warm-up: compilation, prepared tables
    cpu = {}
    ts = interleaved(runs, repeats, cpu)
    ms = {k: statistics.median(v) for k, v in ts.items()}
    cpu_ms = {k: statistics.median(v) for k, v in cpu.items()}
    film = {r: ms[f"{r}/{rfilter}"] - ms[f"{r}/box"] for r in ("links1", "direct")}
    film_cpu = {r: cpu_ms[f"{r}/{rfilter}"] - cpu_ms[f"{r}/box"] for r in ("links1", "direct")}
    return dict(id=cid, rfilter=rfilter, spp=spp, ms=ms, runs_ms=ts, filter_ms=film, cpu_ms=cpu_ms,
                filter_cpu_ms=film_cpu, ratio=ms[f"links1/{rfilter}"] / ms[f"direct/{rfilter}"],
                ratio_cpu=cpu_ms[f"links1/{rfilter}"] / cpu_ms[f"direct/{rfilter}"])


def markdown(rows, info, cmd) -> str:
    out = ["# The filter's cost: links1_whitted's film against Mitsuba's splat\n", machine_markdown(info, cmd),
           "\nThe machine was shared with other jobs (2 cores): only values from the same run mean something.\n",
           "\n| scene | filter | spp | links1 box / filter ms | direct box / filter ms | filter − box: links1 | "
           "filter − box: direct | links1 / direct (filter) | CPU ms a frame: filter − box, links1 / direct "
           "| links1 / direct (filter, CPU) |", "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        m, f, rf = r["ms"], r["filter_ms"], r["rfilter"]
        fc = r["filter_cpu_ms"]
        out.append(f"| `{r['id']}` | {rf} | {r['spp']} | {m['links1/box']:.0f} / {m[f'links1/{rf}']:.0f} | "
                   f"{m['direct/box']:.0f} / {m[f'direct/{rf}']:.0f} | {f['links1']:.0f} | {f['direct']:.0f} | "
                   f"{r['ratio']:.2f} | {fc['links1']:.0f} / {fc['direct']:.0f} | {r['ratio_cpu']:.2f} |")
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m compare.film_splat", description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="*", default=["teapot", "cbox_point"], help="compare.ray_floor case ids")
    ap.add_argument("--filter", default="gaussian")
    ap.add_argument("--spp", type=int, nargs="+", default=[1, 16])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--out", default=str(RESULTS / "film_splat"))
    a = ap.parse_args(argv)
    from pathlib import Path
    info, cmd = machine_info(), command_line()
    rows = []
    for cid in a.only:
        for spp in a.spp:
            r = measure(cid, a.filter, spp, a.width, a.variant, a.repeats)
            rows.append(r)
            m = r["ms"]
            print(f"{cid:12s} spp {spp:3d}: " + " ".join(f"{k} {v:.1f}" for k, v in m.items())
                  + f" | filter - box: links1 {r['filter_ms']['links1']:.1f} direct {r['filter_ms']['direct']:.1f} ms"
                  + f" | CPU: links1/direct {r['ratio_cpu']:.2f}",
                  flush=True)
    out = Path(a.out)
    out.with_suffix(".json").write_text(json.dumps(dict(machine=info, command=cmd, args=vars(a), rows=rows), indent=1))
    out.with_suffix(".md").write_text(markdown(rows, info, cmd))
    print(f"wrote {out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
