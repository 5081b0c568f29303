"""The root's load model (4-1) and object data per node (4-4).

Per-object load ``w_j`` comes from the object's representation and finish through a
documented table (:data:`DEFAULT_LOAD_TABLE`, overridable with a JSON file)::

    w_j = representation[type_j] * (1 + finish["reflective"] * reflective_j
                                      + finish["transmissive"] * transmissive_j)

Each object's world bounding box is projected to the film; its bounding rectangle ``R_j``
(pixels, row 0 at the top) gives the overlap area ``A_ij`` with tile ``i`` and the tile load
``W_i = sum_j w_j A_ij + background * area_i`` (eq. 4.1; the background term keeps empty
tiles from being free: their eye rays still cost a box test each). With many objects
(more than ``many`` = 64), the loads are spread over the leaves of a median-split box
hierarchy instead (the paper: "use the hierarchy's boxes"): a leaf's load density is
``sum_j w_j |R_j| / |R_leaf|``, which keeps the total and costs O(leaves) per tile.

The per-pixel map of the same sum (:meth:`SceneModel.load_map`) is what every strategy
reads: a unit's predicted load is the map summed over the unit.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import UsageError
from ..scene import params
from ..scene.loader import load_scene
from .strategies import unit_loads

#: Default per-object load table (relative units: one quadric ~ 1).
DEFAULT_LOAD_TABLE = {
    "representation": {
        "quadric": 1.0,        # eq. 3.4-3.5: one quadratic solve (+ clip planes)
        "disk": 0.6,
        "rectangle": 0.8,      # two triangles
        "trianglemesh": 2.0,   # hierarchy traversal + a few triangle tests
        "mesh": 2.0,
        "blob": 12.0,          # eq. 3.6-3.9: iterative root finding, many field evaluations
        "default": 1.0,
    },
    "finish": {"reflective": 1.0, "transmissive": 2.0},  # extra rays spawned per hit
    "background": 0.05,        # per pixel, for every pixel
}


#: Tables fitted per renderer to measured tile times (:func:`fit_load_table`, run by
#: ``python -m compare.load_table``; results in ``compare/results/load_table.md``), merged
#: over :data:`DEFAULT_LOAD_TABLE`. The core keeps the default table. For ``links1_whitted``
#: (Mitsuba) every pixel's lanes pay for the whole frozen ray tree, meshes are Embree's, and
#: reflection/refraction trees are what cost: a very different table from the core's.
RENDERER_LOAD_TABLES: dict = {
    # python -m compare.load_table --rounds 5 (512², 32 tiles a scene, all 10 scenes; 2-core
    # AMD EPYC, load 1.1, git 97e652e + light buffers, 2026-11-25): relative RMS residual 0.34;
    # a two-node subscreen plan's measured imbalance 1.15 -> 1.10 on average over the scenes
    # held out of the fit (fig11 1.43 -> 1.08, mitsuba_glass 1.24 -> 1.02)
    "mitsuba": {
        "representation": {"quadric": 1.0, "trianglemesh": 0.85, "blob": 0.70},
        "finish": {"reflective": 5.5, "transmissive": 12.0},
        "background": 2.95,
    },
}


def _merge(table: dict, update: dict) -> None:
    for k, v in update.items():
        if isinstance(v, dict) and isinstance(table.get(k), dict):
            table[k].update(v)
        else:
            table[k] = v


def load_table(path=None, renderer: str | None = None) -> dict:
    """The default table, then the ``renderer``'s fitted table (:data:`RENDERER_LOAD_TABLES`),
    then a JSON file with the same layout (any subset of keys)."""
    table = json.loads(json.dumps(DEFAULT_LOAD_TABLE))
    _merge(table, json.loads(json.dumps(RENDERER_LOAD_TABLES.get(str(renderer), {}))))
    if path:
        try:
            with open(path) as f:
                user = json.load(f)
        except (OSError, ValueError) as e:
            raise UsageError(f"load table {path}: {e}") from None
        if not isinstance(user, dict):
            raise UsageError(f"load table {path}: expected a JSON object like DEFAULT_LOAD_TABLE")
        _merge(table, user)
    return table


def _rep_key(shape, rep) -> str:
    t = str(shape.get("type", "")).lower()
    return t if t in rep else "default"


def fit_load_table(samples, *, reflective=None, transmissive=None, base=None) -> dict:
    """Fit the load table to measured unit times (least squares, eq. 4.1 kept as it is).

    ``samples``: ``[(model, units, seconds), ...]``, one per scene: a :class:`SceneModel`, the
    units (``Unit``s) and each unit's measured seconds when rendered in its own launch. For
    fixed finish extras the predicted unit load is linear in ``representation[t]`` and
    ``background``: ``seconds_u ~ sum_t rep[t] L_u(t) + background * area_u + c`` (``c``: the
    launch's fixed cost, the same for all units); the finish extras are chosen from a grid.
    Each scene's rows are divided by its mean time, so every scene counts alike. Coefficients
    are kept >= 0 (a negative one is set to 0 and the rest refitted). The result is scaled
    to ``representation["quadric"] = 1`` (when fitted > 0) and returned with ``"fit"``: the
    relative RMS residual and the launch constant in seconds.
    """
    base = json.loads(json.dumps(base or DEFAULT_LOAD_TABLE))
    reflective = np.linspace(0.0, 32.0, 65) if reflective is None else reflective
    transmissive = np.linspace(0.0, 32.0, 33) if transmissive is None else transmissive
    keys = sorted({_rep_key(s, base["representation"]) for m, _, _ in samples for s in m.shapes})
    # w_j = rep[t] (1 + fr refl_j + ft trans_j) is linear in (rep[t], rep[t] fr, rep[t] ft):
    # per scene and representation, the unit loads of its objects with w_j = 1, refl_j, trans_j
    basis, rhs = [], []
    for m, units, sec in samples:
        sec = np.asarray(sec, dtype=np.float64)
        scale = 1.0 / max(float(sec.mean()), 1e-12)
        refl = np.array([bool(s.get("reflective")) for s in m.shapes], dtype=np.float64)
        trans = np.array([bool(s.get("transmissive")) for s in m.shapes], dtype=np.float64)
        rk = np.array([_rep_key(s, base["representation"]) for s in m.shapes])
        cols = []
        for k in keys:
            for f in (1.0, refl, trans):
                w = (rk == k) * f
                cols.append(unit_loads(units, replace(m, loads=w, background=0.0, meta=dict(m.meta)).load_map()))
        area = np.array([u.w * u.h for u in units], dtype=np.float64)
        basis.append(np.stack(cols + [area, np.ones(len(units))], axis=1) * scale)
        rhs.append(sec * scale)
    B, b = np.concatenate(basis), np.concatenate(rhs)
    nk = len(keys)
    best = None
    for fr in reflective:
        for ft in transmissive:
            A = np.concatenate([B[:, 3 * i:3 * i + 1] + fr * B[:, 3 * i + 1:3 * i + 2] + ft * B[:, 3 * i + 2:3 * i + 3]
                                for i in range(nk)] + [B[:, 3 * nk:]], axis=1)
            free = np.ones(A.shape[1], dtype=bool)
            while True:
                x = np.zeros(A.shape[1])
                x[free] = np.linalg.lstsq(A[:, free], b, rcond=None)[0]
                if (x >= 0).all():
                    break
                free &= x > 0
            res = float(np.sqrt(np.mean((A @ x - b) ** 2)))
            if best is None or res < best[0] - 1e-12:
                best = (res, fr, ft, x)
    res, fr, ft, x = best
    rep = dict(zip(keys, x[:len(keys)]))
    unit = rep.get("quadric", 0.0) or max(max(rep.values(), default=0.0), x[len(keys)], 1e-30)
    table = base
    table["representation"].update({k: float(v / unit) for k, v in rep.items()})
    table["finish"] = {"reflective": float(fr), "transmissive": float(ft)}
    table["background"] = float(x[len(keys)] / unit)
    table["fit"] = {"relative_rms": res, "launch_s": float(x[-1]), "seconds_per_load": float(unit),
                    "fitted": keys}
    return table


def object_loads(shapes, table=None) -> np.ndarray:
    """``w_j`` for each entry of ``shapes_info()``."""
    table = table or DEFAULT_LOAD_TABLE
    rep, fin = table["representation"], table["finish"]
    w = []
    for s in shapes:
        base = rep.get(str(s.get("type", "")).lower(), rep.get("default", 1.0))
        w.append(base * (1.0 + fin.get("reflective", 0.0) * bool(s.get("reflective"))
                         + fin.get("transmissive", 0.0) * bool(s.get("transmissive"))))
    return np.asarray(w, dtype=np.float64)


# ---------------------------------------------------------------------- projection
_EDGES = [(0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 4), (1, 5), (2, 6), (3, 7)]


def project_boxes(camera, lo, hi, width=None, height=None, pad: float = 0.5) -> np.ndarray:
    """Bounding rectangles of world boxes on the film: (J, 4) ``[x0, y0, x1, y1]`` pixels.

    Row 0 at the top. Boxes are clipped against the near plane first (corners in front plus
    the points where box edges cross the plane), so boxes around or behind the eye are
    handled; a box wholly behind the eye gets an empty rectangle (x0 = x1 = y0 = y1 = 0).
    Rectangles are padded by ``pad`` pixels and clipped to the film.
    """
    width = int(width or camera.width)
    height = int(height or camera.height)
    lo = np.atleast_2d(np.asarray(lo, dtype=np.float64))
    hi = np.atleast_2d(np.asarray(hi, dtype=np.float64))
    cam_from_world = np.linalg.inv(np.asarray(camera.to_world, dtype=np.float64))
    ortho = getattr(camera, "projection", "perspective") == "orthographic"
    t = 1.0 if ortho else math.tan(math.radians(camera.fov_x) / 2.0)
    aspect = width / height
    z_near = max(float(getattr(camera, "near_clip", 1e-2)), 1e-9)
    out = np.zeros((len(lo), 4))
    bits = np.array([[(k >> 0) & 1, (k >> 1) & 1, (k >> 2) & 1] for k in range(8)], dtype=bool)
    for j in range(len(lo)):
        corners = np.where(bits, hi[j], lo[j])                      # (8, 3) world
        pc = corners @ cam_from_world[:3, :3].T + cam_from_world[:3, 3]
        pts = [pc[pc[:, 2] >= z_near]]
        for a, b in _EDGES:                                         # near-plane crossings
            za, zb = pc[a, 2], pc[b, 2]
            if (za - z_near) * (zb - z_near) < 0:
                s = (z_near - za) / (zb - za)
                pts.append((pc[a] + s * (pc[b] - pc[a]))[None])
        p = np.concatenate(pts)
        if len(p) == 0:
            continue
        # Mitsuba perspective: x_film = (1 - x/(z t)) / 2, y_film = (1 - y aspect/(z t)) / 2;
        # orthographic: the same with z t = 1 (links1.sensor.camera)
        zt = 1.0 if ortho else p[:, 2] * t
        fx = (1.0 - p[:, 0] / zt) * 0.5 * width
        fy = (1.0 - p[:, 1] * aspect / zt) * 0.5 * height
        x0, x1 = max(fx.min() - pad, 0.0), min(fx.max() + pad, width)
        y0, y1 = max(fy.min() - pad, 0.0), min(fy.max() + pad, height)
        if x1 > x0 and y1 > y0:
            out[j] = (x0, y0, x1, y1)
    return out


def _overlap_1d(r0, r1, n):
    """(J, n) overlap lengths of intervals [r0_j, r1_j] with the pixel cells [k, k+1)."""
    k = np.arange(n, dtype=np.float64)
    return np.clip(np.minimum(r1[:, None], k + 1) - np.maximum(r0[:, None], k), 0.0, None)


def box_hierarchy(lo, hi, leaf_size: int = 8) -> list[np.ndarray]:
    """Leaves (index arrays) of a median split over box centroids along the longest axis."""
    idx = np.arange(len(lo))
    centre = 0.5 * (lo + hi)
    leaves, stack = [], [idx]
    while stack:
        ids = stack.pop()
        if len(ids) <= leaf_size:
            leaves.append(ids)
            continue
        c = centre[ids]
        axis = int(np.argmax(c.max(axis=0) - c.min(axis=0)))
        order = ids[np.argsort(c[:, axis], kind="stable")]
        half = len(order) // 2
        stack += [order[:half], order[half:]]
    return leaves


def rect_area(rects) -> np.ndarray:
    return np.clip(rects[:, 2] - rects[:, 0], 0, None) * np.clip(rects[:, 3] - rects[:, 1], 0, None)


@dataclass
class SceneModel:
    """What the root knows about a scene: film, objects, loads, rectangles, secondary rays."""

    width: int
    height: int
    shapes: list                      # shapes_info() dicts
    loads: np.ndarray                 # w_j
    rects: np.ndarray                 # (J, 4) projected rectangles, pixels, row 0 at the top
    background: float = 0.05
    max_depth: int = params.default("links1_whitted", "max_depth")
    lights: list | None = None        # [{"position": (3,)} | {"position": None}] ; None: unknown
    many: int = 64
    leaf_size: int = 8
    meta: dict = field(default_factory=dict)

    @property
    def nbytes(self) -> np.ndarray:
        return np.array([int(s.get("nbytes", 0) or 0) for s in self.shapes], dtype=np.int64)

    def load_map(self) -> np.ndarray:
        """(height, width) predicted per-pixel load: ``background + sum_j w_j [pixel in R_j]``
        weighted by the covered fraction of the pixel (so tile sums are eq. 4.1 exactly)."""
        rects, w = self.rects, self.loads
        if len(rects) > self.many:
            lo = np.array([s["bounds_lo"] for s in self.shapes], dtype=np.float64)
            hi = np.array([s["bounds_hi"] for s in self.shapes], dtype=np.float64)
            leaves = box_hierarchy(lo, hi, self.leaf_size)
            area = rect_area(rects)
            lr, lw = [], []
            for ids in leaves:
                vis = ids[area[ids] > 0]
                if len(vis) == 0:
                    continue
                r = np.array([rects[vis, 0].min(), rects[vis, 1].min(), rects[vis, 2].max(), rects[vis, 3].max()])
                lr.append(r)
                lw.append(float(np.sum(w[vis] * area[vis])) / max(rect_area(r[None])[0], 1e-12))
            rects = np.array(lr).reshape(-1, 4)
            w = np.array(lw)
            self.meta["hierarchy_leaves"] = len(rects)
        ox = _overlap_1d(rects[:, 0], rects[:, 2], self.width)     # (J, W)
        oy = _overlap_1d(rects[:, 1], rects[:, 3], self.height)    # (J, H)
        return self.background + oy.T @ (w[:, None] * ox)          # eq. (4.1) per pixel

    # ---------------------------------------------------------------- 4-4
    def touching(self, windows) -> np.ndarray:
        """(U, J) bool: object j's rectangle touches window u (primary rays of u may hit j)."""
        win = np.asarray(windows, dtype=np.float64).reshape(-1, 4)
        x0, y0 = win[:, 0:1], win[:, 1:2]
        x1, y1 = x0 + win[:, 2:3], y0 + win[:, 3:4]
        r = self.rects
        vis = rect_area(r) > 0
        return (vis[None] & (r[None, :, 0] < x1) & (r[None, :, 2] > x0)
                & (r[None, :, 1] < y1) & (r[None, :, 3] > y0))

    def secondary(self, primary: np.ndarray) -> np.ndarray:
        """Objects that secondary rays from hits on ``primary`` objects may reach (bool (J,)).

        Reflection/refraction (a reflective or transmissive primary object and
        max_depth > 1) can reach anything: all objects. Shadow rays from a hit to a point
        light stay inside the box around the primary objects' boxes and the light
        positions: the objects whose box meets that box. A light without a position
        (parallel) or unknown lights: all objects.
        """
        n = len(self.shapes)
        primary = np.asarray(primary, dtype=bool)
        if not primary.any():
            return np.zeros(n, dtype=bool)
        refl = np.array([bool(s.get("reflective")) or bool(s.get("transmissive")) for s in self.shapes])
        if self.max_depth > 1 and (refl & primary).any():
            return np.ones(n, dtype=bool)
        if self.lights is None:
            return np.ones(n, dtype=bool)
        if not self.lights:
            return primary.copy()
        lo = np.array([s["bounds_lo"] for s in self.shapes], dtype=np.float64)
        hi = np.array([s["bounds_hi"] for s in self.shapes], dtype=np.float64)
        pos = []
        for light in self.lights:
            if light.get("position") is None:
                return np.ones(n, dtype=bool)
            pos.append(np.asarray(light["position"], dtype=np.float64))
        blo = np.minimum(lo[primary].min(axis=0), np.min(pos, axis=0))
        bhi = np.maximum(hi[primary].max(axis=0), np.max(pos, axis=0))
        meets = np.all((lo <= bhi) & (hi >= blo), axis=1)
        return meets | primary

    def node_data(self, plan) -> list[dict]:
        """Per node of a plan: objects (count, bytes) for primary rays and what secondary rays add."""
        touch = self.touching([u.window for u in plan.units])
        nb = self.nbytes
        nodes = range(plan.n_nodes)
        out = []
        for k in nodes:
            ids = plan.node_units(k) if plan.static else list(range(len(plan.units)))
            prim = touch[ids].any(axis=0) if ids else np.zeros(len(self.shapes), bool)
            sec = self.secondary(prim) & ~prim
            out.append({"node": k, "units": len(ids),
                        "objects_primary": int(prim.sum()), "bytes_primary": int(nb[prim].sum()),
                        "objects_secondary": int(sec.sum()), "bytes_secondary": int(nb[sec].sum())})
        return out

    def needed(self, window) -> np.ndarray:
        """Indices of the objects a window needs (primary and secondary rays): what --cull ships."""
        prim = self.touching([window])[0]
        return np.flatnonzero(prim | self.secondary(prim))


def camera_of(renderer, path=None, params=None):
    """The core :class:`~links1.sensor.camera.Camera` of a renderer's scene, at its film size, or None."""
    cam = getattr(renderer, "camera", None)
    if cam is None:
        scene = getattr(renderer, "scene", None)
        cam = getattr(scene, "camera", None) if scene is not None else None
    if cam is None and path is not None:
        try:
            cam = load_scene(path, **(params or {})).camera
        except Exception:  # noqa: BLE001 - the core cannot read this scene: no projection
            return None
    if cam is None:
        return None
    w, h = renderer.film_size
    if (cam.width, cam.height) != (w, h):
        cam = replace(cam, width=int(w), height=int(h), crop_offset=(0, 0), crop_size=(int(w), int(h)))
    return cam


def lights_of(renderer):
    """Light positions for the shadow-ray analysis: list of {"position": (3,) or None}, or None."""
    info = getattr(renderer, "lights_info", None)
    if callable(info):
        return info()
    scene = getattr(renderer, "scene", None)
    lights = getattr(scene, "lights", None) if scene is not None else None
    if lights is None:
        return None
    return [{"position": (None if type(lt).__name__ in ("ParallelLight", "CylinderSpotLight")
                          else getattr(lt, "position", None))} for lt in lights]


def scene_model(renderer, *, path=None, params=None, table=None) -> SceneModel:
    """Build the root's :class:`SceneModel` from a renderer (Renderer contract + optional extras)."""
    table = table or DEFAULT_LOAD_TABLE
    w, h = (int(v) for v in renderer.film_size)
    shapes = list(renderer.shapes_info()) if hasattr(renderer, "shapes_info") else []
    cam = camera_of(renderer, path, params)
    if shapes and cam is not None:
        lo = np.array([s["bounds_lo"] for s in shapes], dtype=np.float64)
        hi = np.array([s["bounds_hi"] for s in shapes], dtype=np.float64)
        rects = project_boxes(cam, lo, hi, w, h)
    else:  # no projection: every object may be anywhere
        rects = np.tile(np.array([0.0, 0.0, w, h]), (len(shapes), 1))
    md = getattr(renderer, "max_depth", None)
    if md is None:
        md = getattr(getattr(renderer, "scene", None), "max_depth", None) or 5
    return SceneModel(w, h, shapes, object_loads(shapes, table), rects,
                      background=float(table.get("background", 0.05)), max_depth=int(md),
                      lights=lights_of(renderer), meta={"projected": cam is not None, "load_table": table})
