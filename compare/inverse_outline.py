"""Inverse rendering through outlines and shadow edges (``links1_whitted`` with
``projective=true``): a benchmark.

    python -m compare.inverse_outline [--width 64] [--iters 150] [--blob-iters 2000] [--rounds 9] [--spp-grad N]
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
  surface ``W = T`` unchanged, so no image tells both). The view is from the front, left and
  above, where each lobe shows in the outline (straight from the front, with the lights in
  front, the back lobe's height changes nothing the camera sees: it stays where it starts).

4 samples a pixel (box filter) in both frames, 1 in the derivative pass (``mi.render``'s
``spp_grad``, :func:`compare.inverse.spp_grad`), ``max_depth`` 2, every iteration at ``seed`` 0. The times: ``--rounds`` interleaved rounds of an iteration and a
primal frame at ``--big`` (``compare.inverse.timing_only``), medians. With ``--stages``,
where an iteration at ``--big`` goes (:func:`stages`); with ``--ab``, what the recordings buy
(:func:`timing_ab`: the frozen launches kept over a geometry update or recorded again at each,
the term's stages frozen or traced); with ``--guided``, a blob's camera crossings searched
by its margin's secant against bisection (:func:`timing_guided`); with ``--where``,
the iteration part by part (:func:`where`); with ``--host``, Python's share of it (:func:`host_split`);
with ``--kernels``, its kernels one by one (:func:`kernels`); with ``--flag-ab``, module flags
at their values and flipped, alternated (:func:`flag_ab`). Writes ``compare/results/inverse_outline.{json,md}``,
or with ``--no-fit`` (the times alone) ``compare/results/inverse_outline_timing_<big>.{json,md}``
(``inverse_outline_guided_<big>`` with ``--guided``)
(``..._threads<N>`` with ``--threads N``: Dr.Jit's thread pool at N threads for the whole run,
the primal frames too; ``..._<flags>`` with ``--flag-ab``).
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
    "quadric_outline": dict(camera=dict(fov=40, origin="0, 3, 6", target="0, 0.8, 0"), spp=4, spp_grad=1,
                            integrator=PROJECTIVE,
                            body="""
  <shape type="links1_quadric" id="ball"><string name="kind" value="sphere"/>
    <transform name="to_world"><scale value="1.2"/><translate x="0.2" y="1.4" z="0.3"/></transform>
    <bsdf type="links1_phong"><rgb name="ambient" value="0.8, 0.6, 0.4"/><rgb name="diffuse" value="0"/></bsdf></shape>"""
                            + inverse.LIGHTS),
    "blob_view": dict(camera=dict(fov=50, origin="-3, 4, 3.8", target="0.1, 1.3, 0"), spp=4, spp_grad=1,
                      integrator=PROJECTIVE,
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


def _start(mi, dr, name, cls, variables, lrs, width):
    """A case at ``width``² ready to iterate: ``(iteration, frame)``, each synced."""
    scene = inverse.load(name, width)
    case = cls(name, scene, variables, lrs, 1)
    params = mi.traverse(scene)
    case.setup(mi, params)
    target = mi.render(scene, seed=0)
    inverse.sync(target)
    case.set_values(mi, params, {k: d["start"] for k, d in variables.items()})
    opt = inverse.optimizer(mi, case, params, variables, lrs)

    def iteration():
        img = mi.render(scene, params, seed=0, spp_grad=inverse.spp_grad(name))
        dr.backward(dr.mean(dr.square(img - target), axis=None))
        opt.step()
        case.apply(mi, params, opt)
        inverse.sync(opt[next(iter(variables))])

    def frame():
        inverse.sync(mi.render(scene, seed=0))
    return iteration, frame


def stages(mi, dr, name, cls, variables, lrs, width, n, log):
    """Where an iteration at ``width``² goes, ``n`` iterations (after 2) with
    ``dr.JitFlag.KernelHistory``: its wall time, the visibility term's (``boundary_image``
    wrapped: made, evaluated, synced) and the kernels of each (count, execution time as Dr.Jit
    reports it, compiled ones), the primal frame's wall time; medians."""
    from links1_mitsuba import boundary
    iteration, frame = _start(mi, dr, name, cls, variables, lrs, width)
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
            iteration()
            t_it = time.perf_counter() - t0
            rest = jit(dr.kernel_history()) + [k for _, _, b in term for k in b]
            t0 = time.perf_counter()
            frame()
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


