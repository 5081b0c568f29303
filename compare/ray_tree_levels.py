"""Where ``links1_whitted``'s mirror/glass frame goes, level by level, against the rays' floor.

    python -m compare.ray_tree_levels [--only delta_bsdfs] [--spp 16] [--repeats 9] [--variant llvm_ad_rgb]

Per case (``compare.ray_floor``'s mirror/glass scenes with their own filter, 512 px wide), one
scene object: the ray tree traced as the frame traces it (``Tracer.trace_tree`` over the
camera rays of every sample, not frozen, so that parts can be switched off), its parts alone
and variants with one part switched off, all interleaved, ``repeats`` rounds after one
warm-up. Each run is timed twice: the process's CPU time (user + system, every thread: barely
inflated when other jobs share the cores) and the kernels' time (``dr.kernel_history``, wall),
split into the level-1 kernel, the deeper levels' loop kernel and the rest (compaction,
copies, the scatter back to the samples). The runs:

* ``ray tree``: the whole tree as the frame traces it (level 1, compaction, the loop of the
  deeper levels, the scatter back; the camera rays handed over as a function of the lanes too,
  ``trace_tree``'s ``rays``, as the launches do: level 1 keeps the preliminary hits of the
  samples that can spawn and the loop's kernel makes their record and children again);
* ``children stored at level 1``: the tree without ``rays``: level 1 computes its children's
  lobes and stores their origins, directions, weights and keys (20 arrays a sample);
* ``no lobe branch``: every hit computes its delta lobes (``Prepared.spawns`` all true: no
  packet skips them, and every hit is compacted for the loop's kernel to make them); ``no direct-light branch on shaded slots``: the direct light skipped
  only where rays escape (``Prepared.all_shaded``), not also at hits whose BSDF has no smooth
  lobe (both the same bits);
* ``delta lobes computed twice``: the lobes (their BSDF calls included) a second time, added
  times an opaque zero (the same bits): what the lobes cost, i.e. the most that evaluating
  them without BSDF calls could save;
* ``no direct light below level 1``: the tree with the deeper levels' direct light (light
  factors, shadow rays) switched off (the same rays; the image differs);
* ``level 1 as the tree``: the level-1 kernel alone as the tree has it (its radiance,
  counters, which samples can spawn and their preliminary hits, stored);
* ``level 1, children stored``: level 1 as the tree without ``rays`` (its children's lobes,
  rays, weights and keys stored);
* ``level 1, no children``: level 1's radiance alone (no delta lobes sampled, nothing kept);
* ``camera + nearest``: the camera rays and their nearest hit (Embree's full record) alone;
* ``floor, level 1`` / ``floor, deeper levels``: ``compare.ray_floor.trace_floor`` of the
  floor's rays of the camera level / of the levels below it (dense, nearest hits as
  ``ray_intersect_preliminary``, shadow rays as ``ray_test``), with its nearest-hit and
  shadow parts apart, and its nearest hits with Embree's full record (``ray_intersect``,
  ``RayFlags.All``, as links1 traces them; position, normals, frame and uv written);
* ``Mitsuba path frame``: a frame of Mitsuba's ``path`` at the matching depth (its kernels,
  film included; for scale).

Reported: medians of each, and the ratio to the ray tree's of the same round (median over the
rounds); ``same``: the run's radiance equals the tree's bit for bit. Writes
``compare/results/ray_tree_levels.{json,md}``.
"""
from __future__ import annotations

import numpy as np

from compare.common import cpu_seconds, machine_markdown
from compare.ray_tree_parts import measured_note, patched, probe_args, run_probe, traced_case


def _timed(fn, n, tree):
    """``({cpu, level1, deeper, rest}: ms, fn's result)`` of one run of ``fn``; ``tree``: it
    traces links1's ray tree, whose large kernels of ``n`` lanes (the camera level's) are
    level 1's and the others the loop's (else every kernel is "rest")."""
    import drjit as dr
    dr.sync_thread()
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()
    try:
        c0 = cpu_seconds()
        out = fn()
        dr.sync_thread()
        cpu = 1e3 * (cpu_seconds() - c0)
        hist = dr.kernel_history()
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    t = dict(cpu=cpu, level1=0.0, deeper=0.0, rest=0.0)
    for k in hist:
        big = tree and "JIT" in str(k.get("type", "")) and int(k.get("operation_count", 0) or 0) > 200
        part = ("level1" if int(k.get("size", 0) or 0) == n else "deeper") if big else "rest"
        t[part] += float(k.get("execution_time", 0.0))
    return t, out


