"""``links1_whitted`` against Mitsuba's own ``direct`` on real scenes, on the CPU.

    python -m compare.vs_direct [--width 512] [--spp 1 16] [--repeats 7] [--variant llvm_ad_rgb]
                                [--only ID ...] [--profile]

Scenes: every corpus scene of ``tests/corpus/manifest.py`` expected to render as ``direct``
whose emitters are all delta lights (point, spot, directional; a scene with an area or
environment light is listed as skipped, with why), and ``compare.scaling.quadric_scene(10,
mitsuba_shapes=True)`` at 512² (``spheres10``). The corpus scenes that cannot be committed come
from ``tools/fetch_corpus.py`` (into the git-ignored ``tests/corpus/external/``); a missing one
is skipped, saying so.

Each scene renders with its own film filter and, where that is ``box``, once more with
``gaussian`` (Mitsuba's default; the file's ``<rfilter type="box"/>`` replaced in a temporary
copy next to it), ``--width`` pixels wide (the file's aspect and horizontal field of view kept).

Per scene, filter and spp, one scene object in one process renders

* ``links1``: ``mi.render(scene)`` with the scene's ``links1_whitted`` at ``max_depth`` 1.
  Every scene here is diffuse (Lambertian ``diffuse``, textured or not) under delta lights,
  where a Whitted ray tree has no secondary rays: depth 1 is the eye ray plus one shadow ray
  per light, which is what ``direct`` computes. (A larger ``max_depth`` gives the same image;
  it only makes the kernels carry reflection/refraction branches that are never taken.)
* ``direct``: ``mi.render(scene, integrator=direct)`` with ``emitter_samples`` 1 and
  ``bsdf_samples`` 0: for a delta light, BSDF sampling cannot find it, so this is the same work
  (one emitter sample, one shadow ray per sample; with several lights ``direct`` samples one
  light per sample where links1 traces a shadow ray to each).

one warm-up frame each (compilation), then ``rounds`` × ``repeats`` frames alternating links1 / direct; each
frame's tensor is kept on the device (``dr.eval`` + ``dr.sync_thread``, never copied to numpy),
as ``compare/host_overhead.py``. Reported: per integrator the best round's median, their ratio
(links1 / direct) and the range of the per-round ratios (each round's frames interleaved).
Targets: every scene ≤ 0.5× at spp 1 and 16; ``spheres10`` ≤ 0.8× at spp 1.

Agreement: at the highest spp, ``relMSE(links1, direct)`` between the two frames, and both
against a ``direct`` reference at 16× that spp (``links1.imaging.diff.relmse``): links1's error must be
of the order of ``direct``'s own (both are then noise, not a different image).

``--profile``: per spp, the case with the worst ratio and the worst with a box filter (or each
``--profile-case ID:FILTER:SPP``) is
rendered ``repeats`` more frames under ``cProfile`` with ``dr.kernel_history``: wall time,
kernel time (summed ``execution_time``) and host = wall − kernels, the kernels grouped by hash,
and the top host functions. Writes ``compare/results/vs_direct.{json,md}``.
"""
from __future__ import annotations

import argparse
import cProfile
import io
import json
import os
import platform
import pstats
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from compare.common import kernel_history_of

RESULTS = Path(__file__).resolve().parent / "results"
ROOT = Path(__file__).resolve().parent.parent
MAX_DEPTH = 1


# ----------------------------------------------------------------------------- scenes
def _corpus():
    sys.path.insert(0, str(ROOT))
    from tests.corpus.manifest import SCENES
    return [s for s in SCENES if s.expect == "direct"]


def _rfilter_name(scene) -> str:
    f = scene.sensors()[0].film().rfilter()
    name = f.class_name() if hasattr(f, "class_name") else str(f).split("[")[0]
    return name.lower().removesuffix("filter")


def _delta_only(scene) -> str | None:
    """None if every emitter is a delta light, else why not."""
    import mitsuba as mi
    for e in scene.emitters():
        if not mi.has_flag(e.flags(), mi.EmitterFlags.Delta):
            return f"non-delta emitter {type(e).__name__} ({str(e).splitlines()[0].strip()})"
    if not scene.emitters():
        return "no emitter"
    return None


def _resize(scene, width: int):
    """``width`` pixels wide, the film's aspect and ``x_fov`` kept; the crop = the whole film."""
    from links1_mitsuba.renderer import resize_film
    sensor = scene.sensors()[0]
    W, H = (int(v) for v in sensor.film().size())
    h = max(1, int(round(width * H / W)))
    resize_film(sensor, width, h)
    return width, h


