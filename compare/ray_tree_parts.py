"""Where ``links1_whitted``'s ray-tree kernel spends its time beyond the rays' floor.

    python -m compare.ray_tree_parts [--only teapot cbox_point data_instancing delta_bsdfs cbox_mirror_glass]
                                     [--spp 16] [--repeats 9]

Per case (``compare.ray_floor``'s scenes with a box filter, 512 px wide), one scene object,
the level-1 ray tree traced as the frame traces it (``Tracer.trace_tree`` over the camera
rays of every sample, not frozen, so that parts can be switched off) and variants of it with
one part switched off or replaced, all interleaved, ``repeats`` rounds after one warm-up:
the time of the kernels each launches (``dr.kernel_history``), medians, and the ratio to
the whole kernel of the same round (median over the rounds). The variants:

* ``no box cull``: the shadow rays go to Embree without the occluder boxes' slab test
  (``Tuning.box_cull`` off);
* ``no counters``: the level's radiance alone evaluated (no per-lane cost and shadow-ray
  counts written; level 1 alone: where the tree goes deeper, through delta BSDFs, the image
  differs);
* ``minimal record``: Embree's hit expanded with ``RayFlags.Minimal | ShadingFrame`` (no uv,
  no dp/du: the diffuse BSDFs read the shading normal alone);
* ``camera rays loaded``: the camera rays made beforehand and read (the kernel without
  making them);
* ``no shadow rays``: every shadow ray unoccluded (the image differs);
* ``shadow rays made beforehand and read``: each light's shadow test on its rays captured
  from level 1 (below), read instead of made in the kernel (the same lanes; no box cull); the
  deeper levels' shadow rays (delta BSDFs) made in the kernel, no box cull either;
* ``shadow origins made beforehand and read``: the same with the origins alone read;
* ``no branch on the hit``: direct light computed masked at every lane, not under the
  symbolic branch that skips escaped rays (``Tuning.skip_misses``);
* ``geometric normal := shading normal``: Mitsuba's record's geometric normal ``si.n`` (the
  side and direction of the shadow rays' offset) replaced by its shading normal (the image
  differs where the kernel reads ``si.n``);
* ``Mitsuba's surface record``: the nearest hit's record from ``scene.ray_intersect`` (Embree's
  hit and the shapes' surface call) where the kernel makes it from the preliminary hit on
  the meshes (``tables.MeshRecord``, ``intersect.mesh_surface``; the same bits);
* ``fixed BSDF``: a Lambert factor in place of the BSDF factor (the image differs);
* ``diffuse BSDFs called``: every BSDF called (``BSDF::eval``), the ``diffuse`` BSDFs of one
  reflectance too, which the kernel evaluates from their table (``tables._lambert_tables``);
* ``record from the mesh buffers``: the meshes' hits read their face's index and its vertices
  from the meshes' buffers (gathers), not from the per-face table (``MeshRecord.packets``,
  packet gathers); the same bits;
* ``no shadow rays, no branch on the hit``: both of the variants above (the image differs); and
  the same with the record's reads of its tables (the per-face table, the meshes' buffers,
  each slot's first face, the rows of rectangles and spheres) or the shading's (the diffuse
  table's reflectance, each slot's ray offset) replaced by arithmetic on their index: what
  reading them costs (without shadow tests and the branch, the made-up points and normals
  change no lane's work, only values);
* ``camera + nearest``: the camera rays and their nearest hit only (``t``, slot);
* ``camera + preliminary hit``: the camera rays and Embree's preliminary hit alone
  (``scene.ray_intersect_preliminary``: what the full record adds to ``camera + nearest``).

And the floor's parts (``compare.ray_floor.trace_floor``): the camera rays' preliminary
hits (rays read), the shadow rays links1 traces (captured from the level) densely packed and
as full-width masked packets; and a frame of Mitsuba's ``direct`` (emitter_samples 1,
bsdf_samples 0), or of its ``path`` at the case's depth where the tree goes deeper (kernels,
so also its film). ``same`` says whether a variant's radiance equals
the kernel's bit for bit. Writes ``compare/results/ray_tree_parts.{json,md}``: the cases run
replace those of the same id there, the others are kept, each with the commit and load of
the run that measured it.
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json

import numpy as np

from compare.common import RESULTS, command_line, machine_info, machine_markdown, write_results


def _kernels_ms(fn) -> float:
    """Milliseconds of the kernels ``fn()`` launches (``dr.kernel_history``)."""
    import drjit as dr
    dr.sync_thread()
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()
    try:
        fn()
        dr.sync_thread()
        return sum(float(k.get("execution_time", 0.0)) for k in dr.kernel_history())
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)


@contextlib.contextmanager
def patched(*pairs):
    """``(object, attribute, value)`` set for the block, restored after it (a class's own
    entry restored as it was: a staticmethod stays one)."""
    old = [(o, a, o.__dict__[a] if isinstance(o, type) else getattr(o, a)) for o, a, _ in pairs]
    for o, a, v in pairs:
        setattr(o, a, v)
    try:
        yield
    finally:
        for o, a, v in old:
            setattr(o, a, v)


def made_up(sources):
    """A stand-in for the ``drjit`` module whose ``gather`` from one of the arrays ``sources``
    returns values made by arithmetic on the index (no memory read; the values differ), every
    other name Dr.Jit's: ``module.dr`` patched with it, what ``module``'s reads of ``sources``
    cost."""
    import types

    import drjit as dr
    import mitsuba as mi
    ids = {id(a) for a in sources if a is not None}

    def gather(dtype, source, index, active=True, **kw):
        if id(source) not in ids:
            return dr.gather(dtype, source, index, active, **kw)
        x = mi.Float(index) * 1e-3
        if dtype is mi.ArrayXf:
            return [x + 0.25 * i for i in range(kw["shape"][0])]
        if dtype in (mi.UInt32, mi.Int32):
            return dtype(index & 7)
        if dtype is mi.Float:
            return x + 0.5
        return dtype(*[x + 0.25 * i for i in range(dr.size_v(dtype))])
    return types.SimpleNamespace(**{**{k: getattr(dr, k) for k in dir(dr) if not k.startswith("__")},
                                    "gather": gather})


def traced_case(scene, spp):
    """What tracing a loaded case's ray tree by hand takes (after one frame): ``(tracer,
    tables, lanes, sample ids, (spp, strata), seeds)`` as the frame's launch has them."""
    import drjit as dr
    import mitsuba as mi
    from links1.maths.sampling import key_seed, strata
    mi.render(scene, spp=1)
    eng = scene.integrator().engine
    tracer = eng._tracer()
    tables = eng.tables.prepare(scene, None, tracer.tuning)
    W, H = tables.film_size
    n = W * H * spp
    sid = dr.arange(mi.UInt32, n)
    dr.eval(sid)
    spp_ = (dr.opaque(mi.UInt32, spp), dr.opaque(mi.UInt32, strata(spp)))
    seeds = (dr.opaque(mi.UInt32, 0), dr.opaque(mi.UInt32, key_seed(0)))
    return tracer, tables, n, sid, spp_, seeds


