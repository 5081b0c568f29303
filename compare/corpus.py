"""Every corpus scene in both renderers against Mitsuba's sampling restricted to Whitted's paths.

    python -m compare.corpus [--width 128] [--spp 4] [--seeds 16] [--ref-factor 16] [--only ID ...]
                             [--timeout 300] [--variant llvm_ad_rgb] [--stem corpus] [--update]

Scenes: every entry of ``tests/corpus/manifest.py`` whose files are here (the ones that cannot
be committed come from ``tools/fetch_corpus.py``; a missing one is listed as not fetched).
Each renders ``--width`` pixels wide, the file's aspect and horizontal field of view kept, with
the file's own film filter.

The reference is ``whitted_reference`` (tests/corpus/whitted_reference.py): Mitsuba's emitter
and BSDF sampling with MIS at each hit, recursion through delta lobes only, on the file loaded
by plain ``mi.load_file``, at links1's ``max_depth`` for the file (its integrator's, else 5)
plus one (Mitsuba counts the emitter's vertex). Per scene, in a process of its own (a crash or a hang costs one row):

* ``ref``: the reference at ``spp x ref-factor`` (seed 1): the image everything is judged by;
* ``mitsuba``: the reference at ``spp`` (seeds 2, 3, ...): Mitsuba's own error at equal spp;
* ``plugin``: ``links1_whitted`` (``links1_mitsuba``'s loader) at ``spp`` and its default depth
  (seeds 0, 1, ...);
* ``core``: the float64 core at ``spp`` (seed 0), in another process.

Mitsuba and the plugin render ``--seeds`` times: one seed's relMSE at a few spp is itself noisy
(a luminaire's edge or a firefly hit once more or less moves it by 2x), so their errors are
means over the seeds, the ratio given with its standard error. Reported per scene: relMSE
(``links1.imaging.diff.relmse``) of the plugin and of the core against ``ref``, the ratio
plugin / Mitsuba at equal spp (target: <= 1.5 where Whitted covers the scene's light paths),
relMSE(core, plugin) at seed 0 (target <= 1e-4: the core's verdict), each renderer's
frame time at ``spp`` (the second frame for the Dr.Jit ones, whose first compiles; the core's first),
the one-line warnings each renderer gave, and a verdict per renderer: ``ok`` (plugin: ratio <= 1.5;
core: relMSE(core, plugin) <= 1e-4), ``noisy`` (plugin: the ratio above 1.5 by less than two
standard errors and the ratio of the seeds' median relMSEs <= 1.5: a rare bright sample, such as
a point light's highlight seen in a mirror, hit at one seed more than Mitsuba's), ``differs``
(larger), ``fails`` (an error, a timeout or a non-finite image). Writes
``compare/results/<stem>.{json,md}``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
TARGET_RATIO = 1.5
TARGET_CORE = 1e-4


# ----------------------------------------------------------------------------- one job
def _timed(render):
    """Two frames (the first compiles); the image and time of the second."""
    render()
    t0 = time.perf_counter()
    img = render()
    return img, time.perf_counter() - t0


def _seeded(renderer, seed):
    """The renderer's image (RGB, float64) at another seed."""
    renderer.seed = seed
    return np.asarray(renderer.render(), dtype=np.float64)[..., :3]


