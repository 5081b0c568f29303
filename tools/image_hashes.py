"""Hashes of the images links1 renders, for a refactoring that must leave them bit-identical.

    python tools/image_hashes.py OUT.json [--width 64] [--spp 2] [--no-core]
    python tools/image_hashes.py --compare A.json B.json

Renders, small, every ``scenes/*.xml``, the committed corpus scene and the fetched ones under
``tests/corpus/external/`` (when present) with ``links1_whitted`` (``links1_mitsuba.load_file``,
``mi.render``), and besides: a crop window and AOVs (``render_window``), adaptive
anti-aliasing, a frame assembled from 2 local workers (the partition API), plain
``mi.load_file`` on a few scenes, ``render_forward``/``render_backward`` gradients (and the
primal frame that keeps the derivative pass's graph), a tuning switch, and the core renderer
on the small scenes. Writes ``{case: sha256 of the float32 (float64 for numpy results)
buffer}``; ``--compare`` lists the cases that differ or are missing (exit 1 if any).

To take a reference at another commit without the working tree's edits::

    git worktree add /tmp/ref <commit>
    ln -s $PWD/tests/corpus/external /tmp/ref/tests/corpus/external   # the fetched scenes
    PYTHONPATH=/tmp/ref:/tmp/ref/plugins python /tmp/ref/tools/image_hashes.py ref.json
"""
from __future__ import annotations

import argparse
import glob
import hashlib
import json
import os
import sys
import traceback
import warnings

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

#: a scene of tests/plugins/test_gradients.py (Phong and Mitsuba BSDFs, links1 and Mitsuba
#: point lights, a spot, mirror and glass down to depth 4)
GRAD_SCENE = """<scene version="3.0.0">
  <integrator type="links1_whitted"><integer name="max_depth" value="4"/></integrator>
  <sensor type="perspective"><float name="fov" value="40"/>
    <transform name="to_world"><lookat origin="0, 3, 6" target="0, 0.5, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="24"/><integer name="height" value="18"/>{rfilter}</film>
    <sampler type="independent"><integer name="sample_count" value="1"/></sampler></sensor>
  <shape type="rectangle" id="floor"><transform name="to_world"><scale value="5"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.5, 0.4"/></bsdf></shape>
  <shape type="sphere" id="ball"><point name="center" x="-0.9" y="0.8" z="0"/><float name="radius" value="0.8"/>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.3, 0.4, 0.5"/><rgb name="specular" value="0.3"/>
      <rgb name="ambient" value="0.05"/><float name="exponent" value="15"/></bsdf></shape>
  <shape type="sphere" id="glass"><point name="center" x="0.9" y="0.9" z="0.6"/><float name="radius" value="0.7"/>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.1"/><rgb name="specular" value="0.2"/>
      <rgb name="reflectance" value="0.3"/><rgb name="transmittance" value="0.5"/><float name="ior" value="1.3"/></bsdf></shape>
  <emitter type="links1_point" id="lp"><point name="position" x="2" y="4" z="3"/><rgb name="L1" value="0.7"/>
    <rgb name="L2" value="0.3"/><vector name="direction" x="-0.4" y="-1" z="-0.6"/></emitter>
  <emitter type="point" id="mp"><point name="position" x="-2" y="3" z="2"/><rgb name="intensity" value="5"/></emitter>
  <emitter type="links1_spot" id="sp"><point name="origin" x="0" y="5" z="0"/><vector name="direction" x="0" y="-1" z="0"/>
    <float name="radius" value="1.5"/><rgb name="intensity" value="0.4"/></emitter>
</scene>"""
GRAD_KEYS = ["ball.bsdf.diffuse.value", "glass.bsdf.transmittance.value", "lp.L2.value",
             "ball.bsdf.exponent", "floor.bsdf.reflectance.value", "mp.intensity.value", "lp.position"]

#: cases whose image varies from run to run at the same commit (none: --compare names any listed
#: here apart and does not count them)
VARIES: tuple = ()

#: scenes/*.xml the core renders too (the others take minutes in float64 numpy)
CORE_SCENES = ("fig4", "lights", "shadows", "delta_bsdfs", "mitsuba_direct")
#: scenes/*.xml loaded by plain mi.load_file (no links1 shapes)
PLAIN_SCENES = ("mitsuba_direct", "lights", "bicubic")


def digest(a) -> str:
    a = np.ascontiguousarray(a)
    return hashlib.sha256(str(a.dtype).encode() + str(a.shape).encode() + a.tobytes()).hexdigest()[:32]