def timing_ab(mi, dr, name, cls, variables, lrs, width, n, log):
    """What the recordings buy: ``n`` rounds (after 3) alternating three ways, each an
    iteration, a timed iteration, a frame and a timed frame (as
    :func:`compare.inverse.timing_only`): ``kept`` (as the plugin runs: the frozen launches
    replayed after an update that changes no literal of their kernels, tables.py, and the
    boundary term's stages of queries frozen, ``Launches.frozen_stage``), ``recorded`` (both
    launches recorded again at every update: the check of their literals made to see a change
    each time) and ``stages traced`` (the term's stages traced every frame). Wall and process
    CPU times, medians."""
    from links1_mitsuba import launch, tables
    same, frozen_stage = tables._geometry_literals, launch.Launches.frozen_stage

    def traced(self, tables_, scene, tracer, fn, *args, key=()):
        return fn(tables_, scene, *args)
    iteration, frame = _start(mi, dr, name, cls, variables, lrs, width)
    ways = {"kept": (same, frozen_stage), "recorded": (lambda base: object(), frozen_stage),
            "stages traced": (same, traced)}
    got = {k: [] for k in ways}

    def timed(f):
        t0, c0 = time.perf_counter(), time.process_time()
        f()
        return time.perf_counter() - t0, time.process_time() - c0
    try:
        for r in range(n + 3):
            for way, (literals, stage) in ways.items():
                tables._geometry_literals, launch.Launches.frozen_stage = literals, stage
                iteration()
                ti = timed(iteration)
                frame()
                tp = timed(frame)
                if r >= 3:
                    got[way].append([*ti, *tp])
    finally:
        tables._geometry_literals, launch.Launches.frozen_stage = same, frozen_stage
    out = {}
    for way, rows in got.items():
        a = np.array(rows) * 1e3
        it_w, it_c, fr_w, fr_c = np.median(a, axis=0)
        out[way] = dict(iteration_ms=it_w, iteration_cpu_ms=it_c, primal_ms=fr_w, primal_cpu_ms=fr_c,
                        ratio=it_w / fr_w, ratio_cpu=it_c / fr_c, ratio_of_rounds=float(np.median(a[:, 0] / a[:, 2])))
        log(f"  {name} at {width}², {way}: iteration {it_w:.1f} ms (CPU {it_c:.1f}), primal "
            f"{fr_w:.1f} ms (CPU {fr_c:.1f}), ratio {it_w / fr_w:.2f} (CPU {it_c / fr_c:.2f})")
    return dict(case=name, width=width, rounds=n, ways=out)


def timing_guided(mi, dr, name, cls, variables, lrs, width, n, log):
    """A blob's camera crossings searched by its margin's secant or by bisection
    (``boundary.GUIDED``, docs/method.md §6): ``n`` rounds (after 3) alternating the two, each
    an iteration timed whole and its bisection stage (``_bisected`` or ``_bisected_plain``,
    synced before and after). Wall and process CPU times, medians."""
    from links1_mitsuba import boundary, launch
    frozen_stage, guided = launch.Launches.frozen_stage, boundary.GUIDED
    acc = [0.0, 0.0]

    def timed_stage(self, tables_, scene, tracer, fn, *args, key=()):
        if fn not in (boundary._bisected, boundary._bisected_plain):
            return frozen_stage(self, tables_, scene, tracer, fn, *args, key=key)
        dr.eval()
        dr.sync_thread()
        t0, c0 = time.perf_counter(), time.process_time()
        out = frozen_stage(self, tables_, scene, tracer, fn, *args, key=key)
        dr.eval(out)
        dr.sync_thread()
        acc[0] += time.perf_counter() - t0
        acc[1] += time.process_time() - c0
        return out
    iteration, _ = _start(mi, dr, name, cls, variables, lrs, width)
    got = {"bisection": [], "guided": []}
    try:
        launch.Launches.frozen_stage = timed_stage
        for r in range(n + 3):
            for way in (got if r % 2 else reversed(list(got))):
                boundary.GUIDED = way == "guided"
                iteration()
                acc[:] = [0.0, 0.0]
                t0, c0 = time.perf_counter(), time.process_time()
                iteration()
                if r >= 3:
                    got[way].append([time.perf_counter() - t0, time.process_time() - c0, *acc])
    finally:
        launch.Launches.frozen_stage, boundary.GUIDED = frozen_stage, guided
    out = {}
    for way, rows in got.items():
        it_w, it_c, st_w, st_c = np.median(np.array(rows) * 1e3, axis=0)
        out[way] = dict(iteration_ms=it_w, iteration_cpu_ms=it_c, stage_ms=st_w, stage_cpu_ms=st_c)
        log(f"  {name} at {width}², {way}: iteration {it_w:.1f} ms (CPU {it_c:.1f}), its bisection stage "
            f"{st_w:.1f} ms (CPU {st_c:.1f})")
    return dict(case=name, width=width, rounds=n, ways=out)


