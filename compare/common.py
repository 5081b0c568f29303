"""Shared pieces of the benchmarks: machine description, result files, and isolated
render jobs.

Every timed render runs in its own Python process (``python -m compare.worker``) so that
a kernel compilation that takes too long, or a crash inside LLVM, costs one entry of the
table (recorded as *skipped* with the reason) instead of the whole run, and so that peak
memory (``ru_maxrss``) is per job.
"""
from __future__ import annotations

import json
import os
import platform
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "compare" / "results"
SCENES = ROOT / "scenes"

#: Renderer names used by every benchmark.
#: core          the float64 numpy core (links1.tracing.render.CoreRenderer)
#: links1-llvm   the links1_whitted Dr.Jit integrator on llvm_ad_rgb (links1_mitsuba)
#: links1-cuda   the same on cuda_ad_rgb (only where a GPU works)
#: mitsuba-direct, mitsuba-path   Mitsuba's own integrators (Mitsuba-only scenes)
RENDERERS = ("links1-llvm", "links1-cuda", "core", "mitsuba-direct", "mitsuba-path")


# ------------------------------------------------------------------------- machine
def machine_info() -> dict:
    """CPU model, cores, memory, OS and package versions (for every results file)."""
    info = {"platform": platform.platform(), "python": platform.python_version(),
            "cores": os.cpu_count(), "numpy": np.__version__}
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    info["cpu"] = line.split(":", 1)[1].strip()
                    break
    except OSError:
        info["cpu"] = platform.processor()
    try:
        with open("/proc/meminfo") as f:
            kb = int(f.readline().split()[1])
        info["memory_gib"] = round(kb / 2 ** 20, 1)
    except (OSError, ValueError, IndexError):
        pass
    try:
        info["load_average_at_start"] = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        pass
    from importlib import metadata
    for mod, dist in (("mitsuba", "mitsuba"), ("drjit", "drjit"), ("flip_evaluator", "flip-evaluator"),
                      ("matplotlib", "matplotlib"), ("hypothesis", "hypothesis")):
        try:
            info[mod] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            info[mod] = "not installed"
    info["gpu"] = gpu_name()
    try:
        info["git_commit"] = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                                            capture_output=True, text=True).stdout.strip()
    except OSError:
        pass
    return info


def cpu_seconds() -> float:
    """This process's CPU time so far (user + system, all threads). Frame times as CPU time are
    barely inflated when other processes share the machine's cores; wall times are."""
    import resource
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def timed_render(scene, spp, seed=0):
    """One ``mi.render`` of ``scene`` (evaluated, the threads synchronised before and after):
    ``(wall ms, process CPU ms, image as numpy)``."""
    import drjit as dr
    import mitsuba as mi
    dr.sync_thread()
    t0, c0 = time.perf_counter(), cpu_seconds()
    img = mi.render(scene, spp=spp, seed=seed)
    dr.eval(img)
    dr.sync_thread()
    return (time.perf_counter() - t0) * 1e3, (cpu_seconds() - c0) * 1e3, np.array(img)


def gpu_name() -> str | None:
    """The NVIDIA GPU's name, or None (no GPU: the CUDA rows are skipped)."""
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"],
                             capture_output=True, text=True, timeout=20)
    except (OSError, subprocess.TimeoutExpired):
        return None
    name = out.stdout.strip().splitlines()
    return name[0] if out.returncode == 0 and name else None


def command_line() -> str:
    return "python -m " + " ".join(shlex.quote(a) for a in [_module_name()] + sys.argv[1:])


def _module_name() -> str:
    main = sys.modules.get("__main__")
    spec = getattr(main, "__spec__", None)
    return spec.name if spec is not None else Path(sys.argv[0]).stem


def machine_markdown(info: dict, command: str) -> str:
    keys = ["cpu", "cores", "memory_gib", "platform", "python", "numpy", "mitsuba", "drjit",
            "flip_evaluator", "gpu", "git_commit", "load_average_at_start"]
    rows = " · ".join(f"{k}: {info.get(k)}" for k in keys if k in info)
    return f"Command: `{command}`\n\nMachine: {rows}\n"


