"""What reconstruction filters cost: frame time per filter against box, both renderers.

    python -m compare.filters [--res 256] [--spp 4] [--units 16]

The delta-light diffuse scene of tests/plugins/test_filters_vs_mitsuba.py at ``res``², ``spp``
samples: the full frame with the core and with links1_whitted (median of 3 after a warm-up),
links1_whitted as ``units`` horizontal strips (a partition's units: each traces its filter
border too), and Mitsuba's ``direct`` with the same filter as the anchor. Timings in this
process, one after another; ratios are to box in the same run.
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from compare.common import command_line, machine_info, machine_markdown, md_table, write_results

FILTERS = ("box", "tent", "gaussian", "mitchell", "lanczos")


def _timed(fn, repeats):
    fn()  # warm-up (kernel compilation, caches)
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--units", type=int, default=16)
    args = ap.parse_args(argv)

    import mitsuba as mi

    import links1_mitsuba
    from links1_app.renderers import make_renderer
    from tests.plugins import test_filters_vs_mitsuba as t
    links1_mitsuba.register("llvm_ad_rgb")
    t.RES = args.res
    rows, data = [], []
    tmp = Path(tempfile.mkdtemp())
    strip = -(-args.res // args.units)
    windows = [(0, y, args.res, min(strip, args.res - y)) for y in range(0, args.res, strip)]
    for name in FILTERS:
        rf = f'<rfilter type="{name}"/>'
        path = t.write_scene(tmp, rf)
        core = make_renderer("core", path, spp=args.spp)
        plug = make_renderer("mitsuba", path, spp=args.spp)
        sc = mi.load_string(t.scene_xml(rf, '<integrator type="direct"><integer name="bsdf_samples" '
                                            'value="0"/></integrator>'))
        rec = {"filter": name,
               "core_s": _timed(core.render, 1),
               "plugin_s": _timed(plug.render, 3),
               "plugin_units_s": _timed(lambda: [plug.render(w) for w in windows], 3),
               "direct_s": _timed(lambda: mi.render(sc, spp=args.spp), 3)}
        data.append(rec)
    box = data[0]
    for r in data:
        rows.append([r["filter"], r["core_s"], r["core_s"] / box["core_s"], r["plugin_s"],
                     r["plugin_s"] / box["plugin_s"], r["plugin_units_s"],
                     r["plugin_units_s"] / box["plugin_units_s"], r["direct_s"],
                     r["direct_s"] / box["direct_s"]])
    info, cmd = machine_info(), command_line()
    md = (f"# Reconstruction filters: frame time ({args.res}², spp {args.spp})\n\n"
          + machine_markdown(info, cmd) + "\n"
          + md_table(["filter", "core s", "×box", "links1_whitted s", "×box",
                      f"links1_whitted, {len(windows)} strips s", "×box", "Mitsuba direct s", "×box"], rows))
    for p in write_results("filters", {"machine": info, "command": cmd, "args": vars(args), "results": data}, md):
        print(p)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