def guided_markdown(rows):
    return md_table(["case", "width", "search", "iteration ms (CPU)", "bisection stage ms (CPU)"],
                    [[r["case"], f"{r['width']}²", way, f"{w['iteration_ms']:.1f} ({w['iteration_cpu_ms']:.1f})",
                      f"{w['stage_ms']:.1f} ({w['stage_cpu_ms']:.1f})"] for r in rows for way, w in r["ways"].items()])


#: the parts of an iteration :func:`where` times (module.object, attribute, label); a part
#: marked · lies within the part above it, the term within an AD block where the frame is one
#: block (gradients.py: apart from the blocks otherwise)
_PARTS = [("tables.Tables", "_update_values", "  tables brought up to the update"),
          ("gradients.Gradients", "render_backward", "derivative pass (render_backward)"),
          ("gradients.Gradients", "_render_ad", "  AD blocks: traced, film, evaluated"),
          ("boundary", "boundary_image", "  term (boundary_image): made, evaluated"),
          ("boundary", "_active", "    corner queries (_active)"),
          ("launch.Launches", "frozen_stage", "    frozen stages (frozen_stage: corners, lines, bisection, ends)"),
          ("launch.Launches", "trace_points", "    side launch (trace_points)")]


def where(mi, dr, name, cls, variables, lrs, width, n, log):
    """Where an iteration at ``width``² goes, part by part (:data:`_PARTS`; a part waits for
    the kernels before and after it, so the parts' kernels run apart), ``n`` iterations (after
    3): wall and process CPU ms an iteration, medians over the iterations, and the primal
    frame's."""
    import importlib
    from links1_mitsuba import boundary
    acc, real = {}, []

    def wrap(owner, attr, label):
        f = getattr(owner, attr)
        real.append((owner, attr, f))

        def timed(*a, **k):
            dr.sync_thread()
            t0, c0 = time.perf_counter(), time.process_time()
            out = f(*a, **k)
            if isinstance(out, mi.TensorXf):
                dr.eval(out)
            dr.sync_thread()
            acc[label][-1][0] += time.perf_counter() - t0
            acc[label][-1][1] += time.process_time() - c0
            return out
        setattr(owner, attr, timed)
    for path, attr, label in _PARTS:
        mod, _, cls_name = path.partition(".")
        owner = importlib.import_module(f"links1_mitsuba.{mod}")
        wrap(getattr(owner, cls_name) if cls_name else owner, attr, label)
    labels = ["iteration", "primal frame in mi.render(scene, params)", *(lbl for _, _, lbl in _PARTS),
              "primal frame"]
    acc = {k: [] for k in labels}
    try:
        iteration, frame = _start(mi, dr, name, cls, variables, lrs, width)
        from links1_mitsuba import engine
        real_render = engine.Engine.render

        def render(self, *a, **k):
            dr.sync_thread()
            t0, c0 = time.perf_counter(), time.process_time()
            out = real_render(self, *a, **k)
            dr.eval(out)
            dr.sync_thread()
            part = acc["primal frame in mi.render(scene, params)" if stage[0] == "iteration" else "primal frame"][-1]
            part[0] += time.perf_counter() - t0
            part[1] += time.process_time() - c0
            return out
        engine.Engine.render = render
        real.append((engine.Engine, "render", real_render))
        stage = ["iteration"]
        for r in range(n + 3):
            for k in acc:
                acc[k].append([0.0, 0.0])
            stage[0] = "iteration"
            t0, c0 = time.perf_counter(), time.process_time()
            iteration()
            acc["iteration"][-1] = [time.perf_counter() - t0, time.process_time() - c0]
            stage[0] = "frame"
            frame()
            if r < 3:
                for k in acc:
                    acc[k].pop()
    finally:
        for owner, attr, f in reversed(real):
            setattr(owner, attr, f)
    med = {k: np.median(np.array(v) * 1e3, axis=0) for k, v in acc.items()}
    accounted = med["primal frame in mi.render(scene, params)"] + med["derivative pass (render_backward)"]
    med["loss, Adam step, params.update"] = med["iteration"] - accounted   # (the rest of the iteration)
    order = labels[:-1] + ["loss, Adam step, params.update", "primal frame"]
    rows = [dict(part=k, wall_ms=float(med[k][0]), cpu_ms=float(med[k][1])) for k in order]
    for r in rows:
        log(f"  {name} at {width}²: {r['part']:44s} {r['wall_ms']:8.1f} ms (CPU {r['cpu_ms']:.1f})")
    return dict(case=name, width=width, iterations=n, parts=rows)


