"""Where a ``links1_blob`` ray's time goes: camera rays and directional-light shadow rays of
``compare.blob_mesh.scene_xml(k)``'s blob, traced alone (``BlobSpec.intersect`` in one kernel,
``dr.kernel_history()``), their candidate centres found by the hierarchy's walk or by the film
cells' / light grid's lists, and the counters of each.

    python -m compare.blob_rays [--centres 100] [--res 128] [--spp 16] [--rounds 3] [--reps 5]

Camera rays: the benchmark scene's pinhole (its eye, 50° field of view), ``--spp`` jittered
samples a pixel in consecutive lanes (the launch's order); shadow rays: from their hits (1e-3
along the light) toward the scene's directional light. Parts: ``lists`` (the candidate lists
only), ``+ set-up`` (and the register slots, the span and the bounds), ``intersect`` (and the root
finder: the whole nearest-hit search), ``any-hit`` (a shadow ray's search). Each part's kernel
time is the median of ``--reps`` runs, the table the median over ``--rounds`` interleaved
rounds, in ns a ray (of the kernel; one Dr.Jit thread). Counters: candidate centres a camera
ray, field evaluations a ray (the ``cost`` of ``intersect``), the share of rays that meet a 3S
sphere and that hit.

Writes ``compare/results/blob_rays.{json,md}``.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

os.environ.setdefault("DRJIT_NUM_THREADS", "1")

from . import common  # noqa: E402
from .common import md_table  # noqa: E402
from .scaling import blob_centres  # noqa: E402

THRESHOLD = 0.5
LIGHT = np.array([0.4, 1.0, 0.3])   # toward compare.blob_mesh's directional light


def _rays(k, res, spp):
    """The camera's rays (numpy float64 eye, unit directions (n, 3)) and the camera matrix."""
    _, m = blob_centres(k)
    eye = np.array([0.0, 0.95 * m + 1, 0.95 * m + 1])
    f = -eye / np.linalg.norm(eye)
    left = np.cross([0.0, 1.0, 0.0], f)
    left /= np.linalg.norm(left)
    cam = np.eye(4)
    cam[:3, 0], cam[:3, 1], cam[:3, 2], cam[:3, 3] = left, np.cross(f, left), f, eye
    rng = np.random.default_rng(1)
    iy, ix = np.mgrid[0:res, 0:res]
    ix, iy = np.repeat(ix.ravel(), spp), np.repeat(iy.ravel(), spp)
    tn = np.tan(np.radians(25.0))
    sx = (1.0 - (ix + rng.random(ix.size)) / res * 2.0) * tn
    sy = (1.0 - (iy + rng.random(ix.size)) / res * 2.0) * tn
    d = np.c_[sx, sy, np.ones(ix.size)] @ cam[:3, :3].T
    return eye, d / np.linalg.norm(d, axis=1)[:, None], cam


