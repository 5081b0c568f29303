"""The figures of ``links1 schedule``: the report's Gantt chart and scatter plots, the
simulation's and the sweep's curves.

matplotlib is an optional dependency (``links1[plot]``) and slow to import, so it is imported
by :func:`pyplot`, when a figure is drawn, not with this module.
"""
from __future__ import annotations

import io
import os

import numpy as np

from .checkpoint import atomic_write_bytes

def pyplot():
    """matplotlib.pyplot on the Agg backend (imported here: see the module docstring)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def save_figure(fig, path):
    """Write ``fig`` to ``path`` atomically, in the format its suffix names (default PNG)."""
    buf = io.BytesIO()
    fig.savefig(buf, format=str(path).rsplit(".", 1)[-1].lower() if "." in str(path) else "png", dpi=110)
    atomic_write_bytes(path, buf.getvalue())


def plot_report(report, path) -> None:
    """Gantt chart of the measured launches per node, and each unit's seconds launched alone
    (measured: filled; derived from counts: open) and exact ray tests against predicted load."""
    plt = pyplot()
    fig, (ax1, ax2, ax3) = plt.subplots(1, 3, figsize=(18, 4.8), gridspec_kw={"width_ratios": [2, 1, 1]})
    ts = report.get("time_split")
    if ts:
        gantt_time_split(ax1, ts)
    else:
        nodes = sorted({str(u["node"]) for u in report["units"]})
        row = {k: j for j, k in enumerate(nodes)}
        cmap = plt.get_cmap("tab20")
        seen = {}
        for u in report["units"]:
            lid = tuple(u["launch"])
            if lid in seen:
                continue
            seen[lid] = True
            ax1.barh(row[str(u["node"])], u["launch_seconds"], left=u["start"], color=cmap(len(seen) % 20),
                     edgecolor="k", linewidth=0.3)
        ax1.set_yticks(range(len(nodes)), nodes)
        ax1.set_xlabel("seconds (measured launches, node clocks)")
        ax1.set_ylabel("node")
    te = report.get("true_efficiency")
    ax1.set_title(f"{report['strategy']}: makespan {report['makespan_s']:.3g} s (measured)\n"
                  f"true efficiency {'n/a' if te is None else f'{te:.2f}'}, busy efficiency "
                  f"{report['parallel_efficiency'] or 0:.2f}, imbalance {report['imbalance'] or 0:.3f}", fontsize=9)
    rc = report["rank_correlation"]
    fmt = (lambda v: "n/a" if v is None else f"{v:.3f}")
    units = report["units"]
    if None not in [u["predicted_load"] for u in units]:
        for src, mk in (("measured", "o"), ("derived", "o")):
            us = [u for u in units if u["seconds_source"] == src]
            if us:
                ax2.scatter([u["predicted_load"] for u in us], [u["seconds"] for u in us], s=14, marker=mk,
                            facecolors="C0" if src == "measured" else "none", edgecolors="C0",
                            label=f"{src} ({len(us)} units)")
        ax2.legend(fontsize=8)
        ax2.set_title(f"Spearman predicted vs measured seconds {fmt(rc.get('predicted_vs_measured_seconds'))}\n"
                      f"(over {rc.get('n_measured')} units launched alone)", fontsize=9)
        tests = [u["ray_tests"] for u in units]
        if None not in tests:
            ax3.scatter([u["predicted_load"] for u in units], tests, s=10, color="C1")
        ax3.set_title(f"Spearman predicted vs exact ray tests {fmt(rc.get('predicted_vs_ray_tests'))}", fontsize=9)
    ax2.set_xlabel("predicted load (eq. 4.1)")
    ax2.set_ylabel("unit seconds launched alone: measured (filled) / derived from counts (open)", fontsize=8)
    ax3.set_xlabel("predicted load (eq. 4.1)")
    ax3.set_ylabel("ray-primitive tests (exact, cost AOV)")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


SPLIT_COLOURS = {"work": "#2ca02c", "launch overhead": "#ff7f0e", "slowdown": "#d62728",
                 "dispatch": "#9467bd", "transfer": "#1f77b4", "waiting": "#d9d9d9", "start-up": "#7f7f7f",
                 "assembly": "#8c564b"}


def gantt_time_split(ax, ts) -> None:
    """The makespan's time split as a Gantt chart: one row per node (each launch drawn as its
    work, launch overhead and slowdown, then its results in transfer, dispatch before its first
    launch, waiting the rest) and one for the root (dispatches, assembly); start-up before 0."""
    span = ts["makespan_s"]
    nodes = [k for k in ts["nodes"]]
    rows = nodes + ["root"]
    used = set()

    def bar(y, a, b, name, hatch=None):
        if b > a:
            ax.barh(y, b - a, left=a, color=SPLIT_COLOURS[name], edgecolor="k" if name != "waiting" else "none",
                    linewidth=0.2, height=0.7, hatch=hatch, label=None if name in used else name)
            used.add(name)

    for y, k in enumerate(nodes):
        seg = ts["segments"].get(k, {})
        su = ts["nodes"][k].get("startup_s")
        if su:  # drawn at most a fifth of the makespan long, its measured length written on it
            bar(y, -min(su, 0.2 * span), 0.0, "start-up", hatch="//")
            ax.text(-0.1 * span, y, f"{su:.2g} s", ha="center", va="center", fontsize=6, color="w")
        bar(y, 0.0, span, "waiting")
        for a, b in seg.get("dispatch", []):
            bar(y, a, b, "dispatch")
        for a, b in seg.get("transfer", []):
            bar(y, a, b, "transfer")
        for a, b, work, ovh in seg.get("launch", []):
            if work is None:
                bar(y, a, b, "work")
                continue
            d = b - a
            w, o = max(work, 0.0), max(ovh, 0.0)
            f = min(1.0, d / (w + o)) if w + o > 0 else 1.0   # a node faster than the reference: no slowdown
            bar(y, a, a + w * f, "work")
            bar(y, a + w * f, a + (w + o) * f, "launch overhead")
            bar(y, a + (w + o) * f, b, "slowdown")
    yr = len(nodes)
    root = ts["segments"].get("root", {})
    bar(yr, 0.0, span, "waiting")
    for a, b in root.get("dispatch", []):
        bar(yr, a, max(b, a + span * 2e-3), "dispatch")
    for a, b in root.get("assembly", []):
        bar(yr, a, max(b, a + span * 2e-3), "assembly")
    ax.axvline(0.0, color="k", linewidth=0.5)
    ax.axvline(span, color="k", linewidth=0.5, linestyle="--")
    ax.set_yticks(range(len(rows)), [f"node {k}" for k in nodes] + ["root"])
    ax.invert_yaxis()
    sh = ts["shares"]
    ax.set_xlabel("seconds from the first dispatch (measured; launch parts derived; start-up before 0, "
                  "not to scale)\n"
                  + ", ".join(f"{k} {v:.0%}" for k, v in sh.items()) + " of nodes x makespan", fontsize=8)
    ax.legend(fontsize=6, loc="lower right", ncol=2)


def plot_simulation(rows, path) -> None:
    """Makespan, imbalance and objects per node versus the node count, per strategy."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    for name in dict.fromkeys(r["strategy"] for r in rows):
        rs = [r for r in rows if r["strategy"] == name]
        n = [r["nodes"] for r in rs]
        axes[0].plot(n, [r["makespan_s"] for r in rs], "o-", label=name)
        axes[1].plot(n, [r["imbalance"] or np.nan for r in rs], "o-", label=name)
        axes[2].plot(n, [r["objects_per_node_mean"] for r in rs], "o-", label=name)
    for ax, t in zip(axes, ("simulated makespan (s)", "simulated imbalance max/mean busy",
                            "objects per node (mean)")):
        ax.set_xscale("log", base=2)
        ax.set_xlabel("nodes")
        ax.set_title(t)
    axes[0].set_yscale("log")
    axes[1].axhline(1.1, color="grey", lw=0.8, ls="--")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def plot_sweep(sweep, path) -> None:
    """Makespan, imbalance and true efficiency against node count, per strategy (and unit
    size): measured runs as points, the simulator's curves as lines, on the same axes."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.6))
    rows = sweep["rows"]
    keys = list(dict.fromkeys((r["strategy"], r["tiles_per_node"]) for r in rows))
    names = list(dict.fromkeys(k for k, _ in keys))
    tiles = list(dict.fromkeys(t for _, t in keys))
    many = len(tiles) > 1
    for name, tpn in keys:
        color = f"C{names.index(name) % 10}"   # a colour per strategy, a line style / marker per unit size
        ls, mk = ("-", "--", ":", "-.")[tiles.index(tpn) % 4], ("o", "s", "^", "D")[tiles.index(tpn) % 4]
        label = f"{name}" + (f" ({tpn}/node)" if many else "")
        for kind, style in (("simulated", ls), ("measured", mk)):
            rs = sorted((r for r in rows if r["kind"] == kind and r["strategy"] == name and r["tiles_per_node"] == tpn),
                        key=lambda r: r["nodes"])
            if not rs:
                continue
            n = [r["nodes"] for r in rs]
            kw = dict(color=color, label=f"{label}, {kind}")
            if kind == "measured":
                kw.update(markersize=7, markerfacecolor="none", markeredgewidth=1.5)
            for ax, key in zip(axes, ("makespan_s", "imbalance", "true_efficiency")):
                ax.plot(n, [np.nan if r[key] is None else r[key] for r in rs], style, **kw)
    titles = ("makespan (s): measured points, simulated lines", "imbalance max/mean busy",
              "true efficiency: one-process frame / (nodes x makespan)")
    for ax, t in zip(axes, titles):
        ax.set_xscale("log", base=2)
        ax.set_xlabel("nodes")
        ax.set_title(t, fontsize=9)
    axes[0].set_yscale("log")
    axes[1].axhline(1.1, color="grey", lw=0.8, ls="--")
    axes[2].axhline(1.0, color="grey", lw=0.8, ls="--")
    axes[0].legend(fontsize=6, ncol=2)
    fig.suptitle(f"{os.path.basename(sweep.get('scene', ''))}, {sweep.get('renderer')}, film "
                 f"{'x'.join(str(v) for v in sweep.get('film', []))}: measured at {sweep.get('measured_nodes')} nodes, "
                 f"simulated from the runs on {max(sweep.get('measured_nodes') or [1])}", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