def host_split(mi, dr, name, cls, variables, lrs, width, n, log):
    """Python's share of an iteration at ``width``² and of its parts (:data:`_PARTS`, the
    primal frame in it): ``n`` iterations (after 3) with ``dr.JitFlag.LaunchBlocking`` (each
    kernel runs as it is launched, so a part's wall time is its kernels' time, as Dr.Jit's
    kernel history reports it, plus its host time: tracing, launching, numpy) and the kernel
    history on; per iteration, medians."""
    import importlib
    got, real, kern, timing = {}, [], [0.0, 0], [False]

    def drain():
        for k in dr.kernel_history():
            kern[0] += k.get("execution_time", 0.0)
            kern[1] += k.get("type") == dr.KernelType.JIT

    def wrap(owner, attr, label):
        f = getattr(owner, attr)
        real.append((owner, attr, f))

        def timed(*a, **k):
            if not timing[0]:   # (the primal frame between iterations)
                return f(*a, **k)
            drain()
            k0, t0 = list(kern), time.perf_counter()
            out = f(*a, **k)
            drain()
            row = got[label][-1]
            row[0] += (time.perf_counter() - t0) * 1e3
            row[1] += kern[0] - k0[0]
            row[2] += kern[1] - k0[1]
            return out
        setattr(owner, attr, timed)
    parts = [("engine.Engine", "render", "primal frame in mi.render(scene, params)"),
             ("tables.Tables", "prepare", "  tables prepared (all calls)")] + _PARTS[1:]
    labels = ["iteration"] + [lbl for _, _, lbl in parts]
    try:
        iteration, frame = _start(mi, dr, name, cls, variables, lrs, width)
        for path, attr, label in parts:
            mod, _, cls_name = path.partition(".")
            owner = importlib.import_module(f"links1_mitsuba.{mod}")
            wrap(getattr(owner, cls_name) if cls_name else owner, attr, label)
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.set_flag(dr.JitFlag.LaunchBlocking, True)
        for r in range(n + 3):
            for k in labels:
                got.setdefault(k, []).append([0.0, 0.0, 0])
            drain()
            timing[0] = True
            k0, t0 = list(kern), time.perf_counter()
            iteration()
            drain()
            timing[0] = False
            got["iteration"][-1] = [(time.perf_counter() - t0) * 1e3, kern[0] - k0[0], kern[1] - k0[1]]
            if r < 3:
                for k in labels:
                    got[k].pop()
            frame()
    finally:
        dr.set_flag(dr.JitFlag.LaunchBlocking, False)
        dr.set_flag(dr.JitFlag.KernelHistory, False)
        for owner, attr, f in reversed(real):
            setattr(owner, attr, f)
    rows = []
    for k in labels:
        wall, kms, nk = np.median(np.array(got[k]), axis=0)
        rows.append(dict(part=k, wall_ms=float(wall), kernel_ms=float(kms), host_ms=float(wall - kms), kernels=float(nk)))
        log(f"  {name} at {width}² (launch-blocking): {k:44s} {wall:7.2f} ms: kernels {kms:6.2f} ({nk:.0f}), "
            f"host {wall - kms:6.2f}")
    return dict(case=name, width=width, iterations=n, parts=rows)


def _launch_blocking(dr, fn):
    """``fn()`` with each kernel run as it is launched and Dr.Jit's kernel history on -> the JIT
    kernels it ran (their history entries; ``site``: where in links1_mitsuba, or this
    benchmark, each was launched: the innermost frames at the first Python return after it)."""
    import sys
    import traceback
    ks = []

    def prof(frame_, event, arg):
        if event in ("c_return", "return"):
            h = [k for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT]
            if h:
                site = [f"{f.f_code.co_filename.rsplit('/', 1)[-1]}:{f.f_code.co_name}"
                        for f, _ in traceback.walk_stack(frame_)
                        if ("links1_mitsuba" in f.f_code.co_filename or "compare" in f.f_code.co_filename)
                        and not f.f_code.co_name.startswith(("_traverse", "_call_frozen", "<"))]
                for k in h:
                    k["site"] = " < ".join(site[:3])
                ks.extend(h)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.set_flag(dr.JitFlag.LaunchBlocking, True)
    dr.kernel_history()
    sys.setprofile(prof)
    try:
        fn()
    finally:
        sys.setprofile(None)
        dr.set_flag(dr.JitFlag.LaunchBlocking, False)
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    return ks


