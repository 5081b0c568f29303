"""Scaling with scene size: frame time and peak memory against the number
of quadrics (10 … 10,000) and of blob centres (10 … 1,000).

    python -m compare.scaling [--quick]

Scene families (generated into a temporary directory, same camera framing for every size,
so rays per pixel stay the same):

* ``quadric-N``: N ``links1_quadric`` spheres on a jittered grid over a floor rectangle,
  8 shared Phong BSDFs, one parallel light (shadow rays), direct light only. Renderers: core, links1-llvm.
* ``msphere-N``: the same with Mitsuba ``sphere`` shapes and 8 ``diffuse`` BSDFs (Mitsuba-only):
  core, links1-llvm, mitsuba-direct (Mitsuba's own BVH: the yardstick).
* ``blob-K``: one ``links1_blob`` with K centres on a jittered grid (S = 0.6, spacing 1:
  a ray meets a bounded number of 3S spheres whatever K), ambient-only, primary rays.
  Reported with the centres a ray meets (mean over rays meeting any) and field
  evaluations per ray (``cost`` AOV).

Each (scene, renderer) runs in its own process (peak memory = its ``ru_maxrss``, which
includes the interpreter and, for Mitsuba, its libraries: compare against the smallest
size). Once a renderer times out at some size, larger sizes of that family are skipped.

Targets: 10,000 quadrics ≤ 10× the frame time of 10; blob cost per ray grows with
the centres the ray meets, not with all centres.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from . import common
from .common import md_table

CAMERA = """<sensor type="perspective">
    <float name="fov" value="50"/><float name="near_clip" value="0.01"/><float name="far_clip" value="100000"/>
    <transform name="to_world"><lookat origin="{ex}, {ey}, {ez}" target="0, 0, 0" up="0, 1, 0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="1"/></sampler>
    <film type="hdrfilm"><integer name="width" value="$res"/><integer name="height" value="$res"/>
        <rfilter type="box"/></film>
