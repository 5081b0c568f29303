"""What skipping unneeded work saves, measured on the core.

    python -m compare.skip_study [--quick] [--scenes ...]

The core integrator (links1/tracing/integrator.py) looks at the scene once: it spawns mirror rays
only from surfaces with ``r > 0``, refraction rays only from surfaces with ``t > 0``,
shadow rays only where the BSDF and the light give a non-zero contribution, and stops a
branch whose weight falls below ``min_weight``. This study switches each skip *off* by
wrapping the scene's materials and lights (the integrator itself is not changed):

* ``reflect``: every material reports a reflection of 1e-30 (every hit spawns a mirror
  ray, as a Whitted tracer without the scene check would);
* ``refract``: every material reports a transmission of 1e-30 at η = 1;
* ``shadow``: every BSDF value and light value gets +1e-30 where it is zero (a shadow ray
  for every hit and light);

so the image changes by ~1e-30 while the rays are all traced. It reports rays per pixel
by kind (the integrator's ``stats.rays``), the warm median frame time, and the image's
max abs difference to the baseline (all skips on, ``min_weight = 0``). The weight
threshold is measured at ``min_weight`` = 1/255 (POV-Ray's adc_bailout) and 1/64: the
image must stay within the threshold (max abs difference / threshold reported; dropped
branches carry at most ``min_weight`` × their radiance, which is ≤ 1 on these scenes
except at light-source-like highlights).

Skips the core cannot switch (custom-shape code, blob solver: the core has no code path
for a shape a scene lacks) and the Mitsuba integrator's skips (no flags exposed) are
listed in the results as not measured.
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from . import common
from .common import md_table

TINY = 1e-30

CONFIGS = [
    ("baseline", [], 0.0),
    ("no reflect skip", ["reflect"], 0.0),
    ("no refract skip", ["refract"], 0.0),
    ("no shadow skip", ["shadow"], 0.0),
    ("no skips", ["reflect", "refract", "shadow"], 0.0),
    ("min_weight 1/255", [], 1.0 / 255.0),
    ("min_weight 1/64", [], 1.0 / 64.0),
]
SCENES = ["fig4", "fig6a", "fig11", "lights", "shadows", "mitsuba_glass", "mitsuba_direct"]


# ---------------------------------------------------------------- patches (used by compare.worker)
class _MaterialProxy:
    """Delegates to a material, reporting tiny reflection / transmission / BSDF values."""

    def __init__(self, inner, patches):
        self._inner = inner
        self._patches = set(patches)
        if "reflect" in self._patches:
            self.has_reflection = True
        if "refract" in self._patches:
            self.has_transmission = True

    def __getattr__(self, name):
        return getattr(self._inner, name)

    def eval(self, wo, wi, n, n_raw):
        f = self._inner.eval(wo, wi, n, n_raw)
        if "shadow" in self._patches:
            f = np.where(f == 0.0, TINY, f)
        return f

    def specular(self, wo, n, entering):
        r, t, eta = self._inner.specular(wo, n, entering)
        if "reflect" in self._patches:
            r = np.where(r == 0.0, TINY, r)
        if "refract" in self._patches:
            opaque = np.all(t == 0.0, axis=1)
            t = np.where(t == 0.0, TINY, t)
            eta = np.where(opaque, 1.0, eta)
        return r, t, eta


class _LightProxy:
    def __init__(self, inner):
        self._inner = inner

    def __getattr__(self, name):
        return getattr(self._inner, name)

    def illuminate(self, p):
        wi, dist, L = self._inner.illuminate(p)
        return wi, dist, np.where(L == 0.0, TINY, L)


def patched_integrator(base, patches):
    """A subclass of the core's WhittedIntegrator whose scene has the given skips off."""
    patches = list(patches)

    class NoSkip(base):
        def __init__(self, scene, *a, **k):
            for s in scene.shapes:
                if not isinstance(s.material, _MaterialProxy):
                    s.material = _MaterialProxy(s.material, patches)
            if "shadow" in patches:
                scene.lights = [lt if isinstance(lt, _LightProxy) else _LightProxy(lt) for lt in scene.lights]
            super().__init__(scene, *a, **k)

    return NoSkip