def kernels(mi, dr, name, cls, variables, lrs, width, n, log):
    """Where an iteration's kernel time goes, kernel by kernel: ``n`` iterations (after 3), each
    kernel run as it is launched (:func:`_launch_blocking`), then a primal frame; per kernel (in
    launch order) its lanes, IR operations, launch site and execution time as Dr.Jit reports it
    (median and minimum over the iterations: the load preempts a kernel's threads now and then,
    the minimum is what it costs alone), and the primal frame's kernel likewise."""
    iteration, frame = _start(mi, dr, name, cls, variables, lrs, width)
    runs, prim = [], []
    for r in range(n + 3):
        ks = _launch_blocking(dr, iteration)
        pk = _launch_blocking(dr, frame)
        if r >= 3:
            runs.append(ks)
            prim.append(sum(k["execution_time"] for k in pk))
    m = int(np.median([len(h) for h in runs]))
    runs = [h for h in runs if len(h) == m]
    t = np.array([[k["execution_time"] for k in h] for h in runs])
    rows = [dict(i=i, lanes=int(k["size"]), ops=int(k["operation_count"]), site=k["site"],
                 median_ms=float(np.median(t[:, i])), min_ms=float(t[:, i].min())) for i, k in enumerate(runs[0])]
    out = dict(case=name, width=width, iterations=len(runs), kernels=m, rows=rows,
               sum_median_ms=float(np.median(t.sum(axis=1))), sum_of_medians_ms=float(np.median(t, axis=0).sum()),
               sum_of_min_ms=float(t.min(axis=0).sum()), primal_median_ms=float(np.median(prim)),
               primal_min_ms=float(np.min(prim)))
    log(f"  {name} at {width}²: {m} kernels an iteration, their time {out['sum_median_ms']:.2f} ms (median), "
        f"per-kernel minima summed {out['sum_of_min_ms']:.2f} ms; primal frame's kernels {out['primal_median_ms']:.2f} "
        f"(min {out['primal_min_ms']:.2f})")
    for r_ in sorted(rows, key=lambda r_: -r_["min_ms"])[:12]:
        log(f"    #{r_['i']:2d} {r_['min_ms']:6.3f} ms min, {r_['median_ms']:6.3f} median, {r_['lanes']:7d} lanes, "
            f"{r_['ops']:5d} ops: {r_['site']}")
    return out


def kernels_markdown(r):
    return (f"{r['case']} at {r['width']}²: {r['kernels']} kernels an iteration ({r['iterations']} iterations); "
            f"their time {r['sum_median_ms']:.2f} ms (median of the sums), per-kernel minima summed "
            f"{r['sum_of_min_ms']:.2f} ms; the primal frame's kernels {r['primal_median_ms']:.2f} ms (min "
            f"{r['primal_min_ms']:.2f}).\n\n"
            + md_table(["#", "lanes", "ops", "min ms", "median ms", "launched in"],
                       [[q["i"], q["lanes"], q["ops"], f"{q['min_ms']:.3f}", f"{q['median_ms']:.3f}", q["site"]]
                        for q in r["rows"]]))


def flag_ab(mi, dr, name, cls, variables, lrs, width, n, log, flag):
    """Module flags of links1_mitsuba (``flag``: ``module.NAME``, bools, comma-separated) at
    their values and all flipped, alternated in one process: ``n`` rounds (after 2 iterations each way), each way
    once a round (the order alternating), then a primal frame; per way the iteration's kernels
    (run as launched, :func:`_launch_blocking`: their count and time) and then an iteration timed
    as it runs (wall and process CPU); medians and the medians of the per-round ratios."""
    import importlib
    flags = []
    for f in flag.split(","):
        mod_name, _, attr = f.strip().rpartition(".")
        mod = importlib.import_module(f"links1_mitsuba.{mod_name}")
        flags.append((mod, attr, getattr(mod, attr)))

    def way(flip):
        return " ".join(f"{a}={v != flip}" for _, a, v in flags), flip
    ways = dict(map(way, (False, True)))

    def put(flip):
        for mod, a, v in flags:
            setattr(mod, a, v != flip)
    iteration, frame = _start(mi, dr, name, cls, variables, lrs, width)
    got, each = {w: [] for w in ways}, {w: [] for w in ways}
    prim = []
    try:
        for w, v in ways.items():
            put(v)
            iteration()
            iteration()
        for r in range(n):
            for w in (list(ways) if r % 2 == 0 else list(ways)[::-1]):
                put(ways[w])
                ks = _launch_blocking(dr, iteration)
                t0, c0 = time.perf_counter(), time.process_time()
                iteration()
                got[w].append([sum(k["execution_time"] for k in ks), len(ks), (time.perf_counter() - t0) * 1e3,
                               (time.process_time() - c0) * 1e3])
                each[w].append([k["execution_time"] for k in ks])
            c0 = time.process_time()
            frame()
            prim.append((time.process_time() - c0) * 1e3)
    finally:
        put(False)
    base = np.array(got[list(ways)[0]])
    out = dict(case=name, width=width, rounds=n, flag=flag, primal_cpu_ms=float(np.median(prim)), ways={})
    for w in ways:
        a = np.array(got[w])
        q = dict(kernel_ms=float(np.median(a[:, 0])), kernels=float(np.median(a[:, 1])),
                 wall_ms=float(np.median(a[:, 2])), cpu_ms=float(np.median(a[:, 3])),
                 kernel_min_ms=float(np.min([e for e in each[w] if len(e) == a[0, 1]], axis=0).sum()),
                 kernel_ratio=float(np.median(a[:, 0] / base[:, 0])), wall_ratio=float(np.median(a[:, 2] / base[:, 2])),
                 cpu_ratio=float(np.median(a[:, 3] / base[:, 3])))
        out["ways"][w] = q
        log(f"  {name} at {width}², {w}: kernels {q['kernels']:.0f}, {q['kernel_ms']:.2f} ms (ratio of the rounds "
            f"{q['kernel_ratio']:.3f}), per-kernel minima summed {q['kernel_min_ms']:.2f} ms; iteration wall {q['wall_ms']:.2f} ms ({q['wall_ratio']:.3f}), CPU "
            f"{q['cpu_ms']:.2f} ms ({q['cpu_ratio']:.3f})")
    log(f"  primal frame CPU {out['primal_cpu_ms']:.2f} ms")
    return out