def _load(sc_or_xml, rfilter: str | None, variant: str):
    """Load a corpus scene (or the quadric scene's XML) with links1_whitted; ``rfilter``:
    replace the file's ``<rfilter type="box"/>`` with that filter (temporary copy next to it)."""
    import links1_mitsuba as lm
    lm.register(variant)
    if isinstance(sc_or_xml, str):
        xml = sc_or_xml
        if rfilter:
            if xml.count('<rfilter type="box"/>') != 1:
                raise RuntimeError("quadric_scene's film no longer has one box filter")
            xml = xml.replace('<rfilter type="box"/>', f'<rfilter type="{rfilter}"/>')
        scene = lm.load_string(xml, links1_integrator="links1", variant=variant, res=512)
    else:
        path = sc_or_xml.local_path
        if not rfilter:
            scene = lm.load_file(path, links1_integrator="links1", variant=variant)
        else:
            text = Path(path).read_text()
            if text.count('<rfilter type="box"/>') != 1:
                raise RuntimeError(f"{sc_or_xml.id}: no single <rfilter type=\"box\"/> in {path}")
            fd, tmp = tempfile.mkstemp(suffix=".xml", prefix=".vs_direct_", dir=os.path.dirname(path))
            try:
                with os.fdopen(fd, "w") as f:
                    f.write(text.replace('<rfilter type="box"/>', f'<rfilter type="{rfilter}"/>'))
                scene = lm.load_file(tmp, links1_integrator="links1", variant=variant)
            finally:
                os.unlink(tmp)
    scene.integrator().max_depth = MAX_DEPTH
    return scene


def _cases(only):
    from .scaling import quadric_scene
    cases, skipped = [], []
    for sc in _corpus():
        if only and sc.id not in only:
            continue
        if not os.path.exists(sc.local_path):
            skipped.append(dict(id=sc.id, why="not fetched: run tools/fetch_corpus.py (tests/corpus/external/)"))
            continue
        cases.append((sc.id, sc))
    if not only or "spheres10" in only:
        cases.append(("spheres10", quadric_scene(10, mitsuba_shapes=True)))
    return cases, skipped


# ----------------------------------------------------------------------------- timing
def _frame(scene, integ, spp, seed=0):
    import drjit as dr
    import mitsuba as mi
    img = mi.render(scene, spp=spp, seed=seed) if integ is None else \
        mi.render(scene, integrator=integ, spp=spp, seed=seed)
    dr.eval(img)
    dr.sync_thread()
    return img


def _timed(scene, integ, spp):
    t0 = time.perf_counter()
    img = _frame(scene, integ, spp)
    return time.perf_counter() - t0, img


def _rgb(img) -> np.ndarray:
    return np.asarray(img, dtype=np.float64)[..., :3]


def measure(scene, spps, repeats: int, ref_factor: int, rounds: int = 1) -> dict:
    import mitsuba as mi
    from links1.imaging.diff import relmse
    direct = mi.load_dict({"type": "direct", "emitter_samples": 1, "bsdf_samples": 0})
    out = {}
    for spp in spps:
        _frame(scene, None, spp)          # warm-up: compilation, prepared tables
        _frame(scene, direct, spp)
        per_round = []
        for _ in range(rounds):
            tl, td = [], []
            for _ in range(repeats):
                t, img_l = _timed(scene, None, spp)
                tl.append(t)
                t, img_d = _timed(scene, direct, spp)
                td.append(t)
            per_round.append((1e3 * float(np.median(tl)), 1e3 * float(np.median(td)),
                              [1e3 * t for t in tl], [1e3 * t for t in td]))
        # the best round of each (the least disturbed by the machine's other load); the ratio
        # of those, and the range of the per-round ratios (each from interleaved frames)
        ml, md = min(r[0] for r in per_round), min(r[1] for r in per_round)
        ratios = [r[0] / r[1] for r in per_round]
        out[spp] = dict(links1_ms=ml, direct_ms=md, ratio=ml / md, round_ratios=ratios,
                        links1_round_ms=[r[0] for r in per_round], direct_round_ms=[r[1] for r in per_round],
                        links1_all_ms=[r[2] for r in per_round], direct_all_ms=[r[3] for r in per_round])
    hi = max(spps)
    a, b = _rgb(_frame(scene, None, hi)), _rgb(_frame(scene, direct, hi, seed=1))
    ref = _rgb(_frame(scene, direct, hi * ref_factor, seed=2))
    agree = dict(spp=hi, ref_spp=hi * ref_factor, links1_vs_direct=float(relmse(a, b)),
                 links1_vs_ref=float(relmse(a, ref)), direct_vs_ref=float(relmse(b, ref)),
                 finite=bool(np.all(np.isfinite(a))))
    return dict(timing=out, agree=agree)