# ---------------------------------------------------------------- study
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m compare.skip_study")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--scenes", nargs="*", default=SCENES)
    ap.add_argument("--res", type=int)
    ap.add_argument("--spp", type=int, default=1)
    a = ap.parse_args(argv)
    res = a.res or (32 if a.quick else 96)
    repeats = 2 if a.quick else 3
    info = common.machine_info()
    command = common.command_line()
    t_start = time.perf_counter()
    out = {"machine": info, "command": command, "res": res, "spp": a.spp, "repeats": repeats,
           "scenes": {}, "not_measured": [
               "custom-shape code and the blob solver: the core has no per-shape-type code path "
               "a scene without that shape type runs (the hierarchy only visits shapes present)",
               "links1_whitted (Mitsuba): only min_weight can be switched (rows 'links1-llvm ...'); its "
               "scene-level skips (specular code, custom-shape code, shadow rays no shape can block) "
               "are always on",
               "'no shadow rays where no occluder can be': not implemented by the core (it traces a "
               "shadow ray for every non-zero contribution); see docs/benchmarks.md"]}
    for name in a.scenes:
        path = common.SCENES / f"{name}.xml"
        rows, base_img = [], None
        for label, patches, mw in CONFIGS:
            res_ = common.run_job({"scene": str(path), "renderer": "core", "params": {"res": res},
                                   "spp": [a.spp], "repeats": repeats, "seed": 0,
                                   "core_patch": patches, "min_weight": mw}, timeout=300)
            if not res_.get("ok"):
                rows.append({"config": label, "skipped": res_.get("reason")})
                continue
            r = res_["results"][0]
            img = res_["images"][a.spp]
            if base_img is None:
                base_img = img
            npix = img.shape[0] * img.shape[1]
            diff = float(np.max(np.abs(img - base_img)))
            rows.append({"config": label, "patches": patches, "min_weight": mw,
                         "median_s": r["median_s"], "rays": r["rays"],
                         "rays_per_pixel": sum(r["rays"].values()) / npix,
                         "by_kind_per_pixel": {k: v / npix for k, v in r["rays"].items()},
                         "max_abs_diff": diff, "diff_over_threshold": diff / mw if mw > 0 else None,
                         "finite": r["finite"]})
            print(f"  {name} {label}: {rows[-1]['rays_per_pixel']:.2f} rays/px, "
                  f"{r['median_s'] * 1e3:.1f} ms, max diff {diff:.3g}", file=sys.stderr)
        # links1_whitted: only its weight threshold can be switched (its scene-level skips are
        # always on); rays per pixel from its ``stats`` counters
        plugin_base = None
        for label, mw in (("links1-llvm min_weight 0", 0.0), ("links1-llvm min_weight 1/255", 1 / 255),
                          ("links1-llvm min_weight 1/64", 1 / 64)):
            res_ = common.run_job({"scene": str(path), "renderer": "links1-llvm", "params": {"res": res},
                                   "spp": [a.spp], "repeats": repeats, "seed": 0, "min_weight": mw},
                                  timeout=300)
            if not res_.get("ok"):
                rows.append({"config": label, "skipped": res_.get("reason")})
                continue
            r = res_["results"][0]
            img = res_["images"][a.spp]
            npix = img.shape[0] * img.shape[1]
            rays = r["rays"] or {}
            if plugin_base is None:
                plugin_base = img
            diff = float(np.max(np.abs(img - plugin_base)))
            rows.append({"config": label, "patches": [], "min_weight": mw, "renderer": "links1-llvm",
                         "max_abs_diff_to_core": float(np.max(np.abs(img - base_img))) if base_img is not None else None,
                         "median_s": r["median_s"], "rays": rays,
                         "rays_per_pixel": sum(rays.values()) / npix if rays else float("nan"),
                         "by_kind_per_pixel": {k: v / npix for k, v in rays.items()},
                         "max_abs_diff": diff, "diff_over_threshold": diff / mw if mw > 0 else None,
                         "finite": r["finite"]})
        base = next((r for r in rows if r["config"] == "baseline" and "skipped" not in r), None)
        mbase = next((r for r in rows if r["config"] == "links1-llvm min_weight 0" and "skipped" not in r), None)
        for r in rows:
            b = mbase if r.get("renderer") == "links1-llvm" else base
            if b and "skipped" not in r:
                r["time_ratio_to_baseline"] = r["median_s"] / b["median_s"]
                r["rays_ratio_to_baseline"] = r["rays_per_pixel"] / b["rays_per_pixel"]
        out["scenes"][name] = rows
    out["wall_s"] = time.perf_counter() - t_start
    md = _markdown(out)
    paths = common.write_results("skip_study", out, md, _plot(out))
    print(md)
    print("wrote " + ", ".join(str(p.relative_to(common.ROOT)) for p in paths), file=sys.stderr)
    return 0