</sensor>"""


def _grid(n, rng):
    m = int(math.ceil(math.sqrt(n)))
    ij = np.array([(i, j) for i in range(m) for j in range(m)][:n], dtype=np.float64)
    xy = ij - (m - 1) / 2.0 + rng.uniform(-0.15, 0.15, ij.shape)
    return xy, m


def quadric_scene(n, mitsuba_shapes=False, seed=0, bsdf=None):
    """N spheres on a grid over a floor, one directional light: ``links1_quadric`` spheres
    (links1_whitted) or Mitsuba ``sphere`` shapes (Mitsuba ``direct``). ``bsdf``: ``None``
    (links1_phong on quadrics, Mitsuba ``diffuse`` on Mitsuba spheres), or ``"diffuse"`` /
    ``"phong"`` for both (the same materials whichever shapes carry them)."""
    if bsdf not in (None, "diffuse", "phong"):
        raise ValueError(f"quadric_scene: bsdf must be None, 'diffuse' or 'phong', got {bsdf!r}")
    diffuse = mitsuba_shapes if bsdf is None else bsdf == "diffuse"
    rng = np.random.default_rng(seed)
    xz, m = _grid(n, rng)
    r = rng.uniform(0.2, 0.35, n)
    # a palette of 8 shared BSDFs (per-shape BSDFs would make every renderer's material
    # dispatch grow with N, which is not what this measures)
    pal = rng.uniform(0.2, 0.9, (8, 3))
    bsdfs = []
    for k, col in enumerate(pal):
        c = f"{col[0]:.3f}, {col[1]:.3f}, {col[2]:.3f}"
        bsdfs.append(f'<bsdf type="diffuse" id="m{k}"><rgb name="reflectance" value="{c}"/></bsdf>' if diffuse
                     else f'<bsdf type="links1_phong" id="m{k}"><rgb name="ambient" value="0.05"/><rgb name="diffuse" '
                          f'value="{c}"/><rgb name="specular" value="0.3"/><float name="exponent" value="20"/></bsdf>')
    shapes = list(bsdfs)
    for i, ((x, z), ri) in enumerate(zip(xz, r)):
        ref = f'<ref id="m{i % 8}"/>'
        if mitsuba_shapes:
            shapes.append(f'<shape type="sphere"><point name="center" x="{x:.6g}" y="{ri:.6g}" z="{z:.6g}"/>'
                          f'<float name="radius" value="{ri:.6g}"/>{ref}</shape>')
        else:
            shapes.append(f'<shape type="links1_quadric"><string name="kind" value="sphere"/><transform name="to_world">'
                          f'<scale value="{ri:.6g}"/><translate x="{x:.6g}" y="{ri:.6g}" z="{z:.6g}"/></transform>'
                          f'{ref}</shape>')
    floor_bsdf = ('<bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf>' if diffuse else
                  '<bsdf type="links1_phong"><rgb name="ambient" value="0.05"/><rgb name="diffuse" value="0.5"/>'
                  '<rgb name="specular" value="0"/></bsdf>')
    half = m / 2.0 + 1.0
    body = "\n".join(shapes) + (
        f'\n<shape type="rectangle"><transform name="to_world"><scale value="{half:.6g}"/><rotate x="1" angle="-90"/>'
        f'</transform>{floor_bsdf}</shape>\n<emitter type="directional"><vector name="direction" x="-0.4" y="-1" '
        f'z="-0.3"/><rgb name="irradiance" value="2"/></emitter>')
    integ = '<integrator type="direct"/>' if mitsuba_shapes else \
        '<integrator type="links1_whitted"><integer name="max_depth" value="1"/></integrator>'
    cam = CAMERA.format(ex=0, ey=f"{0.95 * m + 1:.6g}", ez=f"{0.95 * m + 1:.6g}")
    return f'<scene version="3.0.0">\n<default name="res" value="64"/>\n{integ}\n{cam}\n{body}\n</scene>\n'


def blob_centres(k, seed=0):
    rng = np.random.default_rng(seed)
    xz, m = _grid(k, rng)
    y = rng.uniform(-0.2, 0.2, k)
    S = np.full(k, 0.6)
    w = np.ones(k)
    return np.c_[xz[:, 0], y, xz[:, 1], w, S], m


def blob_scene(k, seed=0):
    c, m = blob_centres(k, seed)
    vals = " ".join(f"{v:.6g}" for v in c.ravel())
    cam = CAMERA.format(ex=0, ey=f"{0.95 * m + 1:.6g}", ez=f"{0.95 * m + 1:.6g}")
    return (f'<scene version="3.0.0">\n<default name="res" value="64"/>\n<integrator type="links1_whitted">'
            f'<integer name="max_depth" value="1"/></integrator>\n{cam}\n<shape type="links1_blob">'
            f'<string name="centers" value="{vals}"/><float name="threshold" value="0.5"/>'
            f'<bsdf type="links1_phong"><rgb name="ambient" value="1"/><rgb name="diffuse" value="0"/>'
            f'<rgb name="specular" value="0"/></bsdf></shape>\n</scene>\n')


def centres_met(path, res, centres):
    """Mean number of 3S spheres a pixel-centre ray crosses (over rays crossing any)."""
    from links1.scene.loader import load_scene
    cam = load_scene(str(path), res=res).camera
    ys, xs = np.divmod(np.arange(cam.width * cam.height), cam.width)
    o, d, _, _ = cam.generate_rays((xs + 0.5) / cam.width, (ys + 0.5) / cam.height)
    met = np.zeros(o.shape[0])
    for a in range(0, centres.shape[0], 256):
        c = centres[a:a + 256]
        rel = c[None, :, :3] - o[:, None, :]
        h2 = np.sum(np.cross(rel, d[:, None, :]) ** 2, axis=2)
        met += np.sum(h2 < 9 * c[None, :, 4] ** 2, axis=1)
    return float(met[met > 0].mean()) if np.any(met > 0) else 0.0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m compare.scaling")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--res", type=int)
    ap.add_argument("--timeout", type=float)
    ap.add_argument("--repeats", type=int, help="timed frames per job (median; default 3, --quick 2)")
    ap.add_argument("--families", default="quadric,msphere,blob",
                    help="comma-separated families to run (default: all)")
    a = ap.parse_args(argv)
    res = a.res or (32 if a.quick else 64)
    repeats = a.repeats or (2 if a.quick else 3)
    timeout = a.timeout or (30 if a.quick else 300)
    counts = [10, 100, 1000, 10000]
    blob_counts = [10, 30, 100, 300, 1000]
    info = common.machine_info()
    command = common.command_line()
    t_start = time.perf_counter()
    tmp = tempfile.TemporaryDirectory(prefix="links1-scaling-")
    families = {
        "quadric": (counts, lambda n: quadric_scene(n), ["core", "links1-llvm"]),
        "msphere": (counts, lambda n: quadric_scene(n, mitsuba_shapes=True), ["core", "links1-llvm", "mitsuba-direct"]),
        "blob": (blob_counts, blob_scene, ["core", "links1-llvm"]),
    }
    families = {k: v for k, v in families.items() if k in a.families.split(",")}
    out = {"machine": info, "command": command, "res": res, "repeats": repeats, "timeout_s": timeout,
           "families": {}}
    for fam, (sizes, make, renderers) in families.items():
        rows = []
        dead: dict = {}
        for n in sizes:
            core_img = None
            path = Path(tmp.name) / f"{fam}-{n}.xml"
            path.write_text(make(n))
            extra = {}
            if fam == "blob":
                extra["centres_met_per_ray"] = centres_met(path, res, blob_centres(n)[0])
            for r in renderers:
                row = {"size": n, "renderer": r, **extra}
                if r in dead:
                    row["skipped"] = f"skipped: already {dead[r]} at a smaller size"
                    rows.append(row)
                    continue
                aovs = ["cost"] if fam == "blob" and r != "mitsuba-direct" else []
                res_ = common.run_job({"scene": str(path), "renderer": r, "params": {"res": res}, "spp": [1],
                                       "repeats": repeats, "seed": 0, "aovs": aovs}, timeout=timeout)
                if not res_.get("ok"):
                    row["skipped"] = res_.get("reason")
                    dead[r] = "timed out" if "timed out" in str(res_.get("reason")) else "failed"
                    rows.append(row)
                    print(f"  {fam}-{n} {r}: {row['skipped']}", file=sys.stderr)
                    continue
                rr = res_["results"][0]
                img = res_["images"][1]
                if r == "core":
                    core_img = img
                elif core_img is not None and r.startswith("links1-"):
                    from links1.imaging import diff
                    row["relmse_vs_core"] = diff.relmse(img[..., :3], core_img[..., :3])
                row.update(load_s=res_["load_s"], first_s=rr["first_s"], median_s=rr["median_s"],
                           peak_rss_mib=res_["peak_rss_mib"], finite=rr["finite"])
                if aovs:
                    cost = img[..., 3]
                    met = cost > 0
                    row["evals_per_ray_meeting"] = float(cost[met].mean()) if met.any() else 0.0
                rows.append(row)
                print(f"  {fam}-{n} {r}: {rr['median_s'] * 1e3:.1f} ms, load {res_['load_s']:.1f} s, "
                      f"{res_['peak_rss_mib']:.0f} MiB", file=sys.stderr)
        for r in renderers:
            base = next((x for x in rows if x["renderer"] == r and x["size"] == sizes[0] and "median_s" in x), None)
            for x in rows:
                if x["renderer"] == r and base and "median_s" in x:
                    x["time_ratio_to_smallest"] = x["median_s"] / base["median_s"]
                    x["rss_delta_mib"] = x["peak_rss_mib"] - base["peak_rss_mib"]
        out["families"][fam] = rows
    tmp.cleanup()
    out["wall_s"] = time.perf_counter() - t_start
    for fam in out["families"]:
        out.setdefault("family_runs", {})[fam] = {"command": command, "machine": info, "wall_s": out["wall_s"]}
    if set(families) != {"quadric", "msphere", "blob"}:
        # a partial run replaces its families in the committed results and keeps the others
        old = json.loads((common.ROOT / "compare" / "results" / "scaling.json").read_text())
        for fam, rows in old["families"].items():
            if fam not in out["families"]:
                out["families"][fam] = rows
                out["family_runs"][fam] = old.get("family_runs", {}).get(
                    fam, {"command": old["command"], "machine": old["machine"], "wall_s": old["wall_s"]})
        out["families"] = {f: out["families"][f] for f in ("quadric", "msphere", "blob") if f in out["families"]}
    md = _markdown(out)
    paths = common.write_results("scaling", out, md, _plot(out))
    print(md)
    print("wrote " + ", ".join(str(p.relative_to(common.ROOT)) for p in paths), file=sys.stderr)
    return 0


def _markdown(out) -> str:
    s = ["# Scaling: frame time and peak memory against scene size\n\n",
         common.machine_markdown(out["machine"], out["command"]),
         f"\nFilm {out['res']}×{out['res']}, 1 spp, warm median of {out['repeats']} frames, each "
         f"(scene, renderer) in its own process with a {out['timeout_s']:.0f} s limit (loading and the "
         "warm-up frame, which includes kernel compilation, count toward it). ×smallest = frame time / "
         "frame time at the smallest size (same renderer, same run). relMSE vs core: the links1-llvm image "
         "against the core's image of the same scene (same sample pattern; checks the fast path is right). Peak RSS includes the interpreter "
         f"and libraries; Δ = minus the smallest size's. Run took {out['wall_s']:.0f} s.\n"]
    for fam, rows in out["families"].items():
        s.append(f"\n## {fam}\n\n")
        run = out.get("family_runs", {}).get(fam)
        if run and run["command"] != out["command"]:
            m = run["machine"]
            s.append(f"From an earlier run: `{run['command']}` (git commit {m.get('git_commit')}, load average "
                     f"at start {m.get('load_average_at_start')}).\n\n")
        t = []
        for x in rows:
            if "skipped" in x:
                t.append([x["size"], x["renderer"], "skipped: " + str(x["skipped"])[:90]] + [None] * 8)
                continue
            t.append([x["size"], x["renderer"], x["median_s"] * 1e3, x.get("time_ratio_to_smallest"),
                      x["first_s"], x["load_s"], x["peak_rss_mib"], x.get("rss_delta_mib"),
                      x.get("centres_met_per_ray"), x.get("evals_per_ray_meeting"), x.get("relmse_vs_core")])
        s.append(md_table(["size", "renderer", "median ms", "×smallest", "first s", "load s", "peak MiB",
                           "Δ MiB", "centres met/ray", "evals/ray", "relMSE vs core"], t))
    return "".join(s)


def _plot(out):
    plt = common.pyplot()
    fams = list(out["families"])
    fig, axes = plt.subplots(2, len(fams), figsize=(4.5 * len(fams), 7), squeeze=False)
    for j, fam in enumerate(fams):
        rows = out["families"][fam]
        for r in sorted({x["renderer"] for x in rows}):
            pts = [x for x in rows if x["renderer"] == r and "median_s" in x]
            if not pts:
                continue
            axes[0, j].loglog([x["size"] for x in pts], [x["median_s"] for x in pts], "o-", label=r)
            axes[1, j].semilogx([x["size"] for x in pts], [x["peak_rss_mib"] for x in pts], "o-", label=r)
        axes[0, j].set_title(fam)
        axes[0, j].set_ylabel("warm median frame time [s]")
        axes[1, j].set_ylabel("peak RSS [MiB]")
        axes[1, j].set_xlabel("centres" if fam == "blob" else "shapes")
        axes[0, j].legend(fontsize=7)
    fig.tight_layout()
    return fig


if __name__ == "__main__":
    sys.exit(main())