def measure(k, res, spp, rounds, reps):
    import drjit as dr
    import mitsuba as mi
    from links1_mitsuba import eyegrid
    from links1_mitsuba.blob import BlobSpec
    c, _ = blob_centres(k)
    spec = BlobSpec(0, "blob", c, THRESHOLD)
    eye, d, cam = _rays(k, res, spp)
    n = len(d)
    R = eyegrid.camera_frame(cam)
    film = spec.film_lists(eye, R, eyegrid.film_window(cam, 50.0, (res, res), R), (res, res), 1e-4, 1e-4)
    w = LIGHT / np.linalg.norm(LIGHT)
    lo, hi = spec.bounds()
    ext = float(np.abs(np.r_[lo, hi, eye]).max())
    grid = spec.dir_lists(w, ext, 1e-4 * (1.0 + ext))
    O = mi.Vector3f(np.tile(eye[:, None], n).astype(np.float32))
    D = mi.Vector3f(d.T.astype(np.float32))
    act = dr.ones(mi.Bool, n)
    t, _ = spec.intersect(O, D, 0.0, np.inf, act)
    hit = dr.isfinite(t)
    W = mi.Vector3f(np.tile(w[:, None], n).astype(np.float32))
    S = O + D * dr.select(hit, t, 0.0) + W * 1e-3
    dr.eval(O, D, W, S, hit)

    def lists(lst):
        u, v, _ = spec._unit_ray(O, D)
        return spec._line_candidates(u, v, act) if lst is None else spec._film_candidates(u, v, lst, O, D, act)

    def setup(lst):
        u, v, _ = spec._unit_ray(O, D)
        _, *span = spec._setup_lists(u, v, act, None if lst is None else lists(lst))
        return span

    def full(lst):
        cost = dr.zeros(mi.UInt32, n)
        return spec.intersect(O, D, 0.0, np.inf, act, cost, film=lst)[0], cost

    def shadow(lst):
        cost = dr.zeros(mi.UInt32, n)
        return spec.intersect(S, W, 0.0, 1e4, hit, cost, any_hit=True, film=lst)[0], cost

    parts = {"camera: lists": lists, "camera: + set-up": setup, "camera: intersect": full,
             "shadow: any-hit": shadow}
    times = {(p, s): [] for p in parts for s in ("walk", "lists")}
    for _ in range(rounds):
        for (p, s) in times:
            fn, lst = parts[p], None if s == "walk" else (grid if p.startswith("shadow") else film)
            ms = []
            for _ in range(reps):
                _, hist = common.kernel_history_of(lambda: dr.eval(fn(lst)))
                ms.append(sum(h["execution_time"] for h in hist if h.get("type") == dr.KernelType.JIT))
            times[(p, s)].append(float(np.median(ms)))
    cnt = np.array(lists(None)[1])
    _, cost = full(film)
    _, scost = shadow(grid)
    nh = max(int(np.array(hit).sum()), 1)
    counters = {"rays": n, "candidates_mean": float(cnt.mean()), "candidates_max": int(cnt.max()),
                "meet_share": float((cnt > 0).mean()), "hit_share": float(np.array(hit).mean()),
                "evaluations_camera": float(np.array(cost).mean()),
                "evaluations_meeting": float(np.array(cost)[cnt > 0].mean()),
                "evaluations_shadow": float(np.array(scost).sum() / nh),
                "film_entries_per_cell": film.entries / (film.nu * film.nv + 1),
                "grid_entries_per_cell": grid.entries / (grid.N * grid.N + 1)}
    ns = {f"{p} ({s})": 1e6 * float(np.median(v)) / (n if p.startswith("camera") else nh) for (p, s), v in times.items()}
    return ns, counters


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m compare.blob_rays")
    ap.add_argument("--centres", type=int, default=100)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--reps", type=int, default=5)
    a = ap.parse_args(argv)
    info, command, t0 = common.machine_info(), common.command_line(), time.perf_counter()
    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    ns, counters = measure(a.centres, a.res, a.spp, a.rounds, a.reps)
    rows = []
    for p in ("camera: lists", "camera: + set-up", "camera: intersect", "shadow: any-hit"):
        wk, ls = ns[f"{p} (walk)"], ns[f"{p} (lists)"]
        rows.append([p, wk, ls, wk / ls])
    text = ("# Where a links1_blob ray's time goes\n\n" + common.machine_markdown(info, command)
            + "\nThe machine's two cores are shared with other processes: compare within a run.\n\n"
            f"`compare.blob_mesh.scene_xml({a.centres})`'s blob, {a.res}², spp {a.spp} "
            f"({counters['rays']} camera rays), one Dr.Jit thread; ns a ray of the kernel (camera parts: "
            "a camera ray; shadow: a shadow ray from a hit), medians; walk: the candidate hierarchy's "
            "walk, lists: the film cells' (camera) or the light grid's (shadow) lists.\n\n"
            + md_table(["part", "walk ns", "lists ns", "walk / lists"], rows)
            + "\n" + md_table(["counter", "value"], [[key, v] for key, v in counters.items()]))
    out = {"machine": info, "command": command, "centres": a.centres, "res": a.res, "spp": a.spp,
           "ns_per_ray": ns, "counters": counters, "wall_s": time.perf_counter() - t0}
    print(text)
    for path in common.write_results("blob_rays", out, text, None):
        print("wrote", path.relative_to(common.ROOT), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