def _markdown(out) -> str:
    s = ["# Skip study: rays and time with and without each skip (core)\n\n",
         common.machine_markdown(out["machine"], out["command"]),
         f"\nFilm {out['res']}×{out['res']}, {out['spp']} spp; warm median of {out['repeats']} frames; "
         "each configuration in its own process. rays/px = camera + shadow + reflect + refract rays per "
         "pixel. ×time, ×rays = relative to the baseline (all skips on, min_weight 0). "
         "max |Δ| = largest per-channel difference to the baseline image (for the links1-llvm rows: to "
         "links1-llvm at min_weight 0, which is also their ×rays and ×time baseline; their difference to "
         "the core is in the JSON as max_abs_diff_to_core); "
         "/thr = that over min_weight. "
         f"Run took {out['wall_s']:.0f} s.\n\nNot measured:\n"]
    s += [f"- {x}\n" for x in out["not_measured"]]
    for name, rows in out["scenes"].items():
        s.append(f"\n## {name}\n\n")
        t = []
        for r in rows:
            if "skipped" in r:
                t.append([r["config"], "skipped: " + str(r["skipped"])[:80]] + [None] * 9)
                continue
            k = r["by_kind_per_pixel"]
            t.append([r["config"], r["rays_per_pixel"], k.get("shadow"), k.get("reflect"), k.get("refract"),
                      r.get("rays_ratio_to_baseline"), r["median_s"] * 1e3, r.get("time_ratio_to_baseline"),
                      r["max_abs_diff"], r["diff_over_threshold"], "yes" if r["finite"] else "NO"])
        s.append(md_table(["config", "rays/px", "shadow/px", "reflect/px", "refract/px", "×rays",
                           "median ms", "×time", "max |Δ|", "/thr", "finite"], t))
    return "".join(s)


def _plot(out):
    plt = common.pyplot()
    names = list(out["scenes"])
    labels = [c[0] for c in CONFIGS] + ["links1-llvm min_weight 0", "links1-llvm min_weight 1/255", "links1-llvm min_weight 1/64"]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4))
    w = 0.8 / max(len(labels), 1)
    for j, lab in enumerate(labels):
        rr, tt = [], []
        for n in names:
            r = next((x for x in out["scenes"][n] if x["config"] == lab and "skipped" not in x), None)
            rr.append(r["rays_ratio_to_baseline"] if r else np.nan)
            tt.append(r["time_ratio_to_baseline"] if r else np.nan)
        x = np.arange(len(names)) + j * w
        axes[0].bar(x, rr, w, label=lab)
        axes[1].bar(x, tt, w, label=lab)
    for ax, yl in zip(axes, ["rays per pixel / baseline", "frame time / baseline"]):
        ax.set_xticks(np.arange(len(names)) + 0.4 - w / 2)
        ax.set_xticklabels(names, rotation=30, fontsize=8)
        ax.set_ylabel(yl)
        ax.axhline(1.0, color="grey", lw=0.8)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    return fig


if __name__ == "__main__":
    sys.exit(main())
