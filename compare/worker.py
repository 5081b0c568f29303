"""One render job in its own process: ``python -m compare.worker '<json job>'``.

Job keys: ``scene`` (path), ``renderer`` (see :data:`compare.common.RENDERERS`), ``params``
(``$name`` values), ``spp`` (list), ``repeats`` (timed frames after one warm-up frame;
0 = one untimed-warm-up-free frame only), ``seed``, ``max_depth`` (optional),
``min_weight`` (absent: the renderer's default), ``aovs``, ``out`` (npz path for the images), ``core_patch``
(core only: names of skip-disabling patches, see :mod:`compare.skip_study`).

Prints one JSON line: ``ok``, ``load_s``, ``results`` = per spp ``{spp, first_s, times,
median_s, rays}``, ``peak_rss_mib``. Images go to ``out`` as ``spp<N>`` arrays.
"""
from __future__ import annotations

import json
import resource
import sys
import time

import numpy as np


def _core(job):
    from links1.tracing import render as R
    created = []

    base = R.WhittedIntegrator
    patches = job.get("core_patch") or []
    if patches:
        from compare.skip_study import patched_integrator
        base = patched_integrator(base, patches)

    class Recording(base):  # keeps the integrator so that its ray counters can be read
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            created.append(self)

    R.WhittedIntegrator = Recording
    kw = {} if job.get("min_weight") is None else {"min_weight": float(job["min_weight"])}
    r = R.CoreRenderer(job["scene"], params=job.get("params"), spp=1, seed=job.get("seed", 0),
                       max_depth=job.get("max_depth"), aovs=tuple(job.get("aovs") or ()), **kw)

    def render(spp):
        r.spp = spp
        created.clear()
        img = r.render()
        rays = dict(created[-1].stats.rays) if created else None
        return img, rays

    return render


def _links1(job, variant):
    from links1_app.renderers import make_renderer
    kw = {} if job.get("min_weight") is None else {"min_weight": float(job["min_weight"])}
    r = make_renderer("mitsuba", job["scene"], params=job.get("params"), spp=1,
                      seed=job.get("seed", 0), max_depth=job.get("max_depth"),
                      aovs=tuple(job.get("aovs") or ()), variant=variant, **kw)

    def render(spp):
        r.spp = spp
        img = r.render()
        stats = getattr(getattr(r, "integrator", None), "stats", None)
        if stats is not None and hasattr(stats, "rays"):
            stats = stats.rays
        kinds = ("camera", "shadow", "reflect", "refract")
        rays = ({k: int(stats[k]) for k in kinds if k in stats}
                if isinstance(stats, dict) and stats else None)
        return img, rays

    return render


def _mitsuba(job, kind):
    import mitsuba as mi
    mi.set_variant(job.get("variant") or "llvm_ad_rgb")
    params = {k: str(v) for k, v in (job.get("params") or {}).items()}
    scene = mi.load_file(job["scene"], **params)
    md = job.get("max_depth") or 5
    if kind == "direct":
        integ = mi.load_dict({"type": "direct"})
    else:  # links1 max_depth D surface interactions = Mitsuba path max_depth D + 1
        integ = mi.load_dict({"type": "path", "max_depth": int(md) + 1})
    seed = int(job.get("seed", 0))

    def render(spp):
        img = mi.render(scene, integrator=integ, spp=int(spp), seed=seed)
        return np.array(img, dtype=np.float64)[:, :, :3], None

    return render


def main(argv=None) -> int:
    job = json.loads((argv or sys.argv[1:])[0])
    kind = job["renderer"]
    t0 = time.perf_counter()
    if kind == "core":
        render = _core(job)
    elif kind == "links1-llvm":
        render = _links1(job, "llvm_ad_rgb")
    elif kind == "links1-cuda":
        render = _links1(job, "cuda_ad_rgb")
    elif kind in ("mitsuba-direct", "mitsuba-path"):
        render = _mitsuba(job, kind.split("-")[1])
    else:
        raise SystemExit(f"unknown renderer {kind!r}")
    load_s = time.perf_counter() - t0
    images, results = {}, []
    for spp in job["spp"]:
        t = time.perf_counter()
        img, rays = render(int(spp))
        first = time.perf_counter() - t
        times = []
        for _ in range(int(job.get("repeats", 3))):
            t = time.perf_counter()
            img, rays = render(int(spp))
            times.append(time.perf_counter() - t)
        images[f"spp{int(spp)}"] = np.asarray(img, dtype=np.float32 if job.get("float32") else np.float64)
        results.append({"spp": int(spp), "first_s": first, "times": times,
                        "median_s": float(np.median(times)) if times else first,
                        "rays": rays, "finite": bool(np.all(np.isfinite(img)))})
    np.savez_compressed(job["out"], **images)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(json.dumps({"ok": True, "load_s": load_s, "results": results, "peak_rss_mib": peak}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
