"""Sequences of frames over the nodes (``links1 animate``): one loaded scene per node, updated per frame.

The frames of a sequence are stacked into one tall film, frame ``k`` of the sequence in rows
``k*H .. (k+1)*H`` (:class:`SequenceRenderer`): a unit is then a window of that film, and the
partitioning runtime (:func:`.executors.render_plan` on the local pool or Dask, checkpoints'
atomic writes, faults, hand-out) runs sequences unchanged. A node's renderer sees which frame
a window belongs to, sets its scene to that frame's values (kept loaded: only values change)
and renders the window shifted into the frame: the same bits as the single-process render of
that frame, whatever the units (whole frames, screen partitions of frames, or both).
"""
from __future__ import annotations

import importlib
import os
import re
import time

import numpy as np

from ..renderers import make_renderer
from .runtime import RendererSpec, set_threads

#: the kind of a sequence's RendererSpec (a ``module:callable`` factory)
KIND = "links1_app.partition.sequence:SequenceRenderer"


def resolve_update(update):
    """A per-frame update function from ``"module:function"`` (what travels to the nodes)."""
    if update is None or callable(update):
        return update
    mod, _, name = str(update).partition(":")
    fn = importlib.import_module(mod)
    for part in name.split("."):
        fn = getattr(fn, part)
    return fn


def update_name(update) -> str | None:
    """``"module:qualname"`` of a per-frame update function (it must be importable on the nodes)."""
    if update is None or isinstance(update, str):
        return update
    mod, name = getattr(update, "__module__", None), getattr(update, "__qualname__", "")
    if not mod or "<" in name:
        raise TypeError(f"the update function {update!r} must be a module-level function (the nodes import it)")
    return f"{mod}:{name}"


class SequenceRenderer:
    """The Renderer contract over a sequence: film ``(W, H * frames)``; each window lies in one frame.

    Parameters
    ----------
    path : scene file
    renderer : ``"core"`` | ``"mitsuba"``
    frames : per frame, ``$name`` -> value (strings: :func:`links1_app.expressions.frame_values`)
    numbers, times : the frame numbers and times (``t``) the ``update`` function gets
    update : ``"module:function"`` or None: ``function(params, f, t)`` changes the loaded scene for
        frame ``f`` (Mitsuba: ``params`` is ``mi.traverse(scene)``, updated after it returns; the
        core: the :class:`links1.scene.scene.Scene`)
    options : the renderer's options (params: the values every frame shares, spp, aovs, ...)
    """

    kind = "sequence"

    def __init__(self, path, *, renderer="core", frames=({},), numbers=None, times=None, update=None, **options):
        self.path, self.inner_kind = str(path), renderer
        self.frames = [dict(v) for v in frames]
        self.numbers = list(numbers) if numbers is not None else list(range(len(self.frames)))
        self.times = list(times) if times is not None else [float(n) for n in self.numbers]
        self.update = resolve_update(update)
        self.options = dict(options)
        self.base = dict(self.options.pop("params", None) or {})
        self.current = None
        #: seconds each frame change took on this node (set-up: the scene updated to the frame)
        self.setup_s: list = []
        if renderer == "mitsuba":   # a node's Dr.Jit threads, as RendererSpec.build sets them for "mitsuba"
            set_threads(os.environ.get("OMP_NUM_THREADS"), "mitsuba")
        self.inner = make_renderer(renderer, self.path, params=self._params(0), **self.options)
        self._set(0, first=True)
        w, h = self.inner.film_size
        self.frame_size = (int(w), int(h))

    def _params(self, k):
        return {**self.base, **self.frames[k]}

    # ------------------------------------------------------------ Renderer contract
    @property
    def film_size(self):
        w, h = self.frame_size
        return w, h * len(self.frames)

    @property
    def channels(self):
        return self.inner.channels

    def __getattr__(self, name):   # spp, seed, aovs, max_depth, ...: the frame renderer's
        if name in ("inner", "__setstate__"):
            raise AttributeError(name)
        return getattr(self.inner, name)

    def render(self, window=None):
        if window is None:
            window = (0, 0, *self.film_size)
        return self.render_batch([window])[0]

    def render_batch(self, windows) -> list:
        """One array per window (in order), each exactly the frame renderer's ``render`` of the
        window shifted into its frame; consecutive windows of one frame in one launch."""
        h = self.frame_size[1]
        out, run, at = [], [], None
        for w in windows:
            x0, y0, ww, wh = (int(v) for v in w)
            k = y0 // h
            if (y0 + wh - 1) // h != k:
                raise ValueError(f"window {tuple(w)} crosses frames {k} and {(y0 + wh - 1) // h}")
            if k != at and run:
                out.extend(self._render(at, run))
                run = []
            at = k
            run.append((x0, y0 - k * h, ww, wh))
        if run:
            out.extend(self._render(at, run))
        return out

    def _render(self, k, windows):
        self._set(k)
        batch = getattr(self.inner, "render_batch", None)
        return batch(windows) if batch is not None else [self.inner.render(window=w) for w in windows]

    def shapes_info(self):
        return self.inner.shapes_info()

    # ------------------------------------------------------------ frames
    def _set(self, k, first=False):
        """Make the loaded scene frame ``k``'s (nothing when it already is)."""
        if self.current == k:
            return
        t = time.perf_counter()
        if self.update is not None:
            self._apply_update(k)
        elif not first and self._params(k) != self._params(self.current):
            self._apply_values(k)
        self.current = k
        if not first:
            self.setup_s.append(time.perf_counter() - t)

    def _apply_update(self, k):
        f, t = self.numbers[k], self.times[k]
        if self.inner_kind == "mitsuba":
            import mitsuba as mi   # lazy: Mitsuba is optional
            params = mi.traverse(self.inner.scene)
            self.update(params, f, t)
            params.update()
            self._reprepare()
        else:
            self.update(self.inner.scene, f, t)
            self.inner.scene.unpin_content()   # the scene changed: its caches hash it again
            self.inner.scene.pin_content()

    def _apply_values(self, k):
        """Frame ``k``'s ``$name`` values: the core's loaded scene takes them in place (its file
        parsed again from memory, only the elements whose parameters changed built again, the
        BVH and the integrator's plan kept where the shapes and lights did not change:
        :meth:`links1.tracing.render.CoreRenderer.set_params`); Mitsuba's loaded scene is kept
        and updated through ``mi.traverse`` / ``params.update()`` with the values that differ in
        the file read with the frame's values (its kernels, recordings and memory stay)."""
        if self.inner_kind != "mitsuba":
            self.inner.set_params(self._params(k))
            return
        import mitsuba as mi   # lazy: Mitsuba is optional
        from links1_mitsuba import load_file
        fresh = mi.traverse(load_file(self.path, params=self._params(k)))
        kept = mi.traverse(self.inner.scene)
        old, new = list(kept.keys()), list(fresh.keys())
        if [_unnamed(a) for a in old] != [_unnamed(b) for b in new]:
            raise RuntimeError(f"{self.path}: frame {self.numbers[k]}'s values change the scene's structure, "
                               "not only its values (a sequence can only change values)")
        for a, b in zip(old, new):
            if ".film." in a:      # the film is the renderer's (--width/--height), not the file's
                continue
            if not _same(kept[a], fresh[b]):
                kept[a] = fresh[b]
        kept.update()
        self._reprepare()

    def _reprepare(self):
        """The integrator's tables for the changed scene (a renderer's own scene is not watched
        per launch: verify_scene is off; it is on for this one prepare)."""
        integ = getattr(self.inner, "integrator", None)
        if integ is None or not hasattr(integ, "prepare"):
            return
        integ.verify_scene = True
        try:
            integ.prepare(self.inner.scene, self.inner.sensor)
        finally:
            integ.verify_scene = False