# ------------------------------------------------------------------------- output
def write_results(stem: str, payload: dict, markdown: str, fig=None) -> list[Path]:
    """``compare/results/{stem}.json|.md|.png``; returns the paths written."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    paths = []
    p = RESULTS / f"{stem}.json"
    p.write_text(json.dumps(payload, indent=1, default=_json_default) + "\n")
    paths.append(p)
    p = RESULTS / f"{stem}.md"
    p.write_text(markdown)
    paths.append(p)
    if fig is not None:
        p = RESULTS / f"{stem}.png"
        fig.savefig(p, dpi=90, bbox_inches="tight")
        paths.append(p)
    return paths


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(type(o))


def fmt(v, digits=3) -> str:
    if v is None:
        return "–"
    if isinstance(v, str):
        return v
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if not np.isfinite(v):
        return str(v)
    if v == 0:
        return "0"
    return f"{v:.{digits}g}"


def md_table(header: list[str], rows: list[list]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for r in rows:
        out.append("| " + " | ".join(fmt(c) for c in r) + " |")
    return "\n".join(out) + "\n"


def pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


# ------------------------------------------------------------------------- scenes
def scene_plugins(path) -> set[str]:
    """The plugin type names a scene file (and its includes) uses."""
    import xml.etree.ElementTree as ET
    path = Path(path)
    types: set[str] = set()
    for el in ET.parse(path).getroot().iter():
        if "type" in el.attrib:
            types.add(el.attrib["type"])
        if el.tag == "include" and "filename" in el.attrib:
            types |= scene_plugins(path.parent / el.attrib["filename"])
    return types


def mitsuba_only(path) -> bool:
    """True when the scene uses only Mitsuba's own plugins (no ``links1_*``)."""
    return not any(t.startswith("links1_") for t in scene_plugins(path))


# ------------------------------------------------------------------------- jobs
def run_job(job: dict, timeout: float) -> dict:
    """Run one render job (see :mod:`compare.worker`) in a subprocess.

    Returns the worker's result dict plus the images (``images``: {spp: ndarray}); on a
    failure or a timeout ``{"ok": False, "reason": ...}``.
    """
    with tempfile.TemporaryDirectory(prefix="links1-bench-") as tmp:
        job = dict(job, out=os.path.join(tmp, "images.npz"))
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(ROOT), str(ROOT / "plugins"),
                                             env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
        t0 = time.perf_counter()
        try:
            res = subprocess.run([sys.executable, "-m", "compare.worker", json.dumps(job)],
                                 cwd=ROOT, env=env, capture_output=True, text=True,
                                 timeout=timeout)
        except subprocess.TimeoutExpired:
            return {"ok": False, "reason": f"timed out after {timeout:.0f} s (kernel compilation "
                                           "or rendering too slow for this mode)"}
        wall = time.perf_counter() - t0
        lines = [ln for ln in res.stdout.splitlines() if ln.startswith("{")]
        if res.returncode != 0 or not lines:
            tail = (res.stderr or res.stdout).strip().splitlines()[-1:] or ["(no output)"]
            return {"ok": False, "reason": f"exit {res.returncode}: {tail[0][:300]}"}
        out = json.loads(lines[-1])
        out["job_wall_s"] = wall
        if out.get("ok") and os.path.exists(job["out"]):
            with np.load(job["out"]) as z:
                out["images"] = {int(k[3:]): z[k] for k in z.files if k.startswith("spp")}
                out["aux"] = {k: z[k] for k in z.files if not k.startswith("spp")}
        return out


def kernel_history_of(fn):
    """``fn()`` run with Dr.Jit's kernel history recording: ``(wall seconds, the kernels it
    launched)`` (``dr.kernel_history()``: a dict a kernel)."""
    import drjit as dr   # (here only: most benchmarks of this module never load Dr.Jit)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()
    try:
        t0 = time.perf_counter()
        fn()
        return time.perf_counter() - t0, dr.kernel_history()
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)


def check_finite(img, what: str) -> None:
    if not np.all(np.isfinite(img)):
        bad = int(np.sum(~np.isfinite(img)))
        raise FloatingPointError(f"{what}: {bad} non-finite values in the image")
