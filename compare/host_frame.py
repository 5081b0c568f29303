"""A warm frame's host time by function: what ``links1_whitted``'s Python costs a frame.

    python -m compare.host_frame [--only cbox_point:box data_instancing:box] [--spp 1]
                                 [--frames 200] [--width 512] [--variant llvm_ad_rgb]

Per case of :mod:`compare.ray_floor` (one scene object, ``width`` px wide, its ``links1_whitted``
at the case's depth), after warm-up frames, ``frames`` frames of ``mi.render(scene)`` +
``dr.eval``, each started after ``dr.sync_thread`` (as in a render loop: the host starts a frame
after the last one's kernels, its caches cold), with every function and method of the plugin's
frame path (``engine``, ``launch``, ``film``, ``views``, ``tables``) wrapped in a timer
(inclusive time, ~1 µs a call added). Reported per case:

* ``submit``: ``mi.render`` + ``dr.eval`` until they return, unwrapped (links1's and Mitsuba's
  ``direct``, emitter_samples 1, bsdf_samples 0, frames alternated): the host's work a frame, the
  kernels queued on Dr.Jit's threads (waited for outside the timed part);
* per function its inclusive µs a frame (mean over the wrapped frames) and calls a frame;
  ``mi.render`` less ``Engine.render`` is Mitsuba's own wrapper (``dr.custom``, the sampler's
  re-seeding).

With ``--ab ROUNDS``, also the host-time cuts against the code before them, alternated in the
same process (ROUNDS rounds of 5 frames each way, the order swapped every round, the same bits
checked): ``film.PIXEL_LANES`` and ``paramwatch.ROOT_BY_ADDRESS`` off, the SIGINT hold through
``signal``'s enum-converting functions instead of ``_signal``'s, ``Tuning.key`` made every frame;
medians of wall, process CPU and submit time a frame.

Writes ``compare/results/host_frame.{json,md}`` (``--out``).
"""
from __future__ import annotations

import argparse
import functools
import json
import time
import types
from pathlib import Path

import numpy as np

from compare.common import command_line, machine_info, machine_markdown

RESULTS = Path(__file__).resolve().parent / "results"


def _wrap_all(acc):
    """Every plain function and method of the frame's modules wrapped in a timer that adds its
    inclusive time to ``acc[name]``; returns the undo list."""
    import links1_mitsuba.engine as E
    import links1_mitsuba.film as F
    import links1_mitsuba.launch as L
    import links1_mitsuba.tables as T
    import links1_mitsuba.views as V

    def wrap(name, f):
        @functools.wraps(f)
        def g(*a, **k):
            t0 = time.perf_counter()
            try:
                return f(*a, **k)
            finally:
                acc.setdefault(name, []).append(time.perf_counter() - t0)
        return g

    undo = []

    def put(owner, attr, name):
        f = getattr(owner, attr)
        undo.append((owner, attr, f))
        setattr(owner, attr, wrap(name, f))

    for mod in (L, F, V, T):
        short = mod.__name__.rsplit(".", 1)[-1]
        for n, f in list(vars(mod).items()):
            if isinstance(f, types.FunctionType) and f.__module__ == mod.__name__:
                put(mod, n, f"{short}.{n}")
    # the names launch.py imported from film (its calls go through them)
    for n in ("reconstruct", "cached_batch", "sample_ids", "widen", "camera_rays"):
        if isinstance(getattr(L, n, None), types.FunctionType):
            put(L, n, f"launch→{n}")
    for cls in (L.Launches, T.Tables, E.Engine):
        for n, f in list(vars(cls).items()):
            if isinstance(f, types.FunctionType):
                put(cls, n, f"{cls.__name__}.{n}")
    return undo


def _host_cuts(on: bool) -> None:
    """The host-time cuts on (as the code is) or off (the code before them: module docstring)."""
    import _signal
    import signal

    import links1_mitsuba.film as F
    import links1_mitsuba.paramwatch as P
    from links1 import interrupts
    F.PIXEL_LANES = P.ROOT_BY_ADDRESS = on
    interrupts._signal = _signal if on else signal


def ab(scene, spp, rounds) -> dict:
    """``{"old"|"new": {"wall"|"cpu"|"submit": ms}}``: frames alternated with the host-time cuts
    off and on (:func:`_host_cuts`), medians; ``same_bits``: the two frames' pixels equal."""
    import drjit as dr
    import mitsuba as mi
    from links1_mitsuba import tuning
    imgs = {}
    for on in (False, True):
        _host_cuts(on)
        for _ in range(3):
            img = mi.render(scene, spp=spp, seed=0)
            dr.eval(img)
        imgs[on] = np.asarray(img).view(np.uint32)
    same = bool(np.array_equal(imgs[False], imgs[True]))
    res = {on: {"wall": [], "cpu": [], "submit": []} for on in (False, True)}
    try:
        for r in range(rounds):
            for on in ((False, True) if r % 2 == 0 else (True, False)):
                _host_cuts(on)
                for _ in range(5):
                    if not on:   # Tuning.key made every frame, as before
                        tuning.current().__dict__.pop("_key", None)
                    dr.sync_thread()
                    c0, t0 = time.process_time(), time.perf_counter()
                    img = mi.render(scene, spp=spp, seed=0)
                    dr.eval(img)
                    t1 = time.perf_counter()
                    dr.sync_thread()
                    res[on]["submit"].append(t1 - t0)
                    res[on]["wall"].append(time.perf_counter() - t0)
                    res[on]["cpu"].append(time.process_time() - c0)
    finally:
        _host_cuts(True)
    return dict(same_bits=same, rounds=rounds,
                **{("new" if on else "old"): {k: 1e3 * float(np.median(v)) for k, v in d.items()}
                   for on, d in res.items()})


