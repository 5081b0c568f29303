"""The film of ``links1_whitted`` in a real frame: this tree's ``film.reconstruct`` against a
reference copy of ``film.py``, frames alternated in one process.

    python -m compare.film_frame --ref FILM.py|REV [--only cbox_point teapot]
                                 [--filter gaussian] [--spp 16] [--rounds 9] [--width 512]

Per ``compare.ray_floor`` case: one scene object renders ``mi.render(scene, spp)`` frames whose
film is this tree's ``reconstruct`` or ``--ref``'s (``launch.reconstruct`` swapped: the same
launch, the same traced samples, later frames of the same windows as the benchmarks time),
alternating after two warm-up frames each. Reports the medians of the frame's wall and process
CPU time and of its film kernels (``dr.kernel_history()``: every kernel but the launch's, whose
lanes are the samples), their ratios, and whether the two films' images have the same bits.
Writes ``compare/results/film_frame.{json,md}`` (``--out``: another stem).
"""
from __future__ import annotations

import argparse
import statistics
import time

from compare.common import command_line, machine_info, machine_markdown, write_results
from compare.film_gather import load_ref


def measure(case, rfilter, width, spp, rounds, ref, variant):
    import drjit as dr
    import mitsuba as mi
    import numpy as np
    from compare.ray_floor import load_case
    from links1_mitsuba import film, launch
    scene, _, _, (W, H) = load_case(case, rfilter, width, variant)
    films = {"this": film.reconstruct, "ref": ref.reconstruct}

    def frame(k):
        launch.reconstruct = films[k]
        try:
            dr.kernel_history()
            c, t = time.process_time(), time.perf_counter()
            img = mi.render(scene, spp=spp)
            dr.eval(img)
            dr.sync_thread()
            wall, cpu = time.perf_counter() - t, time.process_time() - c
            hist = [e for e in dr.kernel_history() if e["type"] == dr.KernelType.JIT]
        finally:
            launch.reconstruct = film.reconstruct
        kern = sum(e["execution_time"] for e in hist if e["size"] != W * H * spp)
        return wall * 1e3, cpu * 1e3, kern, np.asarray(img)

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        imgs = {k: [frame(k)[3] for _ in range(2)][-1] for k in films}
        same = bool(np.array_equal(imgs["this"], imgs["ref"]))
        runs = {k: [] for k in films}
        for r in range(rounds):
            for k in (("this", "ref") if r % 2 == 0 else ("ref", "this")):
                runs[k].append(frame(k)[:3])
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    med = {k: [statistics.median(x[i] for x in v) for i in range(3)] for k, v in runs.items()}
    return dict(case=case, filter=rfilter, size=[W, H], spp=spp, same_bits=same, runs=runs,
                median_ms={k: dict(zip(("wall", "cpu", "film"), v)) for k, v in med.items()},
                ratio={n: med["this"][i] / med["ref"][i] for i, n in enumerate(("wall", "cpu", "film"))})


def markdown(rows, info, cmd, ref) -> str:
    out = ["# The film in a real frame: this tree's `film.reconstruct` against another `film.py`\n",
           machine_markdown(info, cmd),
           f"\nReference: `{ref}`. Frames of one scene object alternate the two films in one process "
           "(the same launch and samples); film = the frame's kernels but the launch's. The machine was "
           "shared with other jobs (2 cores): only the ratios of one run mean something.\n",
           "\n| case | filter | size | spp | frame wall ms this / ref | frame CPU ms this / ref | film kernels ms "
           "this / ref | wall ratio | CPU ratio | film ratio | same bits |",
           "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        m, q = r["median_ms"], r["ratio"]
        cells = [f"`{r['case']}`", r["filter"], f"{r['size'][0]}×{r['size'][1]}", r["spp"],
                 *[f"{m['this'][k]:.1f} / {m['ref'][k]:.1f}" for k in ("wall", "cpu", "film")],
                 f"{q['wall']:.3f}", f"**{q['cpu']:.3f}**", f"**{q['film']:.3f}**", r["same_bits"]]
        out.append("| " + " | ".join(map(str, cells)) + " |")
    return "\n".join(out) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m compare.film_frame", description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="+", default=["cbox_point", "teapot"], help="compare.ray_floor case ids")
    ap.add_argument("--ref", required=True, help="the film.py to compare with, or a git revision")
    ap.add_argument("--filter", nargs="+", default=["gaussian"])
    ap.add_argument("--spp", type=int, nargs="+", default=[16])
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--out", default="film_frame", help="results stem under compare/results/")
    a = ap.parse_args(argv)

    import mitsuba as mi
    mi.set_variant(a.variant)
    info, cmd = machine_info(), command_line()
    ref = load_ref(a.ref)
    rows = []
    for case in a.only:
        for name in a.filter:
            for spp in a.spp:
                r = measure(case, name, a.width, spp, a.rounds, ref, a.variant)
                rows.append(r)
                m, q = r["median_ms"], r["ratio"]
                print(f"{case} {name} spp {spp}: frame CPU {m['this']['cpu']:.1f} / {m['ref']['cpu']:.1f} ms "
                      f"({q['cpu']:.3f}), film kernels {m['this']['film']:.1f} / {m['ref']['film']:.1f} ms "
                      f"({q['film']:.3f}), wall {q['wall']:.3f}, same bits: {r['same_bits']}", flush=True)
    paths = write_results(a.out, dict(machine=info, command=cmd, args=vars(a), rows=rows), markdown(rows, info, cmd, a.ref))
    print("wrote", *map(str, paths))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
