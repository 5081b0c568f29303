"""Inverse rendering through outlines and shadow edges (``links1_whitted`` with
``projective=true``): a benchmark.

    python -m compare.inverse_outline [--width 64] [--iters 150] [--blob-iters 300] [--rounds 9]
                                      [--variant llvm_ad_rgb] [--only quadric_outline blob_view]

As :mod:`compare.inverse` (its ``run_case``: ``mi.ad.Adam`` on the L2 image loss, the worst
parameter's error over its range, iteration time against the primal frame), on cases whose
gradients need the visibility term (docs/method.md §6):

* ``quadric_outline``: a ``links1_quadric`` sphere of one constant colour (ambient only)
  before black, placed from its outline alone (translation ``t``): without the term its
  gradient is 0 everywhere;
* ``blob_view``: the 6-centre blob of ``compare.inverse`` over the Phong floor, one view, no
  loss mask: its centres and threshold ``T`` (eq. 3.6–3.9) from its outline, shading and
  shadow on the floor (its weights are known: every weight and ``T`` scaled alike leave the
  surface ``W = T`` unchanged, so no image tells both).

4 samples a pixel (box filter) in both frames and the derivative pass, ``max_depth`` 2, every
iteration at ``seed`` 0. The times: ``--rounds`` interleaved rounds of an iteration and a
primal frame at ``--big`` (``compare.inverse.timing_only``), medians. With ``--stages``,
where an iteration at ``--big`` goes (:func:`stages`). Writes
``compare/results/inverse_outline.{json,md}``.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from compare import inverse
from compare.common import command_line, machine_info, machine_markdown, md_table, write_results

PROJECTIVE = """<integrator type="links1_whitted"><integer name="max_depth" value="2"/>
    <boolean name="projective" value="true"/></integrator>"""

BLOB = """<shape type="links1_blob" id="blob">
    <string name="centers" value=\"""" + ", ".join(" ".join(f"{x:g}" for x in r) for r in inverse.BLOB_CENTRES) + """\"/>
    <float name="threshold" value="0.5"/>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.5, 0.4, 0.3"/><rgb name="specular" value="0.3"/>
      <rgb name="reflectance" value="0"/><float name="exponent" value="10"/></bsdf></shape>"""

SCENES = {
    "quadric_outline": dict(camera=dict(fov=40, origin="0, 3, 6", target="0, 0.8, 0"), spp=4, integrator=PROJECTIVE,
                            body="""
  <shape type="links1_quadric" id="ball"><string name="kind" value="sphere"/>
    <transform name="to_world"><scale value="1.2"/><translate x="0.2" y="1.4" z="0.3"/></transform>
    <bsdf type="links1_phong"><rgb name="ambient" value="0.8, 0.6, 0.4"/><rgb name="diffuse" value="0"/></bsdf></shape>"""
                            + inverse.LIGHTS),
    "blob_view": dict(camera=dict(fov=50, origin="0, 2.6, 5", target="0.1, 1.3, 0"), spp=4, integrator=PROJECTIVE,
                      body=inverse.FLOOR.format(refl=0) + BLOB + inverse.LIGHTS),
}


def make_cases(iters, blob_iters):
    rng = np.random.default_rng(29)
    t0 = np.array([0.2, 1.4, 0.3])
    c0 = np.array(inverse.BLOB_CENTRES)[:, :3].T
    return [
        # translation within ±0.25 per axis (range 0.5), as compare.inverse's quadric
        ("quadric_outline", inverse.QuadricCase, {
            "t": dict(truth=t0, start=t0 + np.array([0.2, -0.15, 0.2]), range=0.5, lo=None),
        }, {"t": 0.01}, iters),
        # centres ±0.1 per axis (range 0.2), threshold ±0.05 (range 0.1); the weights are known
        # (scaling every weight and T alike leaves the surface W = T as it is: not both)
        ("blob_view", inverse.Case, {
            "links1_whitted.blob.centers": dict(truth=c0, start=c0 + rng.uniform(-0.1, 0.1, c0.shape), range=0.2, lo=None),
            "links1_whitted.blob.threshold": dict(truth=np.array([0.5]), start=np.array([0.54]), range=0.1, lo=0.05),
        }, {"links1_whitted.blob.centers": 0.005, "links1_whitted.blob.threshold": 0.002}, blob_iters),
    ]


def stages(mi, dr, name, cls, variables, lrs, width, n, log):
    """Where an iteration at ``width``² goes, ``n`` iterations (after 2) with
    ``dr.JitFlag.KernelHistory``: its wall time, the visibility term's (``boundary_image``
    wrapped: made, evaluated, synced) and the kernels of each (count, execution time as Dr.Jit
    reports it, compiled ones), the primal frame's wall time; medians."""
    from links1_mitsuba import boundary
    scene = inverse.load(name, width)
    case = cls(name, scene, variables, lrs, n)
    params = mi.traverse(scene)
    case.setup(mi, params)
    target = mi.render(scene, seed=0)
    inverse.sync(target)
    case.set_values(mi, params, {k: d["start"] for k, d in variables.items()})
    opt = inverse.optimizer(mi, case, params, variables, lrs)
    term, inner = [], boundary.boundary_image

    def jit(history):
        return [k for k in history if k.get("type") == dr.KernelType.JIT]

    def timed_term(*args, **kwargs):
        dr.sync_thread()
        before = jit(dr.kernel_history())
        t0 = time.perf_counter()
        img = inner(*args, **kwargs)
        dr.eval(img)
        dr.sync_thread()
        term.append((time.perf_counter() - t0, jit(dr.kernel_history()), before))
        return img

    def kernels(ks):
        return len(ks), sum(k["execution_time"] for k in ks), sum(1 for k in ks if not k["cache_hit"])

    rows = []
    boundary.boundary_image = timed_term
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        for r in range(n + 2):
            term.clear()
            dr.kernel_history()
            t0 = time.perf_counter()
            img = mi.render(scene, params, seed=0)
            dr.backward(dr.mean(dr.square(img - target), axis=None))
            opt.step()
            case.apply(mi, params, opt)
            inverse.sync(opt[next(iter(variables))])
            t_it = time.perf_counter() - t0
            rest = jit(dr.kernel_history()) + [k for _, _, b in term for k in b]
            t0 = time.perf_counter()
            inverse.sync(mi.render(scene, seed=0))
            t_primal = time.perf_counter() - t0
            dr.kernel_history()
            if r >= 2:
                rows.append([t_it * 1e3, sum(t for t, _, _ in term) * 1e3, len(term),
                             *kernels([k for _, ks, _ in term for k in ks]), *kernels(rest), t_primal * 1e3])
    finally:
        boundary.boundary_image = inner
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    med = np.median(np.array(rows), axis=0)
    out = dict(case=name, width=width, iterations=n, iteration_ms=med[0], term_ms=med[1], term_calls=med[2],
               term_kernels=med[3], term_kernel_ms=med[4], term_compiled=med[5], other_kernels=med[6],
               other_kernel_ms=med[7], other_compiled=med[8], primal_ms=med[9])
    log(f"  {name} at {width}²: iteration {med[0]:.1f} ms, term {med[1]:.1f} ms ({med[3]:.0f} kernels, "
        f"{med[4]:.1f} ms of them), other kernels {med[6]:.0f} ({med[7]:.1f} ms), primal {med[9]:.1f} ms")
    return out


