"""Fit the partitioning load table (eq. 4.1) to a renderer's measured tile times.

    python -m compare.load_table [--renderer mitsuba] [--res 512] [--tiles 32] [--rounds 5]

For every scene in ``scenes/``: the frame as ``--tiles`` equal tiles, each rendered in its own
launch on one thread (a node's conditions), median of ``--rounds`` interleaved rounds after a
warm-up. :func:`links1.partition.loadmodel.fit_load_table` then fits the table's
``representation``, ``finish`` and ``background`` to all scenes at once, and each scene is
also fitted with itself left out (the held-out column: how well a table fitted elsewhere
predicts it). Per scene the table reports the Pearson correlation of predicted and measured
tile times and the imbalance a two-node ``subscreen`` plan would have with the measured times
(max/mean of the nodes' summed times; 1 = balanced) under the default table, the table fitted
to every scene, and the held-out fit. Results: ``compare/results/load_table.*``; the fitted
table is what ``RENDERER_LOAD_TABLES`` in ``links1/partition/loadmodel.py`` holds.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from compare.common import ROOT, command_line, machine_info, machine_markdown, md_table, write_results
from compare.realtime import SCENES


def tile_times(kind: str, scene: str, res: int, tiles: int, rounds: int):
    """(units, median seconds per unit) with one launch per unit on one thread."""
    from links1_app.partition.runtime import RendererSpec, get_renderer, set_threads
    from links1.partition.strategies import grid_shape, tile_units
    set_threads(1, kind)
    r = get_renderer(RendererSpec.make(kind, str(ROOT / "scenes" / f"{scene}.xml"), params={"res": str(res)}, spp=1))
    w, h = r.film_size
    units = tile_units(w, h, *grid_shape(w, h, tiles))
    for u in units:                      # warm-up: recordings, kernels, caches
        r.render(window=u.window)
    t = np.zeros((rounds, len(units)))
    for k in range(rounds):
        for i, u in enumerate(units):
            t0 = time.perf_counter()
            r.render(window=u.window)
            t[k, i] = time.perf_counter() - t0
    return units, np.median(t, axis=0)


def scene_model_of(scene: str, res: int, table=None):
    """The root's model of a scene (read with the core, as ``links1 schedule`` does)."""
    import warnings

    from links1.scene.xmlparse import SceneWarning
    from links1.partition.loadmodel import scene_model
    from links1_app.partition.runtime import RendererSpec, get_renderer
    path = str(ROOT / "scenes" / f"{scene}.xml")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        r = get_renderer(RendererSpec.make("core", path, params={"res": str(res)}, spp=1))
    return scene_model(r, path=path, params={"res": str(res)}, table=table)


def evaluate(model, units, seconds, table):
    """Correlation of predicted and measured unit times, and the two-node subscreen imbalance
    (measured times) of the plan this table makes."""
    from dataclasses import replace

    from links1.partition.loadmodel import object_loads
    from links1.partition.strategies import make_plan, unit_loads
    m = replace(model, loads=object_loads(model.shapes, table), background=float(table["background"]),
                meta=dict(model.meta))
    lm = m.load_map()
    pred = unit_loads(units, lm)
    sec = {u.window: s for u, s in zip(units, seconds)}
    plan = make_plan("subscreen", m.width, m.height, 2, tiles_per_node=len(units) // 2, load_map=lm)
    busy = np.zeros(2)
    for i, u in enumerate(plan.units):
        busy[plan.owner[i]] += sec[u.window]
    return float(np.corrcoef(pred, seconds)[0, 1]), float(busy.max() / busy.mean())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--renderer", default="mitsuba", choices=("mitsuba", "core"))
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--tiles", type=int, default=32)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--scenes", default=",".join(SCENES))
    args = ap.parse_args(argv)
    from links1.partition.loadmodel import DEFAULT_LOAD_TABLE, fit_load_table
    scenes = [s for s in args.scenes.split(",") if s]
    data = {}
    for s in scenes:
        units, sec = tile_times(args.renderer, s, args.res, args.tiles, args.rounds)
        data[s] = (scene_model_of(s, args.res), units, sec)
        print(f"{s:15s} tiles {sec.sum() * 1e3:7.1f} ms (min {sec.min() * 1e3:.2f}, max {sec.max() * 1e3:.2f})",
              flush=True)
    table = fit_load_table(list(data.values()))
    rows, per_scene = [], {}
    for s in scenes:
        m, units, sec = data[s]
        held = fit_load_table([v for k, v in data.items() if k != s]) if len(scenes) > 1 else table
        c0, i0 = evaluate(m, units, sec, DEFAULT_LOAD_TABLE)
        c1, i1 = evaluate(m, units, sec, table)
        c2, i2 = evaluate(m, units, sec, held)
        per_scene[s] = {"tile_seconds": sec, "windows": [u.window for u in units], "default": [c0, i0],
                        "fitted": [c1, i1], "held_out": [c2, i2]}
        rows.append([s, c0, c1, c2, i0, i1, i2])
    info, cmd = machine_info(), command_line()
    rep = ", ".join(f"{k} {table['representation'][k]:.3g}" for k in table["fit"]["fitted"])
    md = (f"# The load table (eq. 4.1) fitted to {args.renderer} tile times\n\n" + machine_markdown(info, cmd) + "\n"
          + f"{args.res}², spp 1, {args.tiles} tiles per scene, each in its own launch on one thread, median of "
          f"{args.rounds} rounds. Fitted table (relative units, a quadric = 1; representations that no scene "
          f"holds keep the default's values): representation {rep}; finish "
          f"reflective {table['finish']['reflective']:.3g}, transmissive {table['finish']['transmissive']:.3g}; "
          f"background {table['background']:.3g} per pixel; relative RMS residual {table['fit']['relative_rms']:.3f}, "
          f"launch constant {table['fit']['launch_s'] * 1e3:.2f} ms.\n\n"
          "Correlation: predicted vs measured tile times (Pearson). Imbalance: a two-node `subscreen` plan of "
          "the tiles made with the table, its nodes' measured times (max/mean; 1 = balanced). Held out: the "
          "table fitted to the other scenes.\n\n"
          + md_table(["scene", "corr default", "corr fitted", "corr held out", "imbalance default",
                      "imbalance fitted", "imbalance held out"], rows))
    payload = {"machine": info, "command": cmd, "args": vars(args), "table": table, "scenes": per_scene}
    for p in write_results(f"load_table_{args.renderer}", payload, md):
        print(p)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
