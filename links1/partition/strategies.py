"""Screen units and the root's partitioning strategies (paper section 4).

Coordinates: a unit is a window ``(x0, y0, w, h)`` of the film in pixels with row 0 at the
top (the renderer's crop convention). The paper counts from the *bottom*-left, so the
walks below go from the bottom row up: tile ``(row 0, col 0)`` is the bottom-left tile
and scanline ``k = 0`` is the bottom row (``y0 = height - 1``).

Strategies
----------
subscreen  4-1: ``tiles_per_node * N`` equal tiles, tile loads ``W_i = sum_j w_j A_ij``
           (eq. 4.1, see :mod:`.loadmodel`), walked bottom-left -> top-right, a group
           closing each time the running sum reaches a multiple of ``total / N``; group g
           -> node g. Static.
scanline   4-2: scanline k (from the bottom) -> node ``k mod N``. Static.
dynamic    4-3: one unit (``unit="scanline"`` or ``"tile"``) at a time; a node that
           finishes gets the next. Dispatch order: ``"lpt"`` (largest predicted load
           first, the default when a load map is given) or ``"walk"`` (bottom-left first).
grid       equal tiles dealt round-robin in walk order (a plain baseline). Static.
subscreen-balanced
           not the paper's: subscreen's tiles, eq. (4.1) loads and walk, each group still a
           run of consecutive tiles of the walk, but the cuts placed where the heaviest group
           is lightest (the linear partition problem) instead of at the tile that crosses
           each multiple of the average, which leaves the first groups up to one tile heavier
           (fig11 at 512², 2 nodes: predicted max/mean 1.11 with 4-1's cuts). Static.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import UsageError

STRATEGIES = ("subscreen", "scanline", "dynamic", "grid", "subscreen-balanced")
UNITS = ("scanline", "tile")
STATIC = ("subscreen", "scanline", "grid", "subscreen-balanced")


@dataclass(frozen=True)
class Unit:
    """One unit of work: a window of the film (row 0 at the top)."""

    index: int
    x0: int
    y0: int
    w: int
    h: int

    @property
    def window(self) -> tuple[int, int, int, int]:
        return (self.x0, self.y0, self.w, self.h)

    @property
    def pixels(self) -> int:
        return self.w * self.h

    @property
    def key(self) -> str:
        return f"{self.x0}_{self.y0}_{self.w}_{self.h}"


@dataclass
class Plan:
    """The root's plan for one frame.

    Attributes
    ----------
    strategy : str
    width, height : int          film size
    n_nodes : int
    units : list[Unit]           in walk order (bottom-left first)
    owner : list[int] | None     node of each unit (static strategies); None for dynamic
    order : list[int]            dispatch order (unit indices)
    predicted : ndarray | None   predicted load of each unit (eq. 4.1), if a load map was given
    """

    strategy: str
    width: int
    height: int
    n_nodes: int
    units: list
    owner: list | None
    order: list
    predicted: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    @property
    def static(self) -> bool:
        return self.owner is not None

    def node_units(self, node: int) -> list[int]:
        """Unit indices of a node, in dispatch order (static plans)."""
        if self.owner is None:
            raise ValueError("a dynamic plan has no fixed owners")
        return [i for i in self.order if self.owner[i] == node]

    def coverage(self) -> np.ndarray:
        """How many units cover each pixel, (height, width) int (1 everywhere for a valid plan)."""
        c = np.zeros((self.height, self.width), dtype=np.int64)
        for u in self.units:
            c[u.y0:u.y0 + u.h, u.x0:u.x0 + u.w] += 1
        return c

    def __repr__(self) -> str:
        return (f"Plan({self.strategy}, film={self.width}x{self.height}, nodes={self.n_nodes}, "
                f"units={len(self.units)})")


# ---------------------------------------------------------------------- units
def grid_shape(width: int, height: int, n_tiles: int) -> tuple[int, int]:
    """Columns and rows ``(nx, ny)`` of about ``n_tiles`` equal tiles shaped like the film.

    Uses an exact factorisation ``nx * ny = n_tiles`` whose tile aspect is closest to square
    when one fits the film, else the nearest grid that does.
    """
    n_tiles = max(1, int(n_tiles))
    best = None
    for nx in range(1, n_tiles + 1):
        if n_tiles % nx:
            continue
        ny = n_tiles // nx
        if nx > width or ny > height:
            continue
        score = abs(math.log((width / nx) / (height / ny)))
        if best is None or score < best[0]:
            best = (score, nx, ny)
    if best is not None:
        return best[1], best[2]
    nx = min(width, max(1, round(math.sqrt(n_tiles * width / height))))
    ny = min(height, max(1, math.ceil(n_tiles / nx)))
    return nx, ny


def _edges(n_pixels: int, n_parts: int) -> np.ndarray:
    """Part boundaries of ``n_pixels`` split into ``n_parts`` near-equal parts."""
    return (np.arange(n_parts + 1) * n_pixels) // n_parts


def tile_units(width: int, height: int, nx: int, ny: int) -> list[Unit]:
    """``nx * ny`` tiles in walk order: bottom row first, each row left to right."""
    xe, ye = _edges(width, nx), _edges(height, ny)
    units = []
    for r in range(ny):  # r = 0 is the bottom row of tiles
        y1 = height - ye[r]
        y0 = height - ye[r + 1]
        for c in range(nx):
            units.append(Unit(len(units), int(xe[c]), int(y0), int(xe[c + 1] - xe[c]), int(y1 - y0)))
    return units


def scanline_units(width: int, height: int) -> list[Unit]:
    """One unit per scanline, k = 0 the bottom row."""
    return [Unit(k, 0, height - 1 - k, width, 1) for k in range(height)]


def unit_loads(units, load_map) -> np.ndarray:
    """Sum of a per-pixel load map over each unit (eq. 4.1 when the map comes from :mod:`.loadmodel`)."""
    if load_map is None:
        return None
    # summed-area table: exact sums in O(1) per unit
    sat = np.zeros((load_map.shape[0] + 1, load_map.shape[1] + 1))
    sat[1:, 1:] = np.cumsum(np.cumsum(load_map, axis=0), axis=1)
    out = np.empty(len(units))
    for i, u in enumerate(units):
        y1, x1 = u.y0 + u.h, u.x0 + u.w
        out[i] = sat[y1, x1] - sat[u.y0, x1] - sat[y1, u.x0] + sat[u.y0, u.x0]
    return out


# ---------------------------------------------------------------------- strategies
def subscreen_groups(loads, n_nodes: int) -> list[int]:
    """The 4-1 walk: group of each tile, tiles given in walk order.

    The running sum of tile loads closes group ``g`` at the tile where it first reaches
    ``(g + 1) * average`` (that tile belongs to group g), ``average = total / n_nodes``.
    Every group gets at least one tile while tiles remain for the later groups; the last
    group takes the rest. Zero total load falls back to equal tile counts.
    """
    loads = np.asarray(loads, dtype=np.float64)
    n = len(loads)
    if n_nodes < 1:
        raise UsageError(f"nodes must be >= 1, got {n_nodes}")
    total = float(loads.sum())
    if not total > 0:
        loads = np.ones(n)
        total = float(n)
    average = total / n_nodes
    groups, g, running = [], 0, 0.0
    for i, w in enumerate(loads):
        groups.append(g)
        running += w
        tiles_left = n - i - 1
        groups_left = n_nodes - 1 - g
        if g < n_nodes - 1 and (running >= (g + 1) * average * (1 - 1e-12) or tiles_left <= groups_left):
            g += 1
    return groups


def _cut_at_cap(loads, n_nodes, cap):
    """Consecutive groups of ``loads`` (walk order), each closed before it would pass ``cap``
    or when the tiles left are just enough for one per group left -> group of each tile, or
    None when the last group passes ``cap`` (no such cut exists: ``cap`` is too small)."""
    groups, g, running, n = [], 0, 0.0, len(loads)
    for i, w in enumerate(loads):
        if g < n_nodes - 1 and running > 0 and (running + w > cap or n - i <= n_nodes - 1 - g):
            g, running = g + 1, 0.0
        groups.append(g)
        running += w
    return groups if running <= cap else None


def balanced_groups(loads, n_nodes: int) -> list[int]:
    """Group of each tile (walk order) for ``subscreen-balanced``: consecutive groups whose
    heaviest predicted load is as small as cuts between tiles allow (bisection on that load,
    each try a greedy walk, :func:`_cut_at_cap`); every group gets a tile while tiles remain.
    Zero total load falls back to equal tile counts, as :func:`subscreen_groups`."""
    loads = np.asarray(loads, dtype=np.float64)
    if n_nodes < 1:
        raise UsageError(f"nodes must be >= 1, got {n_nodes}")
    if not float(loads.sum()) > 0:
        loads = np.ones(len(loads))
    total = float(loads.sum())
    # hi: the total, a little over (a running sum in walk order may round above numpy's sum)
    lo, hi = max(float(loads.max(initial=0.0)), total / n_nodes), total * (1 + 1e-9)
    best = _cut_at_cap(loads, n_nodes, hi)
    for _ in range(60):   # until the cap is known to 1e-12 of the total
        if hi - lo <= 1e-12 * total:
            break
        mid = 0.5 * (lo + hi)
        got = _cut_at_cap(loads, n_nodes, mid)
        if got is None:
            lo = mid
        else:
            hi, best = mid, got
    return best


def make_plan(strategy: str, width: int, height: int, n_nodes: int, *, tiles_per_node: int = 16,
              unit: str = "scanline", load_map=None, order: str | None = None) -> Plan:
    """Partition a ``width x height`` film for ``n_nodes`` nodes.

    Parameters
    ----------
    strategy : {"subscreen", "scanline", "dynamic", "grid", "subscreen-balanced"}
    tiles_per_node : int
        Tiles per node for subscreen, grid and dynamic tiles (the paper: 16 or 64).
    unit : {"scanline", "tile"}
        The unit handed out by ``dynamic``.
    load_map : ndarray (height, width), optional
        Predicted per-pixel load (:func:`links1.partition.loadmodel.SceneModel.load_map`);
        subscreen needs it (without it, tile loads are the pixel counts).
    order : {"lpt", "walk"}, optional
        Dispatch order for dynamic (default ``lpt`` with a load map, else ``walk``).
    """
    if strategy not in STRATEGIES:
        raise UsageError(f"unknown partition {strategy!r}; choose from {', '.join(STRATEGIES)}")
    if unit not in UNITS:
        raise UsageError(f"unknown unit {unit!r}; choose from {', '.join(UNITS)}")
    n_nodes, tiles_per_node = int(n_nodes), int(tiles_per_node)
    if n_nodes < 1:
        raise UsageError(f"nodes must be >= 1, got {n_nodes}")
    if tiles_per_node < 1:
        raise UsageError(f"tiles per node must be >= 1, got {tiles_per_node}")
    if load_map is not None:
        load_map = np.asarray(load_map, dtype=np.float64)
        if load_map.shape != (height, width):
            raise ValueError(f"load map {load_map.shape} does not match the film {height}x{width}")
    meta = {"tiles_per_node": tiles_per_node}

    if strategy == "scanline" or (strategy == "dynamic" and unit == "scanline"):
        units = scanline_units(width, height)
    else:
        nx, ny = grid_shape(width, height, n_nodes * tiles_per_node)
        units = tile_units(width, height, nx, ny)
        meta["grid"] = [nx, ny]
    predicted = unit_loads(units, load_map)
    walk = list(range(len(units)))

    if strategy == "scanline":
        owner = [k % n_nodes for k in range(len(units))]  # 4-2: line k -> node k mod N
        return Plan(strategy, width, height, n_nodes, units, owner, walk, predicted, meta)
    if strategy == "grid":
        owner = [i % n_nodes for i in range(len(units))]
        return Plan(strategy, width, height, n_nodes, units, owner, walk, predicted, meta)
    if strategy in ("subscreen", "subscreen-balanced"):
        loads = predicted if predicted is not None else np.array([u.pixels for u in units], float)
        if strategy == "subscreen":
            owner = subscreen_groups(loads, n_nodes)  # eq. (4.1) loads, 4-1 walk
        else:
            owner = balanced_groups(loads, n_nodes)   # the same walk, cuts at the least max load
        meta["average_load"] = float(np.sum(loads)) / n_nodes
        return Plan(strategy, width, height, n_nodes, units, owner, walk, predicted, meta)
    # dynamic (4-3)
    meta["unit"] = unit
    order = order or ("lpt" if predicted is not None else "walk")
    if order not in ("lpt", "walk"):
        raise UsageError(f"unknown dispatch order {order!r}; choose lpt or walk")
    meta["order"] = order
    if order == "lpt" and predicted is not None:
        walk = [int(i) for i in np.argsort(-predicted, kind="stable")]
    return Plan(strategy, width, height, n_nodes, units, None, walk, predicted, meta)
