"""links1_whitted's frame with one switch of ``tuning.Tuning`` at its default and flipped,
alternated in one process.

    python -m compare.tuning_ab --switch coherent_shadows [--only ID[:FILTER] ...] [--spp 16]
                                [--pairs 15] [--out NAME]

Per case (``compare.ray_floor``'s scenes, 512 px wide, the file's filter or ``:FILTER``), one
scene object; frames of ``mi.render`` with the switch at its default and flipped
(``tuning.tuned``: each setting its own frozen launch, both recorded before the timing), in
pairs whose order alternates; per pair the default's frame over the flipped one's, process CPU
time (every thread) and wall time; medians over the pairs, their range. Every frame must equal
the first of its setting, and the two settings' frames each other bit for bit (the switches
change no pixel beyond float32 rounding: a difference is reported). Writes
``compare/results/<--out>.{json,md}`` (``tuning_ab_<switch>``).
"""
from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from compare.common import command_line, machine_info, machine_markdown, timed_render, write_results


def measure(cid, filt, spp, pairs, switch, variant):
    from compare.ray_floor import CASES, load_case
    from links1_mitsuba import tuning

    filt = filt or CASES[cid][3][0]
    scene, _, _, _ = load_case(cid, filt, 512, variant)
    default = getattr(tuning.Tuning(), switch)
    flipped = (not default) if isinstance(default, bool) else 10 ** 9

    def frame(value):
        with tuning.tuned(**{switch: value}):
            return timed_render(scene, spp)
    first = {v: [frame(v)[2] for _ in range(2)][-1] for v in (default, flipped)}
    same = bool(np.array_equal(first[default], first[flipped]))
    rc, rw, ms = [], [], {default: [], flipped: []}
    for p in range(pairs):
        got = {}
        for v in ((default, flipped) if p % 2 else (flipped, default)):
            tw, tc, img = frame(v)
            same &= bool(np.array_equal(img, first[v]))
            got[v] = (tw, tc)
            ms[v].append(tc)
        rw.append(got[default][0] / got[flipped][0])
        rc.append(got[default][1] / got[flipped][1])
    return dict(id=cid, filter=filt, spp=spp, switch=switch, default=default, pairs=pairs,
                cpu_ms_default=float(np.median(ms[default])), cpu_ms_flipped=float(np.median(ms[flipped])),
                cpu_ratio=float(np.median(rc)), cpu_range=[min(rc), max(rc)],
                wall_ratio=float(np.median(rw)), wall_range=[min(rw), max(rw)], same=same)


def main(argv=None) -> int:
    from links1_mitsuba import tuning
    ap = argparse.ArgumentParser(prog="compare.tuning_ab", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--switch", required=True, choices=[f.name for f in dataclasses.fields(tuning.Tuning)])
    ap.add_argument("--only", nargs="+", default=["teapot", "cbox_point", "data_instancing", "delta_bsdfs",
                                                  "cbox_mirror_glass"], help="case ids (optionally ID:FILTER)")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--pairs", type=int, default=15)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--out", default=None, help="name of the result files in compare/results")
    a = ap.parse_args(argv)
    info, cmd = machine_info(), command_line()
    rows = []
    for item in a.only:
        cid, _, filt = item.partition(":")
        r = measure(cid, filt or None, a.spp, a.pairs, a.switch, a.variant)
        rows.append(r)
        print(f"{cid:16s} {r['filter']:8s} spp {a.spp}: default / flipped CPU {r['cpu_ratio']:.3f} "
              f"({r['cpu_range'][0]:.2f}-{r['cpu_range'][1]:.2f}), wall {r['wall_ratio']:.3f}, same={r['same']}",
              flush=True)
    md = [f"# links1_whitted's frame: `{a.switch}` at its default and flipped\n", machine_markdown(info, cmd),
          f"\n`mi.render` (512 px wide, spp {a.spp}), frames of the two settings in {a.pairs} pairs of alternating "
          "order; per pair the default's frame over the flipped one's (process CPU time, every thread; wall time), "
          "medians and the range of the pairs; same: every frame of both settings the same bits "
          "(`compare/tuning_ab.py`).\n",
          "| scene | filter | default | CPU ms (default / flipped) | default / flipped, CPU | wall | same |",
          "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        md.append(f"| `{r['id']}` | {r['filter']} | {r['default']} | {r['cpu_ms_default']:.1f} / {r['cpu_ms_flipped']:.1f} | "
                  f"**{r['cpu_ratio']:.3f}** ({r['cpu_range'][0]:.2f}–{r['cpu_range'][1]:.2f}) | {r['wall_ratio']:.3f} "
                  f"({r['wall_range'][0]:.2f}–{r['wall_range'][1]:.2f}) | {r['same']} |")
    paths = write_results(a.out or f"tuning_ab_{a.switch}", dict(machine=info, command=cmd, cases=rows),
                          "\n".join(md) + "\n")
    print("wrote " + ", ".join(str(p) for p in paths))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