def measure(cid, rfilter, spp, frames, width, variant, ab_rounds=0) -> dict:
    import drjit as dr
    import mitsuba as mi
    from compare.ray_floor import load_case, mitsuba_integrator
    scene, kind, depth, size = load_case(cid, rfilter, width, variant)
    integ = mitsuba_integrator(kind, depth)

    def submit(i):
        dr.sync_thread()
        t0 = time.perf_counter()
        img = mi.render(scene, spp=spp, seed=0) if i is None else mi.render(scene, integrator=i, spp=spp, seed=0)
        dr.eval(img)
        t = time.perf_counter() - t0
        dr.sync_thread()
        return t

    for _ in range(5):
        submit(None)
        submit(integ)
    subs = {"links1": [], "mitsuba": []}
    for _ in range(frames):
        subs["links1"].append(submit(None))
        subs["mitsuba"].append(submit(integ))
    acc = {}
    undo = _wrap_all(acc)
    try:
        submit(None)
        acc.clear()
        for _ in range(frames):
            dr.sync_thread()
            t0 = time.perf_counter()
            img = mi.render(scene, spp=spp, seed=0)
            acc.setdefault("mi.render", []).append(time.perf_counter() - t0)
            dr.eval(img)
    finally:
        for owner, attr, f in reversed(undo):
            setattr(owner, attr, f)
    dr.sync_thread()
    us = {k: 1e6 * sum(v) / frames for k, v in acc.items()}
    funcs = sorted(({"name": k, "us": us[k], "calls": len(v) / frames} for k, v in acc.items()), key=lambda r: -r["us"])
    # what no wrapped function holds: Mitsuba's wrapper around the integrator's render; the
    # SIGINT hold (links1.interrupts.held_interrupts) and the tensor around the flat frame
    derived = {"Mitsuba's mi.render wrapper (mi.render − Engine.render)": us["mi.render"] - us["Engine.render"],
               "SIGINT hold + tensor (render_windows_device − _render_flat)":
                   us["Launches.render_windows_device"] - us["Launches._render_flat"],
               "freeze's call and the caller's record (_call_frozen − launch._extra_scenes)": us["Launches._call_frozen"]
                   - us.get("launch._extra_scenes", 0.0)}
    cuts = ab(scene, spp, ab_rounds) if ab_rounds else None
    return dict(id=cid, rfilter=rfilter, spp=spp, size=list(size), frames=frames, ab=cuts,
                submit_us={k: 1e6 * float(np.median(v)) for k, v in subs.items()},
                functions=[f for f in funcs if f["us"] >= 1.0], derived=derived)


def markdown(rows, info, cmd) -> str:
    md = ["# A warm frame's host time by function (`compare/host_frame.py`)\n\n", machine_markdown(info, cmd),
          "\n`submit`: `mi.render` + `dr.eval` until they return (medians; links1 and Mitsuba `direct` "
          "frames alternated, each after the last one's kernels). By function: inclusive µs a frame "
          "(means, every plugin function wrapped in a timer: ~1 µs a call added), calls a frame.\n\n"]
    for r in rows:
        s = r["submit_us"]
        md.append(f"## `{r['id']}` {r['rfilter']} {r['size'][0]}×{r['size'][1]} spp {r['spp']}\n\n"
                  f"submit: links1 **{s['links1']:.0f} µs**, Mitsuba `direct` {s['mitsuba']:.0f} µs\n\n"
                  "| function | µs a frame | calls a frame |\n| --- | --- | --- |\n")
        for f in r["functions"][:30]:
            md.append(f"| `{f['name']}` | {f['us']:.1f} | {f['calls']:g} |\n")
        for name, v in r["derived"].items():
            md.append(f"| {name} | {v:.1f} | |\n")
        if r.get("ab"):
            a = r["ab"]
            md.append(f"\nThe host-time cuts off / on, alternated ({a['rounds']} rounds × 5 frames each way; "
                      f"the same bits: {a['same_bits']}):\n\n| ms a frame (median) | off | on | on / off |\n"
                      "| --- | --- | --- | --- |\n")
            for k in ("wall", "cpu", "submit"):
                md.append(f"| {k} | {a['old'][k]:.3f} | {a['new'][k]:.3f} | **{a['new'][k] / a['old'][k]:.3f}** |\n")
        md.append("\n")
    return "".join(md)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m compare.host_frame", description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="*", default=["cbox_point:box", "data_instancing:box"],
                    help="compare.ray_floor case ids as ID:FILTER")
    ap.add_argument("--spp", type=int, default=1)
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--ab", type=int, default=0, metavar="ROUNDS",
                    help="also alternate the host-time cuts off and on, ROUNDS rounds (module docstring)")
    ap.add_argument("--out", default=str(RESULTS / "host_frame"))
    a = ap.parse_args(argv)
    import links1_mitsuba as lm
    lm.register(a.variant)
    info = machine_info()
    rows = []
    for case in a.only:
        cid, _, rfilter = case.partition(":")
        if not rfilter:
            raise SystemExit(f"compare.host_frame: --only {case}: give ID:FILTER (e.g. cbox_point:box)")
        rows.append(measure(cid, rfilter, a.spp, a.frames, a.width, a.variant, a.ab))
        print(f"{case}: submit {rows[-1]['submit_us']}", flush=True)
    cmd = command_line()
    out = Path(a.out)
    out.with_suffix(".json").write_text(json.dumps(dict(machine=info, command=cmd, rows=rows), indent=1))
    out.with_suffix(".md").write_text(markdown(rows, info, cmd))
    print(out.with_suffix(".md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
