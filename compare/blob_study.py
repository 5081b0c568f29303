"""Blob solver study: the paper's sampled-quadratic solver at 3…64
samples per centre chord against the ``exact`` solver, on the camera rays of the fig6
scenes.

    python -m compare.blob_study [--quick]

Reference: a float64 root finder independent of ``links1.geometry.blob``: sphere tracing with the
global Lipschitz bound ``L = Σ|w_i|·2/(3S_i)`` (a step ``(T − W)/L`` cannot cross the
surface), floored at ``1e-9`` and capped at 200,000 steps, then 80 bisection steps on the
bracket. A ray is *in the tangent band* when the largest field value along it is within
``1e-4·T`` of ``T`` (it barely touches the surface; hit or miss are both defensible).

Per solver: depth error in float32 ulps of the reference depth (median, p99, max over rays
both call hits), hit/miss disagreements (all, and outside the tangent band), field
evaluations per ray (the ``cost`` rule: one per evaluation; averaged over the rays that
cross at least one centre's 3S sphere, and over all camera rays), and intersect time.
The core solvers are float64; where the Mitsuba renderer works, its float32 ``exact`` and
``paper`` solvers are measured too, from the ``depth`` and ``cost`` AOVs of a blob-only
scene with primary rays only (its depths include float32 camera-ray rounding).

Targets: exact on the fig6 scenes ≤ 16 field evaluations per ray on average,
≤ 8 ulp float32 depth error, no hit/miss disagreement outside the tangent band.
Note: the core rejects ``samples`` < 3 (a quadratic needs three points), so the paper
sweep starts at 3, not 2.
"""
from __future__ import annotations

import argparse
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from . import common
from .common import md_table

SAMPLES = [3, 4, 6, 8, 16, 32, 64]
BAND = 1e-4


def load_blob(scene_name, res):
    from links1.geometry.blob import Blob
    from links1.scene.loader import load_scene
    scene = load_scene(str(common.SCENES / f"{scene_name}.xml"), res=res)
    blob = next(s for s in scene.shapes if isinstance(s, Blob))
    if not np.allclose(blob.to_world, np.eye(4)):
        raise SystemExit("blob_study: expects a blob without to_world")
    cam = scene.camera
    ys, xs = np.divmod(np.arange(cam.width * cam.height), cam.width)
    o, d, _, _ = cam.generate_rays((xs + 0.5) / cam.width, (ys + 0.5) / cam.height)
    return blob, o, d


# ---------------------------------------------------------------- float64 reference
def _field(x, C):
    W = np.zeros(x.shape[0])
    for cx, cy, cz, w, S in C:
        r = np.sqrt((x[:, 0] - cx) ** 2 + (x[:, 1] - cy) ** 2 + (x[:, 2] - cz) ** 2)
        W += w * np.where(r < S, 1 - r * r / (3 * S * S),
                          np.where(r < 3 * S, (r - 3 * S) ** 2 / (6 * S * S), 0.0))
    return W


