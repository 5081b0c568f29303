"""The same rays on mitsuba-data's ``data_instancing`` as ``links1_mitsuba.load_file`` loads it
(its instances flattened into plain meshes and shapes: one Embree BVH) and as ``mi.load_file``
loads it (three instances of one shapegroup: Embree's two-level BVH).

    python -m compare.instancing_bvh [--spp 16] [--repeats 9]

512 px wide. The rays: ``compare.ray_floor.floor_rays`` of the flattened scene (the camera rays'
nearest hits and the shadow rays to the point light, densely packed), traced on each scene with
``ray_intersect_preliminary`` and ``ray_test``; with them Mitsuba ``direct`` (emitter_samples 1,
bsdf_samples 0) on each scene and links1_whitted's frame (the flattened scene: the loader's).
All interleaved in one process, ``repeats`` rounds after a warm-up: wall and process CPU time
(every thread), medians. Also which hits agree (the same hit or miss, the same ``t`` bits).
Writes ``compare/results/instancing_bvh.{json,md}``.
"""
from __future__ import annotations

import argparse

import numpy as np

from compare.common import command_line, machine_info, machine_markdown, write_results


def measure(spp, repeats, variant):
    import drjit as dr
    import mitsuba as mi
    from compare.ray_floor import DATA, _frame, floor_rays, interleaved, load_case, mitsuba_integrator
    from links1_mitsuba.renderer import resize_film

    flat, kind, depth, size = load_case("data_instancing", "box", 512, variant)
    inst = mi.load_file(str(DATA / "tests/scenes/instancing/test_instancing_path.xml"))
    resize_film(inst.sensors()[0], *size)
    # (the shadow rays toward its light at the eye too, which links1 does not trace: the BVHs' rays)
    batches, counts = floor_rays(flat, size, spp, depth, 0.0, eye_rule=False)
    nearest = [(r, c) for _, r, c, k, _ in batches if k == "nearest"]
    shadow = [(r, c) for _, r, c, k, _ in batches if k == "shadow"]

    def trace_nearest(scene):
        for ray, coherent in nearest:
            pi = scene.ray_intersect_preliminary(ray, coherent)
            dr.eval(pi.t, pi.prim_index, pi.shape_index)
        dr.sync_thread()

    def trace_shadow(scene):
        outs = []
        for ray, coherent in shadow:
            outs.append(scene.ray_test(ray, coherent, True))
            dr.eval(outs[-1])
        dr.sync_thread()
        return outs

    agree = []
    for ray, coherent in nearest:
        ta = np.asarray(flat.ray_intersect_preliminary(ray, coherent).t)
        tb = np.asarray(inst.ray_intersect_preliminary(ray, coherent).t)
        ha, hb = np.isfinite(ta), np.isfinite(tb)
        both = ha & hb
        agree.append(dict(rays=int(ta.size), same_hit_or_miss=float(np.mean(ha == hb)),
                          same_t_bits=float(np.mean(ta[both] == tb[both])),
                          max_rel_t=float(np.max(np.abs(ta[both] - tb[both]) / ta[both])),
                          rel_t_over_1e3=float(np.mean(np.abs(ta[both] - tb[both]) > 1e-3 * ta[both]))))
    integ = mitsuba_integrator(kind, depth)
    runs = {"nearest, flattened": lambda: trace_nearest(flat), "nearest, instanced": lambda: trace_nearest(inst),
            "shadow, flattened": lambda: trace_shadow(flat), "shadow, instanced": lambda: trace_shadow(inst),
            "direct, flattened": lambda: _frame(flat, integ, spp), "direct, instanced": lambda: _frame(inst, integ, spp),
            "links1 (flattened)": lambda: _frame(flat, None, spp)}
    for f in runs.values():
        f()
    cpu = {}
    wall = interleaved(runs, repeats, cpu)
    return dict(spp=spp, size=size, counts=counts, agree=agree,
                shapes=dict(flattened=len(flat.shapes()), instanced=len(inst.shapes())),
                wall_ms={k: float(np.median(v)) for k, v in wall.items()},
                cpu_ms={k: float(np.median(v)) for k, v in cpu.items()})


def markdown(r, info, cmd) -> str:
    w, c = r["wall_ms"], r["cpu_ms"]
    lines = ["# `data_instancing`: flattened (links1's loader) against instanced (`mi.load_file`)", "",
             machine_markdown(info, cmd), "",
             f"512×{r['size'][1]}, spp {r['spp']}: {r['counts']['camera']:,} camera rays, "
             f"{r['counts']['shadow']:,} shadow rays; shapes: {r['shapes']['flattened']} flattened, "
             f"{r['shapes']['instanced']} instances. Interleaved in one process, medians (`compare/instancing_bvh.py`).", "",
             "| run | wall ms | CPU ms | instanced / flattened (CPU) |", "| --- | --- | --- | --- |"]
    for k in w:
        other = k.replace("instanced", "flattened") if "instanced" in k else None
        ratio = f"{c[k] / c[other]:.2f}" if other in c else ""
        lines.append(f"| {k} | {w[k]:.1f} | {c[k]:.1f} | {ratio} |")
    a = r["agree"][0]
    lines += ["", f"links1 / `direct` (CPU): {c['links1 (flattened)'] / c['direct, flattened']:.2f} on the flattened "
              f"scene, {c['links1 (flattened)'] / c['direct, instanced']:.2f} against `direct` on `mi.load_file`'s "
              f"instanced scene; the floor (nearest + shadow) / `direct` on the flattened scene "
              f"{(c['nearest, flattened'] + c['shadow, flattened']) / c['direct, flattened']:.2f}.", "",
              f"The camera rays' hits: the same hit or miss on {100 * a['same_hit_or_miss']:.2f} % of the rays, "
              f"the same `t` bits on {100 * a['same_t_bits']:.1f} % of the hits (largest relative difference "
              f"{a['max_rel_t']:.2g}, above 1e-3 on {100 * a['rel_t_over_1e3']:.3f} % of the hits: the instanced BVH "
              f"intersects in the group's space, another surface wins there).", ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    a = ap.parse_args(argv)
    import mitsuba as mi
    mi.set_variant(a.variant)
    info, cmd = machine_info(), command_line()
    r = measure(a.spp, a.repeats, a.variant)
    md = markdown(r, info, cmd)
    write_results("instancing_bvh", dict(machine=info, command=cmd, args=vars(a), result=r), md)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
