"""Area lights and environments: time and error against Mitsuba's ``direct``.

    python -m compare.area_lights [--res 64] [--spp 64] [--ref-spp 1024]

The diffuse-only scenes of tests/plugins/test_area_lights_vs_mitsuba.py (a floor and a sphere
lit by an area rectangle, an area sphere, an ``obj`` luminaire, a ``constant`` and an
``envmap`` environment) at ``res``², rendered at ``spp`` by the core, by links1_whitted and by
Mitsuba's ``direct`` (its default: one emitter and one BSDF sample per pixel sample, MIS),
against a ``ref-spp`` Mitsuba ``direct`` reference. relMSE = Σ(x − ref)² / Σ ref² (the tests'
measure; the reference's own noise is in every figure). Times: median of 3 frames after a
warm-up (core: 1 frame), one after another in this process.
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
import time

from compare.common import command_line, machine_info, machine_markdown, md_table, write_results


def _timed(fn, repeats):
    out = fn()  # warm-up (kernel compilation, caches); its image is the one measured for error
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--ref-spp", type=int, default=1024)
    args = ap.parse_args(argv)

    import mitsuba as mi
    import numpy as np

    import links1_mitsuba
    from links1_app.renderers import make_renderer
    from tests.plugins import test_area_lights_vs_mitsuba as t
    links1_mitsuba.register("llvm_ad_rgb")
    d = tempfile.mkdtemp()
    t.write_files(d)
    rows, data = [], []
    for kind in t.KINDS:
        path = t.write_scene(d, kind, res=args.res)
        sc = mi.load_file(path)
        ref = np.array(mi.render(sc, spp=args.ref_spp, seed=11), dtype=np.float64)[..., :3]
        core = make_renderer("core", path, spp=args.spp)
        plug = make_renderer("mitsuba", path, spp=args.spp)
        rec = {"scene": kind}
        for name, fn, reps in (("core", core.render, 1), ("links1_whitted", plug.render, 3),
                               ("direct", lambda: np.array(mi.render(sc, spp=args.spp, seed=12)), 3)):
            s, img = _timed(fn, reps)
            rec[f"{name}_s"], rec[f"{name}_relmse"] = s, t.rel_mse(np.asarray(img, dtype=np.float64)[..., :3], ref)
        data.append(rec)
        rows.append([kind, rec["core_s"], rec["core_relmse"], rec["links1_whitted_s"], rec["links1_whitted_relmse"],
                     rec["direct_s"], rec["direct_relmse"], rec["links1_whitted_relmse"] / rec["direct_relmse"],
                     rec["links1_whitted_s"] / rec["direct_s"]])
        print(kind, rec, flush=True)
    info, cmd = machine_info(), command_line()
    md = (f"# Area lights and environments vs Mitsuba's direct ({args.res}², {args.spp} spp; "
          f"reference: direct at {args.ref_spp} spp)\n\n" + machine_markdown(info, cmd) + "\n"
          + md_table(["scene", "core s", "core relMSE", "links1_whitted s", "links1_whitted relMSE",
                      "direct s", "direct relMSE", "relMSE ×direct", "time ×direct"], rows))
    for p in write_results("area_lights", {"machine": info, "command": cmd, "args": vars(args), "results": data}, md):
        print(p)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