def reference(blob, o, d, max_steps=200_000):
    """(t_ref, max_W) per ray: first crossing of W = T (inf: none), and the largest field
    value seen along the ray (for the tangent band)."""
    C = blob.centers
    T = blob.threshold
    L = float(np.sum(np.abs(C[:, 3]) * 2.0 / (3.0 * C[:, 4])))
    n = o.shape[0]
    # span: the union of the positive centres' 3S spheres along each ray
    P, S = C[C[:, 3] > 0, :3], C[C[:, 3] > 0, 4]
    rel = P[None] - o[:, None]
    tau = np.einsum("nkc,nc->nk", rel, d)
    h2 = np.sum(np.cross(rel, d[:, None]) ** 2, axis=2)
    half = np.sqrt(np.maximum(9 * S * S - h2, 0.0))
    crossed = h2 < 9 * S * S
    t0 = np.maximum(np.min(np.where(crossed, tau - half, np.inf), axis=1), 0.0)
    t1 = np.max(np.where(crossed, tau + half, -np.inf), axis=1)
    t_ref = np.full(n, np.inf)
    maxw = np.full(n, -np.inf)
    act = np.nonzero(crossed.any(axis=1) & (t1 > t0))[0]
    t = t0[act].copy()
    tp = t.copy()
    for _ in range(max_steps):
        if act.size == 0:
            break
        W = _field(o[act] + t[:, None] * d[act], C)
        maxw[act] = np.maximum(maxw[act], W)
        cross = W >= T
        if cross.any():
            a, b, idx = tp[cross], t[cross], act[cross]
            for _ in range(80):
                m = 0.5 * (a + b)
                inside = _field(o[idx] + m[:, None] * d[idx], C) >= T
                b = np.where(inside, m, b)
                a = np.where(inside, a, m)
            t_ref[idx] = b
        step = np.maximum((T - W) / L, 1e-9)
        tp = t
        t = t + step
        keep = ~cross & (t < t1[act])
        act, t, tp = act[keep], t[keep], tp[keep]
    # the largest field value along every ray meeting the blob (dense grid, then a finer
    # grid around the best sample): the tangent band
    rel_rays = np.nonzero(crossed.any(axis=1) & (t1 > t0))[0]
    grid = np.linspace(0.0, 1.0, 2001)
    for c0 in range(0, rel_rays.size, 64):
        idx = rel_rays[c0:c0 + 64]
        ts = t0[idx, None] + (t1[idx] - t0[idx])[:, None] * grid[None]
        x = o[idx, None, :] + ts[..., None] * d[idx, None, :]
        W = _field(x.reshape(-1, 3), C).reshape(idx.size, -1)
        k = np.argmax(W, axis=1)
        lo = ts[np.arange(idx.size), np.maximum(k - 1, 0)]
        hi = ts[np.arange(idx.size), np.minimum(k + 1, grid.size - 1)]
        fine = lo[:, None] + (hi - lo)[:, None] * grid[None]
        x = o[idx, None, :] + fine[..., None] * d[idx, None, :]
        Wf = _field(x.reshape(-1, 3), C).reshape(idx.size, -1)
        maxw[idx] = np.maximum(W.max(axis=1), Wf.max(axis=1))
    return t_ref, maxw, crossed.any(axis=1)


# ---------------------------------------------------------------- measurements
def ulps32(t, ref):
    return np.abs(t - ref) / np.spacing(np.abs(ref).astype(np.float32)).astype(np.float64)


def evaluate(t, cost, t_ref, maxw, relevant, T, seconds, label):
    hit, rhit = np.isfinite(t), np.isfinite(t_ref)
    both = hit & rhit
    err = ulps32(t[both], t_ref[both]) if both.any() else np.zeros(1)
    dis = hit != rhit
    tangent = np.abs(maxw - T) <= BAND * T
    return {"solver": label, "rays": int(t.size), "rays_meeting_blob": int(relevant.sum()),
            "hits": int(hit.sum()), "ref_hits": int(rhit.sum()),
            "ulp_median": float(np.median(err)), "ulp_p99": float(np.percentile(err, 99)),
            "ulp_max": float(np.max(err)), "abs_err_max": float(np.max(np.abs(t[both] - t_ref[both]))) if both.any() else 0.0,
            "disagree": int(dis.sum()), "disagree_outside_band": int((dis & ~tangent).sum()),
            "false_hits": int((hit & ~rhit).sum()), "missed_hits": int((~hit & rhit).sum()),
            "evals_per_ray_meeting": float(cost[relevant].mean()) if relevant.any() else 0.0,
            "evals_per_ray_all": float(cost.mean()), "evals_max": int(cost.max()),
            "time_s": seconds}


def core_solver(blob, o, d, solver, samples, repeats):
    from links1.geometry.blob import Blob
    b = Blob(blob.centers, blob.threshold, solver=solver, samples=samples)
    n = o.shape[0]
    times = []
    for _ in range(repeats):
        cost = np.zeros(n, dtype=np.int64)
        t0 = time.perf_counter()
        t, _ = b.intersect(o, d, np.zeros(n), np.full(n, np.inf), cost)
        times.append(time.perf_counter() - t0)
    return t, cost, float(np.median(times))


