"""Frame time and error of every renderer on every scene.

    python -m compare.bench [--quick] [--scenes fig4 many ...] [--renderers core links1-llvm ...]

For every scene of ``scenes/`` (Mitsuba-only ones included) and each renderer

* ``links1-llvm``: the links1_whitted Dr.Jit integrator on ``llvm_ad_rgb``;
* ``links1-cuda``: the same on ``cuda_ad_rgb``, only where a GPU works (skipped otherwise);
* ``core``: the float64 numpy core;
* ``mitsuba-direct``, ``mitsuba-path``: Mitsuba's own integrators, only on scenes built
  from Mitsuba plugins alone (path's ``max_depth`` = links1's + 1);

and every spp of the mode, it measures the **warm median frame time** (one warm-up frame,
then ``repeats`` timed frames in the same process; the warm-up frame's time is reported
as ``first``: it includes kernel compilation) and the error against a **converged
reference**: relative MSE (``links1.imaging.diff.relmse``), max abs, and mean LDR-FLIP
(flip-evaluator).

Reference: the core at ``ref_spp`` (256; 64 with ``--quick``) with seed
:data:`REF_SEED` (a different stratified pattern from the measured renders' seed 0); on a
Mitsuba-only scene the Mitsuba integrator the file names (``direct`` or ``path``; the
Mitsuba-only scenes are built so that it computes what Whitted recursion computes: Mitsuba
``path`` on a diffuse scene would add indirect light, which Whitted has not) at ``ref_spp``
with the same seed. The reference traces every branch (``min_weight = 0``); the measured
renders use each renderer's default weight threshold (1/255).

Ratios: time of each renderer / time of the Mitsuba integrator the scene file names,
measured in the same run at the same spp (Mitsuba-only scenes only; elsewhere Mitsuba
cannot render the scene), and links1-llvm / core everywhere.

Each render job runs in its own process with a time limit; a job over the limit (e.g. a
kernel that takes minutes to compile) is reported as skipped with the reason.

Writes ``compare/results/bench[_quick].{json,md,png}``.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from . import common
from .common import RENDERERS, SCENES, fmt, md_table

#: Seed of the reference renders (measured renders use seed 0).
REF_SEED = 1

MODES = {
    #        film res, spp list,        repeats, reference spp, seconds per job, overall budget
    "quick": dict(res=24, spp=[1, 4, 16], repeats=2, ref_spp=64, timeout=25, budget=150),
    "full": dict(res=64, spp=[1, 4, 16, 64], repeats=5, ref_spp=256, timeout=600, budget=None),
}


def scene_paths(names=None) -> list[Path]:
    # Mitsuba-only scenes first (the ratios to Mitsuba), the costliest scenes last (a --quick
    # budget then cuts those).
    last = {"bicubic": 1, "many": 2}
    paths = sorted(SCENES.glob("*.xml"),
                   key=lambda p: (not common.mitsuba_only(p), last.get(p.stem, 0), p.stem))
    if names:
        want = []
        for n in names:
            p = Path(n)
            if not p.suffix:
                p = SCENES / f"{n}.xml"
            if not p.exists():
                raise SystemExit(f"bench: no scene {n!r} (looked for {p})")
            want.append(p.resolve())
        return want
    return paths


def renderer_plan(path: Path, wanted) -> list[tuple[str, str | None]]:
    """(renderer, reason-if-skipped) for a scene."""
    only_mi = common.mitsuba_only(path)
    plan = []
    mi_ok, mi_why = _mitsuba_status()
    for r in wanted:
        why = None
        if r in ("mitsuba-direct", "mitsuba-path") and not only_mi:
            why = "the scene uses links1 plugins, which Mitsuba's integrators cannot load"
        elif r != "core" and not mi_ok:
            why = mi_why
        elif r == "links1-cuda" and not _cuda_status()[0]:
            why = _cuda_status()[1]
        elif r.startswith("links1-") and not _plugin_status()[0]:
            why = _plugin_status()[1]
        plan.append((r, why))
    return plan


_STATUS: dict = {}


def _mitsuba_status():
    if "mi" not in _STATUS:
        try:
            import mitsuba as mi
            ok = "llvm_ad_rgb" in mi.variants()
            _STATUS["mi"] = (ok, None if ok else "mitsuba has no llvm_ad_rgb variant")
        except Exception as e:  # noqa: BLE001
            _STATUS["mi"] = (False, f"mitsuba unavailable: {e}")
    return _STATUS["mi"]


def _cuda_status():
    if "cuda" not in _STATUS:
        gpu = common.gpu_name()
        _STATUS["cuda"] = (gpu is not None, None if gpu else "no CUDA GPU on this machine")
    return _STATUS["cuda"]


def _plugin_status():
    if "plugin" not in _STATUS:
        try:
            from links1_app.renderers import make_renderer  # noqa: F401
            import links1_mitsuba  # noqa: F401
            _STATUS["plugin"] = (True, None)
        except Exception as e:  # noqa: BLE001
            _STATUS["plugin"] = (False, f"links1_mitsuba unavailable: {e}")
    return _STATUS["plugin"]


def errors(img, ref) -> dict:
    from links1.imaging import diff
    out = {"relmse": diff.relmse(img, ref), "max_abs": diff.max_error(img, ref)}
    try:
        out["flip"] = diff.flip(img.astype(np.float32), ref.astype(np.float32), ldr=True)
    except Exception as e:  # noqa: BLE001 - FLIP is optional
        out["flip"] = None
        out["flip_error"] = str(e)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m compare.bench", description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="small film and spp: < 3 minutes")
    ap.add_argument("--scenes", nargs="*", help="scene names (scenes/<name>.xml) or paths")
    ap.add_argument("--renderers", nargs="*", choices=RENDERERS, default=list(RENDERERS))
    ap.add_argument("--res", type=int, help="film width and height (default: by mode)")
    ap.add_argument("--spp", type=int, nargs="*", help="spp list (default: by mode)")
    ap.add_argument("--repeats", type=int)
    ap.add_argument("--ref-spp", type=int)
    ap.add_argument("--timeout", type=float, help="seconds per render job")
    ap.add_argument("--stem", help="results file stem (default bench / bench_quick)")
    a = ap.parse_args(argv)
    mode = dict(MODES["quick" if a.quick else "full"])
    for k in ("res", "spp", "repeats", "ref_spp", "timeout"):
        if getattr(a, k) is not None:
            mode[k] = getattr(a, k)
    stem = a.stem or ("bench_quick" if a.quick else "bench")
    t_start = time.perf_counter()
    info = common.machine_info()
    command = common.command_line()
    print(f"bench: {command}\n  mode {mode}", file=sys.stderr)

    scenes_out = []
    for path in scene_paths(a.scenes):
        name = path.stem
        params = {"res": mode["res"]}
        only_mi = common.mitsuba_only(path)
        entry = {"scene": name, "path": str(path.relative_to(common.ROOT)), "mitsuba_only": only_mi,
                 "renderers": {}}
        # --- reference
        ref_kind = _scene_integrator(path) if only_mi else "core"
        if ref_kind != "core" and not _mitsuba_status()[0]:
            ref_kind = "core"
        ref = common.run_job({"scene": str(path), "renderer": ref_kind, "params": params,
                              "spp": [mode["ref_spp"]], "repeats": 0, "seed": REF_SEED,
                              "min_weight": 0.0},
                             timeout=max(mode["timeout"], 120))
        if not ref.get("ok"):
            entry["reference"] = {"renderer": ref_kind, "skipped": ref.get("reason")}
            print(f"  {name}: reference failed: {ref.get('reason')}", file=sys.stderr)
            scenes_out.append(entry)
            continue
        ref_img = ref["images"][mode["ref_spp"]]
        common.check_finite(ref_img, f"{name} reference")
        entry["reference"] = {"renderer": ref_kind, "spp": mode["ref_spp"], "seed": REF_SEED,
                              "time_s": ref["results"][0]["first_s"]}
        # --- renderers
        for rname, why in renderer_plan(path, a.renderers):
            if why is None and mode.get("budget") and time.perf_counter() - t_start > mode["budget"]:
                why = f"the --quick time budget ({mode['budget']} s) was spent"
            if why is not None:
                entry["renderers"][rname] = {"skipped": why}
                continue
            res = common.run_job({"scene": str(path), "renderer": rname, "params": params,
                                  "spp": mode["spp"], "repeats": mode["repeats"], "seed": 0},
                                 timeout=mode["timeout"])
            if not res.get("ok"):
                entry["renderers"][rname] = {"skipped": res.get("reason")}
                print(f"  {name} {rname}: skipped: {res.get('reason')}", file=sys.stderr)
                continue
            rows = []
            for r in res["results"]:
                img = res["images"][r["spp"]]
                row = {k: r[k] for k in ("spp", "first_s", "times", "median_s", "finite")}
                if r.get("rays"):
                    npix = img.shape[0] * img.shape[1]
                    row["rays_per_pixel"] = sum(r["rays"].values()) / npix
                    row["rays"] = r["rays"]
                if r["finite"]:
                    row.update(errors(img, ref_img))
                rows.append(row)
                print(f"  {name} {rname} spp={r['spp']}: median {r['median_s']:.4f} s "
                      f"relmse {row.get('relmse', float('nan')):.3g}", file=sys.stderr)
            entry["renderers"][rname] = {"load_s": res["load_s"], "peak_rss_mib": res["peak_rss_mib"],
                                         "rows": rows}
        _ratios(entry)
        scenes_out.append(entry)

    payload = {"machine": info, "command": command, "mode": mode, "ref_seed": REF_SEED,
               "wall_s": time.perf_counter() - t_start, "scenes": scenes_out}
    md = _markdown(payload)
    fig = _plot(scenes_out)
    paths = common.write_results(stem, payload, md, fig)
    print(md)
    print("wrote " + ", ".join(str(p.relative_to(common.ROOT)) for p in paths), file=sys.stderr)
    return 0


def _scene_integrator(path) -> str:
    """``mitsuba-direct`` or ``mitsuba-path``: the integrator a Mitsuba-only file names."""
    import xml.etree.ElementTree as ET
    integ = ET.parse(path).getroot().find("integrator")
    kind = integ.attrib.get("type") if integ is not None else "path"
    return f"mitsuba-{kind}" if kind in ("direct", "path") else "mitsuba-path"


def _ratios(entry):
    """time / Mitsuba's time (the integrator the file names) and links1-llvm / core."""
    rs = entry["renderers"]
    base_name = None
    if entry["mitsuba_only"]:
        base_name = _scene_integrator(common.ROOT / entry["path"])
        if base_name not in rs or "rows" not in rs[base_name]:
            base_name = next((k for k in ("mitsuba-direct", "mitsuba-path") if "rows" in rs.get(k, {})), None)
    entry["mitsuba_baseline"] = base_name
    base = {r["spp"]: r["median_s"] for r in rs.get(base_name, {}).get("rows", [])} if base_name else {}
    core = {r["spp"]: r["median_s"] for r in rs.get("core", {}).get("rows", [])}
    for k, v in rs.items():
        for r in v.get("rows", []):
            if r["spp"] in base:
                r["ratio_to_mitsuba"] = r["median_s"] / base[r["spp"]]
            if r["spp"] in core:
                r["ratio_to_core"] = r["median_s"] / core[r["spp"]]