def measure_case(cid, spp, repeats, variant):
    import drjit as dr
    import mitsuba as mi
    import links1_mitsuba.intersect as isect
    import links1_mitsuba.raytree as rt
    from links1_mitsuba.camera import camera_rays
    from compare.ray_floor import floor_rays, load_case, mitsuba_integrator, trace_floor

    scene, kind, depth, size = load_case(cid, "box", 512, variant)
    tracer, tables, n, sid, spp_, seeds = traced_case(scene, spp)
    loaded = camera_rays(tables, sid, spp_, seeds)
    dr.eval(*loaded[:5], *loaded[5])

    def rays(pre=False):
        return loaded if pre else camera_rays(tables, sid, spp_, seeds)

    def tree(pre=False):
        o, d, tmin, tmax, key, sample = rays(pre)
        return tracer.trace_tree(tables, scene, o, d, tmin, tmax, key, False, sample)[0]

    def level_only():
        o, d, tmin, tmax, key, sample = rays()
        res = tracer.level(tables, scene, o, d, tmin, tmax, key, 1, False, sample=sample)
        dr.eval(res.L)
        return res.L

    def camera_nearest():
        o, d, tmin, tmax, _, _ = rays()
        t, slot, _, _ = isect.nearest(tables, scene, o, d, tmin, tmax, dr.full(mi.Bool, True, n),
                                      dr.zeros(mi.UInt32, n), coherent=True)
        dr.eval(t, slot)

    def camera_preliminary():
        o, d, tmin, tmax, _, _ = rays()
        pi = scene.ray_intersect_preliminary(mi.Ray3f(o + d * tmin, d, tmax - tmin), True)
        dr.eval(pi.t, pi.shape)

    def nearest_flags(flags):
        def nearest(tables, scene, o, d, tmin, tmax, active, cost, eye=False, coherent=False, ad=False, **_):
            ray = mi.Ray3f(o + d * tmin, d, tmax - tmin)
            si = scene.ray_intersect(ray, flags, bool(coherent), active)
            valid = active & si.is_valid()
            t = dr.select(valid, si.t + tmin, isect.INF)
            reg = dr.reinterpret_array(mi.UInt32, si.shape)
            slot = dr.select(valid, dr.gather(mi.Int32, tables.reg_to_slot, reg, valid), -1)
            cost += dr.select(active, mi.UInt32(1), 0)
            return t, slot, si, dr.zeros(mi.UInt32, dr.width(o))
        if tables.custom or not tables.any_mitsuba_shapes:
            raise RuntimeError(f"{cid}: the minimal record variant is for Mitsuba shapes alone")
        return nearest

    def unoccluded(tables, scene, o, d, smax, active, T, cost, tuning, light=None, own=None, coherent=False):
        return T

    def lambert(self, wi):
        return mi.Color3f(0.5) * dr.maximum(dr.dot(self.nf, wi), 0.0)

    # links1's own shadow rays (captured from the level traced in steps, by light) and the floor's
    captured = []

    def capture(tables, scene, o, d, smax, active, T, cost, tuning, light=None, own=None, coherent=False):
        captured.append((mi.Ray3f(o, d, smax, 0.0, mi.Color0f()), mi.Bool(active)))
        return T
    with patched((isect, "shadow_mitsuba", capture),
                 (tracer, "tuning", dataclasses.replace(tracer.tuning, skip_misses=False))):
        o, d, tmin, tmax, key, sample = rays()
        dr.eval(tracer.level(tables, scene, o, d, tmin, tmax, key, 1, False, sample=sample, symbolic=False).L)
    for ray, act in captured:
        dr.eval(ray, act)

    # the shadow rays read are level 1's: a deeper level's (the tree's loop, another width)
    # makes its own, as the kernel does without the box cull
    plain_level, plain_shadow = type(tracer).level, isect.shadow_mitsuba
    in_level1 = [False]

    def level(self, tables, scene, o, d, tmin, tmax, key, depth, *args, **kw):
        in_level1[0] = depth == 1
        try:
            return plain_level(self, tables, scene, o, d, tmin, tmax, key, depth, *args, **kw)
        finally:
            in_level1[0] = False

    def read_rays(tables, scene, o, d, smax, active, T, cost, tuning, light=None, own=None, coherent=False):
        """The shadow test of light ``light`` on its level-1 ray captured above (made beforehand
        and read; the same lanes), no box cull; Embree's mode the kernel's."""
        if not in_level1[0]:
            return plain_shadow(tables, scene, o, d, smax, active, T, cost, no_cull, light, own)
        cost += dr.select(active, mi.UInt32(1), 0)
        return dr.select(scene.ray_test(captured[light][0], coherent and tuning.coherent_shadows, active), 0.0, T)

    def read_origins(tables, scene, o, d, smax, active, T, cost, tuning, light=None, own=None, coherent=False):
        """As :func:`read_rays` with the ray's origin alone read (direction, length made here)."""
        if not in_level1[0]:
            return plain_shadow(tables, scene, o, d, smax, active, T, cost, no_cull, light, own)
        cost += dr.select(active, mi.UInt32(1), 0)
        ray = mi.Ray3f(captured[light][0].o, d, smax, 0.0, mi.Color0f())
        return dr.select(scene.ray_test(ray, coherent and tuning.coherent_shadows, active), 0.0, T)

    plain_nearest = isect.nearest

    def shading_normal(*args, **kw):
        t, slot, si, prim = plain_nearest(*args, **kw)
        si.n = mi.Normal3f(si.sh_frame.n)
        return t, slot, si, prim

    base_tables = tables.base or tables
    rec = base_tables.mesh_record
    record_tables = [] if rec is None else [rec.packets, rec.faces, rec.positions, rec.normals, rec.texcoords,
                                            rec.face_off, rec.rows]
    shading_tables = [base_tables.lam_rgb, base_tables.eps_table]
    made_up_shading = made_up(shading_tables)
    no_cull = dataclasses.replace(tracer.tuning, box_cull=False)
    no_branch = dataclasses.replace(tracer.tuning, skip_misses=False)
    plain = ((isect, "shadow_mitsuba", unoccluded), (tracer, "tuning", no_branch))
    base = (tree, ())
    variants = {
        "ray-tree kernel": base,
        "no box cull": (tree, ((tracer, "tuning", no_cull),)),
        "no counters": (level_only, ()),
        "minimal record": (tree, ((isect, "nearest", nearest_flags(mi.RayFlags.Minimal | mi.RayFlags.ShadingFrame)),)),
        "camera rays loaded": (lambda: tree(True), ()),
        "no shadow rays": (tree, ((isect, "shadow_mitsuba", unoccluded),)),
        "shadow rays made beforehand and read": (tree, ((isect, "shadow_mitsuba", read_rays), (type(tracer), "level", level))),
        "no branch on the hit": (tree, ((tracer, "tuning", no_branch),)),
        "shadow origins made beforehand and read": (tree, ((isect, "shadow_mitsuba", read_origins),
                                                           (type(tracer), "level", level))),
        "geometric normal := shading normal": (tree, ((isect, "nearest", shading_normal),)),
        "Mitsuba's surface record": (tree, ((tables.base or tables, "mesh_record", None),)),
        "fixed BSDF": (tree, ((rt.Hit, "f_eval", lambda self, wi: lambert(self, wi)),)),
        "diffuse BSDFs called": (tree, ((tables.base or tables, "any_lam", False),)),
        "record from the mesh buffers": (tree, () if rec is None else ((rec, "packets", None),)),
        "no shadow rays, no branch on the hit": (tree, plain),
        "the same, the record's gathers replaced": (tree, plain + ((isect, "dr", made_up(record_tables)),)),
        "the same, the shading's gathers replaced": (tree, plain + ((rt, "dr", made_up_shading), (
            rt, "gather3", lambda t, i, a=True: made_up_shading.gather(mi.Color3f, t, i, a)))),
        "camera + nearest": (camera_nearest, ()),
        "camera + preliminary hit": (camera_preliminary, ()),
    }
    images = {}
    for name, (fn, patch) in variants.items():
        with patched(*patch):
            out = fn()
            if out is not None:
                images[name] = np.asarray(out).copy()
    dense = []
    for ray, act in captured:
        dr.eval(ray, act)
        dense.append(dr.gather(mi.Ray3f, ray, dr.compress(act)))
        dr.eval(dense[-1])
    batches, _ = floor_rays(scene, size, spp, depth, float(scene.integrator().min_weight))
    cam_batches = [b for b in batches if b[3] == "nearest"]
    direct = mitsuba_integrator(kind, depth)
    floors = {
        "floor: camera rays' preliminary hits": lambda: trace_floor(scene, cam_batches),
        "floor: links1's shadow rays, dense": lambda: [dr.eval(scene.ray_test(r)) for r in dense],
        "floor: links1's shadow rays, masked": lambda: [dr.eval(scene.ray_test(r, False, a)) for r, a in captured],
        f"Mitsuba {kind} frame (its kernels)": lambda: dr.eval(mi.render(scene, integrator=direct, spp=spp, seed=0)),
    }
    runs = {**{k: v for k, v in variants.items()}, **{k: (f, ()) for k, f in floors.items()}}
    for _, (fn, patch) in runs.items():
        with patched(*patch):
            fn()
    times = {k: [] for k in runs}
    for _ in range(repeats):
        for name, (fn, patch) in runs.items():
            with patched(*patch):
                times[name].append(_kernels_ms(fn))
    ms = {k: float(np.median(v)) for k, v in times.items()}
    ref = images["ray-tree kernel"]
    rr = {k: [a / b for a, b in zip(times[k], times["ray-tree kernel"])] for k in runs}
    rows = [dict(part=k, ms=ms[k], ratio=float(np.median(rr[k])), round_ratios=rr[k],
                 same=(bool(np.array_equal(images[k], ref)) if k in images else None)) for k in runs]
    return dict(id=cid, spp=spp, lanes=n, shadow_rays=[int(dr.width(r)) for r in dense], rows=rows)