def _unnamed(key: str) -> str:
    """A traversal key without Mitsuba's per-load names of unnamed objects (``object_<address>``)."""
    return re.sub(r"object_\d+", "object", key)


def _same(a, b) -> bool:
    try:
        return np.array_equal(np.asarray(a), np.asarray(b))
    except Exception:  # noqa: BLE001 - values numpy cannot compare: assume changed
        return False


# ---------------------------------------------------------------------- the root
#: ``--units``: ``frames`` (a node takes whole frames), ``partition`` (each frame split over
#: the nodes in turn), ``both`` (whole frames while there are more than nodes, the last frames split)
UNIT_CHOICES = ("frames", "partition", "both")
#: ``--plan-from`` for split frames: eq. 4.1's object loads, or the previous frame's measured cost
PLAN_FROM = ("eq41", "previous")


def sequence_spec(kind, path, values, *, numbers, times, update=None, threads=None, **options):
    """The :class:`~.runtime.RendererSpec` of a sequence (what every node loads once)."""
    return RendererSpec.make(KIND, path, threads=threads, renderer=kind, frames=tuple(values),
                             numbers=tuple(numbers), times=tuple(float(t) for t in times),
                             update=update_name(update), **options)


def shifted(plan, k, frame_height, n_frames):
    """``plan`` (of one frame) as a plan of the sequence's tall film: units moved to frame ``k``."""
    from links1.partition.strategies import Plan, Unit
    units = [Unit(u.index, u.x0, u.y0 + k * frame_height, u.w, u.h) for u in plan.units]
    return Plan(plan.strategy, plan.width, frame_height * n_frames, plan.n_nodes, units, plan.owner,
                list(plan.order), plan.predicted, dict(plan.meta, frame=k))