def mitsuba_xml(scene_name) -> str:
    s = (common.SCENES / f"{scene_name}.xml").read_text()
    blob = re.search(r'<shape type="links1_blob">.*?</shape>', s, re.S).group(0)
    blob = blob.replace('<string name="solver" value="$solver"/>',
                        '<string name="solver" value="$solver"/><integer name="samples" value="$samples"/>')
    blob = re.sub(r'<bsdf type="links1_phong">.*?</bsdf>', '<bsdf type="links1_phong"><rgb name="ambient" '
                  'value="1"/><rgb name="diffuse" value="0"/><rgb name="specular" value="0"/></bsdf>', blob, flags=re.S)
    head = re.search(r'<scene version="3.0.0">.*?<include filename="include/camera.xml"/>', s, re.S).group(0)
    head = head.replace('include/camera.xml', str(common.SCENES / "include" / "camera.xml"))
    head = head.replace('<scene version="3.0.0">', '<scene version="3.0.0">\n<default name="samples" value="8"/>')
    return (head + '\n<integrator type="links1_whitted"><integer name="max_depth" value="1"/></integrator>\n'
            + blob + "\n</scene>\n")


def mitsuba_solver(path, res, solver, samples):
    from links1_app.renderers import make_renderer
    r = make_renderer("mitsuba", str(path), params={"res": res, "solver": solver, "samples": samples},
                      spp=1, aovs=("depth", "cost"))
    img = r.render()  # warm-up (compilation)
    t0 = time.perf_counter()
    img = r.render()
    sec = time.perf_counter() - t0
    depth = img[..., 3].reshape(-1)
    cost = img[..., 4].reshape(-1).astype(np.int64)
    t = np.where(depth > 0, depth, np.inf)
    if not np.all(np.isfinite(img)):
        raise FloatingPointError("non-finite values in the Mitsuba render")
    return t, cost, sec


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m compare.blob_study")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--res", type=int)
    ap.add_argument("--no-mitsuba", action="store_true")
    a = ap.parse_args(argv)
    res = a.res or (64 if a.quick else 160)
    repeats = 1 if a.quick else 3
    info = common.machine_info()
    command = common.command_line()
    out = {"machine": info, "command": command, "res": res, "band_rel": BAND, "scenes": {}}
    mi_reason = None if not a.no_mitsuba else "--no-mitsuba"
    if mi_reason is None:
        try:
            import links1_mitsuba  # noqa: F401
            from tests.plugins.llvm_probe import llvm_status
            ok, why = llvm_status()
            mi_reason = None if ok else why
        except Exception as e:  # noqa: BLE001
            mi_reason = f"links1_mitsuba unavailable: {e}"
    out["mitsuba_skipped"] = mi_reason
    tmp = tempfile.TemporaryDirectory(prefix="links1-blob-")
    for name in ("fig6a", "fig6b"):
        blob, o, d = load_blob(name, res)
        t0 = time.perf_counter()
        t_ref, maxw, relevant = reference(blob, o, d)
        print(f"{name}: reference {time.perf_counter() - t0:.1f} s, {int(np.isfinite(t_ref).sum())} hits",
              file=sys.stderr)
        rows = []
        configs = [("exact", 8)] + [("paper", s) for s in SAMPLES]
        for solver, samples in configs:
            label = "exact" if solver == "exact" else f"paper/{samples}"
            t, cost, sec = core_solver(blob, o, d, solver, samples, repeats)
            rows.append(dict(evaluate(t, cost, t_ref, maxw, relevant, blob.threshold, sec, label),
                             renderer="core (float64)"))
        if mi_reason is None:
            path = Path(tmp.name) / f"blob_{name}.xml"
            path.write_text(mitsuba_xml(name))
            for solver, samples in [("exact", 8), ("paper", 8), ("paper", 32)]:
                label = "exact" if solver == "exact" else f"paper/{samples}"
                try:
                    t, cost, sec = mitsuba_solver(path, res, solver, samples)
                except Exception as e:  # noqa: BLE001
                    rows.append({"renderer": "links1-llvm (float32)", "solver": label,
                                 "skipped": f"{type(e).__name__}: {e}"})
                    continue
                rows.append(dict(evaluate(t, cost, t_ref, maxw, relevant, blob.threshold, sec, label),
                                 renderer="links1-llvm (float32)"))
        out["scenes"][name] = {"centres": blob.centers.tolist(), "threshold": blob.threshold,
                               "reference_hits": int(np.isfinite(t_ref).sum()),
                               "tangent_band_rays": int((np.abs(maxw - blob.threshold) <= BAND * blob.threshold).sum()),
                               "rows": rows}
    tmp.cleanup()
    md = _markdown(out)
    paths = common.write_results("blob_study", out, md, _plot(out))
    print(md)
    print("wrote " + ", ".join(str(p.relative_to(common.ROOT)) for p in paths), file=sys.stderr)
    return 0


