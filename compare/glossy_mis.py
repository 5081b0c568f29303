"""Glossy BSDFs under area and environment lights: error and time against Mitsuba's ``direct``.

    python -m compare.glossy_mis [--res 64] [--spp 16] [--ref-spp 2048]

The scenes of tests/plugins/test_glossy_mis_vs_mitsuba.py (a floor and a ``roughconductor`` or
``roughplastic`` sphere under an area rectangle or a ``constant`` environment) at ``res``²,
rendered at ``spp`` by links1_whitted (light samples and one BSDF sample, MIS) and by
Mitsuba's ``direct`` (one emitter and one BSDF sample, MIS), against a ``ref-spp`` ``direct``
reference; relMSE = Σ(x − ref)² / Σ ref². Times: median of 3 frames after a warm-up
(:func:`compare.area_lights._timed`).
"""
from __future__ import annotations

import argparse
import tempfile

from compare.area_lights import _timed
from compare.common import command_line, machine_info, machine_markdown, md_table, write_results


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--ref-spp", type=int, default=2048)
    args = ap.parse_args(argv)

    import mitsuba as mi
    import numpy as np

    import links1_mitsuba
    from links1_app.renderers import make_renderer
    from tests.plugins import test_glossy_mis_vs_mitsuba as t
    links1_mitsuba.register("llvm_ad_rgb")
    t.RES = args.res
    d = tempfile.mkdtemp()
    t.write_files(d)
    direct = mi.load_dict({"type": "direct"})
    rows, data = [], []
    for bsdf, light in t.CASES:
        path = t.write_scene(d, bsdf, light)
        sc = mi.load_file(path)
        ref = np.array(mi.render(sc, integrator=direct, spp=args.ref_spp, seed=11), dtype=np.float64)[..., :3]
        plug = make_renderer("mitsuba", path, spp=args.spp)
        rec = {"scene": f"{bsdf}, {light}"}
        for name, fn in (("links1_whitted", plug.render),
                         ("direct", lambda: np.array(mi.render(sc, integrator=direct, spp=args.spp, seed=12)))):
            s, img = _timed(fn, 3)
            rec[f"{name}_s"], rec[f"{name}_relmse"] = s, t.rel_mse(np.asarray(img, dtype=np.float64)[..., :3], ref)
        data.append(rec)
        rows.append([rec["scene"], rec["links1_whitted_s"], rec["links1_whitted_relmse"], rec["direct_s"],
                     rec["direct_relmse"], rec["links1_whitted_relmse"] / rec["direct_relmse"],
                     rec["links1_whitted_s"] / rec["direct_s"]])
        print(rec, flush=True)
    info, cmd = machine_info(), command_line()
    md = (f"# Glossy BSDFs under sampled lights vs Mitsuba's direct ({args.res}², {args.spp} spp; "
          f"reference: direct at {args.ref_spp} spp)\n\n" + machine_markdown(info, cmd) + "\n"
          + md_table(["scene", "links1_whitted s", "links1_whitted relMSE", "direct s", "direct relMSE",
                      "relMSE ×direct", "time ×direct"], rows))
    for p in write_results("glossy_mis", {"machine": info, "command": cmd, "args": vars(args), "results": data}, md):
        print(p)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