# ----------------------------------------------------------------------------- profile
def _ir_features(ir) -> dict:
    """What a kernel does, read from its LLVM IR: float64 / float32 instructions, gathers,
    scatters and the functions it calls (ray tracing, vcalls, ``exp``...)."""
    import re
    if hasattr(ir, "getvalue"):   # Dr.Jit hands the IR over as a StringIO
        ir = ir.getvalue()
    if not isinstance(ir, str) or not ir:
        return dict(f64=0, f32=0, gathers=0, scatters=0, calls="")
    callees = {}
    for m in re.finditer(r"call [^@]*@([\w.$]+)", ir):
        name = m.group(1)
        if name.startswith("llvm.") and not any(t in name for t in ("exp", "log", "sin", "cos", "sqrt")):
            continue
        callees[name] = callees.get(name, 0) + 1
    calls = ", ".join(f"{n}×{c}" if c > 1 else n for n, c in sorted(callees.items(), key=lambda kv: -kv[1])[:5])
    return dict(f64=len(re.findall(r"= f\w+ [^\n]*double", ir)), f32=len(re.findall(r"= f\w+ [^\n]*float", ir)),
                gathers=ir.count("masked.gather"), scatters=ir.count("masked.scatter"), calls=calls)


def profile(scene, spp: int, repeats: int) -> dict:
    import mitsuba as mi
    direct = mi.load_dict({"type": "direct", "emitter_samples": 1, "bsdf_samples": 0})
    res = {}
    for name, integ in (("links1", None), ("direct", direct)):
        _frame(scene, integ, spp)
        walls, kern, groups = [], [], {}
        pr = cProfile.Profile()
        for _ in range(repeats):
            pr.enable()
            wall, hist = kernel_history_of(lambda: _frame(scene, integ, spp))
            pr.disable()
            walls.append(wall)
            ks = 0.0
            for k in hist:
                t = float(k.get("execution_time", 0.0))
                ks += t
                key = str(k.get("hash", "?"))
                g = groups.setdefault(key, dict(hash=key, type=str(k.get("type", "")), launches=0, ms=0.0,
                                                size=int(k.get("size", 0) or 0),
                                                ops=int(k.get("operation_count", 0) or 0),
                                                ins=int(k.get("input_count", 0) or 0),
                                                outs=int(k.get("output_count", 0) or 0),
                                                **_ir_features(k.get("ir"))))
                g["launches"] += 1
                g["ms"] += t
            kern.append(ks / 1e3)
        s = io.StringIO()
        st = pstats.Stats(pr, stream=s)
        st.sort_stats("tottime").print_stats(12)
        top = []
        for (fn, line, func), (cc, nc, tt, ct, _) in sorted(st.stats.items(), key=lambda kv: -kv[1][2])[:12]:
            top.append(dict(func=f"{os.path.relpath(fn, ROOT) if fn.startswith(str(ROOT)) else os.path.basename(fn)}"
                                 f":{line}({func})", calls=nc / repeats, tottime_ms=1e3 * tt / repeats,
                            cumtime_ms=1e3 * ct / repeats))
        ks = sorted(groups.values(), key=lambda g: -g["ms"])
        for g in ks:
            g["launches_per_frame"] = g.pop("launches") / repeats
            g["ms_per_frame"] = g.pop("ms") / repeats
        wall = 1e3 * float(np.median(walls))
        kms = 1e3 * float(np.median(kern))
        res[name] = dict(wall_ms=wall, kernels_ms=kms, host_ms=wall - kms, kernels=ks[:10], n_kernels=len(ks),
                         host_top=top)
    return res


