"""Adaptive anti-aliasing (issue 11) in the core: time against error, uniform spp vs adaptive.

    python -m compare.adaptive [--res 128] [--ref-spp 1024] [--scenes lights fig4 ...]

Each scene at ``res``² with a box filter (``-D`` overrides nothing else): uniform stratified
spp 1, 4, 16, 64 and adaptive thresholds 0.1 / 0.03 / 0.01 at depths 2 and 3, against a
uniform ``ref-spp`` core render. relMSE = Σ(x − ref)² / Σ ref². Times: one frame each, one
after another in this process (the core is numpy; its run-to-run spread here is a few per
cent). Also writes ``docs/images/adaptive-samples.png``: an adaptive image and its
``samples`` AOV (camera samples per pixel).

Only the core renders adaptively so far: the plugin's Dr.Jit passes are not written (see
issue 11's note), so the issue's target (the plugin at ≤ 0.25× the time of 64 spp) is not
measured here.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from compare.common import ROOT, command_line, machine_info, machine_markdown, md_table, pyplot, write_results

UNIFORM = (1, 4, 16, 64)
ADAPTIVE = ((0.1, 2), (0.03, 2), (0.01, 2), (0.03, 3), (0.01, 3))
DEFAULT_SCENES = ("lights", "fig4", "shadows", "mitsuba_direct")


def rel_mse(a, ref):
    return float(np.sum((a - ref) ** 2) / max(np.sum(ref ** 2), 1e-30))


def _timed(fn):
    t = time.perf_counter()
    out = fn()
    return time.perf_counter() - t, out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--scenes", nargs="+", default=list(DEFAULT_SCENES))
    args = ap.parse_args(argv)

    from links1 import load_scene
    from links1.filters import Filter
    from links1.render import render

    plt = pyplot()
    fig, axes = plt.subplots(1, len(args.scenes), figsize=(4.2 * len(args.scenes), 3.6), squeeze=False)
    rows, data, picture = [], [], None
    for k, name in enumerate(args.scenes):
        scene = load_scene(str(ROOT / "scenes" / f"{name}.xml"), res=args.res)
        scene.camera = _box(scene.camera, Filter)
        ref = render(scene, spp=args.ref_spp)
        rec = {"scene": name, "uniform": [], "adaptive": []}
        for spp in UNIFORM:
            s, img = _timed(lambda: render(scene, spp=spp))
            rec["uniform"].append({"spp": spp, "s": s, "relmse": rel_mse(img, ref)})
        for thr, depth in ADAPTIVE:
            s, img = _timed(lambda: render(scene, adaptive=thr, adaptive_depth=depth, aovs=("samples",)))
            n = img[..., 3]
            rec["adaptive"].append({"threshold": thr, "depth": depth, "s": s, "relmse": rel_mse(img[..., :3], ref),
                                    "mean_samples": float(n.mean()), "refined_fraction": float((n > 4).mean())})
            if name == args.scenes[0] and (thr, depth) == (0.03, 3):
                picture = img
        u64 = rec["uniform"][-1]
        for a in rec["adaptive"]:
            rows.append([name, f"{a['threshold']} / {a['depth']}", a["mean_samples"], a["refined_fraction"],
                         a["s"], a["relmse"], a["relmse"] / u64["relmse"], a["s"] / u64["s"]])
        for u in rec["uniform"]:
            rows.append([name, f"uniform {u['spp']} spp", float(u["spp"]), None, u["s"], u["relmse"],
                         u["relmse"] / u64["relmse"], u["s"] / u64["s"]])
        ax = axes[0, k]
        ax.loglog([u["s"] for u in rec["uniform"]], [u["relmse"] for u in rec["uniform"]], "o-", label="uniform spp")
        for depth in sorted({d for _, d in ADAPTIVE}):
            pts = [a for a in rec["adaptive"] if a["depth"] == depth]
            ax.loglog([a["s"] for a in pts], [a["relmse"] for a in pts], "s--", label=f"adaptive, depth {depth}")
        ax.set_title(f"{name} ({args.res}², core)")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("relMSE vs uniform %d spp" % args.ref_spp)
        ax.legend(fontsize=7)
        data.append(rec)
        print(name, rec, flush=True)

    info, cmd = machine_info(), command_line()
    md = (f"# Adaptive anti-aliasing in the core ({args.res}², box filter; reference: uniform "
          f"{args.ref_spp} spp)\n\n" + machine_markdown(info, cmd) + "\n"
          + "Rows: adaptive `threshold / depth`, then uniform spp. `samples`: mean camera samples "
          "per pixel (adaptive: distinct lattice points a pixel uses; 4 = its corners only). "
          "Ratios are to uniform 64 spp of the same scene, measured in the same run.\n\n"
          + md_table(["scene", "setting", "samples", "refined", "time s", "relMSE", "relMSE ×64spp",
                      "time ×64spp"], rows))
    for p in write_results("adaptive", {"machine": info, "command": cmd, "args": vars(args), "results": data},
                           md, fig):
        print(p)
    if picture is not None:
        _picture(plt, picture, args.scenes[0])
    print(md)
    return 0


def _box(cam, Filter):
    from dataclasses import replace
    return replace(cam, rfilter=Filter("box"))


def _picture(plt, img, name):
    from links1.image import linear_to_srgb
    fig, (a, b) = plt.subplots(1, 2, figsize=(8.4, 3.9))
    a.imshow(np.clip(linear_to_srgb(img[..., :3]), 0, 1))
    a.set_title(f"{name}: adaptive, threshold 0.03, depth 3")
    im = b.imshow(img[..., 3], cmap="magma")
    b.set_title("samples AOV (camera samples per pixel)")
    for ax in (a, b):
        ax.set_axis_off()
    fig.colorbar(im, ax=b, fraction=0.046)
    out = ROOT / "docs" / "images" / "adaptive-samples.png"
    fig.savefig(out, dpi=80, bbox_inches="tight")
    print(out)


if __name__ == "__main__":
    raise SystemExit(main())