def markdown(cases, a, info, cmd) -> str:
    md = ["# links1_whitted's ray-tree kernel by part\n\n", machine_markdown(info, cmd),
          f"\nThe machine was shared with other jobs (2 cores): only ratios measured in the same run mean "
          f"something (the header's run is the latest; each case names its own). Kernel time (`dr.kernel_history`) of each variant, rounds interleaved (`--repeats` of the case's run, 9 by default), "
          "medians; ratio: to the whole ray-tree kernel of the same round (median over the rounds, "
          "min–max in brackets); same: the "
          "variant's radiance equals the kernel's bit for bit (`compare/ray_tree_parts.py`).\n"]
    for c in cases:
        md.append(f"\n## `{c['id']}`, box filter, spp {c['spp']} ({c['lanes']:,} camera rays; links1's shadow "
                  f"rays by light: {', '.join(f'{v:,}' for v in c['shadow_rays'])})\n\n"
                  + measured_note(c) + "| part | kernels ms | / ray-tree kernel | same image |\n| --- | --- | --- | --- |\n")
        for r in c["rows"]:
            rr = r["round_ratios"]
            same = "—" if r["same"] is None else ("yes" if r["same"] else "no")
            md.append(f"| {r['part']} | {r['ms']:.1f} | {r['ratio']:.3f} ({min(rr):.2f}–{max(rr):.2f}) | {same} |\n")
    return "".join(md)