# ----------------------------------------------------------------------------- main
def _fmt_err(x):
    return f"{x:.2e}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m compare.vs_direct", description=__doc__.split("\n\n")[0])
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--spp", type=int, nargs="+", default=[1, 16])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--ref-factor", type=int, default=16)
    ap.add_argument("--rounds", type=int, default=2, help="rounds of repeats frames per case (best median kept)")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--only", nargs="*", default=None, help="scene ids (corpus ids, spheres10)")
    ap.add_argument("--profile", action="store_true",
                    help="profile, per spp, the worst ratio and the worst with a box filter")
    ap.add_argument("--profile-case", action="append", default=None, metavar="ID:FILTER:SPP",
                    help="profile this case instead (repeatable), e.g. spheres10:box:1")
    ap.add_argument("--out", default=str(RESULTS / "vs_direct"))
    a = ap.parse_args(argv)
    import drjit as dr
    cases, skipped = _cases(set(a.only) if a.only else None)
    rows = []
    scenes_kept = {}
    for sid, src in cases:
        base = _load(src, None, a.variant)
        why = _delta_only(base)
        if why:
            skipped.append(dict(id=sid, why=why))
            print(f"{sid}: skipped: {why}", flush=True)
            continue
        own = _rfilter_name(base)
        variants = [(own, False)] + ([("gaussian", True)] if own == "box" else [])
        for fname, replaced in variants:
            scene = base if not replaced else _load(src, "gaussian", a.variant)
            w, h = (512, 512) if sid == "spheres10" else _resize(scene, a.width)
            if sid == "spheres10":
                w, h = (int(v) for v in scene.sensors()[0].film().size())
            r = measure(scene, a.spp, a.repeats, a.ref_factor, a.rounds)
            row = dict(id=sid, rfilter=fname, own_filter=not replaced, width=w, height=h,
                       lights=sorted({e.class_name().removesuffix("Light").removesuffix("Emitter").lower()
                                      for e in scene.emitters()}),
                       n_lights=len(scene.emitters()), **r)
            rows.append(row)
            scenes_kept[f"{sid}:{fname}"] = scene
            t = r["timing"]
            print(f"{sid:22s} {fname:8s} {w}x{h} " + "  ".join(
                f"spp {s}: links1 {t[s]['links1_ms']:7.1f} ms direct {t[s]['direct_ms']:7.1f} ms "
                f"ratio {t[s]['ratio']:.2f} ({min(t[s]['round_ratios']):.2f}–{max(t[s]['round_ratios']):.2f})"
                for s in a.spp)
                + f"  relMSE(l,d) {r['agree']['links1_vs_direct']:.2e} l/ref {r['agree']['links1_vs_ref']:.2e} "
                  f"d/ref {r['agree']['direct_vs_ref']:.2e}", flush=True)
            if replaced:
                del scene
            dr.sync_thread()
    profs = []
    if (a.profile or a.profile_case) and rows:
        if a.profile_case:
            todo = []
            for c in a.profile_case:
                sid, fname, spp = c.split(":")
                todo.append((f"{sid}:{fname}", int(spp)))
        else:   # per spp: the worst ratio, and the worst with the scene's own box filter
            todo = []
            for spp in a.spp:
                for pool in (rows, [r for r in rows if r["rfilter"] == "box"]):
                    if pool:
                        w = max(pool, key=lambda r: r["timing"][spp]["ratio"])
                        if (f"{w['id']}:{w['rfilter']}", spp) not in todo:
                            todo.append((f"{w['id']}:{w['rfilter']}", spp))
        for key, spp in todo:
            prof = dict(case=key, spp=spp, repeats=a.repeats, **profile(scenes_kept[key], spp, a.repeats))
            profs.append(prof)
            p = prof["links1"]
            print(f"profile {key} spp {spp}: links1 wall {p['wall_ms']:.1f} kernels {p['kernels_ms']:.1f} host "
                  f"{p['host_ms']:.1f} ms; direct wall {prof['direct']['wall_ms']:.1f} kernels "
                  f"{prof['direct']['kernels_ms']:.1f} ms", flush=True)
    import drjit
    import mitsuba
    cpu = platform.processor() or platform.machine()
    try:
        cpu = next(ln.split(":", 1)[1].strip() for ln in open("/proc/cpuinfo") if ln.startswith("model name"))
    except (OSError, StopIteration):
        pass
    machine = (f"{platform.node()} ({cpu}, {os.cpu_count()} cores shared with other jobs, "
               f"load {os.getloadavg()[0]:.1f}), {a.variant}, Mitsuba {mitsuba.__version__}, Dr.Jit {drjit.__version__}")
    cmd = "python -m compare.vs_direct " + " ".join(argv if argv is not None else sys.argv[1:])
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    # json keys must be strings
    for r in rows:
        r["timing"] = {str(k): v for k, v in r["timing"].items()}
    out.with_suffix(".json").write_text(json.dumps(dict(machine=machine, command=cmd.strip(), repeats=a.repeats,
                                                        width=a.width, spp=a.spp, max_depth=MAX_DEPTH, rows=rows,
                                                        skipped=skipped, profiles=profs), indent=1))
    out.with_suffix(".md").write_text(_markdown(rows, skipped, profs, a, machine, cmd.strip()))
    print(f"wrote {out.with_suffix('.md')}")
    return 0