def _markdown(out) -> str:
    s = ["# Blob solver study: paper (sampled quadratics) vs exact vs float64 reference\n\n",
         common.machine_markdown(out["machine"], out["command"]),
         f"\nCamera rays of each fig6 scene at {out['res']}×{out['res']} (pixel centres). Reference: "
         "float64 sphere tracing with the global Lipschitz bound + bisection (independent of "
         f"links1.geometry.blob). Tangent band: rays whose largest field value is within {out['band_rel']:g}·T "
         "of T. ulp = float32 ulps of the reference depth. evals/ray: field evaluations per ray "
         "meeting a 3S sphere (all camera rays in brackets). Time: one intersect call over all rays "
         "(core) or one warm frame (links1-llvm).\n"]
    if out.get("mitsuba_skipped"):
        s.append(f"\nlinks1-llvm rows skipped: {out['mitsuba_skipped']}\n")
    for name, e in out["scenes"].items():
        s.append(f"\n## {name} ({len(e['centres'])} centres, T = {e['threshold']}; "
                 f"{e['reference_hits']} reference hits, {e['tangent_band_rays']} rays in the tangent band)\n\n")
        rows = []
        for r in e["rows"]:
            if "skipped" in r:
                rows.append([r["renderer"], r["solver"], "skipped: " + r["skipped"][:80]] + [None] * 7)
                continue
            rows.append([r["renderer"], r["solver"], f"{r['evals_per_ray_meeting']:.1f} ({r['evals_per_ray_all']:.1f})",
                         r["ulp_median"], r["ulp_p99"], r["ulp_max"], r["abs_err_max"],
                         f"{r['disagree']} ({r['missed_hits']} missed, {r['false_hits']} false)",
                         r["disagree_outside_band"], r["time_s"] * 1e3])
        s.append(md_table(["renderer", "solver", "evals/ray", "ulp median", "ulp p99", "ulp max",
                           "max |Δt|", "hit/miss disagreements", "outside band", "ms"], rows))
    return "".join(s)


def _plot(out):
    plt = common.pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for name, e in out["scenes"].items():
        for rend, mk in (("core (float64)", "o"), ("links1-llvm (float32)", "s")):
            rows = [r for r in e["rows"] if r.get("renderer") == rend and "skipped" not in r]
            paper = [r for r in rows if r["solver"].startswith("paper")]
            exact = [r for r in rows if r["solver"] == "exact"]
            if paper:
                x = [r["evals_per_ray_meeting"] for r in paper]
                axes[0].loglog(x, [max(r["ulp_p99"], 1e-2) for r in paper], mk + "-", label=f"{name} paper, {rend}")
                axes[1].semilogx(x, [r["disagree_outside_band"] for r in paper], mk + "-", label=f"{name} paper, {rend}")
                for r in paper:
                    axes[0].annotate(r["solver"].split("/")[1], (r["evals_per_ray_meeting"], max(r["ulp_p99"], 1e-2)), fontsize=6)
            for r in exact:
                axes[0].loglog([r["evals_per_ray_meeting"]], [max(r["ulp_p99"], 1e-2)], mk, ms=10, mfc="none",
                               label=f"{name} exact, {rend}")
                axes[1].semilogx([r["evals_per_ray_meeting"]], [r["disagree_outside_band"]], mk, ms=10, mfc="none",
                                 label=f"{name} exact, {rend}")
    axes[0].axhline(8, color="grey", ls=":", lw=1)
    axes[0].axvline(16, color="grey", ls=":", lw=1)
    axes[0].set_xlabel("field evaluations per ray (rays meeting the blob)")
    axes[0].set_ylabel("p99 depth error [float32 ulp] (floored at 0.01)")
    axes[1].set_xlabel("field evaluations per ray")
    axes[1].set_ylabel("hit/miss disagreements outside the tangent band")
    axes[0].legend(fontsize=6)
    fig.tight_layout()
    return fig


if __name__ == "__main__":
    sys.exit(main())
