"""Peak memory of a reverse-mode iteration against the primal frame.

    python -m compare.grad_memory [--res 1024] [--depths 1 3 5 8] [--budgets 262144 1099511627776]

Each measurement is a fresh process (``--one``) that loads ``scenes/fig11.xml`` (mirror and glass
quadrics, a Phong ``transmittance`` with gradients enabled) at ``res``² and ``max_depth``, then
makes either one primal frame (``mi.render``) or one reverse-mode iteration (``mi.render(scene,
params)`` + ``dr.backward`` of the image mean) with the derivative pass cut into blocks of at
most ``budget`` sample lanes (``links1_mitsuba.gradients.AD_BLOCK_LANES``; a budget above the
frame's sample count is the whole frame in one block, as before the blocks), and reports its
peak resident memory (``VmHWM``) and that of the process right after loading the scene. LLVM;
memory, not time: it does not depend on the machine's load. Writes
``compare/results/grad_memory.{json,md}``.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "compare" / "results"
KEY = "links1_whitted.links1_quadric_2.bsdf.transmittance.value"


def _vm_hwm_mib() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024.0
    raise RuntimeError("no VmHWM in /proc/self/status (Linux only)")


def one(res: int, depth: int, mode: str, budget: int) -> dict:
    """In this process: load, then one primal frame or one reverse-mode iteration."""
    import drjit as dr
    import mitsuba as mi
    import links1_mitsuba as lm
    from links1_mitsuba import gradients
    lm.register("llvm_ad_rgb")
    gradients.AD_BLOCK_LANES = int(budget)
    scene = lm.load_file(str(ROOT / "scenes" / "fig11.xml"), res=res, max_depth=depth)
    dr.eval()
    loaded = _vm_hwm_mib()
    if mode == "primal":
        img = mi.render(scene)
        dr.eval(img)
    else:
        params = mi.traverse(scene)
        dr.enable_grad(params[KEY])
        img = mi.render(scene, params)
        dr.backward(dr.mean(img, axis=None))
        g = dr.grad(params[KEY])
        dr.eval(g)
        if not float(dr.sum(dr.abs(g))[0]) > 0.0:
            raise RuntimeError("no gradient reached the parameter")
    dr.sync_thread()
    return dict(res=res, depth=depth, mode=mode, budget=int(budget), loaded_mib=loaded, peak_mib=_vm_hwm_mib())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m compare.grad_memory", description=__doc__.split("\n\n")[0])
    ap.add_argument("--res", type=int, default=1024)
    ap.add_argument("--depths", type=int, nargs="+", default=[1, 3, 5, 8])
    ap.add_argument("--budgets", type=int, nargs="+", default=[1 << 17, 1 << 40],
                    help="AD_BLOCK_LANES values (the default's and one block)")
    ap.add_argument("--one", nargs=4, metavar=("RES", "DEPTH", "MODE", "BUDGET"), help=argparse.SUPPRESS)
    ap.add_argument("--out", default=str(RESULTS / "grad_memory"))
    a = ap.parse_args(argv)
    if a.one:
        print(json.dumps(one(int(a.one[0]), int(a.one[1]), a.one[2], int(a.one[3]))))
        return 0
    rows = []
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    cases = [(d, "primal", a.budgets[0]) for d in a.depths] + [(d, "reverse", b) for d in a.depths for b in a.budgets]
    for depth, mode, budget in cases:
        out = subprocess.run([sys.executable, "-m", "compare.grad_memory", "--one", str(a.res), str(depth), mode,
                              str(budget)], capture_output=True, text=True, env=env, cwd=ROOT)
        if out.returncode != 0:
            raise SystemExit(f"compare.grad_memory: the {mode} run at depth {depth} failed:\n{out.stderr[-2000:]}")
        r = json.loads(out.stdout.strip().splitlines()[-1])
        rows.append(r)
        print(f"{a.res}² max_depth {depth} {mode:8s} budget {budget:>14d}: loaded {r['loaded_mib']:.0f} MiB, "
              f"peak {r['peak_mib']:.0f} MiB", flush=True)
    machine = f"{platform.node()} ({platform.processor() or platform.machine()}), llvm_ad_rgb"
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(dict(machine=machine, res=a.res, rows=rows), indent=1))
    peak = {(r["depth"], r["mode"], r["budget"]): r["peak_mib"] for r in rows}
    md = ["# Peak memory of a reverse-mode iteration\n\n",
          f"`python -m compare.grad_memory --res {a.res} --depths {' '.join(map(str, a.depths))} --budgets "
          f"{' '.join(map(str, a.budgets))}` on {machine}. `scenes/fig11.xml` at {a.res}², spp 1, "
          "`transmittance` of its glass with gradients; peak resident memory (VmHWM) of a fresh process: "
          "one primal frame, or one `mi.render(scene, params)` + `dr.backward` with the derivative pass in "
          "blocks of at most *budget* sample lanes (`AD_BLOCK_LANES`; "
          f"{1 << 40} = the whole frame in one block, as before the blocks). Loaded scene: "
          f"{min(r['loaded_mib'] for r in rows):.0f}–{max(r['loaded_mib'] for r in rows):.0f} MiB.\n\n",
          "| max_depth | primal MiB | " + " | ".join(f"reverse, budget {b} MiB" for b in a.budgets) + " |\n",
          "| --- | --- | " + " | ".join("---" for _ in a.budgets) + " |\n"]
    for d in a.depths:
        md.append(f"| {d} | {peak[(d, 'primal', a.budgets[0])]:.0f} | "
                  + " | ".join(f"{peak[(d, 'reverse', b)]:.0f}" for b in a.budgets) + " |\n")
    out.with_suffix(".md").write_text("".join(md))
    print(f"wrote {out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
