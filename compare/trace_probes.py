"""Two probes behind the suggestions of ``compare/vs_direct.py``'s profile.

    python -m compare.trace_probes [--scene data_instancing] [--repeats 5]

1. ``scene.ray_intersect`` of eye rays with ``coherent`` False (what ``links1_mitsuba``'s
   ``intersect.py`` passes today: the one-argument overload) against True (what Mitsuba's own
   ``direct`` passes for the camera ray), on a corpus scene at 512², rays ordered as links1's
   sample ids (``pixel * spp + i``, ``i`` innermost), spp 1 and 16; where the hits differ, how many
   and by how much.
2. The film's sample ids ``((ly + sy0) * W + lx + sx0) * spp + i`` from ``j // spp`` and
   ``// sw`` by opaque divisors (``links1_mitsuba/film.py`` ``sample_ids``: a vector ``udiv``,
   which x86 has no instruction for) against ``arange + sy0 * W * spp`` for a window of whole
   film rows (the full frame), which gives the same ids.

Medians of ``repeats`` runs after one warm-up, in one process. Writes
``compare/results/trace_probes.{json,md}``.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"


def _median_ms(fn, repeats):
    import drjit as dr
    fn()
    ts = []
    for _ in range(repeats):
        dr.sync_thread()
        t0 = time.perf_counter()
        fn()
        dr.sync_thread()
        ts.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(ts))


def coherent_probe(scene_id, width, spps, repeats, variant):
    import drjit as dr
    import mitsuba as mi
    from .vs_direct import _corpus, _load, _resize
    sc = next(s for s in _corpus() if s.id == scene_id)
    if not os.path.exists(sc.local_path):
        raise SystemExit(f"{scene_id}: not fetched: run tools/fetch_corpus.py")
    scene = _load(sc, None, variant)
    W, H = _resize(scene, width)
    sensor = scene.sensors()[0]
    rows = []
    for spp in spps:
        j = dr.arange(mi.UInt32, W * H * spp)
        pix = j // spp
        x = mi.Float(pix % W) + (mi.Float(j % spp) + 0.5) / spp
        y = mi.Float(pix // W) + 0.5
        ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(x / W, y / H), mi.Point2f(0.5))
        dr.eval(ray)
        out = {}

        def run(coh):
            si = scene.ray_intersect(ray, mi.RayFlags.All, coh)
            dr.eval(si.t, si.n, si.prim_index)
            out[coh] = si
        ms = {coh: _median_ms(lambda: run(coh), repeats) for coh in (False, True, False, True)}
        t0, t1 = np.asarray(out[False].t), np.asarray(out[True].t)
        p0, p1 = np.asarray(out[False].prim_index), np.asarray(out[True].prim_index)
        s0, s1 = np.asarray(out[False].is_valid()), np.asarray(out[True].is_valid())
        both = s0 & s1
        rel = np.abs(t0[both] - t1[both]) / np.maximum(np.abs(t0[both]), 1e-30)
        diff = dict(t_differs=int(np.count_nonzero(t0 != t1)), valid_differs=int(np.count_nonzero(s0 != s1)),
                    prim_differs=int(np.count_nonzero((p0 != p1) & both)),
                    max_rel_t=float(rel.max()) if rel.size else 0.0)
        rows.append(dict(spp=spp, lanes=W * H * spp, incoherent_ms=ms[False], coherent_ms=ms[True],
                         speedup=ms[False] / ms[True], **diff))
        print(f"ray_intersect {W}x{H} spp {spp}: coherent=False {ms[False]:.1f} ms, True {ms[True]:.1f} ms "
              f"({ms[False] / ms[True]:.2f}x), differ: {diff}", flush=True)
    return dict(scene=scene_id, width=W, height=H, rows=rows)


def ids_probe(width, height, spps, repeats):
    import drjit as dr
    import mitsuba as mi
    U32 = mi.UInt32

    def op(v):
        return dr.opaque(U32, int(v))

    def ids_div(spp, sx0=0, sy0=0, sw=width, sh=height):   # film.py sample_ids, one window
        j = dr.arange(U32, sw * sh * spp)
        s = op(spp)
        pix = j // s
        i = j - pix * s
        ly = pix // op(sw)
        lx = pix - ly * op(sw)
        return ((ly + op(sy0)) * op(width) + lx + op(sx0)) * s + i

    def ids_rows(spp, sy0=0, sh=height):   # whole film rows: the ids are consecutive
        return dr.arange(U32, width * sh * spp) + op(sy0 * width * spp)

    rows = []
    for spp in spps:
        res = {}
        for name, f in (("div", ids_div), ("rows", ids_rows)):
            def run():
                x = f(spp)
                dr.eval(x)
                res[name] = x
            res[name + "_ms"] = _median_ms(run, repeats)
        same = bool(dr.all(res["div"] == res["rows"]))
        rows.append(dict(spp=spp, lanes=width * height * spp, div_ms=res["div_ms"], rows_ms=res["rows_ms"],
                         same=same))
        print(f"sample ids {width}x{height} spp {spp}: udiv {res['div_ms']:.2f} ms, arange {res['rows_ms']:.2f} ms, "
              f"same: {same}", flush=True)
    return dict(width=width, height=height, rows=rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m compare.trace_probes", description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="data_instancing")
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--spp", type=int, nargs="+", default=[1, 16])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--out", default=str(RESULTS / "trace_probes"))
    a = ap.parse_args(argv)
    import links1_mitsuba as lm
    lm.register(a.variant)
    coh = coherent_probe(a.scene, a.width, a.spp, a.repeats, a.variant)
    ids = ids_probe(coh["width"], coh["height"], a.spp, a.repeats)
    import drjit
    import mitsuba
    machine = (f"{platform.node()} ({platform.machine()}, {os.cpu_count()} cores shared with other jobs, load "
               f"{os.getloadavg()[0]:.1f}), {a.variant}, Mitsuba {mitsuba.__version__}, Dr.Jit {drjit.__version__}")
    cmd = "python -m compare.trace_probes " + " ".join(argv if argv is not None else sys.argv[1:])
    out = Path(a.out)
    out.with_suffix(".json").write_text(json.dumps(dict(machine=machine, command=cmd.strip(), coherent=coh,
                                                        sample_ids=ids), indent=1))
    md = ["# Probes: coherent eye rays, sample ids without division\n\n",
          f"`{cmd.strip()}` on {machine}; medians of {a.repeats} runs. See `compare/trace_probes.py`.\n\n",
          f"`scene.ray_intersect` of {coh['width']}×{coh['height']}×spp eye rays (`{coh['scene']}`), links1's "
          "sample order. Where the two differ: lanes whose `t` differs (largest relative difference), "
          "whose hit/miss differs, whose primitive differs.\n\n"
          "| spp | rays | coherent=False ms | coherent=True ms | speed-up | `t` differs | max rel. | hit/miss differs "
          "| primitive differs |\n| --- | --- | --- | --- | --- | --- | --- | --- | --- |\n"]
    for r in coh["rows"]:
        md.append(f"| {r['spp']} | {r['lanes']} | {r['incoherent_ms']:.1f} | {r['coherent_ms']:.1f} | "
                  f"{r['speedup']:.2f}× | {r['t_differs']} | {r['max_rel_t']:.1e} | {r['valid_differs']} | "
                  f"{r['prim_differs']} |\n")
    md.append("\nThe film's sample ids of the full frame:\n\n| spp | ids | two opaque `udiv` ms | `arange` + offset ms "
              "| same ids |\n| --- | --- | --- | --- | --- |\n")
    for r in ids["rows"]:
        md.append(f"| {r['spp']} | {r['lanes']} | {r['div_ms']:.2f} | {r['rows_ms']:.2f} | {r['same']} |\n")
    out.with_suffix(".md").write_text("".join(md))
    print(f"wrote {out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