def _job(job: dict) -> dict:
    """One scene, ``job["kind"]`` = ``mitsuba`` (reference, Mitsuba at equal spp, plugin) or
    ``core``; images into ``job["out"]`` (npz)."""
    sys.path[:0] = [str(ROOT), str(ROOT / "plugins")]
    from tests.corpus.manifest import SCENES
    sc = next(s for s in SCENES if s.id == job["id"])
    w, spp = job["width"], job["spp"]
    out, res = {}, {"ok": True}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        from links1_app.renderers import make_renderer
        if job["kind"] == "mitsuba":
            import links1_mitsuba
            links1_mitsuba.register(job["variant"])
            from tests.corpus.whitted_reference import render_reference
            from links1 import load_scene
            # links1's depth for the file (its integrator's max_depth, a wrapper's nested one,
            # else 5), counted as Mitsuba counts: one more
            kw = dict(width=w, params=dict(sc.params),
                      max_depth=load_scene(sc.local_path, **dict(sc.params)).max_depth + 1)
            t0 = time.perf_counter()
            out["ref"] = render_reference(sc.local_path, spp * job["ref_factor"], seed=1, **kw)
            res["ref_s"] = time.perf_counter() - t0
            res["height"] = int(out["ref"].shape[0])
            out["mitsuba"], res["mitsuba_s"] = _timed(
                lambda: render_reference(sc.local_path, spp, seed=2, **kw))
            out["mitsuba"] = np.stack([out["mitsuba"]] + [render_reference(sc.local_path, spp, seed=2 + k, **kw)
                                                          for k in range(1, job["seeds"])])
            try:
                r = make_renderer("mitsuba", sc.local_path, params=dict(sc.params), width=w,
                                  height=res["height"], spp=spp, variant=job["variant"])
                out["plugin"], res["plugin_s"] = _timed(lambda: np.asarray(r.render(), dtype=np.float64)[..., :3])
                out["plugin"] = np.stack([out["plugin"]] + [_seeded(r, k) for k in range(1, job["seeds"])])
            except Exception as e:  # the row records it; the reference still stands
                res["plugin_error"] = f"{type(e).__name__}: {str(e).splitlines()[0][:240] if str(e) else ''}"
        else:
            r = make_renderer("core", sc.local_path, params=dict(sc.params), width=w, height=job["height"],
                              spp=spp)
            t0 = time.perf_counter()   # one frame: the core compiles nothing
            out["core"] = np.asarray(r.render(), dtype=np.float64)[..., :3]
            res["core_s"] = time.perf_counter() - t0
    res["warnings"] = sorted({str(m.message).splitlines()[0][:200] for m in caught
                              if not issubclass(m.category, DeprecationWarning)})
    np.savez(job["out"], **out)
    return res