def flag_markdown(rows):
    return md_table(["case", "width", "way", "kernels", "kernel ms (ratio)", "per-kernel minima ms",
                     "iteration wall ms (ratio)", "iteration CPU ms (ratio)", "primal CPU ms"],
                    [[r["case"], f"{r['width']}²", w, f"{q['kernels']:.0f}", f"{q['kernel_ms']:.2f} ({q['kernel_ratio']:.3f})",
                      f"{q['kernel_min_ms']:.2f}",
                      f"{q['wall_ms']:.2f} ({q['wall_ratio']:.3f})", f"{q['cpu_ms']:.2f} ({q['cpu_ratio']:.3f})",
                      f"{r['primal_cpu_ms']:.2f}"] for r in rows for w, q in r["ways"].items()])


def host_markdown(rows):
    parts = [p["part"] for p in rows[0]["parts"]]
    return md_table(["part (ms an iteration: wall = kernels + host)"] + [f"{r['case']} {r['width']}²" for r in rows],
                    [[p.replace("  ", "· ")] + [f"{q['wall_ms']:.1f} = {q['kernel_ms']:.1f} ({q['kernels']:.0f}) + "
                                                f"{q['host_ms']:.1f}" for r in rows for q in r["parts"] if q["part"] == p]
                     for p in parts])


def stages_markdown(rows):
    return md_table(["case", "iteration ms", "term ms (calls)", "term kernels: n, ms, compiled",
                     "other kernels: n, ms, compiled", "primal ms"],
                    [[r["case"], f"{r['iteration_ms']:.1f}", f"{r['term_ms']:.1f} ({r['term_calls']:.0f})",
                      f"{r['term_kernels']:.0f}, {r['term_kernel_ms']:.1f}, {r['term_compiled']:.0f}",
                      f"{r['other_kernels']:.0f}, {r['other_kernel_ms']:.1f}, {r['other_compiled']:.0f}",
                      f"{r['primal_ms']:.1f}"] for r in rows])


def ab_markdown(rows):
    return md_table(["case", "width", "way", "iteration ms (CPU)", "primal ms (CPU)", "ratio (CPU)"],
                    [[r["case"], f"{r['width']}²", way, f"{w['iteration_ms']:.1f} ({w['iteration_cpu_ms']:.1f})",
                      f"{w['primal_ms']:.1f} ({w['primal_cpu_ms']:.1f})", f"{w['ratio']:.2f} ({w['ratio_cpu']:.2f})"]
                     for r in rows for way, w in r["ways"].items()])


def where_markdown(rows):
    parts = [p["part"] for p in rows[0]["parts"]]
    return md_table(["part (ms an iteration: wall / CPU)"] + [f"{r['case']} {r['width']}²" for r in rows],
                    [[p.replace("  ", "· ")] + [f"{q['wall_ms']:.1f} / {q['cpu_ms']:.1f}" for r in rows
                                                for q in r["parts"] if q["part"] == p] for p in parts])


