"""The film of ``links1_whitted`` in a real frame: this tree's ``film.reconstruct`` against a
reference copy of ``film.py``, frames alternated in one process.

    python -m compare.film_frame --ref FILM.py|REV [--only cbox_point teapot]
                                 [--filter gaussian] [--spp 16] [--rounds 9] [--width 512] [--frames N]

Per ``compare.ray_floor`` case: one scene object renders ``mi.render(scene, spp)`` frames whose
film is this tree's ``reconstruct`` or ``--ref``'s (``launch.reconstruct`` swapped: the same
launch, the same traced samples, later frames of the same windows as the benchmarks time),
alternating after two warm-up frames each; ``--frames N``: each round the first N frames of a
new batch instead (the integrator's batches dropped: the first as a single ``links1 render``
has it), a row a frame. Reports the medians of the frame's wall and process CPU time and of
its film kernels (``dr.kernel_history()``: every kernel but the launch's, those of one lane a
sample that every frame of both films runs), their ratios, and whether the two films' images
have the same bits. Writes ``compare/results/film_frame.{json,md}`` (``--out``: another stem).
"""
from __future__ import annotations

import argparse
import statistics
import time

from compare.common import command_line, machine_info, machine_markdown, write_results
from compare.film_gather import load_ref


def measure(case, rfilter, width, spp, rounds, ref, variant, frames=0):
    import drjit as dr
    import mitsuba as mi
    import numpy as np
    from compare.ray_floor import load_case
    from links1_mitsuba import film, launch
    scene, _, _, (W, H) = load_case(case, rfilter, width, variant)
    films = {"this": film.reconstruct, "ref": ref.reconstruct}

    def frame(k, new=False):
        launch.reconstruct = films[k]
        if new:
            scene.integrator().engine.batches = {}
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
        return wall * 1e3, cpu * 1e3, [(e["size"], e["hash"], e["execution_time"]) for e in hist], np.asarray(img)

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        warm = {k: [frame(k) for _ in range(2)][-1] for k in films}
        same = bool(np.array_equal(warm["this"][3], warm["ref"][3]))
        runs = [{k: [] for k in films} for _ in range(max(frames, 1))]
        for r in range(rounds):
            for k in (("this", "ref") if r % 2 == 0 else ("ref", "this")):
                for f, run in enumerate(runs):
                    run[k].append(frame(k, new=frames > 0 and f == 0)[:3])
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    rows = []
    for f, run in enumerate(runs):
        # the launch's kernels: those of one lane a sample that every frame of both films runs
        common = set.intersection(*[{h[:2] for h in x[2] if h[0] == W * H * spp} for v in run.values() for x in v])
        for v in run.values():
            v[:] = [(x[0], x[1], sum(t for *h, t in x[2] if tuple(h) not in common)) for x in v]
        med = {k: [statistics.median(x[i] for x in v) for i in range(3)] for k, v in run.items()}
        names = ("wall", "cpu", "film")
        rows.append(dict(case=case, filter=rfilter, size=[W, H], spp=spp, frame=f + 1 if frames else None,
                         same_bits=same, runs=run, median_ms={k: dict(zip(names, v)) for k, v in med.items()},
                         ratio={n: med["this"][i] / med["ref"][i] for i, n in enumerate(names)}))
    return rows


def markdown(rows, info, cmd, ref) -> str:
    out = ["# The film in a real frame: this tree's `film.reconstruct` against another `film.py`\n",
           machine_markdown(info, cmd),
           f"\nReference: `{ref}`. Frames of one scene object alternate the two films in one process "
           "(the same launch and samples); film = the frame's kernels but the launch's (those of one lane a "
           "sample that every frame of both films runs). The machine was shared with other jobs (2 cores): "
           "only the ratios of one run mean something.\n",
           "\n| case | filter | size | spp | frame wall ms this / ref | frame CPU ms this / ref | film kernels ms "
           "this / ref | wall ratio | CPU ratio | film ratio | same bits |",
           "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        m, q = r["median_ms"], r["ratio"]
        spp = f"{r['spp']}" + (f" (frame {r['frame']})" if r.get("frame") else "")
        cells = [f"`{r['case']}`", r["filter"], f"{r['size'][0]}×{r['size'][1]}", spp,
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
    ap.add_argument("--frames", type=int, default=0, help="the first N frames of a new batch each round")
    ap.add_argument("--out", default="film_frame", help="results stem under compare/results/")
    a = ap.parse_args(argv)

    import mitsuba as mi
    mi.set_variant(a.variant)
    info, cmd = machine_info(), command_line()
    ref = load_ref(a.ref)
    rows = []
    for case, name, spp in ((c, n, s) for c in a.only for n in a.filter for s in a.spp):
        for r in measure(case, name, a.width, spp, a.rounds, ref, a.variant, a.frames):
            rows.append(r)
            m, q = r["median_ms"], r["ratio"]
            print(f"{case} {name} spp {spp}{' frame %d' % r['frame'] if r['frame'] else ''}: frame CPU "
                  f"{m['this']['cpu']:.1f} / {m['ref']['cpu']:.1f} ms ({q['cpu']:.3f}), film kernels "
                  f"{m['this']['film']:.1f} / {m['ref']['film']:.1f} ms ({q['film']:.3f}), wall {q['wall']:.3f}, "
                  f"same bits: {r['same_bits']}", flush=True)
    payload = dict(machine=info, command=cmd, args=vars(a), rows=rows)
    paths = write_results(a.out, payload, markdown(rows, info, cmd, a.ref))
    print("wrote", *map(str, paths))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
