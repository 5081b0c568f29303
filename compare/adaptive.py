"""Adaptive anti-aliasing: time against error, uniform spp vs adaptive.

    python -m compare.adaptive --renderer mitsuba --res 512          # every scene in scenes/
    python -m compare.adaptive --renderer core [--res 128] [--ref-spp 1024] [--scenes lights fig4 ...]

Each scene at ``res``² with a box filter: uniform stratified spp 1, 4, 16, 64 and adaptive
thresholds 0.1 / 0.03 / 0.01 at depths 3 and 4, against a uniform ``ref-spp`` render of the
same renderer. relMSE = Σ(x − ref)² / Σ ref²; FLIP = mean LDR-FLIP (flip-evaluator) of the
sRGB images. Where Mitsuba's own integrator renders the same image as links1_whitted
(``mitsuba_direct.xml``: ``direct``), its uniform spp curve is measured too (same reference).
Times: core, one frame each; mitsuba (links1_whitted, llvm), median of 3 frames after 2
warm-up frames (the launches' recordings), one after another in this process. Per scene the
verdict row names the cheapest adaptive setting whose relMSE is at most uniform 64 spp's
(target: in <= 0.25x its time). Results go to ``compare/results/adaptive_<renderer>.*`` (one
plot per scene); the core run also writes ``docs/images/adaptive-samples.png`` (an adaptive
image and its ``samples`` AOV).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from compare.common import ROOT, command_line, machine_info, machine_markdown, md_table, pyplot, write_results

UNIFORM = (1, 4, 16, 64)
ADAPTIVE = ((0.1, 3), (0.03, 3), (0.01, 3), (0.1, 4), (0.03, 4), (0.01, 4))
DEFAULT_SCENES = ("lights", "fig4", "fig6a", "fig6b", "fig11", "shadows", "bicubic", "many", "mitsuba_direct",
                  "mitsuba_glass")
#: Scenes whose own (Mitsuba) integrator renders the image links1_whitted renders.
MITSUBA_SAME = ("mitsuba_direct",)
TARGET_TIME = 0.25


def rel_mse(a, ref):
    return float(np.sum((a - ref) ** 2) / max(np.sum(ref ** 2), 1e-30))


def flip(a, ref):
    from links1.imaging import diff
    try:
        return diff.flip(np.asarray(a, dtype=np.float32), np.asarray(ref, dtype=np.float32), ldr=True)
    except Exception:   # flip-evaluator missing: the column stays empty
        return None


def _timed(fn, warm=0, reps=1):
    for _ in range(warm):
        fn()
    times, out = [], None
    for _ in range(reps):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times)), out


def verdict(rec):
    """The cheapest adaptive setting at or below uniform 64 spp's relMSE, or the most accurate."""
    u64 = rec["uniform"][-1]
    ok = [a for a in rec["adaptive"] if a["relmse"] <= u64["relmse"]]
    if ok:
        best = min(ok, key=lambda a: a["s"])
        return best, best["s"] / u64["s"] <= TARGET_TIME
    return min(rec["adaptive"], key=lambda a: a["relmse"]), False


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--scenes", nargs="+", default=list(DEFAULT_SCENES))
    ap.add_argument("--renderer", choices=("core", "mitsuba"), default="core")
    args = ap.parse_args(argv)

    from links1_app.renderers import make_renderer
    warm, reps = (0, 1) if args.renderer == "core" else (2, 3)

    def renderer(path, **kw):
        r = make_renderer(args.renderer, path, params={"res": args.res}, **kw)
        _box(r)
        return r

    plt = pyplot()
    cols = min(5, len(args.scenes))
    nrows = -(-len(args.scenes) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(4.2 * cols, 3.6 * nrows), squeeze=False)
    rows, verdicts, data, picture = [], [], [], None
    for k, name in enumerate(args.scenes):
        path = str(ROOT / "scenes" / f"{name}.xml")
        ref = renderer(path, spp=args.ref_spp).render()
        rec = {"scene": name, "uniform": [], "adaptive": [], "mitsuba": []}
        for spp in UNIFORM:
            s, img = _timed(renderer(path, spp=spp).render, warm, reps)
            rec["uniform"].append({"spp": spp, "s": s, "relmse": rel_mse(img, ref), "flip": flip(img, ref)})
        for thr, depth in ADAPTIVE:
            s, img = _timed(renderer(path, adaptive=thr, adaptive_depth=depth, aovs=("samples",)).render, warm, reps)
            n = img[..., 3]
            rec["adaptive"].append({"threshold": thr, "depth": depth, "s": s, "relmse": rel_mse(img[..., :3], ref),
                                    "flip": flip(img[..., :3], ref),
                                    "mean_samples": float(n.mean()), "refined_fraction": float((n > 4).mean())})
            if name == args.scenes[0] and (thr, depth) == (0.03, 3) and args.renderer == "core":
                picture = img
        if args.renderer == "mitsuba" and name in MITSUBA_SAME:
            for spp in UNIFORM:
                r = make_renderer("mitsuba", path, params={"res": args.res}, spp=spp, integrator="scene")
                s, img = _timed(r.render, warm, reps)
                rec["mitsuba"].append({"spp": spp, "s": s, "relmse": rel_mse(img, ref), "flip": flip(img, ref)})
        u64 = rec["uniform"][-1]
        for a in rec["adaptive"]:
            rows.append([name, f"{a['threshold']} / {a['depth']}", a["mean_samples"], a["refined_fraction"],
                         a["s"], a["relmse"], a["flip"], a["relmse"] / u64["relmse"], a["s"] / u64["s"]])
        for u in rec["uniform"]:
            rows.append([name, f"uniform {u['spp']} spp", float(u["spp"]), None, u["s"], u["relmse"], u["flip"],
                         u["relmse"] / u64["relmse"], u["s"] / u64["s"]])
        for u in rec["mitsuba"]:
            rows.append([name, f"Mitsuba's own, {u['spp']} spp", float(u["spp"]), None, u["s"], u["relmse"],
                         u["flip"], u["relmse"] / u64["relmse"], u["s"] / u64["s"]])
        best, met = verdict(rec)
        rec["verdict"] = {"setting": [best["threshold"], best["depth"]], "met": met,
                          "relmse_x64": best["relmse"] / u64["relmse"], "time_x64": best["s"] / u64["s"]}
        verdicts.append([name, f"{best['threshold']} / {best['depth']}", best["relmse"] / u64["relmse"],
                         best["s"] / u64["s"], "met" if met else "missed"])
        ax = axes[k // cols, k % cols]
        ax.loglog([u["s"] for u in rec["uniform"]], [u["relmse"] for u in rec["uniform"]], "o-", label="uniform spp")
        for depth in sorted({d for _, d in ADAPTIVE}):
            pts = [a for a in rec["adaptive"] if a["depth"] == depth]
            ax.loglog([a["s"] for a in pts], [a["relmse"] for a in pts], "s--", label=f"adaptive, depth {depth}")
        if rec["mitsuba"]:
            ax.loglog([u["s"] for u in rec["mitsuba"]], [u["relmse"] for u in rec["mitsuba"]], "^:",
                      label="Mitsuba direct, spp")
        ax.axhline(u64["relmse"], color="grey", lw=0.6)
        ax.set_title(f"{name} ({args.res}², {args.renderer})")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("relMSE vs uniform %d spp" % args.ref_spp)
        ax.legend(fontsize=7)
        data.append(rec)
        print(name, rec, flush=True)
    for ax in axes.ravel()[len(args.scenes):]:
        ax.set_axis_off()

    info, cmd = machine_info(), command_line()
    md = (f"# Adaptive anti-aliasing, {args.renderer} renderer ({args.res}², box filter; reference: uniform "
          f"{args.ref_spp} spp)\n\n" + machine_markdown(info, cmd) + "\n"
          + f"Target: per scene, an adaptive setting reaches the relMSE of uniform 64 spp in <= {TARGET_TIME}x its "
          "time. Verdict: the cheapest adaptive setting at or below that relMSE (else the most accurate one).\n\n"
          + md_table(["scene", "cheapest setting reaching 64 spp", "relMSE ×64spp", "time ×64spp", "target"],
                     verdicts)
          + "\n\nAll rows: adaptive `threshold / depth`, uniform spp, and Mitsuba's own integrator where it "
          "renders the same image. `samples`: mean camera samples per pixel (adaptive: distinct lattice points "
          "a pixel uses; 4 = its corners only). FLIP: mean LDR-FLIP against the reference. Ratios are to "
          "uniform 64 spp of the same scene, measured in the same run.\n\n"
          + md_table(["scene", "setting", "samples", "refined", "time s", "relMSE", "FLIP", "relMSE ×64spp",
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
    from links1.sensor.filters import Filter
    if r.kind == "core":
        from dataclasses import replace
        r.scene.camera = replace(r.scene.camera, rfilter=Filter("box"))
    elif r.integrator.prepare(r.scene).rfilter.name != "box":
        raise SystemExit(f"{r.path}: the film's filter is not box")


def _picture(plt, img, name):
    from links1.imaging.image import linear_to_srgb
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
