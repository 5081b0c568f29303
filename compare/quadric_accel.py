"""Nearest-hit queries over N ``links1_quadric`` spheres: the plugin's own BVH walk against
Embree finding the candidates through proxy meshes, with Mitsuba's ``sphere`` shapes as the
yardstick.

    python -m compare.quadric_accel [--res 512] [--sizes 10,300,3000,10000] [--repeats 7]

Two tables. **Frames** (the issue's target: ``links1_quadric`` spheres <= 1.2x Mitsuba ``sphere``
shapes in the same integrator): warm median frame of links1_whitted (512², spp 1) on
``compare.scaling.quadric_scene(N, bsdf=...)`` with the spheres as ``links1_quadric`` and as
Mitsuba ``sphere`` shapes, the same materials on both (Mitsuba ``diffuse``, and ``links1_phong``),
with the kernels' share (``dr.kernel_history``), and Mitsuba's own ``direct`` on the Mitsuba
spheres for reference. **Queries**: the nearest-hit query alone, below.

Rays: the camera rays of ``compare.scaling.quadric_scene(N)`` (pixel centres, ``res``²), the
spheres only (no floor). Per N and method, in one process: one warm-up query (tracing and
kernel compilation), then the median of ``repeats`` queries (tracing + kernel, as a frame of
a BVH scene pays) and the median kernel time (``dr.kernel_history``). Methods:

* ``bvh``: :meth:`links1_mitsuba.bvh.QuadricBVH.nearest` (binary SAH BVH, per-lane stack).
* ``eye``: :meth:`links1_mitsuba.lightbuffer.LightBuffer.nearest` on a cube map around the eye
  (links1_whitted's camera rays use the film grid of :mod:`links1_mitsuba.eyegrid`, measured
  by ``compare.quadric_spp``).
* ``proxy``: every quadric's world box as 12 triangles of one Mitsuba mesh in a second
  scene; a loop of ``scene.ray_intersect`` walks on along the ray while a proxy face is
  nearer than the best exact hit, testing the quadric behind each face (the exact test of
  ``bvh.py``).
* ``mitsuba-sphere``: the same spheres as Mitsuba ``sphere`` shapes, ``scene.ray_intersect``.

Every method's hit/miss and depth are checked against ``bvh`` (the tested path).
Writes ``compare/results/quadric_accel.{json,md}``.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from . import common
from .common import md_table

BOX_FACES = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], dtype=np.uint32)


def _camera_rays(n, res):
    """Pixel-centre rays of the scaling scene's camera (numpy float64)."""
    from .scaling import quadric_scene
    from links1.scene.loader import load_scene
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "q.xml"
        p.write_text(quadric_scene(n))
        cam = load_scene(str(p), res=res).camera
    ys, xs = np.divmod(np.arange(res * res), res)
    o, dd, _, _ = cam.generate_rays((xs + 0.5) / res, (ys + 0.5) / res)
    return o, dd


def _specs(n):
    import links1_mitsuba as lm
    from .scaling import quadric_scene
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "q.xml"
        p.write_text(quadric_scene(n))
        r = lm.MitsubaRenderer(str(p), params={"res": 8}, spp=1)
    return list(r.integrator.info()["custom_shapes"])


def _timed(fn, repeats, cpu=None):
    """Median wall and kernel seconds of ``repeats`` calls of ``fn`` (after a warm-up) and the
    last output; the median CPU seconds are appended to the list ``cpu`` when given."""
    import drjit as dr
    fn()
    wall, kern, cpu_s = [], [], []
    for _ in range(repeats):
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()
        c0 = common.cpu_seconds()
        t0 = time.perf_counter()
        out = fn()
        wall.append(time.perf_counter() - t0)
        cpu_s.append(common.cpu_seconds() - c0)
        kern.append(sum(float(k.get("execution_time", 0.0)) for k in dr.kernel_history()) / 1e3)
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    if cpu is not None:
        cpu.append(float(np.median(cpu_s)))
    return float(np.median(wall)), float(np.median(kern)), out


def run_frames(n, res, repeats):
    """Frame rows for N spheres: links1_whitted on quadrics and on Mitsuba spheres (both
    BSDF variants), Mitsuba ``direct`` on the Mitsuba spheres."""
    import drjit as dr
    from links1_app.renderers import make_renderer
    from .scaling import quadric_scene
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for bsdf in ("diffuse", "phong"):
            row = {"size": n, "bsdf": bsdf}
            cases = [("quadric", False, None), ("sphere", True, None)]
            if bsdf == "diffuse":
                cases.append(("direct", True, "scene"))
            for key, msh, integ in cases:
                p = Path(d) / f"{key}_{bsdf}_{n}.xml"
                p.write_text(quadric_scene(n, mitsuba_shapes=msh, bsdf=bsdf))
                kw = {"integrator": integ} if integ else {}
                r = make_renderer("mitsuba", str(p), params={"res": res}, spp=1, **kw)
                cpu = []
                wall, kern, _ = _timed(r.render, repeats, cpu)
                row[f"{key}_ms"], row[f"{key}_kernel_ms"] = 1e3 * wall, 1e3 * kern
                row[f"{key}_cpu_ms"] = 1e3 * cpu[0]
                del r
                dr.flush_malloc_cache()
            row["ratio"] = row["quadric_ms"] / row["sphere_ms"]
            row["kernel_ratio"] = row["quadric_kernel_ms"] / max(row["sphere_kernel_ms"], 1e-9)
            row["cpu_ratio"] = row["quadric_cpu_ms"] / max(row["sphere_cpu_ms"], 1e-9)
            print(f"  N={n} {bsdf}: quadric {row['quadric_ms']:.1f} ms, Mitsuba sphere {row['sphere_ms']:.1f} ms "
                  f"({row['ratio']:.2f}x; kernels {row['kernel_ratio']:.2f}x; CPU {row['cpu_ratio']:.2f}x)", file=sys.stderr, flush=True)
            rows.append(row)
    return rows