#: the optional tables (--stages, --ab, ...): the results' key, the table's introduction, its table of the
#: list of those results' values
_EXTRA = (
    ("stages", "Where an iteration at the --big width goes (--stages: medians, with Dr.Jit's kernel history on; term: "
               "the visibility term made, evaluated and synced; kernel ms: execution times as Dr.Jit reports them)",
     stages_markdown),
    ("ab", "The recordings' worth (--ab: interleaved rounds, medians, wall and process CPU; kept: as the plugin runs; "
           "recorded: the frozen launches recorded again at every update; stages traced: the term's stages of "
           "queries traced every frame)",
     ab_markdown),
    ("guided", "A blob's camera crossings searched by its margin's secant or by bisection (--guided: interleaved "
               "rounds, medians, wall and process CPU; the bisection stage synced before and after)",
     guided_markdown),
    ("host", "Python's share (--host: each kernel run as it is launched, Dr.Jit's LaunchBlocking; a part's wall time "
             "is its kernels' execution time (their count) plus its host time; medians; · within the part above)",
     host_markdown),
    ("flag", "Module flags at their values and flipped (--flag-ab: alternated in one process, medians and the medians "
             "of the per-round ratios to the first way; kernel ms: the iteration's kernels run as launched, as "
             "Dr.Jit reports them; wall and CPU: an iteration as it runs)",
     flag_markdown),
    ("kernels", "Kernel by kernel (--kernels: each run as it is launched, its execution time as Dr.Jit reports it; "
                "launched in: the innermost frames of links1_mitsuba and this benchmark at the first Python return "
                "after its launch, so a kernel that Dr.Jit or Mitsuba launches from C++ (the loss's reverse) is named "
                "by the call that follows it)",
     lambda v: "\n".join(kernels_markdown(k) for k in v)),
    ("where", "Where an iteration goes, part by part (--where: each part synced before and after, medians; a part "
              "marked · is within the one above it)",
     where_markdown),
)


def _extra_markdown(results):
    """The optional tables (:data:`_EXTRA`) of ``results``."""
    out = ""
    for key, intro, table in _EXTRA:
        values = [r[key] for r in results if key in r]
        if values:
            out += f"\n{intro}:\n\n" + table(values)
    return out


def timing_markdown(results, info, cmd):
    rows = [[r["case"], f"{r['timing']['width']}²", r.get("spp_grad", "–"), f"{r['timing']['primal_median_ms']:.1f}",
             f"{r['timing']['iteration_median_ms']:.1f}", f"{r['timing']['ratio']:.2f}",
             f"{r['timing']['ratio_of_rounds']:.2f}"] for r in results]
    return ("# Inverse rendering through outlines (projective=true): iteration times\n\n"
            + machine_markdown(info, cmd) + "\n"
            + md_table(["case", "width", "derivative pass spp", "primal ms", "iteration ms", "ratio",
                        "ratio of the rounds"], rows)
            + "\nIteration: render with gradients (primal frame, derivative pass with the boundary term), "
              "L2 loss, dr.backward, Adam step, params.update; primal: mi.render without gradients. "
              "Medians of interleaved rounds.\n" + _extra_markdown(results))