def measure_case(cid, spp, repeats, variant):
    import drjit as dr
    import mitsuba as mi
    import links1_mitsuba.raytree as rt
    from links1_mitsuba import intersect
    from links1_mitsuba.camera import camera_rays
    from compare.ray_floor import CASES, floor_rays, load_case, mitsuba_integrator, trace_floor

    scene, kind, depth, size = load_case(cid, CASES[cid][3][0], 512, variant)
    tracer, tables, n, sid, spp_, seeds = traced_case(scene, spp)

    def rays():
        return camera_rays(tables, sid, spp_, seeds)

    def lanes(idx):
        return camera_rays(tables, dr.gather(mi.UInt32, sid, idx), spp_, seeds)[:5]

    def tree(remake=True):
        def run():
            o, d, tmin, tmax, key, sample = rays()
            return tracer.trace_tree(tables, scene, o, d, tmin, tmax, key, False, sample,
                                     rays=lanes if remake else None)[0]
        return run

    def level1(kept):
        def run():
            o, d, tmin, tmax, key, sample = rays()
            keep = [] if kept == "hits" else None
            res = tracer.level(tables, scene, o, d, tmin, tmax, key, 1, kept == "children", sample=sample,
                               keep=keep)
            out = [res.L, res.cost, res.n_shadow]
            if kept == "children":
                cr, ct, w_r, w_t = tracer.children(res, res.hit, mi.Color3f(1.0), mi.UInt32(1))
                key_r, key_t = rt.child_keys(key)
                out += [cr, ct, res.o_r, res.dir_r, w_r, key_r, res.o_t, res.dir_t, w_t, key_t]
            elif kept == "hits":
                can = res.hit & dr.gather(mi.Bool, tables.spawns, mi.UInt32(dr.maximum(res.slot, 0)), res.hit)
                out += [can, *intersect.kept_hit(keep[0])]
            dr.eval(*out)
            return res.L
        return run

    def camera_nearest():
        o, d, tmin, tmax, _, _ = rays()
        t, slot, si, _ = intersect.nearest(tables, scene, o, d, tmin, tmax, dr.full(mi.Bool, True, n),
                                           dr.zeros(mi.UInt32, n), coherent=True)
        dr.eval(t, slot, si.p, si.sh_frame.n)

    plain_level = rt.Tracer.__dict__["level"]

    def level_no_direct_below_1(self, tables, scene, o, d, tmin, tmax, key, depth, spawn, **kw):
        if depth == 1:
            return plain_level(self, tables, scene, o, d, tmin, tmax, key, depth, spawn, **kw)
        with patched((rt.Tracer, "_direct", lambda self, t, s, h, *a: (a[-3], a[-2], a[-1]))):
            return plain_level(self, tables, scene, o, d, tmin, tmax, key, depth, spawn, **kw)

    plain_lobes = rt.Tracer.__dict__["_lobes"]
    zero = dr.opaque(mi.Float, 0.0)

    def lobes_twice(self, tables, h, r, tw, dir_r, dir_t):
        """The lobes computed a second time (BSDF calls included), added times an opaque 0."""
        a = plain_lobes(self, tables, h, r, tw, dir_r, dir_t)
        b = plain_lobes(self, tables, h, r * (1.0 + zero), tw, dir_r, dir_t)
        return tuple(x + y * zero for x, y in zip(a, b))

    def nearest_full(sel):
        def run():
            for _, ray, coherent, _, _ in sel:
                si = scene.ray_intersect(ray, mi.RayFlags.All, coherent)
                dr.eval(si.t, si.p, si.n, si.sh_frame.s, si.sh_frame.n, si.uv)
            dr.sync_thread()
        return run

    base = tables.base or tables
    batches, counts = floor_rays(scene, size, spp, depth, float(scene.integrator().min_weight))
    pick = lambda levels, kinds: [b for b in batches if (b[0] == 0) == (levels == "1") and b[3] in kinds]  # noqa: E731
    integ = mitsuba_integrator(kind, depth)
    floor = lambda levels, kinds: (lambda: trace_floor(scene, pick(levels, kinds)), ())  # noqa: E731
    runs = {
        "ray tree": (tree(), ()),
        "children stored at level 1": (tree(False), ()),
        "no lobe branch (every hit's lobes)": (tree(), ((base, "spawns", dr.full(mi.Bool, True, base.nslots)),)),
        "no direct-light branch on shaded slots": (tree(), ((base, "all_shaded", True),)),
        "delta lobes computed twice": (tree(), ((rt.Tracer, "_lobes", lobes_twice),)),
        "no direct light below level 1": (tree(), ((rt.Tracer, "level", level_no_direct_below_1),)),
        "level 1 as the tree": (level1("hits"), ()),
        "level 1, children stored": (level1("children"), ()),
        "level 1, no children": (level1(None), ()),
        "camera + nearest": (camera_nearest, ()),
        "floor, level 1": floor("1", ("nearest", "shadow")),
        "floor, level 1: nearest": floor("1", ("nearest",)),
        "floor, level 1: nearest, full record": (nearest_full(pick("1", ("nearest",))), ()),
        "floor, level 1: shadow": floor("1", ("shadow",)),
        "floor, deeper levels": floor("deeper", ("nearest", "shadow")),
        "floor, deeper: nearest": floor("deeper", ("nearest",)),
        "floor, deeper: nearest, full record": (nearest_full(pick("deeper", ("nearest",))), ()),
        "floor, deeper: shadow": floor("deeper", ("shadow",)),
        "Mitsuba path frame": (lambda: dr.eval(mi.render(scene, integrator=integ, spp=spp, seed=0)), ()),
    }
    #: the runs that trace the whole tree (their images compared with the tree's)
    whole = ("ray tree", "children stored at level 1",
             "no lobe branch (every hit's lobes)", "no direct-light branch on shaded slots",
             "delta lobes computed twice", "no direct light below level 1")
    images = {}
    for name, (fn, patch) in runs.items():        # warm-up (compilation), and the images
        with patched(*patch):
            _, out = _timed(fn, n, not name.startswith(("floor", "Mitsuba")))
        if name in whole:
            images[name] = np.asarray(out).copy()
    times = {k: [] for k in runs}
    for _ in range(repeats):
        for name, (fn, patch) in runs.items():
            with patched(*patch):
                times[name].append(_timed(fn, n, not name.startswith(("floor", "Mitsuba")))[0])
    ref = times["ray tree"]
    rows = []
    for name, ts in times.items():
        row = dict(part=name, same=(bool(np.array_equal(images[name], images["ray tree"]))
                                    if name in images else None))
        for k in ("cpu", "level1", "deeper", "rest"):
            row[k] = float(np.median([t[k] for t in ts]))
        row["kernels"] = float(np.median([t["level1"] + t["deeper"] + t["rest"] for t in ts]))
        row["cpu_ratio"] = float(np.median([t["cpu"] / r["cpu"] for t, r in zip(ts, ref)]))
        row["cpu_rounds"] = [t["cpu"] for t in ts]
        rows.append(row)
    return dict(id=cid, spp=spp, lanes=n, floor_rays=counts, rows=rows)