def probe_args(argv, module, doc, only):
    """The arguments of a ray-tree probe (this module's, ``compare.ray_tree_levels``'): the
    cases (``only``: the default ones), spp, repeats, variant."""
    ap = argparse.ArgumentParser(prog=f"python -m {module}", description=doc.split("\n\n")[0])
    ap.add_argument("--only", nargs="*", default=only)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    return ap.parse_args(argv)


def merge_cases(old: dict | None, cases: list[dict]) -> list[dict]:
    """The cases of a results file (``old``: its payload, or None) with those of this run
    (``cases``) in place of the ones of the same id, the others kept (order: the file's, then
    the new ids). Each case carries ``measured`` (the commit, load at the start and command of
    the run that measured it); a kept case without one takes its file's."""
    cases = list(cases)
    new = {c["id"]: c for c in cases}
    merged, seen = [], set()
    for c in (old or {}).get("cases", []):
        if c["id"] in new:
            merged.append(new[c["id"]])
            seen.add(c["id"])
            continue
        if "measured" not in c:
            info = old.get("machine", {})
            c = dict(c, measured=dict(commit=info.get("git_commit"), load=info.get("load_average_at_start"),
                                      command=old.get("command")))
        merged.append(c)
    return merged + [c for c in cases if c["id"] not in seen]


