"""``links1_quadric`` spheres against Mitsuba ``sphere`` shapes at 1, 4 and 16 samples per pixel:
where a ray's time goes, per object count and sample count.

    python -m compare.quadric_spp [--res 512] [--sizes 300,3000] [--spp 1,4,16] [--rounds 3]
                                  [--frames 7] [--no-frames] [--no-queries]

The scene is ``compare.scaling.quadric_scene(N, bsdf="diffuse")``: N diffuse spheres on a floor,
one directional light, once as ``links1_quadric`` and once as Mitsuba ``sphere`` shapes, both
rendered by ``links1_whitted`` (max_depth 1).

**Frames.** Each (N, shapes, spp) renders in its own process (a process that renders one
renderer after another pays for switching between their launches, which is not what this
measures), ``--rounds`` rounds with the processes interleaved; per process the median wall and
CPU ms of ``--frames`` warm frames and, from ``dr.kernel_history()``, each kernel's lanes,
operations and ms in one more frame. The table gives the median over rounds and the ratio
quadric / Mitsuba sphere (the issue's target: <= 1.0).

**Queries** (one process per N): the frame's two ray queries taken apart, on the rays of the
frame: camera rays (``spp`` jittered positions per pixel, sample-major within a pixel as the
launch's lanes) and the shadow rays of their hits toward the light. Per query: ns per ray
(median of ``--frames`` after a warm-up, wall) and per ray the quadric tests, list entries and
BVH nodes visited (the counters of a benchmark-only trace: ``bvh.QuadricBVH.nearest(...,
steps=)``; the frame's own kernels count nothing extra). The quadrics' queries are those of the
frame (the eye buffer for camera rays, the light buffer for shadow rays) and the BVH walk (what
rays without a buffer take); Mitsuba's are ``scene.ray_intersect_preliminary`` (coherent) and
``scene.ray_test`` on the same spheres (Embree does not report its node visits).

Writes ``compare/results/quadric_spp.{json,md}``.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from . import common
from .common import md_table

LIGHT_DIR = np.array([-0.4, -1.0, -0.3])   # quadric_scene's directional light (toward the scene)


#: the spheres of quadric_scene as upright cylinders from the floor to 2r (open, the radius r):
#: Mitsuba's ``cylinder`` and a ``links1_quadric`` cylinder clipped to |z| <= 1 in object space
_MITSUBA_SPHERE = re.compile(r'<shape type="sphere"><point name="center" x="([^"]+)" y="([^"]+)" z="([^"]+)"/>')
_LINKS1_SPHERE = re.compile(r'<string name="kind" value="sphere"/><transform name="to_world"><scale value="([^"]+)"/>')


def _as_cylinders(xml):
    xml = _MITSUBA_SPHERE.sub(lambda m: f'<shape type="cylinder"><point name="p0" x="{m[1]}" y="0" z="{m[3]}"/>'
                              f'<point name="p1" x="{m[1]}" y="{2 * float(m[2]):.6g}" z="{m[3]}"/>', xml)
    return _LINKS1_SPHERE.sub(lambda m: '<string name="kind" value="cylinder"/><vector name="clip_0" value="0,0,1"/>'
                              '<float name="clip_0_offset" value="1"/><vector name="clip_1" value="0,0,-1"/>'
                              '<float name="clip_1_offset" value="1"/><transform name="to_world">'
                              f'<scale value="{m[1]}"/><rotate x="1" angle="-90"/>', xml)


def _scene_file(d, n, mitsuba_shapes, kind="sphere"):
    """quadric_scene(n) (diffuse) in a file under ``d``; ``kind`` "cylinder": its spheres as
    upright open cylinders of the same radius and height 2r."""
    from .scaling import quadric_scene
    p = Path(d) / f"{'sphere' if mitsuba_shapes else 'quadric'}_{kind}_{n}.xml"
    xml = quadric_scene(n, mitsuba_shapes=mitsuba_shapes, bsdf="diffuse")
    p.write_text(_as_cylinders(xml) if kind == "cylinder" else xml)
    return p


# ---------------------------------------------------------------------------- frames
def tests_per_sample(path, spp, res):
    """The integrator's ray-primitive tests per camera sample (its ``cost`` AOV over the frame:
    exact links1 tests, field evaluations of a blob, one per Embree query) of one frame."""
    from links1_app.renderers import make_renderer
    r = make_renderer("mitsuba", str(path), params={"res": res}, spp=spp, aovs=("cost",))
    img = r.render()
    return float(np.mean(img[..., list(r.channels).index("cost.N")])) / spp


def measure_frames(path, spp, res, frames):
    """One renderer's frames (a process of its own): the median wall and CPU ms of ``frames``
    warm frames, each kernel's lanes, operations and ms in one more (``dr.kernel_history``),
    and the tests per camera sample (:func:`tests_per_sample`)."""
    import drjit as dr
    from links1_app.renderers import make_renderer
    tests = tests_per_sample(path, spp, res)
    r = make_renderer("mitsuba", str(path), params={"res": res}, spp=spp)
    r.render()
    r.render()
    wall, cpu = [], []
    for _ in range(frames):
        c0, t0 = common.cpu_seconds(), time.perf_counter()
        r.render()
        wall.append(time.perf_counter() - t0)
        cpu.append(common.cpu_seconds() - c0)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()
    r.render()
    hist = dr.kernel_history()
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    kernels = [{"lanes": int(k.get("size", 0)), "ops": int(k.get("operation_count", 0)),
                "ms": float(k.get("execution_time", 0.0))} for k in hist if k.get("type") == dr.KernelType.JIT]
    return {"wall_ms": 1e3 * float(np.median(wall)), "cpu_ms": 1e3 * float(np.median(cpu)), "kernels": kernels,
            "tests": tests}


def frame_job(n, shapes, spp, res, frames, kind="sphere"):
    """One process's measurement (run by ``--job``): :func:`measure_frames` of one scene."""
    with tempfile.TemporaryDirectory() as d:
        return measure_frames(_scene_file(d, n, shapes == "sphere", kind), spp, res, frames)