def stages_markdown(rows):
    return md_table(["case", "iteration ms", "term ms (calls)", "term kernels: n, ms, compiled",
                     "other kernels: n, ms, compiled", "primal ms"],
                    [[r["case"], f"{r['iteration_ms']:.1f}", f"{r['term_ms']:.1f} ({r['term_calls']:.0f})",
                      f"{r['term_kernels']:.0f}, {r['term_kernel_ms']:.1f}, {r['term_compiled']:.0f}",
                      f"{r['other_kernels']:.0f}, {r['other_kernel_ms']:.1f}, {r['other_compiled']:.0f}",
                      f"{r['primal_ms']:.1f}"] for r in rows])


def markdown(results, info, cmd):
    rows = [[r["case"], r["iters"], f"{r['final_worst_error'] * 100:.3f} %", r["iterations_to_1pct"],
             ", ".join(f"{k.split('.')[-1]} {v * 100:.3f} %" for k, v in r["final_error"].items()),
             f"{r['timing']['primal_median_ms']:.1f}", f"{r['timing']['iteration_median_ms']:.1f}",
             f"{r['timing']['ratio']:.2f}"] for r in results]
    return ("# Inverse rendering through outlines (projective=true)\n\n" + machine_markdown(info, cmd) + "\n"
            + md_table(["case", "iterations", "worst error / range", "iterations to ≤ 1 %", "per parameter",
                        "primal ms", "iteration ms", "ratio"], rows)
            + "\nIteration: render with gradients (primal frame, derivative pass with the boundary term), "
              "L2 loss, dr.backward, Adam step, params.update; primal: mi.render without gradients. "
              "Times: medians of interleaved rounds at the --big width.\n"
            + ("" if not any("stages" in r for r in results) else
               "\nWhere an iteration at the --big width goes (--stages: medians, with Dr.Jit's kernel "
               "history on; term: the visibility term made, evaluated and synced; kernel ms: execution "
               "times as Dr.Jit reports them):\n\n" + stages_markdown([r["stages"] for r in results if "stages" in r])))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=64)
    ap.add_argument("--iters", type=int, default=150)
    ap.add_argument("--blob-iters", type=int, default=300)
    ap.add_argument("--rounds", type=int, default=9, help="timing rounds (interleaved iteration / frame)")
    ap.add_argument("--big", type=int, default=256, help="the width the times are taken at")
    ap.add_argument("--no-fit", action="store_true", help="the times alone")
    ap.add_argument("--stages", type=int, default=0, metavar="N",
                    help="also where an iteration at --big goes, N iterations with Dr.Jit's kernel history")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--only", nargs="*", default=None)
    ap.add_argument("--no-write", action="store_true")
    a = ap.parse_args(argv)
    import links1_mitsuba as lm
    lm.register(a.variant)
    import drjit as dr
    import mitsuba as mi
    inverse.SCENES.update(SCENES)
    info = machine_info()
    info["variant"] = a.variant
    cmd = command_line()
    log = (lambda s: print(s, flush=True))
    results = []
    t_all = time.perf_counter()
    for name, cls, variables, lrs, iters in make_cases(a.iters, a.blob_iters):
        if a.only and name not in a.only:
            continue
        log(f"case {name}")
        r = {"case": name} if a.no_fit else inverse.run_case(mi, dr, name, cls, variables, lrs, iters, a.width, log)[0]
        r["timing"] = inverse.timing_only(mi, dr, name, cls, variables, lrs, a.big, a.rounds, log)
        if a.stages:
            r["stages"] = stages(mi, dr, name, cls, variables, lrs, a.big, a.stages, log)
        if a.no_fit:
            continue
        results.append(r)
        log("  per parameter: " + ", ".join(f"{k} {v:.4f}" for k, v in r["final_error"].items()))
        log(f"  {name}: final worst error {r['final_worst_error']:.4f}")
    payload = dict(machine=info, command=cmd, width=a.width, results=results, total_s=time.perf_counter() - t_all)
    if not a.no_write:
        log("wrote " + ", ".join(map(str, write_results("inverse_outline", payload, markdown(results, info, cmd)))))
    log(f"total {payload['total_s']:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
