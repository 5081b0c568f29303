"""Where a ``links1_blob`` ray's time goes: camera rays and directional-light shadow rays of
``compare.blob_mesh.scene_xml(k)``'s blob, traced alone (``BlobSpec.intersect`` in one kernel,
``dr.kernel_history()``), their candidate centres found by the hierarchy's walk or by the film
cells' / light grid's lists, and the counters of each.

    python -m compare.blob_rays [--centres 10,100] [--res 128] [--spp 16] [--rounds 3] [--reps 5]
                                [--list-min N] [--check 20000]

Camera rays: the benchmark scene's pinhole (its eye, 50° field of view), ``--spp`` jittered
samples a pixel in consecutive lanes (the launch's order); shadow rays: from their hits (1e-3
along the light) toward the scene's directional light. Parts: ``lists`` (the candidate lists
only), ``+ set-up`` (and the register slots, the span and the bounds), ``intersect`` (and the root
finder: the whole nearest-hit search), ``any-hit`` (a shadow ray's search) and, with the light
grid's lists, ``bound`` (its first part: the bound of ``W`` over the cell's list alone, which
decides whether the ray goes on to its list, set-up and march); a blob that sums
all its centres (under ``LIST_MIN_CENTRES``; ``--list-min`` sets it for the run) has the last
two only. Each part's kernel time is the process CPU time of its evaluation (traced first, so
tracing is not counted; one Dr.Jit thread: robust to other processes on the machine, which
stretch wall time), the smallest of ``--reps`` runs, the table the median over ``--rounds``
interleaved rounds, in ns a ray. Counters:
candidate centres a camera ray, field evaluations a ray (the ``cost`` of ``intersect``) split
into the march's (an any-hit search of the same ray: the march up to a sign change or a
certain root) and the rest (the refinement), per camera ray, per camera ray that meets a 3S sphere, per hit, and per shadow ray;
the share of rays that meet a 3S sphere and that hit; the camera rays' evaluations, the mean over
packets of :data:`PACKET` consecutive lanes (a pixel's samples at spp 16) of their largest
(a packet's loop runs until its last lane is done); the share of shadow rays whose bound does not
exclude a root and of packets with one such lane; the list entries a camera ray's film cell and a
shadow ray's grid cell hold. Precision: ``--check`` camera rays' hit
distances against the float64 core's (``links1.geometry.blob.Blob`` on the same float32 rays):
the error in float32 ulps of the distance (quantiles, largest) and the rays whose hit or miss
differs.

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
#: lanes of a CPU packet (AVX-512 float32) for the packet counters
PACKET = 16


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


def hit_errors(c, O, D, t, check):
    """``check`` rays' (evenly spread over the film) float32 hit distances ``t`` against the
    float64 core's on the same (float32) rays: error quantiles in float32 ulps of the core's
    distance, and the rays whose hit or miss differs."""
    from links1.geometry.blob import Blob
    pick = np.linspace(0, len(t) - 1, min(check, len(t))).astype(np.int64)
    o = np.array(O, dtype=np.float64).T[pick]
    d = np.array(D, dtype=np.float64).T[pick]
    t32 = np.array(t, dtype=np.float64)[pick]
    t64, _ = Blob(c, THRESHOLD).intersect(o, d, 0.0, np.inf)
    both = np.isfinite(t32) & np.isfinite(t64)
    ulps = np.abs(t32[both] - t64[both]) / np.spacing(t64[both].astype(np.float32)).astype(np.float64)
    q = np.quantile(ulps, [0.5, 0.9, 0.99]) if ulps.size else [np.nan] * 3
    return {"checked_rays": int(len(t32)), "hits_compared": int(both.sum()),
            "ulps_median": float(q[0]), "ulps_p90": float(q[1]), "ulps_p99": float(q[2]),
            "ulps_max": float(ulps.max()) if ulps.size else float("nan"),
            "ulps_mean": float(ulps.mean()) if ulps.size else float("nan"),
            "hit_miss_differs": int((np.isfinite(t32) != np.isfinite(t64)).sum())}


def measure(k, res, spp, rounds, reps, check=0):
    import drjit as dr
    import mitsuba as mi
    from links1_mitsuba import eyegrid
    from links1_mitsuba.blob import BlobSpec
    c, _ = blob_centres(k)
    spec = BlobSpec(0, "blob", c, THRESHOLD)
    eye, d, cam = _rays(k, res, spp)
    n = len(d)
    lists = spec.uses_lists()
    w = LIGHT / np.linalg.norm(LIGHT)
    film = grid = None
    if lists:
        R = eyegrid.camera_frame(cam)
        film = spec.film_lists(eye, R, eyegrid.film_window(cam, 50.0, (res, res), R), (res, res), 1e-4, 1e-4)
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

    def cands(lst):
        u, v, _ = spec._unit_ray(O, D)
        return spec._line_candidates(u, v, act) if lst is None else spec._film_candidates(u, v, lst, O, D, act)

    def setup(lst):
        u, v, _ = spec._unit_ray(O, D)
        _, *span = spec._setup_lists(u, v, act, None if lst is None else cands(lst))
        return span

    def full(lst):
        cost = dr.zeros(mi.UInt32, n)
        return spec.intersect(O, D, 0.0, np.inf, act, cost, film=lst)[0], cost

    def march(lst):
        cost = dr.zeros(mi.UInt32, n)
        return spec.intersect(O, D, 0.0, np.inf, act, cost, any_hit=True, film=lst)[0], cost

    def shadow(lst):
        cost = dr.zeros(mi.UInt32, n)
        return spec.intersect(S, W, 0.0, 1e4, hit, cost, any_hit=True, film=lst)[0], cost

    def bound(lst):
        u, v, _ = spec._unit_ray(S, W)
        return spec._film_bound(u, v, lst, S, W, hit, 0.0)

    parts = {"camera: lists": cands, "camera: + set-up": setup, "camera: intersect": full,
             "shadow: bound": bound, "shadow: any-hit": shadow}
    if not lists:
        parts = {p: parts[p] for p in ("camera: intersect", "shadow: any-hit")}
    times = {(p, s): [] for p in parts for s in (("walk", "lists") if lists else ("all",))
             if (p, s) != ("shadow: bound", "walk")}
    for _ in range(rounds):
        for (p, s) in times:
            fn, lst = parts[p], None if s != "lists" else (grid if p.startswith("shadow") else film)
            ms = []
            for _ in range(reps):
                out = fn(lst)                  # traced, not yet run
                c0 = time.process_time()
                dr.eval(out)
                dr.sync_thread()
                ms.append(1e3 * (time.process_time() - c0))
            times[(p, s)].append(float(np.min(ms)))
    # the centres whose 3S sphere a camera ray's line crosses (float64: the counters only)
    dc = c[:, :3][None] - eye[None, None]
    h2 = np.sum(np.cross(dc, d[:, None]) ** 2, axis=2)
    cnt = (h2 < 9.0 * c[:, 4] ** 2).sum(1)
    tc, cost = full(film)
    _, mcost = march(film)
    _, scost = shadow(grid)
    cost, mcost, scost, hits = (np.array(x, dtype=np.float64) for x in (cost, mcost, scost, hit))
    nh = max(int(hits.sum()), 1)
    meet = cnt > 0
    counters = {"rays": n, "candidates_mean": float(cnt.mean()), "candidates_max": int(cnt.max()),
                "meet_share": float(meet.mean()), "hit_share": float(hits.mean()),
                "evaluations_camera": float(cost.mean()),
                "evaluations_meeting": float(cost[meet].mean()),
                "march_camera": float(mcost.mean()), "march_meeting": float(mcost[meet].mean()),
                "refine_hit": float((cost - mcost)[hits > 0].mean()) if nh else 0.0,
                "evaluations_hit": float(cost[hits > 0].mean()) if nh else 0.0,
                "evaluations_shadow": float(scost.sum() / nh)}
    whole = n - n % PACKET
    counters["evaluations_packet_max"] = float(cost[:whole].reshape(-1, PACKET).max(1).mean())
    if lists:
        Bs = np.array(bound(grid))
        goes = (hits > 0) & (Bs * (1.0 + 1e-5) >= THRESHOLD)    # blob_roots._clear fails: a root may follow
        counters["shadow_goes_on"] = float(goes.sum() / nh)
        counters["shadow_packets_going_on"] = float(goes[:whole].reshape(-1, PACKET).any(1).sum()
                                                    / max(hits[:whole].reshape(-1, PACKET).any(1).sum(), 1))
        counters.update({"film_entries_per_cell": film.entries / (film.nu * film.nv + 1),
                         "grid_entries_per_cell": grid.entries / (grid.N * grid.N + 1)})

        def entries(lst, o, d):     # the list lengths of the rays' cells
            off, cell = np.array(lst.off, dtype=np.int64), np.array(lst.cell(o, d), dtype=np.int64)
            return off[cell + 1] - off[cell]
        counters["film_entries_camera_ray"] = float(entries(film, O, D).mean())
        counters["grid_entries_shadow_ray"] = float(entries(grid, S, W)[hits > 0].mean())
    if check:
        counters.update(hit_errors(c, O, D, tc, check))
    ns = {f"{p} ({s})": 1e6 * float(np.median(v)) / (n if p.startswith("camera") else nh) for (p, s), v in times.items()}
    return ns, counters


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m compare.blob_rays")
    ap.add_argument("--centres", default="10,100")
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--list-min", type=int, default=None,
                    help="LIST_MIN_CENTRES for this run (the smallest blob that takes candidate lists)")
    ap.add_argument("--check", type=int, default=20000, help="camera rays checked against the float64 core")
    a = ap.parse_args(argv)
    info, command, t0 = common.machine_info(), common.command_line(), time.perf_counter()
    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    from links1_mitsuba import blob_candidates
    if a.list_min is not None:
        blob_candidates.LIST_MIN_CENTRES = a.list_min
    ks = [int(x) for x in a.centres.split(",")]
    text = ("# Where a links1_blob ray's time goes\n\n" + common.machine_markdown(info, command)
            + "\nThe machine's two cores are shared with other processes: compare within a run.\n\n"
            f"`compare.blob_mesh.scene_xml(k)`'s blob, {a.res}², spp {a.spp}, one Dr.Jit thread; CPU ns a "
            "ray of the kernel (camera parts: a camera ray; shadow: a shadow ray from a hit; the least of "
            f"{a.reps} runs, the median over {a.rounds} rounds); "
            "walk: the candidate hierarchy's walk, lists: the film cells' (camera) or the light grid's "
            f"(shadow) lists, all: every centre summed (under LIST_MIN_CENTRES = "
            f"{blob_candidates.LIST_MIN_CENTRES} centres).\n")
    out = {"machine": info, "command": command, "res": a.res, "spp": a.spp,
           "list_min_centres": blob_candidates.LIST_MIN_CENTRES, "blobs": {}}
    for k in ks:
        ns, counters = measure(k, a.res, a.spp, a.rounds, a.reps, a.check)
        rows = []
        for p in ("camera: lists", "camera: + set-up", "camera: intersect", "shadow: bound", "shadow: any-hit"):
            if f"{p} (walk)" in ns:
                wk, ls = ns[f"{p} (walk)"], ns[f"{p} (lists)"]
                rows.append([p, wk, ls, wk / ls, "–"])
            elif f"{p} (lists)" in ns:
                rows.append([p, "–", ns[f"{p} (lists)"], "–", "–"])
            elif f"{p} (all)" in ns:
                rows.append([p, "–", "–", "–", ns[f"{p} (all)"]])
        text += (f"\n## {k} centres ({counters['rays']} camera rays)\n\n"
                 + md_table(["part", "walk ns", "lists ns", "walk / lists", "all ns"], rows)
                 + "\n" + md_table(["counter", "value"], [[key, v] for key, v in counters.items()]))
        out["blobs"][str(k)] = {"ns_per_ray": ns, "counters": counters}
    out["wall_s"] = time.perf_counter() - t0
    print(text)
    for path in common.write_results("blob_rays", out, text, None):
        print("wrote", path.relative_to(common.ROOT), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
