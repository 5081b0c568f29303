"""Can an iteration of ``compare.inverse_outline``'s ``quadric_outline`` fit run as one
:func:`drjit.freeze` function (render with ``projective=true``, L2 loss, ``dr.backward``, Adam
step, ``params.update()``), as Mitsuba's tutorials freeze a whole optimisation step? A check
of what stops it, not a benchmark:

    python -m compare.inverse_frozen [--width 64]

1. ``whole step``: the step frozen, in a child process (a host read-back while Dr.Jit records
   aborts the process: ``RecordThreadState::enqueue_host_func(): this function cannot be
   recorded``): where it stops, the first frame of links1 code on the stack;
2. ``tables outside``: the same with the tables brought up to the update before the frozen
   call (``integrator.prepare``), the render, loss, ``dr.backward`` and the step frozen: the
   next place it stops;
3. Dr.Jit alone (no links1 code): a frozen function that compacts with ``dr.compress`` and
   then reduces (``dr.sum``, a scatter-add, ``dr.backward``) is recorded again at every call
   (its replay cannot size the compressed array in the dry run such kernels need, LLVM), and
   the same compaction made with a fixed capacity (an exclusive prefix sum and a scatter, the
   count kept on the device) is replayed with the right values and gradient.

Writes ``compare/results/inverse_frozen.{json,md}``.
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys

import numpy as np

from compare.common import command_line, machine_info, machine_markdown, md_table, write_results

_CHILD = r"""
import sys
import mitsuba as mi
mi.set_variant("llvm_ad_rgb")
import drjit as dr
from compare import inverse, inverse_outline as io
inverse.SCENES.update(io.SCENES)
name, cls, variables, lrs, _ = io.make_cases(10, 10)[0]
scene = inverse.load(name, {width})
case = cls(name, scene, variables, lrs, 1)
params = mi.traverse(scene)
case.setup(mi, params)
target = mi.render(scene, seed=0)
case.set_values(mi, params, {{k: d["start"] for k, d in variables.items()}})
opt = inverse.optimizer(mi, case, params, variables, lrs)
outside = {outside}

def step(scene, params, target, opt):
    img = mi.render(scene, params, seed=0)
    loss = dr.mean(dr.square(img - target), axis=None)
    dr.backward(loss)
    opt.step()
    if not outside:
        case.apply(mi, params, opt)
    return loss

frozen = dr.freeze(step)
for it in range(3):
    if outside:
        scene.integrator().prepare(scene)
    frozen(scene, params, target, opt)
    if outside:
        case.apply(mi, params, opt)
print("RECORDED", frozen.n_recordings, flush=True)
"""


def _stop(width, outside):
    """Run the frozen step in a child process: ``(status, message, where)``."""
    env = dict(os.environ, PYTHONFAULTHANDLER="1")
    p = subprocess.run([sys.executable, "-c", _CHILD.format(width=width, outside=outside)], capture_output=True,
                       text=True, env=env, timeout=600)
    out = p.stdout + p.stderr
    if "RECORDED" in out:
        return "ran", out.strip().splitlines()[-1], ""
    msg = next((ln.strip() for ln in out.splitlines() if "what():" in ln or "Error" in ln), out.strip()[-200:])
    frames = re.findall(r'File "([^"]+)", line (\d+) in (\S+)', out)
    mine = [f for f in frames if "site-packages" not in f[0] and "<string>" not in f[0]]
    where = f"{os.path.relpath(mine[0][0])}:{mine[0][1]} ({mine[0][2]})" if mine else "?"
    return f"stopped (exit {p.returncode})", msg, where


def _drjit_alone():
    """The compaction checks of the module's docstring: rows ``(case, calls, recordings, right)``."""
    import drjit as dr
    from drjit.llvm.ad import Float, UInt32

    def compressed(kind):
        @dr.freeze
        def f(x, y):
            idx = dr.compress(x > 0.5)
            v = dr.gather(Float, x, idx) * y
            if kind == "sum":
                return dr.sum(v)
            out = dr.zeros(Float, 16)
            dr.scatter_add(out, v, idx % 16)
            if kind == "backward":
                dr.backward(dr.sum(out * out))
            return out
        return f

    @dr.freeze
    def capacity(x, y):
        m = x > 0.5
        n = dr.width(x)
        idx = dr.zeros(UInt32, n)
        dr.scatter(idx, dr.arange(UInt32, n), dr.prefix_sum(UInt32(m)), m)
        count = dr.sum(UInt32(m))
        valid = dr.arange(UInt32, n) < dr.gather(UInt32, count, UInt32(0))
        v = dr.gather(Float, x, idx, valid) * y
        out = dr.zeros(Float, 16)
        dr.scatter_add(out, v, idx % 16, valid)
        dr.backward(dr.sum(out * out))
        return out

    rows, calls = [], 6
    for kind, fn in [("compress, sum", compressed("sum")), ("compress, scatter-add", compressed("scatter")),
                     ("compress, scatter-add, backward", compressed("backward")),
                     ("fixed capacity (prefix sum), scatter-add, backward", capacity)]:
        rng = np.random.default_rng(1)
        right = True
        for _ in range(calls):
            xn = rng.random(1000).astype(np.float32)
            y = Float(2.0)
            dr.enable_grad(y)
            out = fn(Float(xn), y)
            sel = np.nonzero(xn > 0.5)[0]
            ref = np.bincount(sel % 16, weights=xn[sel] * 2.0, minlength=16)
            if kind.endswith("sum"):
                right &= bool(np.isclose(float(out[0]), ref.sum(), rtol=1e-5))
            else:
                right &= bool(np.allclose(np.array(out), ref, rtol=1e-5))
            if "backward" in kind:
                g = float(np.sum(2.0 * ref * np.bincount(sel % 16, weights=xn[sel], minlength=16)))
                right &= bool(np.isclose(float(dr.grad(y)[0]), g, rtol=1e-5))
        rows.append((kind, calls, fn.n_recordings, "yes" if right else "no"))
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--width", type=int, default=64)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    steps = [("whole step", _stop(args.width, False)), ("tables outside", _stop(args.width, True))]
    for name, (status, msg, where) in steps:
        print(f"{name}: {status}: {msg} at {where}")
    alone = _drjit_alone()
    for row in alone:
        print("Dr.Jit alone: {}: {} calls, {} recordings, values right: {}".format(*row))
    if args.no_write:
        return
    info = machine_info()
    md = ["# An outline-fitting iteration under dr.freeze\n", machine_markdown(info, command_line()),
          "\nThe quadric_outline step frozen (a child process each):\n",
          md_table(["frozen", "result", "message", "where (first links1 frame)"],
                   [[n, s, m.replace("|", "/"), w] for n, (s, m, w) in steps]),
          "\nDr.Jit alone (LLVM): frozen compactions\n",
          md_table(["function", "calls", "recordings", "values and gradient right"], [list(r) for r in alone])]
    write_results("inverse_frozen", {"command": command_line(), "machine": info, "width": args.width,
                                     "steps": {n: dict(zip(("status", "message", "where"), v)) for n, v in steps},
                                     "drjit_alone": [dict(zip(("function", "calls", "recordings", "right"), r))
                                                     for r in alone]}, "\n".join(md) + "\n")


if __name__ == "__main__":
    main()
