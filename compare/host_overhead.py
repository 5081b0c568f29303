"""Host (non-kernel) time of a ``links1_whitted`` frame against the pixel count.

    python -m compare.host_overhead [--res 256 1024 2048] [--repeats 7] [--variant llvm_ad_rgb]

The scene is ``compare.scaling.quadric_scene(10, mitsuba_shapes=True)`` (10 Mitsuba spheres on a
floor, one directional light) with a ``box`` and a ``gaussian`` film filter. For each film size,
filter and integrator (``links1_whitted`` with ``max_depth`` 1, Mitsuba's ``direct`` with
``emitter_samples`` 1 and ``bsdf_samples`` 0: the same work for a delta light) it times
``mi.render(scene)`` the way a Mitsuba user calls it, keeping the returned tensor (evaluated
with ``dr.eval`` and ``dr.sync_thread``, never copied to numpy), one warm-up frame and then
``repeats`` frames in the same process:

* ``wall``: the frame's wall time (median);
* ``kernels``: the summed ``execution_time`` of the frame's kernels (``dr.kernel_history``);
* ``host = wall − kernels``: what the frame costs besides its kernels (tracing the Python
  code, numpy, copies, compilation look-ups). The issue's target is ≤ 0.3 ms and flat in the
  pixel count;
* ``submit``: ``repeats`` more frames timed until ``mi.render`` and ``dr.eval`` return (the
  kernels queued on the LLVM thread pool, waited for outside the timed part; no kernel
  history): the host's own work alone, which ``wall − kernels`` blurs on a loaded machine.

On the LLVM backend kernels run on Dr.Jit's thread pool while the host waits, so ``host`` is an
upper bound on the host's own work. Writes ``compare/results/host_overhead.{json,md}``.
"""
from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from .scaling import quadric_scene

RESULTS = Path(__file__).resolve().parent / "results"


def _scene_xml(integrator: str, rfilter: str) -> str:
    xml = quadric_scene(10, mitsuba_shapes=True)
    if integrator == "links1":
        integ = '<integrator type="links1_whitted"><integer name="max_depth" value="1"/></integrator>'
    else:
        integ = ('<integrator type="direct"><integer name="emitter_samples" value="1"/>'
                 '<integer name="bsdf_samples" value="0"/></integrator>')
    xml = xml.replace('<integrator type="direct"/>', integ)
    if xml.count('<rfilter type="box"/>') != 1:
        raise RuntimeError("quadric_scene's film no longer has one box filter: update compare.host_overhead")
    return xml.replace('<rfilter type="box"/>', f'<rfilter type="{rfilter}"/>')


def measure(res: int, integrator: str, rfilter: str, repeats: int, variant: str) -> dict:
    import drjit as dr
    import mitsuba as mi
    import links1_mitsuba as lm
    lm.register(variant)
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "scene.xml"
        path.write_text(_scene_xml(integrator, rfilter))
        scene = lm.load_file(str(path), links1_integrator="scene", variant=variant, res=res)

    def frame():
        img = mi.render(scene, spp=1, seed=0)
        dr.eval(img)
        dr.sync_thread()
        return img

    frame()
    wall, kern = [], []
    for _ in range(repeats):
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()
        t0 = time.perf_counter()
        img = frame()
        wall.append(time.perf_counter() - t0)
        kern.append(sum(float(k.get("execution_time", 0.0)) for k in dr.kernel_history()) / 1e3)
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    # the host's own part, without the kernels: mi.render and dr.eval return once the kernels
    # are queued (the LLVM backend runs them on its thread pool; no kernel history here, which
    # would time them); sync_thread waits for them outside the timed part
    submit = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        img = mi.render(scene, spp=1, seed=0)
        dr.eval(img)
        submit.append(time.perf_counter() - t0)
        dr.sync_thread()
    wall_ms, kern_ms = 1e3 * float(np.median(wall)), 1e3 * float(np.median(kern))
    host = [1e3 * (w - k) for w, k in zip(wall, kern)]
    return dict(res=res, integrator=integrator, rfilter=rfilter, wall_ms=wall_ms, kernels_ms=kern_ms,
                host_ms=float(np.median(host)), submit_ms=1e3 * float(np.median(submit)),
                shape=list(img.shape))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m compare.host_overhead", description=__doc__.split("\n\n")[0])
    ap.add_argument("--res", type=int, nargs="+", default=[256, 1024, 2048])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--out", default=str(RESULTS / "host_overhead"))
    a = ap.parse_args(argv)
    rows = []
    for res in a.res:
        for rfilter in ("box", "gaussian"):
            for integ in ("links1", "direct"):
                r = measure(res, integ, rfilter, a.repeats, a.variant)
                rows.append(r)
                print(f"{res:5d}² {rfilter:8s} {integ:7s} wall {r['wall_ms']:8.2f} ms  kernels "
                      f"{r['kernels_ms']:8.2f} ms  host {r['host_ms']:8.2f} ms  submit {r['submit_ms']:6.2f} ms",
                      flush=True)
    machine = f"{platform.node()} ({platform.processor() or platform.machine()}), {a.variant}"
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(dict(machine=machine, repeats=a.repeats, rows=rows), indent=1))
    md = ["# Host time of a frame against the pixel count\n\n",
          f"`python -m compare.host_overhead --res {' '.join(map(str, a.res))} --repeats {a.repeats}` on {machine}. "
          "`mi.render(scene, spp=1)`, the tensor kept (never copied to numpy), warm median of "
          f"{a.repeats} frames; host = wall − kernel execution time (`dr.kernel_history`). Scene: "
          "`compare.scaling.quadric_scene(10, mitsuba_shapes=True)`; `direct` with bsdf_samples 0. "
          "submit = the time until `mi.render` and `dr.eval` return, the kernels queued (median of "
          f"{a.repeats} more frames, without kernel history): the host's own work.\n\n",
          "| film | filter | integrator | wall ms | kernels ms | host ms | submit ms |\n"
          "| --- | --- | --- | --- | --- | --- | --- |\n"]
    for r in rows:
        md.append(f"| {r['res']}² | {r['rfilter']} | {r['integrator']} | {r['wall_ms']:.2f} | "
                  f"{r['kernels_ms']:.2f} | {r['host_ms']:.2f} | {r['submit_ms']:.2f} |\n")
    out.with_suffix(".md").write_text("".join(md))
    print(f"wrote {out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