def markdown(cases, a, info, cmd) -> str:
    md = ["# links1_whitted's mirror/glass frame, level by level\n\n", machine_markdown(info, cmd),
          "\nThe machine was shared with other jobs (2 cores). Rounds interleaved (`--repeats` of the case's run), medians; "
          "CPU: the process's CPU time of the run (every thread); kernels: `dr.kernel_history`'s wall "
          "time of its kernels (level 1, the deeper levels' loop, the rest); ratio: CPU time to the ray "
          "tree's of the same round (median over the rounds); same: the run's radiance equals the "
          "tree's bit for bit (`compare/ray_tree_levels.py`).\n"]
    for c in cases:
        fr = c["floor_rays"]
        md.append(f"\n## `{c['id']}`, spp {c['spp']} ({c['lanes']:,} camera rays; the floor's rays: "
                  f"{fr['shadow']:,} shadow, {fr['secondary']:,} below level 1)\n\n"
                  + measured_note(c) + "| run | CPU ms | / ray tree (CPU) | kernels ms | level 1 | deeper | rest | same image |\n"
                  "| --- | --- | --- | --- | --- | --- | --- | --- |\n")
        for r in c["rows"]:
            same = "—" if r["same"] is None else ("yes" if r["same"] else "no")
            md.append(f"| {r['part']} | {r['cpu']:.1f} | {r['cpu_ratio']:.3f} | {r['kernels']:.1f} | "
                      f"{r['level1']:.1f} | {r['deeper']:.1f} | {r['rest']:.1f} | {same} |\n")
    return "".join(md)


def _line(cid, r) -> str:
    return (f"{cid:12s} {r['part']:36s} cpu {r['cpu']:8.1f} ms {r['cpu_ratio']:.3f}  kernels {r['kernels']:7.1f} "
            f"(L1 {r['level1']:6.1f} deeper {r['deeper']:6.1f} rest {r['rest']:5.1f})  same={r['same']}")


def main(argv=None) -> int:
    a = probe_args(argv, "compare.ray_tree_levels", __doc__, ["delta_bsdfs"])
    return run_probe(a, "ray_tree_levels", measure_case, _line, markdown)


if __name__ == "__main__":
    raise SystemExit(main())