def _run(job: dict, timeout: float) -> tuple[dict, dict]:
    """``_job`` in a subprocess -> (result, images); a failure is ``{"ok": False, "error": ...}``."""
    with tempfile.TemporaryDirectory(prefix="links1-corpus-") as tmp:
        job = dict(job, out=os.path.join(tmp, "images.npz"))
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), str(ROOT / "plugins")]))
        try:
            p = subprocess.run([sys.executable, "-m", "compare.corpus", "--job", json.dumps(job)], cwd=ROOT,
                               env=env, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return {"ok": False, "error": f"timed out after {timeout:.0f} s"}, {}
        # (a line may begin with a terminal escape that Mitsuba's logger left behind)
        lines = [ln[ln.index('{"ok"'):] for ln in p.stdout.splitlines() if '{"ok"' in ln]
        if p.returncode != 0 or not lines:
            tail = [ln for ln in (p.stderr or p.stdout).strip().splitlines() if ln.strip()][-1:] or ["(no output)"]
            return {"ok": False, "error": f"exit {p.returncode}: {tail[0][:240]}"}, {}
        with np.load(job["out"]) as z:
            return json.loads(lines[-1]), {k: z[k] for k in z.files}


# ----------------------------------------------------------------------------- table
def _verdict(err, bound, error) -> str:
    if error:
        return "fails"
    if err is None or not np.isfinite(err):
        return "fails"
    return "ok" if err <= bound else "differs"


def _ratio_se(errs, mitsuba_errs) -> tuple[float, float]:
    """mean(errs) / mean(mitsuba_errs) and its standard error (delta method, independent seeds)."""
    a, b = np.asarray(errs, dtype=np.float64), np.asarray(mitsuba_errs, dtype=np.float64)
    r = a.mean() / b.mean()
    n = len(a)
    rel = (a.std(ddof=1) / a.mean()) ** 2 / n + (b.std(ddof=1) / b.mean()) ** 2 / n if n > 1 else np.nan
    return float(r), float(r * np.sqrt(rel))


def _relmses(images, ref) -> list[float]:
    """relMSE against ``ref`` of each seed's image (K, H, W, 3)."""
    from links1.imaging.diff import relmse
    return [float(relmse(img, ref)) for img in images]


def _scene_row(sc, args) -> dict:
    from links1.imaging.diff import relmse
    row = {"id": sc.id, "path": sc.path}
    if not os.path.exists(sc.local_path):
        row["skipped"] = "not fetched: run tools/fetch_corpus.py"
        return row
    base = dict(id=sc.id, width=args.width, spp=args.spp, ref_factor=args.ref_factor, variant=args.variant,
                seeds=args.seeds)
    mres, mimg = _run(dict(base, kind="mitsuba"), args.timeout)
    if not mres.get("ok"):
        row["skipped"] = f"reference: {mres['error']}"
        return row
    cres, cimg = _run(dict(base, kind="core", height=mres["height"]), args.timeout)
    ref = mimg["ref"]
    row.update(height=mres["height"], ref_s=mres["ref_s"], mitsuba_s=mres["mitsuba_s"],
               mitsuba_errs=_relmses(mimg["mitsuba"], ref), warnings_plugin=mres["warnings"],
               warnings_core=cres.get("warnings", []))
    row["mitsuba_err"] = float(np.mean(row["mitsuba_errs"]))
    for kind, img, res, err_key in (("plugin", mimg.get("plugin"), mres, "plugin_error"),
                                    ("core", cimg.get("core"), cres, "error")):
        error = res.get(err_key) if kind == "plugin" else (None if res.get("ok") else res.get("error"))
        if img is not None and not np.all(np.isfinite(img)):
            error = f"{int(np.sum(~np.isfinite(img)))} non-finite values"
        row[f"{kind}_err"] = None
        if img is not None and not error:
            errs = _relmses(img if kind == "plugin" else img[None], ref)
            row[f"{kind}_err"] = float(np.mean(errs))
            if kind == "plugin":
                row["plugin_errs"] = errs
                row["ratio"], row["ratio_se"] = _ratio_se(errs, row["mitsuba_errs"])
                row["ratio_median"] = float(np.median(errs) / np.median(row["mitsuba_errs"]))
        row[f"{kind}_s"] = res.get(f"{kind}_s")
        row[f"{kind}_error"] = error
    if row["plugin_err"] is not None and row["core_err"] is not None:
        row["core_vs_plugin"] = relmse(cimg["core"], mimg["plugin"][0])
    row["plugin_verdict"] = _verdict(row.get("ratio"), TARGET_RATIO, row["plugin_error"])
    if row["plugin_verdict"] == "differs" and row["ratio"] - 2.0 * row["ratio_se"] <= TARGET_RATIO \
            and row["ratio_median"] <= TARGET_RATIO:
        row["plugin_verdict"] = "noisy"   # above 1.5 by a few rare samples, not by two standard errors
    row["core_verdict"] = _verdict(row.get("core_vs_plugin"), TARGET_CORE, row["core_error"] or
                                   (None if row["plugin_err"] is not None else "no plugin image to compare"))
    return row


def _markdown(rows, args, info) -> str:
    from .common import fmt, machine_markdown, md_table
    head = ["scene", "plugin relMSE", "Mitsuba relMSE", "plugin / Mitsuba (± SE)", "of medians", "plugin", "core relMSE",
            "core vs plugin", "core", "plugin s", "Mitsuba s", "core s"]
    table, notes = [], []
    for r in rows:
        if "skipped" in r:
            notes.append(f"- `{r['id']}`: skipped ({r['skipped']})")
            continue
        ratio = None if r.get("ratio") is None else f"{fmt(r['ratio'])} ± {fmt(r['ratio_se'])}"
        table.append([f"`{r['id']}`", r["plugin_err"], r["mitsuba_err"], ratio, r.get("ratio_median"),
                      r["plugin_verdict"],
                      r["core_err"], r.get("core_vs_plugin"), r["core_verdict"],
                      r["plugin_s"], r["mitsuba_s"], r["core_s"]])
        for kind in ("plugin", "core"):
            if r[f"{kind}_error"]:
                notes.append(f"- `{r['id']}` {kind}: {r[f'{kind}_error']}")
            for w in r[f"warnings_{kind}"]:
                notes.append(f"- `{r['id']}` {kind} warns: {w}")
    verdicts = {k: {v: sum(1 for r in rows if r.get(f"{k}_verdict") == v) for v in ("ok", "noisy", "differs", "fails")}
                for k in ("plugin", "core")}
    summary = "; ".join(f"{k}: " + ", ".join(f"{n} {v}" for v, n in c.items()) for k, c in verdicts.items())
    return (f"# Corpus: both renderers against Whitted's paths in Mitsuba\n\n"
            f"{machine_markdown(info, args.command)}\n"
            f"{args.width} px wide, spp {args.spp}; reference `whitted_reference` at spp "
            f"{args.spp * args.ref_factor}; \"Mitsuba\" = the reference at spp {args.spp} (Mitsuba's own error at "
            f"equal spp); plugin and Mitsuba relMSE: means over {args.seeds} seeds, the core's at seed 0. "
            f"Verdicts: the plugin ok where its relMSE <= {TARGET_RATIO}x Mitsuba's (noisy: above by less than two "
            f"standard errors, the ratio of medians within), the core ok where "
            f"relMSE(core, plugin) <= {TARGET_CORE:g}. Times: one frame at spp "
            f"{args.spp}, compilation excluded.\n\n{summary}\n\n"
            + md_table(head, table) + ("\n" + "\n".join(notes) + "\n" if notes else ""))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--job", help=argparse.SUPPRESS)
    p.add_argument("--width", type=int, default=128)
    p.add_argument("--spp", type=int, default=4)
    p.add_argument("--seeds", type=int, default=16,
                   help="renders of Mitsuba and the plugin at equal spp (their errors are means)")
    p.add_argument("--ref-factor", type=int, default=16)
    p.add_argument("--only", nargs="*", default=None, metavar="ID")
    p.add_argument("--timeout", type=float, default=300)
    p.add_argument("--variant", default="llvm_ad_rgb")
    p.add_argument("--stem", default="corpus")
    p.add_argument("--update", action="store_true",
                   help="replace only the rows of the scenes rendered now in an existing <stem>.json")
    args = p.parse_args(argv)
    if args.job:
        print(json.dumps(_job(json.loads(args.job))))
        return 0
    sys.path.insert(0, str(ROOT))
    from tests.corpus.manifest import SCENES
    from .common import command_line, fmt, machine_info, write_results
    args.command = command_line()
    info = machine_info()
    rows = []
    for sc in SCENES:
        if args.only and sc.id not in args.only:
            continue
        row = _scene_row(sc, args)
        rows.append(row)
        print(f"{sc.id}: " + (row.get("skipped") or
              f"plugin {row['plugin_verdict']} ({fmt(row['plugin_err'])} vs {fmt(row['mitsuba_err'])}), "
              f"core {row['core_verdict']} ({fmt(row['core_err'])})"), flush=True)
    if args.update:
        from .common import RESULTS
        old = json.loads((RESULTS / f"{args.stem}.json").read_text())
        new = {r["id"]: r for r in rows}
        order = [sc.id for sc in SCENES]
        rows = sorted([new.pop(r["id"], r) for r in old["rows"]] + list(new.values()),
                      key=lambda r: order.index(r["id"]) if r["id"] in order else len(order))
        args.command = old["command"] + f" (rows {', '.join(args.only or [])} from `{args.command}`)"
        info = old["machine"]
    md = _markdown(rows, args, info)
    for path in write_results(args.stem, {"machine": info, "command": args.command, "rows": rows}, md):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