def spawn(module, job):
    """``python -m module --job JSON`` in a process of its own (the checkout first on its path):
    the dict it prints last."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(common.ROOT), str(common.ROOT / "plugins"), env.get("PYTHONPATH", "")])
    out = subprocess.run([sys.executable, "-m", module, "--job", json.dumps(job)], cwd=common.ROOT, env=env,
                         capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"{module} job {job} failed: {out.stderr.strip().splitlines()[-1:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def parse(ap, argv, job, frames):
    """``ap``'s arguments with those both benchmarks take (``--res``, ``--spp``, ``--rounds``,
    ``--frames``, ``--job``; ``a.spps``: the sample counts as ints; ``a.info``, ``a.command``,
    ``a.t0``: the machine, the command line, the start) and the variant set; a ``--job`` run
    prints ``job(**its JSON)`` and gives None."""
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--spp", default="1,4,16")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=frames)
    ap.add_argument("--job", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    a.spps = [int(v) for v in a.spp.split(",") if v]
    a.info, a.command, a.t0 = common.machine_info(), common.command_line(), time.perf_counter()
    warnings.simplefilter("ignore")
    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    if a.job:
        print(json.dumps(job(**json.loads(a.job))))
        return None
    return a


def run_frames(sizes, spps, res, frames, rounds, kind="sphere"):
    configs = [(n, s, k) for n in sizes for s in spps for k in ("quadric", "sphere")]
    got = {c: [] for c in configs}
    for rnd in range(rounds):
        for c in configs:
            got[c].append(spawn("compare.quadric_spp", {"n": c[0], "shapes": c[2], "spp": c[1], "res": res,
                                                        "frames": frames, "kind": kind}))
            print(f"  round {rnd} N={c[0]} spp={c[1]} {c[2]}: {got[c][-1]['wall_ms']:.1f} ms", file=sys.stderr,
                  flush=True)
    rows = []
    for n in sizes:
        for s in spps:
            row = {"size": n, "spp": s}
            for k in ("quadric", "sphere"):
                rs = got[(n, s, k)]
                row[f"{k}_ms"] = float(np.median([r["wall_ms"] for r in rs]))
                row[f"{k}_cpu_ms"] = float(np.median([r["cpu_ms"] for r in rs]))
                row[f"{k}_kernel_ms"] = float(np.median([sum(x["ms"] for x in r["kernels"]) for r in rs]))
                row[f"{k}_kernels"] = rs[-1]["kernels"]
                row[f"{k}_tests"] = rs[-1]["tests"]
            # per round ratio, then the median (the rounds' loads differ)
            row["ratio"] = float(np.median([a["wall_ms"] / b["wall_ms"] for a, b in
                                            zip(got[(n, s, "quadric")], got[(n, s, "sphere")])]))
            row["cpu_ratio"] = float(np.median([a["cpu_ms"] / b["cpu_ms"] for a, b in
                                                zip(got[(n, s, "quadric")], got[(n, s, "sphere")])]))
            row["kernel_ratio"] = row["quadric_kernel_ms"] / max(row["sphere_kernel_ms"], 1e-9)
            rows.append(row)
    return rows


# ---------------------------------------------------------------------------- queries
def _camera(n, res):
    """The scene's camera: the core's (rays) and the fields ``lightbuffer.plan_eye`` reads."""
    import mitsuba as mi
    from links1.scene.loader import load_scene
    with tempfile.TemporaryDirectory() as d:
        p = _scene_file(d, n, False)
        cam = load_scene(str(p), res=res).camera
        sensor = mi.load_file(str(p), res=res).sensors()[0]
    fields = {"cam": np.array(sensor.world_transform().matrix, dtype=np.float64).reshape(4, 4),
              "x_fov": float(np.array(mi.traverse(sensor)["x_fov"]).ravel()[0]), "film_size": (res, res),
              "perspective": True, "lens": None}
    return cam, fields


def _camera_rays(cam, res, spp, seed=1):
    """``spp`` jittered camera rays per pixel of the camera ``cam`` (the core's), a pixel's
    samples adjacent (numpy float64)."""
    rng = np.random.default_rng(seed)
    pix = np.repeat(np.arange(res * res), spp)
    ys, xs = np.divmod(pix, res)
    jit = rng.random((2, pix.size))
    o, dd, _, _ = cam.generate_rays((xs + jit[0]) / res, (ys + jit[1]) / res)
    return o, dd


def _timed(fn, repeats):
    fn()
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts)), out


def run_queries(n, res, spps, repeats):
    import drjit as dr
    import mitsuba as mi
    from links1_mitsuba import lightbuffer
    from links1_mitsuba.bvh import QuadricBVH
    from .quadric_accel import _specs
    specs = _specs(n)
    bvh = QuadricBVH(specs, np.zeros((max(s.slot for s in specs) + 1, 3)))
    sph = {"type": "scene"}
    for i, s in enumerate(specs):
        sph[f"s{i}"] = {"type": "sphere", "center": [float(v) for v in s.to_world[:3, 3]],
                        "radius": float(s.to_world[0, 0])}
    msc = mi.load_dict(sph)
    w = -LIGHT_DIR / np.linalg.norm(LIGHT_DIR)
    cam, fields = _camera(n, res)
    rows = []
    for spp in spps:
        o_np, d_np = _camera_rays(cam, res, spp)
        m = len(o_np)
        ext = float(max(np.max(np.abs([s.bounds() for s in specs])), np.max(np.abs(o_np[0]))))
        margin = lightbuffer.MARGIN_REL * (1.0 + ext)
        cube = lightbuffer.build(bvh, ("point", o_np[0]), margin, N=lightbuffer.GRID_MAX)
        eye = lightbuffer.plan_eye(SimpleNamespace(bvh=bvh, custom=specs, any_mitsuba_shapes=False, **fields), None)
        sun = lightbuffer.build(bvh, ("dir", w), margin)
        o, d = mi.Point3f(o_np.T), mi.Vector3f(d_np.T)
        on = dr.ones(mi.Bool, m)
        # the floor (the plane y = 0) ends the camera rays, as in the frame
        with np.errstate(divide="ignore", invalid="ignore"):
            t_floor = np.where(d_np[:, 1] < 0, -o_np[:, 1] / d_np[:, 1], np.inf)
        tmax = mi.Float(t_floor)

        def ours(accel, counted):
            def q():
                cost = dr.zeros(mi.UInt32, m)
                steps = dr.zeros(mi.UInt32, m) if counted else None
                kw = {"steps": steps} if counted else {}
                t, _, _, _ = accel.nearest(o, d, mi.Float(0.0), tmax, on, cost, **kw)
                dr.eval(t, cost, steps)
                dr.sync_thread()
                return t, cost, steps
            return q

        def embree():
            si = msc.ray_intersect_preliminary(mi.Ray3f(o, d, tmax), True, on)
            t = dr.select(si.is_valid(), si.t, np.inf)
            dr.eval(t)
            dr.sync_thread()
            return t, None, None

        res_rows = {}
        cases = (("eye grid", ours(eye, False)), ("eye cube map", ours(cube, False)), ("BVH walk", ours(bvh, False)),
                 ("Embree", embree))
        for name, fn in cases:
            sec, (t, cost, _) = _timed(fn, repeats)
            res_rows[name] = {"ns": 1e9 * sec / m, "t": np.array(t)}
            if cost is not None:
                res_rows[name]["tests"] = float(np.mean(np.array(cost)))
        _, cost, steps = ours(bvh, True)()
        res_rows["BVH walk"]["nodes"] = float(np.mean(np.array(steps))) - res_rows["BVH walk"]["tests"]
        t_ref = res_rows["BVH walk"]["t"]
        hit = np.isfinite(t_ref)
        for name, _ in cases:
            r = res_rows.pop(name)
            agree = float(np.mean(np.isfinite(r["t"]) == hit))
            same_t = float(np.mean((r["t"] == t_ref) | (~hit & ~np.isfinite(r["t"]))))
            rows.append({"size": n, "spp": spp, "rays": "camera", "method": name, "ns_per_ray": r["ns"],
                         "tests": r.get("tests"), "nodes": r.get("nodes"), "hit_agree": agree, "same_t": same_t,
                         "hit_fraction": float(np.mean(hit))})
        # shadow rays from the camera hits toward the light
        p_np = o_np[hit] + d_np[hit] * t_ref[hit, None]
        p_np = p_np + 1e-4 * w            # off the surface, as the integrator's offset does
        k = len(p_np)
        so, sd = mi.Point3f(p_np.T), mi.Vector3f(np.tile(w, (k, 1)).T)
        son = dr.ones(mi.Bool, k)
        smax = mi.Float(np.inf)

        def sh_ours(accel):
            def q():
                cost = dr.zeros(mi.UInt32, k)
                T = accel.transmittance(so, sd, smax, son, cost)
                dr.eval(T, cost)
                dr.sync_thread()
                return T, cost
            return q

        def sh_embree():
            occ = msc.ray_test(mi.Ray3f(so, sd), son)
            dr.eval(occ)
            dr.sync_thread()
            return occ, None
        for name, fn in (("light buffer", sh_ours(sun)), ("BVH walk", sh_ours(bvh)), ("Embree", sh_embree)):
            sec, (T, cost) = _timed(fn, repeats)
            rows.append({"size": n, "spp": spp, "rays": "shadow", "method": name, "ns_per_ray": 1e9 * sec / k,
                         "tests": None if cost is None else float(np.mean(np.array(cost))), "nodes": None})
        for r in rows[-7:]:
            print(f"  N={n} spp={spp} {r['rays']} {r['method']}: {r['ns_per_ray']:.1f} ns/ray, tests {r['tests']}, "
                  f"nodes {r['nodes']}", file=sys.stderr, flush=True)
    return rows


# ---------------------------------------------------------------------------- report
def markdown(a, info, command, frames, queries):
    md = [f"# links1_quadric {a.kind}s against Mitsuba {a.kind}s at 1-16 samples per pixel\n\n",
          common.machine_markdown(info, command),
          "\nThe machine's two cores are shared with other processes: compare ratios within a run.\n"]
    if frames:
        md.append(f"\n## Frames (target: quadric <= 1.0x Mitsuba {a.kind})\n\nlinks1_whitted, {a.res}², "
                  "`compare.scaling.quadric_scene(N, bsdf=\"diffuse\")`" + (" with its spheres as upright open "
                  "cylinders of the same radius and height 2r" if a.kind == "cylinder" else "") + ", each case in its "
                  "own process, "
                  f"{a.rounds} interleaved rounds of {a.frames} warm frames; ms: median over the rounds of "
                  "each process's median; ratio: median of the rounds' ratios. kernels: `dr.kernel_history` "
                  "(the frame is one kernel of res² x spp lanes plus the film's), the rest of a frame is "
                  "the launch's traversal of its inputs (Mitsuba's scene, shape by shape) and read-back. tests / "
                  "sample: the `cost` AOV of one frame over the camera samples (exact quadric tests and one per "
                  "Embree query, camera and shadow rays together).\n\n")
        m = f"Mitsuba {a.kind}"
        md.append(md_table(["N", "spp", "quadric ms", f"{m} ms", "ratio", "target (<= 1.0)", "CPU ratio",
                            "quadric kernels ms", f"{m} kernels ms", "kernel ratio", "quadric ms / Mrays",
                            f"{m} ms / Mrays", "quadric tests / sample", f"{m} tests / sample"],
                           [[r["size"], r["spp"], r["quadric_ms"], r["sphere_ms"], r["ratio"],
                             "met" if r["ratio"] <= 1.0 else "missed", r["cpu_ratio"], r["quadric_kernel_ms"],
                             r["sphere_kernel_ms"], r["kernel_ratio"],
                             r["quadric_kernel_ms"] / (a.res * a.res * r["spp"] / 1e6),
                             r["sphere_kernel_ms"] / (a.res * a.res * r["spp"] / 1e6), r["quadric_tests"],
                             r["sphere_tests"]] for r in frames]))
    if queries:
        md.append(f"\n## Queries per ray\n\n{a.res}² x spp jittered camera rays of the scene (spheres only, "
                  "no floor) and the shadow rays of their hits toward the light; ns per ray: median of "
                  f"{a.frames} queries after a warm-up (wall, one process); tests: exact quadric tests per "
                  "ray (eye/light buffer: list entries tested); nodes: BVH inner nodes visited per ray "
                  "(counted in a separate trace). Embree does not report its counts.\n\n")
        md.append(md_table(["N", "spp", "rays", "method", "ns / ray", "tests / ray", "nodes / ray",
                            "hit/miss = BVH walk", "t = BVH walk (bits)"],
                           [[r["size"], r["spp"], r["rays"], r["method"], r["ns_per_ray"], r["tests"], r["nodes"],
                             r.get("hit_agree"), r.get("same_t")] for r in queries]))
    return "".join(md)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m compare.quadric_spp")
    ap.add_argument("--sizes", default="300,3000")
    ap.add_argument("--no-frames", action="store_true")
    ap.add_argument("--no-queries", action="store_true")
    ap.add_argument("--kind", choices=("sphere", "cylinder"), default="sphere",
                    help="the objects (cylinder: frames only, written to quadric_spp_cylinder.*)")
    a = parse(ap, argv, frame_job, frames=7)
    if a is None:
        return 0
    sizes, spps = [int(v) for v in a.sizes.split(",") if v], a.spps
    frames = [] if a.no_frames else run_frames(sizes, spps, a.res, a.frames, a.rounds, a.kind)
    queries = []
    if not a.no_queries and a.kind == "sphere":
        for n in sizes:
            queries += run_queries(n, a.res, spps, a.frames)
    out = {"machine": a.info, "command": a.command, "res": a.res, "frames": frames, "queries": queries,
           "wall_s": time.perf_counter() - a.t0}
    md = markdown(a, a.info, a.command, frames, queries)
    paths = common.write_results("quadric_spp" if a.kind == "sphere" else f"quadric_spp_{a.kind}", out, md, None)
    print(md)
    print("wrote " + ", ".join(str(p.relative_to(common.ROOT)) for p in paths), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