def run_size(n, res, repeats):
    import drjit as dr
    import mitsuba as mi
    from links1_mitsuba.bvh import QuadricBVH
    specs = _specs(n)
    slots = max(s.slot for s in specs) + 1
    bvh = QuadricBVH(specs, np.zeros((slots, 3)))
    o_np, d_np = _camera_rays(n, res)
    o, d = mi.Vector3f(o_np.T), mi.Vector3f(d_np.T)
    m = len(o_np)
    rows = []

    def nearest_query(accel):
        """The nearest-hit query of ``accel`` (the BVH walk or a buffer: the same ``nearest``)."""
        def query():
            t, q, _, found = accel.nearest(o, d, mi.Float(0.0), mi.Float(np.inf), dr.ones(mi.Bool, m),
                                           dr.zeros(mi.UInt32, m))
            dr.eval(t)
            dr.sync_thread()
            return t
        return query

    lo = np.array([s.bounds()[0] for s in bvh.specs])
    hi = np.array([s.bounds()[1] for s in bvh.specs])
    # eye: a cube map around the eye (links1_whitted's camera rays use eyegrid's film grid)
    from links1_mitsuba import lightbuffer
    ext = float(max(np.max(np.abs(lo)), np.max(np.abs(hi)), np.max(np.abs(o_np[0]))))
    t_build = time.perf_counter()
    eye = lightbuffer.build(bvh, ("point", o_np[0].astype(np.float64)), lightbuffer.MARGIN_REL * (1.0 + ext),
                            N=lightbuffer.GRID_MAX)
    t_build = time.perf_counter() - t_build
    q_bvh, q_eye = nearest_query(bvh), nearest_query(eye)

    # proxy: world boxes of the (BVH-ordered) quadrics as one mesh
    corners = np.stack([np.where([(k >> 2) & 1, (k >> 1) & 1, k & 1], hi, lo) for k in range(8)], axis=1)
    mesh = mi.Mesh("proxy", 8 * n, 12 * n)
    prm = mi.traverse(mesh)
    prm["vertex_positions"] = mi.Float(corners.reshape(-1).astype(np.float32))
    prm["faces"] = mi.UInt32((BOX_FACES[None] + 8 * np.arange(n, dtype=np.uint32)[:, None, None]).ravel())
    prm.update()
    proxy_scene = mi.load_dict({"type": "scene", "proxy": mesh})

    def q_proxy():
        best = dr.full(mi.Float, np.inf, m)
        t_cur = dr.zeros(mi.Float, m)
        run = dr.ones(mi.Bool, m)

        def cond(best, t_cur, run, it):
            return run

        def body(best, t_cur, run, it):
            ray = mi.Ray3f(o + d * t_cur, d, best - t_cur)
            si = proxy_scene.ray_intersect_preliminary(ray, active=run)
            hit = run & si.is_valid()
            q = si.prim_index // 12
            tq, _ = bvh.intersect(q, o, d, mi.Float(0.0), best, hit)
            best = dr.select(hit & (tq < best), tq, best)
            # step past the face (relative float32 margin), keep walking while nearer than best
            t_cur = dr.select(hit, (t_cur + si.t) * (1.0 + 1e-5) + 1e-5, t_cur)
            it += 1
            return best, t_cur, hit & (t_cur < best) & (it < 512), it

        best, _, _, _ = dr.while_loop((best, t_cur, run, dr.zeros(mi.UInt32, m)), cond, body)
        dr.eval(best)
        dr.sync_thread()
        return best

    sph = {"type": "scene"}
    for i, s in enumerate(specs):
        c = s.to_world[:3, 3]
        sph[f"s{i}"] = {"type": "sphere", "center": [float(v) for v in c], "radius": float(s.to_world[0, 0])}
    msc = mi.load_dict(sph)

    def q_mitsuba():
        si = msc.ray_intersect_preliminary(mi.Ray3f(o, d), active=dr.ones(mi.Bool, m))
        t = dr.select(si.is_valid(), si.t, np.inf)
        dr.eval(t)
        dr.sync_thread()
        return t

    ref = None
    for name, fn in (("bvh", q_bvh), ("eye", q_eye), ("proxy", q_proxy), ("mitsuba-sphere", q_mitsuba)):
        wall, kern, t = _timed(fn, repeats)
        t = np.array(t, dtype=np.float64)
        row = {"size": n, "method": name, "median_ms": 1e3 * wall, "kernel_ms": 1e3 * kern,
               "hit_fraction": float(np.mean(np.isfinite(t)))}
        if name == "eye":
            row["build_s"] = t_build
        if ref is None:
            ref = t
        else:
            hr, ht = np.isfinite(ref), np.isfinite(t)
            both = hr & ht
            row["hit_disagree"] = float(np.mean(hr != ht))
            row["max_rel_depth"] = float(np.max(np.abs(t[both] - ref[both]) / ref[both])) if both.any() else 0.0
        rows.append(row)
        print(f"  N={n} {name}: {row['median_ms']:.2f} ms (kernels {row['kernel_ms']:.2f} ms)", file=sys.stderr,
              flush=True)
    base = next(r for r in rows if r["method"] == "mitsuba-sphere")
    for r in rows:
        r["x_mitsuba"] = r["median_ms"] / base["median_ms"]
        r["kernel_x_mitsuba"] = r["kernel_ms"] / max(base["kernel_ms"], 1e-9)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m compare.quadric_accel")
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--sizes", default="10,300,3000,10000")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--no-frames", action="store_true", help="the query table only")
    a = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    info = common.machine_info()
    command = common.command_line()
    t0 = time.perf_counter()
    rows, frames = [], []
    sizes = [int(v) for v in a.sizes.split(",") if v]
    if not a.no_frames:
        for n in sizes:
            frames += run_frames(n, a.res, a.repeats)
    for n in sizes:
        rows += run_size(n, a.res, a.repeats)
    out = {"machine": info, "command": command, "res": a.res, "repeats": a.repeats, "rows": rows,
           "frames": frames, "wall_s": time.perf_counter() - t0}
    md = ["# links1_quadric spheres against Mitsuba spheres: frames and nearest-hit queries\n\n",
          common.machine_markdown(info, command)]
    if frames:
        md.append(f"\n## Frames (target: quadric <= 1.2x Mitsuba sphere, same integrator)\n\nlinks1_whitted, "
                  f"{a.res}², spp 1, warm median of {a.repeats} frames, `compare.scaling.quadric_scene(N, bsdf=...)`: "
                  "the same scene and materials with the spheres as `links1_quadric` or Mitsuba `sphere` shapes. "
                  "kernels = `dr.kernel_history` execution time of a frame (the rest: the launch's "
                  "input traversal, read-back). CPU = the process's CPU time of a frame (both threads; "
                  "on a machine whose two cores other processes also use, wall times and their ratio "
                  "swing with the load, CPU times much less). Mitsuba `direct`: Mitsuba's own integrator "
                  "on the Mitsuba spheres (diffuse), for reference.\n\n")
        md.append(md_table(["N", "BSDF", "quadric ms", "Mitsuba sphere ms", "ratio", "target (<= 1.2)",
                            "quadric kernels ms", "sphere kernels ms", "kernel ratio", "quadric CPU ms",
                            "sphere CPU ms", "CPU ratio", "Mitsuba direct ms"],
                           [[r["size"], r["bsdf"], r["quadric_ms"], r["sphere_ms"], r["ratio"],
                             "met" if r["ratio"] <= 1.2 else "missed", r["quadric_kernel_ms"],
                             r["sphere_kernel_ms"], r["kernel_ratio"], r["quadric_cpu_ms"], r["sphere_cpu_ms"],
                             r["cpu_ratio"], r.get("direct_ms")] for r in frames]))
    md += ["\n## Nearest-hit queries: own BVH vs Embree proxies vs Mitsuba spheres\n",
          f"\n{a.res}² camera rays (pixel centres) of `compare.scaling.quadric_scene(N)`, spheres only, one "
          f"process, median of {a.repeats} queries after a warm-up; wall = tracing + kernels (what a frame "
          "of a BVH scene pays), kernels = `dr.kernel_history` execution time. ×mitsuba: over Mitsuba "
          "`sphere` shapes in the same process. Hit/miss and depth against `bvh`.\n\n"]
    md.append(md_table(["N", "method", "wall ms", "×mitsuba", "kernels ms", "kernels ×mitsuba", "hit fraction",
                        "hit/miss vs bvh", "max rel depth vs bvh"],
                       [[r["size"], r["method"], r["median_ms"], r["x_mitsuba"], r["kernel_ms"],
                         r["kernel_x_mitsuba"], r["hit_fraction"], r.get("hit_disagree"), r.get("max_rel_depth")]
                        for r in rows]))
    paths = common.write_results("quadric_accel", out, "".join(md), None)
    print("".join(md))
    print("wrote " + ", ".join(str(p.relative_to(common.ROOT)) for p in paths), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
