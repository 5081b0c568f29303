"""Adaptive anti-aliasing (issue 11): time against error, uniform spp vs adaptive.

    python -m compare.adaptive --renderer core [--res 128] [--ref-spp 1024] [--scenes lights fig4 ...]
    python -m compare.adaptive --renderer mitsuba --res 512

Each scene at ``res``² with a box filter: uniform stratified spp 1, 4, 16, 64 and adaptive
thresholds 0.1 / 0.03 / 0.01 at depths 2 and 3, against a uniform ``ref-spp`` render of the
same renderer. relMSE = Σ(x − ref)² / Σ ref². Times: core, one frame each; mitsuba
(links1_whitted, llvm), median of 3 frames after 2 warm-up frames (the launches' recordings),
one after another in this process. Results go to ``compare/results/adaptive_<renderer>.*``;
the core run also writes ``docs/images/adaptive-samples.png`` (an adaptive image and its
``samples`` AOV).
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


def _timed(fn, warm=0, reps=1):
    for _ in range(warm):
        fn()
    times, out = [], None
    for _ in range(reps):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times)), out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--scenes", nargs="+", default=list(DEFAULT_SCENES))
    ap.add_argument("--renderer", choices=("core", "mitsuba"), default="core")
    args = ap.parse_args(argv)

    from links1.render import make_renderer
    warm, reps = (0, 1) if args.renderer == "core" else (2, 3)

    def renderer(path, **kw):
        r = make_renderer(args.renderer, path, params={"res": args.res}, **kw)
        _box(r)
        return r

    plt = pyplot()
    fig, axes = plt.subplots(1, len(args.scenes), figsize=(4.2 * len(args.scenes), 3.6), squeeze=False)
    rows, data, picture = [], [], None
    for k, name in enumerate(args.scenes):
        path = str(ROOT / "scenes" / f"{name}.xml")
        ref = renderer(path, spp=args.ref_spp).render()
        rec = {"scene": name, "uniform": [], "adaptive": []}
        for spp in UNIFORM:
            s, img = _timed(renderer(path, spp=spp).render, warm, reps)
            rec["uniform"].append({"spp": spp, "s": s, "relmse": rel_mse(img, ref)})
        for thr, depth in ADAPTIVE:
            s, img = _timed(renderer(path, adaptive=thr, adaptive_depth=depth, aovs=("samples",)).render, warm, reps)
            n = img[..., 3]
            rec["adaptive"].append({"threshold": thr, "depth": depth, "s": s, "relmse": rel_mse(img[..., :3], ref),
                                    "mean_samples": float(n.mean()), "refined_fraction": float((n > 4).mean())})
            if name == args.scenes[0] and (thr, depth) == (0.03, 3) and args.renderer == "core":
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
        ax.set_title(f"{name} ({args.res}², {args.renderer})")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("relMSE vs uniform %d spp" % args.ref_spp)
        ax.legend(fontsize=7)
        data.append(rec)
        print(name, rec, flush=True)

    info, cmd = machine_info(), command_line()
    md = (f"# Adaptive anti-aliasing, {args.renderer} renderer ({args.res}², box filter; reference: uniform "
          f"{args.ref_spp} spp)\n\n" + machine_markdown(info, cmd) + "\n"
          + "Rows: adaptive `threshold / depth`, then uniform spp. `samples`: mean camera samples "
          "per pixel (adaptive: distinct lattice points a pixel uses; 4 = its corners only). "
          "Ratios are to uniform 64 spp of the same scene, measured in the same run.\n\n"
          + md_table(["scene", "setting", "samples", "refined", "time s", "relMSE", "relMSE ×64spp",
                      "time ×64spp"], rows))
    for p in write_results(f"adaptive_{args.renderer}", {"machine": info, "command": cmd, "args": vars(args), "results": data},
                           md, fig):
        print(p)
    if picture is not None:
        _picture(plt, picture, args.scenes[0])
    print(md)
    return 0


def _box(r):
    """The paper scenes' films say box already; make sure (the adaptive render ignores filters)."""
    from links1.filters import Filter
    if r.kind == "core":
        from dataclasses import replace
        r.scene.camera = replace(r.scene.camera, rfilter=Filter("box"))
    elif r.integrator.prepare(r.scene).rfilter.name != "box":
        raise SystemExit(f"{r.path}: the film's filter is not box")


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