def measured_note(c: dict) -> str:
    """The line under a case's heading that says which run measured it."""
    m = c.get("measured") or {}
    load = m.get("load")
    load = ", ".join(f"{x:g}" for x in load) if isinstance(load, (list, tuple)) else load
    return f"Measured at commit {m.get('commit')}, load at the start {load}: `{m.get('command')}`.\n\n"


def run_probe(a, stem, measure, line, markdown) -> int:
    """A ray-tree probe's run: ``measure(case, spp, repeats, variant)`` per case of ``a``
    (:func:`probe_args`), a line (``line(case id, row)``) per row printed, and
    ``compare/results/{stem}.{json,md}`` (``markdown(cases, a, info, command)``) written: this
    run's cases replace those of the same id there, the others are kept (:func:`merge_cases`)."""
    info, cmd = machine_info(), command_line()
    cases = []
    for cid in a.only:
        c = measure(cid, a.spp, a.repeats, a.variant)
        c["measured"] = dict(commit=info.get("git_commit"), load=info.get("load_average_at_start"), command=cmd)
        cases.append(c)
        for r in c["rows"]:
            print(line(cid, r), flush=True)
    path = RESULTS / f"{stem}.json"
    cases = merge_cases(json.loads(path.read_text()) if path.exists() else None, cases)
    paths = write_results(stem, dict(machine=info, command=cmd, args=vars(a), cases=cases),
                          markdown(cases, a, info, cmd))
    print("wrote", ", ".join(str(p) for p in paths))
    return 0


def main(argv=None) -> int:
    a = probe_args(argv, "compare.ray_tree_parts", __doc__, ["teapot", "cbox_point", "data_instancing", "delta_bsdfs",
                                                              "cbox_mirror_glass"])
    return run_probe(a, "ray_tree_parts", measure_case,
                     lambda cid, r: f"{cid:12s} {r['part']:40s} {r['ms']:8.1f} ms  {r['ratio']:.3f}  same={r['same']}",
                     markdown)


if __name__ == "__main__":
    raise SystemExit(main())