def _markdown(p) -> str:
    m = p["mode"]
    out = [f"# Benchmark: frame time and error ({'quick' if m.get('budget') else 'full'} mode)\n",
           common.machine_markdown(p["machine"], p["command"]),
           f"\nFilm {m['res']}×{m['res']}; warm median of {m['repeats']} frames after one warm-up "
           f"frame (`first` = the warm-up frame, kernel compilation included); reference = core "
           f"(on Mitsuba-only scenes: the Mitsuba integrator the file names) at {m['ref_spp']} spp, seed {p['ref_seed']}, "
           f"min_weight 0 (measured renders: the renderers' default 1/255). "
           f"relMSE = mean((x−ref)²/(ref²+0.01)); FLIP = mean LDR-FLIP. "
           f"×mi = time / the scene's own Mitsuba integrator's time at the same spp, same run; "
           f"×core = time / core time. The machine is shared (2 cores): timings are noisy. "
           f"Run took {p['wall_s']:.0f} s.\n"]
    for e in p["scenes"]:
        out.append(f"\n## {e['scene']}\n")
        ref = e.get("reference", {})
        if "skipped" in ref:
            out.append(f"Reference failed: {ref['skipped']}\n")
            continue
        rows, skipped = [], []
        for rname, v in e["renderers"].items():
            if "skipped" in v:
                skipped.append(f"- {rname}: skipped: {v['skipped']}")
                continue
            for r in v["rows"]:
                rows.append([rname, r["spp"], r["median_s"] * 1e3, r["first_s"] * 1e3,
                             r.get("ratio_to_mitsuba"), r.get("ratio_to_core"),
                             r.get("rays_per_pixel"), r.get("relmse"), r.get("max_abs"),
                             r.get("flip"), "yes" if r["finite"] else "NO"])
        out.append(md_table(["renderer", "spp", "median ms", "first ms", "×mi", "×core",
                             "rays/px", "relMSE", "max abs", "FLIP", "finite"], rows))
        if skipped:
            out.append("\n" + "\n".join(skipped) + "\n")
    return "".join(out)


def _plot(scenes):
    plt = common.pyplot()
    n = len(scenes)
    cols = min(4, max(1, n))
    nrows = (n + cols - 1) // cols
    fig, axes = plt.subplots(nrows, cols, figsize=(4 * cols, 3.2 * nrows), squeeze=False)
    for ax, e in zip(axes.flat, scenes):
        ax.set_title(e["scene"], fontsize=10)
        for rname, v in e.get("renderers", {}).items():
            rows = [r for r in v.get("rows", []) if r.get("relmse")]
            if not rows:
                continue
            x = [r["median_s"] for r in rows]
            y = [r["relmse"] for r in rows]
            ax.loglog(x, y, "o-", label=rname)
            for r in rows:
                ax.annotate(str(r["spp"]), (r["median_s"], r["relmse"]), fontsize=6)
        ax.set_xlabel("warm median frame time [s]", fontsize=8)
        ax.set_ylabel("relMSE vs reference", fontsize=8)
        ax.tick_params(labelsize=7)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    fig.tight_layout()
    return fig


if __name__ == "__main__":
    sys.exit(main())