def frame_units_plan(width, height, ks, n_nodes, n_frames, *, split_last=0, tiles_per_node=16):
    """Whole frames ``ks`` (sequence indices) as units of the tall film, handed out in order; with
    ``split_last`` the last that many frames are tiles instead (units ``both``)."""
    from links1.partition.strategies import Plan, Unit, grid_shape, tile_units
    units = []
    whole = ks[:len(ks) - split_last] if split_last else ks
    for k in whole:
        units.append(Unit(len(units), 0, k * height, width, height))
    if split_last:
        nx, ny = grid_shape(width, height, n_nodes * tiles_per_node)
        for k in ks[len(ks) - split_last:]:
            for u in tile_units(width, height, nx, ny):
                units.append(Unit(len(units), u.x0, u.y0 + k * height, u.w, u.h))
    return Plan("frames" if not split_last else "both", width, height * n_frames, n_nodes, units, None,
                list(range(len(units))), None, {"frames": list(ks)})


def rank_correlation(a, b) -> float | None:
    """Spearman's rank correlation of ``a`` and ``b`` (None when either is constant)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if len(a) < 2 or np.ptp(a) == 0 or np.ptp(b) == 0:
        return None
    ra, rb = np.argsort(np.argsort(a)), np.argsort(np.argsort(b))
    return float(np.corrcoef(ra, rb)[0, 1])


def node_loads(plan, records, cost, frame_height, n_nodes):
    """Per node: busy seconds (its distinct launches, measured), their CPU seconds (measured in the
    node: what it took of a core, whatever else ran there) and ray tests (exact, the cost AOV over
    its units) of a finished plan's units (``records``: :class:`.executors.RenderResult`'s)."""
    busy, cpu, tests = np.zeros(n_nodes), np.zeros(n_nodes), np.zeros(n_nodes)
    seen, index = set(), {}
    for i, info in records.items():
        # a node's index (the local pool's), or its name (a Dask worker's) numbered as met
        k = index.setdefault(info.get("node", 0), len(index)) % n_nodes
        lid = info.get("launch")
        if lid is not None and tuple(lid) not in seen:
            seen.add(tuple(lid))
            busy[k] += float(info.get("launch_seconds", info.get("seconds", 0.0)))
            cpu[k] += float(info.get("launch_cpu_s", 0.0))
        elif lid is None:
            busy[k] += float(info.get("seconds", 0.0))
            cpu[k] += float(info.get("launch_cpu_s", 0.0))
        if cost is not None:
            u = plan.units[i]
            y = u.y0 % frame_height
            tests[k] += float(cost[y:y + u.h, u.x0:u.x0 + u.w].sum())
    return busy, cpu, tests


def imbalance(loads) -> float | None:
    loads = np.asarray(loads, dtype=np.float64)
    return float(loads.max() / loads.mean()) if loads.size and loads.mean() > 0 else None


def reproject(cost, depth, cam0, cam1):
    """Frame ``f-1``'s per-pixel cost (``cost``, ``depth``: its ``cost`` and ``depth`` AOVs, seen by
    camera ``cam0``) moved to where camera ``cam1`` of frame ``f`` sees the same points: each hit
    pixel's cost lands on the pixel its surface point projects to (the total is kept, less what
    leaves the film); a pixel whose ray missed keeps its cost where it is (the background costs
    the same whatever the view); pixels nothing lands on (surfaces coming into view) get the mean
    cost. A still camera, or a projection other than perspective, gives ``cost`` unchanged."""
    if (cam0.projection != "perspective" or cam1.projection != "perspective"
            or (np.array_equal(cam0.to_world, cam1.to_world) and cam0.fov_x == cam1.fov_x)):
        return cost
    h, w = cost.shape
    ys, xs = np.mgrid[0:h, 0:w]
    o, d, _, _ = cam0.generate_rays(((xs + 0.5) / w).ravel(), ((ys + 0.5) / h).ravel())
    c, z = cost.ravel().astype(np.float64), depth.ravel()
    hit = np.isfinite(z) & (z > 0)
    out = np.zeros(h * w)
    got = np.zeros(h * w, dtype=bool)
    out[~hit] += c[~hit]
    got[~hit] = True
    p = o[hit] + z[hit, None] * d[hit]
    inv = np.linalg.inv(np.asarray(cam1.to_world, dtype=np.float64))
    pc = p @ inv[:3, :3].T + inv[:3, 3]
    front = pc[:, 2] > max(float(cam1.near_clip), 1e-9)
    zt = np.where(front, pc[:, 2], 1.0) * np.tan(np.radians(cam1.fov_x) / 2.0)
    fx = np.floor((1.0 - pc[:, 0] / zt) * 0.5 * w)
    fy = np.floor((1.0 - pc[:, 1] * (w / h) / zt) * 0.5 * h)
    ok = front & (fx >= 0) & (fx < w) & (fy >= 0) & (fy < h)
    at = (fy[ok] * w + fx[ok]).astype(np.int64)
    np.add.at(out, at, c[hit][ok])
    got[at] = True
    out[~got] = float(c.mean())
    return out.reshape(h, w)