def markdown(results, info, cmd):
    rows = [[r["case"], r.get("spp_grad", "–"), r["iters"], f"{r['final_worst_error'] * 100:.3f} %", r["iterations_to_1pct"],
             ", ".join(f"{k.split('.')[-1]} {v * 100:.3f} %" for k, v in r["final_error"].items()),
             f"{r['timing']['primal_median_ms']:.1f}", f"{r['timing']['iteration_median_ms']:.1f}",
             f"{r['timing']['ratio']:.2f}"] for r in results]
    return ("# Inverse rendering through outlines (projective=true)\n\n" + machine_markdown(info, cmd) + "\n"
            + md_table(["case", "derivative pass spp", "iterations", "worst error / range", "iterations to ≤ 1 %",
                        "per parameter",
                        "primal ms", "iteration ms", "ratio"], rows)
            + "\nIteration: render with gradients (primal frame, derivative pass with the boundary term), "
              "L2 loss, dr.backward, Adam step, params.update; primal: mi.render without gradients. "
              "Times: medians of interleaved rounds at the --big width.\n"
            + _extra_markdown(results))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=64)
    ap.add_argument("--iters", type=int, default=150)
    ap.add_argument("--blob-iters", type=int, default=2000)
    ap.add_argument("--rounds", type=int, default=9, help="timing rounds (interleaved iteration / frame)")
    ap.add_argument("--big", type=int, default=256, help="the width the times are taken at")
    ap.add_argument("--no-fit", action="store_true", help="the times alone")
    ap.add_argument("--stages", type=int, default=0, metavar="N",
                    help="also where an iteration at --big goes, N iterations with Dr.Jit's kernel history")
    ap.add_argument("--ab", action="store_true",
                    help="also time the recordings' worth: kept, recorded at each update, the term's stages traced")
    ap.add_argument("--guided", action="store_true",
                    help="also time a blob's camera crossings searched by its margin's secant against bisection")
    ap.add_argument("--where", type=int, default=0, metavar="N",
                    help="also where an iteration at --big goes, part by part, N iterations")
    ap.add_argument("--host", type=int, default=0, metavar="N",
                    help="also Python's share of an iteration at --big and of its parts, N iterations with each "
                         "kernel run as it is launched")
    ap.add_argument("--kernels", type=int, default=0, metavar="N",
                    help="also the iteration's kernels one by one at --big, N iterations with each kernel run as "
                         "it is launched")
    ap.add_argument("--flag-ab", default=None, metavar="MODULE.NAME",
                    help="also links1_mitsuba modules' bool flags (comma-separated) at their values and all "
                         "flipped, alternated in one process, --rounds rounds at --big")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--only", nargs="*", default=None)
    ap.add_argument("--threads", type=int, default=0, metavar="N",
                    help="Dr.Jit's LLVM thread pool at N threads for the whole run, set before the first "
                         "kernel (0: Dr.Jit's default, one a core); the results' file names say N")
    ap.add_argument("--spp-grad", type=int, default=-1, metavar="N",
                    help="the derivative pass's samples a pixel in every case (mi.render's spp_grad; 0: the "
                         "frame's 4; default: each case's own, 1); the results' file names say N")
    ap.add_argument("--no-write", action="store_true")
    a = ap.parse_args(argv)
    import links1_mitsuba as lm
    lm.register(a.variant)
    import drjit as dr
    import mitsuba as mi
    if a.threads:
        dr.set_thread_count(a.threads)
    inverse.SCENES.update(SCENES)
    if a.spp_grad >= 0:
        for name in SCENES:
            inverse.SCENES[name] = dict(SCENES[name], spp_grad=a.spp_grad)
    info = machine_info()
    info["variant"] = a.variant
    info["drjit_threads"] = dr.thread_count()
    cmd = command_line()
    log = (lambda s: print(s, flush=True))
    results, timed_only = [], []
    t_all = time.perf_counter()
    for name, cls, variables, lrs, iters in make_cases(a.iters, a.blob_iters):
        if a.only and name not in a.only:
            continue
        log(f"case {name}")
        r = {"case": name} if a.no_fit else inverse.run_case(mi, dr, name, cls, variables, lrs, iters, a.width, log)[0]
        r["spp_grad"] = inverse.spp_grad(name) or inverse.scene_of(name)[0]["spp"]
        r["timing"] = inverse.timing_only(mi, dr, name, cls, variables, lrs, a.big, a.rounds, log)
        if a.stages:
            r["stages"] = stages(mi, dr, name, cls, variables, lrs, a.big, a.stages, log)
        if a.ab:
            r["ab"] = timing_ab(mi, dr, name, cls, variables, lrs, a.big, a.rounds, log)
        if a.guided:
            r["guided"] = timing_guided(mi, dr, name, cls, variables, lrs, a.big, a.rounds, log)
        if a.where:
            r["where"] = where(mi, dr, name, cls, variables, lrs, a.big, a.where, log)
        if a.host:
            r["host"] = host_split(mi, dr, name, cls, variables, lrs, a.big, a.host, log)
        if a.kernels:
            r["kernels"] = kernels(mi, dr, name, cls, variables, lrs, a.big, a.kernels, log)
        if a.flag_ab:
            r["flag"] = flag_ab(mi, dr, name, cls, variables, lrs, a.big, a.rounds, log, a.flag_ab)
        if a.no_fit:
            timed_only.append(r)
            continue
        results.append(r)
        log("  per parameter: " + ", ".join(f"{k} {v:.4f}" for k, v in r["final_error"].items()))
        log(f"  {name}: final worst error {r['final_worst_error']:.4f}")
    payload = dict(machine=info, command=cmd, width=a.width, results=results or timed_only,
                   total_s=time.perf_counter() - t_all)
    if not a.no_write:
        # the times alone (--no-fit) go to a file of their own per --big, next to the fits' results
        name, text = ("inverse_outline", markdown(results, info, cmd)) if not a.no_fit else \
            (f"inverse_outline_{'guided' if a.guided else 'timing'}_{a.big}", timing_markdown(timed_only, info, cmd))
        name += f"_threads{a.threads}" if a.threads else ""
        name += f"_sppgrad{a.spp_grad}" if a.spp_grad >= 0 else ""
        name += "".join(f"_{f.rpartition('.')[2].lower()}" for f in a.flag_ab.split(",")) if a.flag_ab else ""
        log("wrote " + ", ".join(map(str, write_results(name, payload, text))))
    log(f"total {payload['total_s']:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