def _target(row, spp) -> float | None:
    if row["id"] == "spheres10":
        return 0.8 if spp == 1 else None
    return 0.5


def _markdown(rows, skipped, profs, a, machine, cmd) -> str:
    spps = a.spp
    md = ["# links1_whitted against Mitsuba `direct` on the CPU\n\n",
          f"`{cmd}` on {machine}.\n\n",
          f"`mi.render(scene, spp=…)` of one scene object, {a.width} px wide (aspect and field of view kept; "
          "`spheres10` = `compare.scaling.quadric_scene(10, mitsuba_shapes=True)` at 512²), links1_whitted at "
          f"max_depth {MAX_DEPTH} against `direct` (emitter_samples 1, bsdf_samples 0), warm medians of "
          f"{a.repeats} frames alternating the two ({a.rounds} rounds: the best round's median of each), the tensor "
          "kept on the device (`dr.eval` + `dr.sync_thread`). ratio = links1 / direct (in brackets: the range "
          "of the per-round ratios); target ≤ 0.5 (`spheres10`: ≤ 0.8 at spp 1). "
          "relMSE: links1 against direct at the same spp, and each against a direct reference at "
          f"{a.ref_factor}× the spp.\n\n"]
    head = "| scene | filter | size | lights | " + " | ".join(
        f"spp {s} links1 ms | spp {s} direct ms | spp {s} ratio" for s in spps) + \
        f" | relMSE links1–direct (spp {max(spps)}) | links1–ref | direct–ref |\n"
    md.append(head)
    md.append("| " + " | ".join(["---"] * (4 + 3 * len(spps) + 3)) + " |\n")
    for r in rows:
        cells = [f"`{r['id']}`", r["rfilter"] + ("" if r["own_filter"] else " (replaced)"),
                 f"{r['width']}×{r['height']}", f"{r['n_lights']} {'/'.join(r['lights'])}"]
        for s in spps:
            t = r["timing"][str(s)]
            tg = _target(r, s)
            mark = "" if tg is None else (" ✓" if t["ratio"] <= tg else " ✗")
            rr = t["round_ratios"]
            spread = f" ({min(rr):.2f}–{max(rr):.2f})" if len(rr) > 1 else ""
            cells += [f"{t['links1_ms']:.1f}", f"{t['direct_ms']:.1f}", f"**{t['ratio']:.2f}**{mark}{spread}"]
        g = r["agree"]
        cells += [_fmt_err(g["links1_vs_direct"]), _fmt_err(g["links1_vs_ref"]), _fmt_err(g["direct_vs_ref"])]
        md.append("| " + " | ".join(cells) + " |\n")
    if skipped:
        md.append("\nSkipped: " + "; ".join(f"`{s['id']}` ({s['why']})" for s in skipped) + ".\n")
    for prof in profs:
        md.append(f"\n## Profile: `{prof['case']}`, spp {prof['spp']} ({prof['repeats']} frames, cProfile + "
                  "`dr.kernel_history`)\n\n")
        for name in ("links1", "direct"):
            p = prof[name]
            md.append(f"**{name}**: wall {p['wall_ms']:.1f} ms, kernels {p['kernels_ms']:.1f} ms "
                      f"({p['n_kernels']} distinct), host = wall − kernels {p['host_ms']:.1f} ms.\n\n")
            md.append("| kernel hash | launches/frame | size | ops | in / out arrays | f64 / f32 insns | gathers / scatters "
                      "| calls | ms/frame |\n| --- | --- | --- | --- | --- | --- | --- | --- | --- |\n")
            for k in p["kernels"][:8]:
                md.append(f"| `{k['hash'][:12]}` | {k['launches_per_frame']:.1f} | {k['size']} | {k['ops']} | "
                          f"{k['ins']} / {k['outs']} | {k['f64']} / {k['f32']} | {k['gathers']} / {k['scatters']} | {k['calls'] or '—'} | "
                          f"{k['ms_per_frame']:.2f} |\n")
            if name == "links1":
                md.append("\n| host function (own time) | calls/frame | own ms/frame | cum ms/frame |\n"
                          "| --- | --- | --- | --- |\n")
                for f in p["host_top"][:10]:
                    md.append(f"| `{f['func']}` | {f['calls']:.1f} | {f['tottime_ms']:.2f} | {f['cumtime_ms']:.2f} |\n")
            md.append("\n")
    return "".join(md)


if __name__ == "__main__":
    raise SystemExit(main())