def scene_files():
    """(case name, path, $params) of every scene rendered."""
    out = [(f"scenes/{os.path.basename(p)[:-4]}", p, {})
           for p in sorted(glob.glob(os.path.join(ROOT, "scenes", "*.xml")))]
    sys.path.insert(0, ROOT)
    try:
        from tests.corpus.manifest import SCENES
    except Exception:   # an older tree
        SCENES = []
    for s in SCENES:
        if os.path.exists(s.local_path):
            out.append((f"corpus/{s.id}", s.local_path, dict(s.params)))
    return out


def film_to(scene, width):
    """Give the scene's first sensor a film ``width`` wide (the file's aspect)."""
    from links1_mitsuba.renderer import resize_film
    sensor = scene.sensors()[0]
    W, H = (int(v) for v in sensor.film().size())
    resize_film(sensor, width, max(1, round(H * width / W)))
    return sensor


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", nargs="?")
    ap.add_argument("--compare", nargs=2, metavar=("A", "B"))
    ap.add_argument("--width", type=int, default=64)
    ap.add_argument("--spp", type=int, default=2)
    ap.add_argument("--no-core", action="store_true")
    ap.add_argument("--only", help="render only cases whose name contains this")
    a = ap.parse_args(argv)
    if a.compare:
        A, B = (json.load(open(p)) for p in a.compare)
        bad = sorted(k for k in set(A) | set(B) if A.get(k) != B.get(k))
        for k in [k for k in bad if k in VARIES]:
            print(f"(varies between runs: {k})")
        bad = [k for k in bad if k not in VARIES]
        for k in bad:
            print(f"DIFFERS {k}: {A.get(k)} -> {B.get(k)}")
        print(f"{len(set(A) | set(B)) - len(bad)} identical, {len(bad)} differ or missing")
        return 1 if bad else 0
    if not a.out:
        ap.error("give OUT.json or --compare A B")
    warnings.simplefilter("ignore")
    import drjit as dr
    import links1_mitsuba
    import mitsuba as mi
    links1_mitsuba.register()
    print(f"links1_mitsuba: {links1_mitsuba.__file__}", file=sys.stderr)
    res = {}

    def case(name, fn):
        if a.only and a.only not in name:
            return
        try:
            v = fn()
            for k, x in (v.items() if isinstance(v, dict) else [("", v)]):
                res[name + (f"/{k}" if k else "")] = digest(x)
        except Exception as e:
            res[name] = f"error: {type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"
            traceback.print_exc(limit=3)
        print(f"{name}: {res.get(name, 'ok')}", file=sys.stderr)

    def plugin_render(path, params):
        def go():
            scene = links1_mitsuba.load_file(path, params=params)
            film_to(scene, a.width)
            img = mi.render(scene, spp=a.spp)
            integ = scene.integrator()
            return {"img": np.array(img, dtype=np.float32),
                    "stats": np.array(sorted((k, v) for k, v in integ.stats.items()
                                             if not isinstance(v, dict)), dtype=object).astype(str)}
        return go

    files = scene_files()
    for name, path, params in files:
        case(name, plugin_render(path, params))

    def crop_aovs():
        scene = links1_mitsuba.load_file(os.path.join(ROOT, "scenes", "fig11.xml"))
        film_to(scene, a.width)
        integ = scene.integrator()
        W, H = (int(v) for v in scene.sensors()[0].film().size())
        win = (W // 4, H // 5, W // 2, H // 3)
        return {"window": integ.render_window(scene, win, spp=a.spp, aovs=["depth", "normal", "id", "cost"]),
                "windows": np.concatenate([w.ravel() for w in integ.render_windows(
                    scene, [win, (0, 0, 5, 7)], spp=3, seed=7)]),
                "gaussian": np.array(mi.render(links1_mitsuba.load_file(
                    os.path.join(ROOT, "scenes", "shadows.xml"), res="40", spp="3")), dtype=np.float32)}
    case("fig11 windows", crop_aovs)

    def crop_film():
        scene = links1_mitsuba.load_file(os.path.join(ROOT, "scenes", "delta_bsdfs.xml"))
        sensor = film_to(scene, a.width)
        prm = mi.traverse(sensor)
        prm["film.crop_offset"] = [8, 5]
        prm["film.crop_size"] = [30, 20]
        prm.update()
        return np.array(mi.render(scene, spp=a.spp), dtype=np.float32)
    case("delta_bsdfs crop window", crop_film)

    def adaptive():
        scene = links1_mitsuba.load_file(os.path.join(ROOT, "scenes", "fig4.xml"))
        film_to(scene, 32)
        return scene.integrator().render_adaptive(scene, threshold=0.05, depth=2)
    case("fig4 adaptive", adaptive)

    def tuned():
        from links1_mitsuba import tuning
        out = {}
        for sw in ("split", "box_cull", "light_buffer", "skip_misses"):
            scene = links1_mitsuba.load_file(os.path.join(ROOT, "scenes", "shadows.xml"))
            film_to(scene, 32)
            with tuning.tuned(**{sw: False}):
                out[sw] = np.array(mi.render(scene, spp=1), dtype=np.float32)
        return out
    case("shadows tuned", tuned)

    def workers():
        import importlib

        def find(name, *mods):   # the partition API moves from links1 to links1_app
            for m in mods:
                try:
                    return getattr(importlib.import_module(m), name)
                except (ImportError, AttributeError):
                    pass
            raise ImportError(f"no {name} in {mods}")
        LocalPool = find("LocalPool", "links1_app.partition.local_pool", "links1_app.partition.executors",
                         "links1.partition.executors")
        render_plan = find("render_plan", "links1_app.partition.executors", "links1.partition.executors")
        RendererSpec = find("RendererSpec", "links1_app.partition.runtime", "links1.partition.runtime")
        make_plan = find("make_plan", "links1.partition.strategies", "links1_app.partition.strategies")
        spec = RendererSpec.make("mitsuba", os.path.join(ROOT, "scenes", "fig11.xml"),
                                 width=48, height=36, spp=2, aovs=("id",))
        plan = make_plan("dynamic", 48, 36, 2, tiles_per_node=4)
        with LocalPool(2) as pool:
            return render_plan(plan, spec, pool, progress=False).image
    case("fig11 2 workers", workers)

    def plain():
        out = {}
        for s in PLAIN_SCENES:
            scene = mi.load_file(os.path.join(ROOT, "scenes", f"{s}.xml"))
            film_to(scene, a.width)
            out[s] = np.array(mi.render(scene, spp=a.spp), dtype=np.float32)
        return out
    case("plain mi.load_file", plain)

    def gradients():
        # one thread: reverse mode sums by atomic scatter-adds, whose order (and so the
        # float sum's last bits) varies between runs with several threads; the derivative
        # pass's graph kept by mi.render (the frame "primal_kept")
        from links1_mitsuba import tuning
        threads = dr.thread_count()
        dr.set_thread_count(1)
        try:
            with tuning.tuned(keep_graph=True):
                return gradients_1()
        finally:
            dr.set_thread_count(threads)

    def gradients_1():
        out = {}
        for filt in ('<rfilter type="box"/>', ""):
            tag = "box" if filt else "gaussian"
            scene = mi.load_string(GRAD_SCENE.format(rfilter=filt))
            params = mi.traverse(scene)
            rng = np.random.default_rng(3)
            u = rng.normal(size=(18, 24, 3)).astype(np.float32)
            for k in GRAD_KEYS:
                dr.enable_grad(params[k])
            img = mi.render(scene, params)          # keeps the graph where it may
            out[f"{tag}/primal_kept"] = np.array(img, dtype=np.float32)
            dr.backward(dr.sum(img * mi.TensorXf(u), axis=None))
            for k in GRAD_KEYS:
                out[f"{tag}/backward/{k}"] = np.array(dr.grad(params[k]), dtype=np.float32)
                dr.set_grad(params[k], 0)
            img = mi.render(scene, params, spp=2, seed=5)   # two renders: primal, then the pass
            out[f"{tag}/primal_spp2"] = np.array(img, dtype=np.float32)
            dr.backward(dr.sum(img * mi.TensorXf(u), axis=None))
            for k in GRAD_KEYS:
                out[f"{tag}/backward_spp2/{k}"] = np.array(dr.grad(params[k]), dtype=np.float32)
                dr.disable_grad(params[k])
            params = mi.traverse(scene)
            for i, k in enumerate(GRAD_KEYS):
                dr.enable_grad(params[k])
                dr.set_grad(params[k], 0.1 * (i + 1))
            img = mi.render(scene, params)
            dr.forward_to(img)
            out[f"{tag}/forward"] = np.array(dr.grad(img), dtype=np.float32)
            for k in GRAD_KEYS:
                dr.disable_grad(params[k])
        return out
    case("gradients", gradients)

    if not a.no_core:
        from links1.tracing.render import CoreRenderer
        for s in CORE_SCENES:
            def core(s=s):
                r = CoreRenderer(os.path.join(ROOT, "scenes", f"{s}.xml"), width=24, spp=1)
                return r.render(None)
            case(f"core/{s}", core)

    with open(a.out, "w") as f:
        json.dump(res, f, indent=1, sort_keys=True)
    errors = [k for k, v in res.items() if v.startswith("error")]
    print(f"{len(res)} hashes -> {a.out}; {len(errors)} errors {errors}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
