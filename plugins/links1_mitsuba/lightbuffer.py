"""Light buffers (Haines and Greenberg 1986) for the shadow rays of ``links1_whitted`` toward
positional lights (point, spot) and, as the same idea in parallel projection, directional lights;
and the same lists around a pinhole camera's eye, as a grid over its film (:mod:`.eyegrid`), for
the camera rays' nearest hit (:func:`plan_eye`, :meth:`LightBuffer.nearest`).

At scene set-up, per light, a grid of cells over the directions seen from the light (a cube
map: 6 faces x N x N cells) or, for a directional light, over the plane perpendicular to its
direction (N x N cells): per cell, the quadrics whose bounds can be met by a shadow ray whose
light-side direction (or projection) falls in that cell, ordered by how near to the light they
can come. A shadow ray from a hit point toward the light looks up its cell and tests only the
listed quadrics, with the same exact test as the BVH leaf (:meth:`QuadricBVH.intersect`), the
same any-hit exit for opaque ones and the same transmittance product (paper 3-3-3: a shadow
ray's intensity is multiplied by the transmittance of every object it crosses, once per
object). It stops at the first entry that cannot come as near to the light as the ray's
origin.

Conservative by construction (float64 numpy): every quadric's bound is its world box's
circumscribed sphere inflated by a margin ``m`` (a multiple of the float32 error of the shadow
ray's line, which starts at an offset origin and need not pass exactly through the light); a
cell is a cone around its centre direction (its corner directions included) widened by an
angular margin, and a bound that contains the light is listed in every cell. Lists are CSR
arrays (``offsets``, entries) in 64-byte aligned Dr.Jit tables (:func:`util.table`); an entry is
a pair (quadric row as float bits, key), read with one packet gather.
"""
from __future__ import annotations

import math

import numpy as np

from . import eyegrid
from .lights import DIRECTED, POSITIONED

#: relative distance margin (times 1 + the scene's extent) added to every bound: covers the
#: float32 error of a shadow ray's line (origin offset by the ray epsilon 2^-19, direction
#: rounded) by two orders of magnitude
MARGIN_REL = 1e-4
#: angular margin (radians) on every cell's cone: float32 direction and face/cell rounding
ANGLE_MARGIN = 1e-4
#: cells per side: about sqrt(GRID_FACTOR * n) for n quadrics, at most GRID_MAX (a cube face:
#: the cube map's set-up tests every cell against every bound) or GRID_MAX_DIR (a directional
#: grid: each bound visits only the cells of its box)
GRID_FACTOR = 14.0
#: a directional grid's factor: its set-up costs the cells of each bound's box, not every cell
#: against every bound, so it is made finer (300 spheres: 256 a side, against 65 at
#: GRID_FACTOR: 0.24 instead of 0.40 quadric tests a shadow ray on compare.quadric_spp's scene)
GRID_FACTOR_DIR = 224.0
GRID_MAX = 64
GRID_MAX_DIR = 256
# light buffers on or off: tuning.Tuning.light_buffer (tests and benchmarks turn them off to
# compare with the BVH walk)
#: a light buffer is used for a light when its expected list length per shadow ray is below
#: this many quadric tests (the BVH walk takes ~9.5 steps on many.xml)
MAX_MEAN_LIST = 4.0


def sphere_bounds(lo, hi, margin):
    """Centres and radii (float64) of the spheres around boxes ``lo``, ``hi`` (n, 3), + margin."""
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    c = 0.5 * (lo + hi)
    r = 0.5 * np.linalg.norm(hi - lo, axis=1) * (1.0 + 1e-12) + margin
    return c, r


def quadric_spheres(specs, margin):
    """A bounding sphere per quadric (float64), + margin: the smaller of its world box's
    circumscribed sphere and, for a ``sphere`` quadric (an ellipsoid, clipped or not), the
    sphere around its centre with the largest singular value of its linear map as radius
    (many.xml's spheres: 1.56x smaller radii, and shadow rays test 3.4 -> 1.6 entries)."""
    lo = np.array([s.bounds()[0] for s in specs], dtype=np.float64)
    hi = np.array([s.bounds()[1] for s in specs], dtype=np.float64)
    c, r = sphere_bounds(lo, hi, margin)
    for i, s in enumerate(specs):
        if s.kind == "sphere":
            m = np.asarray(s.to_world, dtype=np.float64)
            re = float(np.linalg.svd(m[:3, :3], compute_uv=False)[0]) * (1.0 + 1e-12) + margin
            if re < r[i]:
                c[i], r[i] = m[:3, 3], re
    return c, r


def cube_cell(dirs, N):
    """Cell index of directions ``dirs`` (m, 3) in a cube map of 6 x N x N cells (the same rule
    as the kernel, in float64): face 2*axis + (component < 0), then the two other components
    over the major one."""
    dirs = np.asarray(dirs, dtype=np.float64)
    a = np.abs(dirs)
    ax = np.argmax(a, axis=1)
    m = np.take_along_axis(dirs, ax[:, None], 1)[:, 0]
    face = 2 * ax + (m < 0)
    o1 = (ax + 1) % 3
    o2 = (ax + 2) % 3
    am = np.abs(m)
    u = np.take_along_axis(dirs, o1[:, None], 1)[:, 0] / am
    v = np.take_along_axis(dirs, o2[:, None], 1)[:, 0] / am
    iu = np.clip(np.floor((u + 1.0) * (0.5 * N)), 0, N - 1).astype(np.int64)
    iv = np.clip(np.floor((v + 1.0) * (0.5 * N)), 0, N - 1).astype(np.int64)
    return (face * N + iv) * N + iu


def cube_cones(N):
    """Centre directions (6N², 3) and half-angles (6N²,) of the cells of a cube map."""
    g = -1.0 + 2.0 * np.arange(N + 1) / N                 # cell borders on a face
    cen, half = [], []
    for face in range(6):
        ax, neg = face // 2, face % 2
        o1, o2 = (ax + 1) % 3, (ax + 2) % 3

        def to3(u, v):
            d = np.zeros(u.shape + (3,))
            d[..., ax] = -1.0 if neg else 1.0
            d[..., o1] = u
            d[..., o2] = v
            return d / np.linalg.norm(d, axis=-1, keepdims=True)
        vv, uu = np.meshgrid(g, g, indexing="ij")          # (N+1, N+1): [iv, iu]
        corners = to3(uu, vv)
        uc = 0.5 * (g[:-1] + g[1:])
        vc, ucc = np.meshgrid(uc, uc, indexing="ij")
        c = to3(ucc, vc)                                   # (N, N, 3)
        cosines = [np.sum(c * corners[a:a + N, b:b + N], axis=-1) for a in (0, 1) for b in (0, 1)]
        h = np.arccos(np.clip(np.minimum.reduce(cosines), -1.0, 1.0))
        cen.append(c.reshape(-1, 3))
        half.append(h.ravel())
    return np.concatenate(cen), np.concatenate(half)


def _csr(ncell, cells, objs, keys):
    """CSR lists: per cell its objects, ordered by key then object."""
    order = np.lexsort((objs, keys, cells))
    cells, objs, keys = cells[order], objs[order], keys[order]
    offsets = np.zeros(ncell + 1, dtype=np.int64)
    np.add.at(offsets, cells + 1, 1)
    return np.cumsum(offsets), objs, keys


def _cones_meet(cen, ch, sh, u, sin_a):
    """(cells, bounds) booleans: cell cone (centre ``cen``, half-angle h + margin given as its
    cosine ``ch`` and sine ``sh``) meets the cone of a bound seen from the point (direction
    ``u``, half-angle a with sine ``sin_a``): angle(cen, u) <= a + h, i.e. cos >= cos(a + h)."""
    sa = np.clip(sin_a, 0.0, 1.0)
    cos_cap = np.multiply.outer(ch, np.sqrt(1.0 - sa * sa))
    cos_cap -= np.multiply.outer(sh, sa)
    return (cen @ u.T) >= cos_cap


def build_point(pos, c, r, N, chunk=None):
    """Light buffer of a light at ``pos`` over bounding spheres ``(c, r)``: (offsets, objects,
    keys) with key = the nearest distance to the light a bound can come (<= 0: contains it)."""
    pos = np.asarray(pos, dtype=np.float64)
    cen, half = cube_cones(N)
    ncell = len(cen)
    rel = c - pos
    D = np.linalg.norm(rel, axis=1)
    keys_all = D - r
    inside = D <= r
    cells, objs = [], []
    idx_in = np.nonzero(inside)[0]
    if idx_in.size:
        cells.append(np.repeat(np.arange(ncell), idx_in.size))
        objs.append(np.tile(idx_in, ncell))
    out = np.nonzero(~inside)[0]
    chunk = chunk or max(1, (1 << 22) // ncell)
    # cos(alpha + h) = cos a cos h - sin a sin h, h = a cell's half-angle + the angular margin:
    # no transcendental per (cell, bound) pair (alpha <= pi/2 and h <= 0.18 rad from N = 8: no wrap)
    hm = half + ANGLE_MARGIN
    ch, sh = np.cos(hm), np.sin(hm)
    for a in range(0, out.size, chunk):
        o = out[a:a + chunk]
        ci, oi = np.nonzero(_cones_meet(cen, ch, sh, rel[o] / D[o, None], r[o] / D[o]))
        cells.append(ci)
        objs.append(o[oi])
    cells = np.concatenate(cells) if cells else np.zeros(0, np.int64)
    objs = np.concatenate(objs) if objs else np.zeros(0, np.int64)
    return _csr(ncell, cells, objs, keys_all[objs])


def sampled_mean_list(pos, c, r, N, k=2048, seed=0):
    """The mean list length of a point buffer's non-empty cells (:func:`build_point`'s rule)
    estimated from ``k`` random cells: a build at 10,000 bounds takes seconds, this a tenth."""
    pos = np.asarray(pos, dtype=np.float64)
    cen, half = cube_cones(N)
    pick = np.random.default_rng(seed).choice(len(cen), size=min(k, len(cen)), replace=False)
    cen, hm = cen[pick], half[pick] + ANGLE_MARGIN
    ch, sh = np.cos(hm), np.sin(hm)
    rel = c - pos
    D = np.linalg.norm(rel, axis=1)
    inside = D <= r
    counts = np.full(len(pick), int(inside.sum()))
    out = np.nonzero(~inside)[0]
    for a in range(0, out.size, 2048):
        o = out[a:a + 2048]
        counts += np.sum(_cones_meet(cen, ch, sh, rel[o] / D[o, None], r[o] / D[o]), axis=1)
    return float(counts[counts > 0].mean()) if np.any(counts > 0) else 0.0


def plane_basis(w):
    """Two unit vectors perpendicular to unit ``w`` (float64)."""
    w = np.asarray(w, dtype=np.float64)
    a = np.array([1.0, 0.0, 0.0]) if abs(w[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(w, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(w, e1)
    return e1, e2


def build_directional(w, c, r, N):
    """Light buffer of a directional light (unit ``w`` toward the light) over bounding spheres:
    (offsets, objects, keys, (e1, e2, u0, v0, inv_cell)) with key = -(the highest a bound
    reaches along ``w``): a shadow ray from height h meets only entries with -key >= h."""
    e1, e2 = plane_basis(w)
    pu, pv, ph = c @ e1, c @ e2, c @ np.asarray(w, dtype=np.float64)
    u0, u1 = float(np.min(pu - r)), float(np.max(pu + r))
    v0, v1 = float(np.min(pv - r)), float(np.max(pv + r))
    size = max(u1 - u0, v1 - v0, 1e-30)
    cell = size / N
    inv = 1.0 / cell
    # cells each disc's box covers (the disc's box: conservative)
    iu0 = np.clip(np.floor((pu - r - u0) * inv), 0, N - 1).astype(np.int64)
    iu1 = np.clip(np.floor((pu + r - u0) * inv), 0, N - 1).astype(np.int64)
    iv0 = np.clip(np.floor((pv - r - v0) * inv), 0, N - 1).astype(np.int64)
    iv1 = np.clip(np.floor((pv + r - v0) * inv), 0, N - 1).astype(np.int64)
    cells, objs = [], []
    for k in range(len(c)):
        vv, uu = np.meshgrid(np.arange(iv0[k], iv1[k] + 1), np.arange(iu0[k], iu1[k] + 1), indexing="ij")
        cells.append((vv * N + uu).ravel())
        objs.append(np.full(vv.size, k))
    cells = np.concatenate(cells) if cells else np.zeros(0, np.int64)
    objs = np.concatenate(objs) if objs else np.zeros(0, np.int64)
    keys_all = -(ph + r)
    off, ob, ke = _csr(N * N, cells, objs, keys_all[objs])
    return off, ob, ke, (e1, e2, u0, v0, inv)


def directional_cell(p, frame, N):
    e1, e2, u0, v0, inv = frame
    iu = np.clip(np.floor((p @ e1 - u0) * inv), 0, N - 1).astype(np.int64)
    iv = np.clip(np.floor((p @ e2 - v0) * inv), 0, N - 1).astype(np.int64)
    return iv * N + iu


def cube_size(n):
    """Cube-map resolution for ``n`` quadrics: about 4 cells per quadric, 8..64 per face."""
    return int(np.clip(round(math.sqrt(4.0 * n / 6.0)), 8, 64))


def grid_size(n, kind="point"):
    """Cells per side for ``n`` quadrics (cube face or directional grid): about 14 n cells per
    face (many.xml, 300 spheres: 64; mean list lengths per shadow ray against N in
    docs/benchmarks.md 5b), a directional grid about 224 n."""
    if kind == "point":
        return int(np.clip(round(math.sqrt(GRID_FACTOR * n)), 8, GRID_MAX))
    return int(np.clip(round(math.sqrt(GRID_FACTOR_DIR * n)), 8, GRID_MAX_DIR))


def scene_extent(P, scene, points):
    """The largest |coordinate| a hit point or one of the light positions ``points`` can have
    (None: unbounded scene)."""
    ext = 0.0
    for spec in P.custom:
        a, b = spec.bounds()
        ab = np.concatenate([np.asarray(a, float), np.asarray(b, float)])
        if not np.all(np.isfinite(ab)):
            return None
        ext = max(ext, float(np.max(np.abs(ab))))
    if P.any_mitsuba_shapes:
        bb = scene.bbox()
        ab = np.array([bb.min[0], bb.min[1], bb.min[2], bb.max[0], bb.max[1], bb.max[2]], dtype=np.float64)
        if not np.all(np.isfinite(ab)):
            return None
        ext = max(ext, float(np.max(np.abs(ab))))
    for pos in points:
        ext = max(ext, float(np.max(np.abs(np.asarray(pos, dtype=np.float64)))))
    return ext


def plan(P, scene):
    """Per analytic light of ``P.lights``: a :class:`LightBuffer` where it pays, else None.

    Only where the quadric shadow rays would walk the BVH (``P.bvh``) and the scene is bounded
    (the margin follows from its extent); per light only when the mean list length of its
    non-empty cells is below the BVH's depth (log2 of the quadric count, at least
    ``MAX_MEAN_LIST``). A directional light's buffer holds in its ``blobs`` the grids of the
    blobs with candidate lists (``BlobSpec.dir_lists``), a :class:`EyeBlobs` where the
    quadrics have none."""
    out = [None] * len(P.lights)
    blobs = _list_blobs(P)
    if P.bvh is None and not blobs:
        return out
    ext = scene_extent(P, scene, [L.position for L in P.lights if isinstance(L, POSITIONED)])
    if ext is None:
        return out
    margin = MARGIN_REL * (1.0 + ext)
    for j, L in enumerate(P.lights):
        if isinstance(L, POSITIONED):
            geom = ("point", np.asarray(L.position, dtype=np.float64))
        elif isinstance(L, DIRECTED):
            w = -np.asarray(L.direction, dtype=np.float64)
            geom = ("dir", w / np.linalg.norm(w))
        else:
            continue
        out[j] = None if P.bvh is None else build_if_it_pays(P.bvh, geom, margin)
        if geom[0] == "dir" and blobs:
            grids = {sp.slot: sp.dir_lists(geom[1], ext, margin) for sp in blobs}
            if out[j] is None:
                out[j] = EyeBlobs(grids)
            else:
                out[j].blobs = grids
    return out


def _list_blobs(P):
    """The blobs of ``P`` that sum over candidate lists (``BlobSpec.uses_lists``)."""
    return [sp for sp in P.custom_unrolled if type(sp).__name__ == "BlobSpec" and sp.uses_lists()]


def plan_eye(P, scene):
    """The light buffer of a perspective camera's eye (Weghorst, Hooper and Greenberg's first-hit
    speed-up in Haines and Greenberg's form) as a grid over its film (:mod:`.eyegrid`): camera
    rays all start there, so per cell of a few pixels the quadrics each ray can meet, nearest
    first (``LightBuffer.nearest``), and in its ``blobs`` the film lists of the blobs with
    candidate lists (:func:`eye_blobs`). None where the camera is not a pinhole, or neither
    exists: an :class:`EyeBlobs` where there are only the blobs' (no BVH or an unbounded
    scene)."""
    if not getattr(P, "perspective", False) or P.lens is not None:
        return None
    eye = np.asarray(P.cam, dtype=np.float64)[:3, 3]
    R = eyegrid.camera_frame(P.cam)
    window = eyegrid.film_window(P.cam, P.x_fov, P.film_size, R)
    blobs = eye_blobs(P, eye, R, window)
    ext = None if P.bvh is None else scene_extent(P, scene, [eye])
    if ext is None:
        return EyeBlobs(blobs) if blobs else None
    margin = MARGIN_REL * (1.0 + ext)
    c, r = quadric_spheres(P.bvh.specs, margin)
    off, ob, ke, frame = eyegrid.lists(eye, R, window, P.film_size, c, r, ANGLE_MARGIN)
    lens = np.diff(off)
    mean = float(lens[lens > 0].mean()) if np.any(lens > 0) else 0.0
    buf = LightBuffer(P.bvh, ("eye", eye, frame), frame[5], off, ob, ke, margin, mean)
    buf.blobs = blobs
    return buf


class EyeBlobs:
    """The eye's or a light's buffer without the quadrics' (:func:`plan_eye`, :func:`plan`):
    the blobs' lists only, ``blobs`` (slot -> ``blob_candidates.BlobFilm`` or
    ``BlobDirGrid``)."""

    def __init__(self, blobs):
        self.blobs = blobs


def eye_blobs(P, eye, R, window):
    """Slot -> ``BlobFilm`` (``BlobSpec.film_lists``) of each blob that sums over candidate lists,
    for camera rays from ``eye`` (frame ``R``, film ``window``): the margin covers the float32
    eye (relative ``MARGIN_REL`` of the largest coordinate of the eye and the blob's bounds)."""
    out = {}
    for sp in _list_blobs(P):
        lo, hi = sp.bounds()
        margin = MARGIN_REL * (1.0 + max(np.abs(eye).max(), np.abs(lo).max(), np.abs(hi).max()))
        out[sp.slot] = sp.film_lists(eye, R, window, P.film_size, margin, ANGLE_MARGIN)
    return out


def build_if_it_pays(bvh, geom, margin, N=None):
    """:func:`build`, kept when the mean list of its non-empty cells is below the BVH walk's
    depth (log2 of the quadric count, at least ``MAX_MEAN_LIST``), else None; a point buffer
    whose sampled estimate (:func:`sampled_mean_list`) is clearly above that is not built."""
    limit = max(MAX_MEAN_LIST, math.log2(max(bvh.n, 2)))
    if geom[0] == "point":
        n_side = grid_size(len(bvh.specs), "point") if N is None else int(N)
        if sampled_mean_list(geom[1], *quadric_spheres(bvh.specs, margin), n_side) > 1.5 * limit:
            return None      # clearly too long: not worth the build
    lb = build(bvh, geom, margin, N=N)
    return lb if lb.mean_list <= limit else None


def build(bvh, geom, margin, N=None):
    """The :class:`LightBuffer` of light ``geom`` (``("point", position)`` or ``("dir", unit
    vector toward the light)``) over the rows of ``bvh``, every bound inflated by ``margin``."""
    specs = bvh.specs                            # BVH rows: entries name the row
    c, r = quadric_spheres(specs, margin)
    N = grid_size(len(specs), geom[0]) if N is None else int(N)
    if geom[0] == "point":
        off, ob, ke = build_point(geom[1], c, r, N)
    else:
        off, ob, ke, frame = build_directional(geom[1], c, r, N)
        geom = ("dir", geom[1], frame)
    lens = np.diff(off)
    mean = float(lens[lens > 0].mean()) if np.any(lens > 0) else 0.0
    return LightBuffer(bvh, geom, N, off, ob, ke, margin, mean)


class LightBuffer:
    """One light's buffer as Dr.Jit tables; ``transmittance`` replaces the BVH's for its
    shadow rays (the same exact test, the same any-hit exit, 3-3-3 transmittance)."""

    def __init__(self, bvh, geom, N, off, ob, ke, margin, mean):
        import mitsuba as mi
        from .util import checked_index, table
        self.bvh = bvh
        self.kind = geom[0]
        self.N = int(N)
        self.margin = float(margin)
        self.mean_list = mean
        self.entries = int(len(ob))
        if self.kind == "point":
            self.pos = [float(x) for x in geom[1]]
        elif self.kind == "eye":                 # eyegrid.build: a grid over the camera's film
            self.pos = [float(x) for x in geom[1]]
            R, u0, v0, su, sv, self.nu, self.nv, self.kappa = geom[2]
            self.frame = [[float(x) for x in row] for row in R]
            self.u0, self.v0, self.su, self.sv = float(u0), float(v0), float(su), float(sv)
        else:
            w, (e1, e2, u0, v0, inv) = geom[1], geom[2]
            self.w, self.e1, self.e2 = ([float(x) for x in v] for v in (w, e1, e2))
            self.u0, self.v0, self.inv = float(u0), float(v0), float(inv)
        # a pair per entry: (BVH row as float bits, key rounded down to float32)
        k32 = ke.astype(np.float32)
        k32 = np.where(k32.astype(np.float64) > ke, np.nextafter(k32, np.float32(-np.inf)), k32)
        pairs = np.zeros((max(len(ob), 1), 2), dtype=np.float32)
        pairs[:len(ob), 0] = ob.astype(np.uint32).view(np.float32)
        pairs[:len(ob), 1] = k32
        # the walk gathers ent[off[cell]:off[cell+1]] and BVH rows ob: both checked when built
        if len(off) and (np.any(np.diff(off) < 0) or off[0] < 0 or off[-1] != len(ob)):
            raise RuntimeError("links1_whitted: light buffer offsets out of order (an internal inconsistency)")
        checked_index(ob, bvh.n, "light buffer entries")
        self.off = table(mi.UInt32, off.astype(np.uint32))
        self.ent = table(mi.Float, pairs)
        self.blobs = {}      # the blobs' film lists (plan_eye)

    def cell(self, o, d, act):
        """The cell of a shadow ray from ``o`` along ``d`` and the key limit of its entries."""
        import drjit as dr
        import mitsuba as mi
        N = self.N
        if self.kind == "point":
            v = -d                                            # from the light toward the point
            ax, ay, az = dr.abs(v.x), dr.abs(v.y), dr.abs(v.z)
            is_x = (ax >= ay) & (ax >= az)
            is_y = ~is_x & (ay >= az)
            major = dr.select(is_x, v.x, dr.select(is_y, v.y, v.z))
            a1 = dr.select(is_x, v.y, dr.select(is_y, v.z, v.x))   # axis + 1
            a2 = dr.select(is_x, v.z, dr.select(is_y, v.x, v.y))   # axis + 2
            axis = dr.select(is_x, mi.UInt32(0), dr.select(is_y, mi.UInt32(1), mi.UInt32(2)))
            face = axis * 2 + dr.select(major < 0, mi.UInt32(1), mi.UInt32(0))
            am = dr.abs(major)
            ok = act & (am > 0)
            am = dr.select(ok, am, 1.0)
            iu = dr.clip(dr.floor((a1 / am + 1.0) * (0.5 * N)), 0.0, N - 1.0)
            iv = dr.clip(dr.floor((a2 / am + 1.0) * (0.5 * N)), 0.0, N - 1.0)
            cell = (face * N + mi.UInt32(iv)) * N + mi.UInt32(iu)
            p = mi.Vector3f(*self.pos)
            lim = dr.norm(o - p) + self.margin
        elif self.kind == "eye":
            cell = eyegrid.film_cell(self, -d)
            ok, lim = act, None
        else:
            e1, e2, w = (mi.Vector3f(*x) for x in (self.e1, self.e2, self.w))
            iu = dr.clip(dr.floor((dr.dot(o, e1) - self.u0) * self.inv), 0.0, N - 1.0)
            iv = dr.clip(dr.floor((dr.dot(o, e2) - self.v0) * self.inv), 0.0, N - 1.0)
            ok = act & dr.isfinite(iu) & dr.isfinite(iv)
            cell = mi.UInt32(iv) * N + mi.UInt32(iu)
            lim = self.margin - dr.dot(o, w)
        return dr.select(ok, cell, 0), lim, ok

    def transmittance(self, o, d, smax, active, cost):
        """Product of shadow_t over the listed quadrics the segment (0, smax) hits, each once,
        in list order (3-3-3); stops at T = 0 (an opaque hit) or at the first entry that
        cannot reach the segment."""
        import drjit as dr
        import mitsuba as mi
        bvh = self.bvh
        n = dr.width(o)
        cell, lim, ok = self.cell(o, d, active)
        k = dr.gather(mi.UInt32, self.off, cell, ok)
        end = dr.gather(mi.UInt32, self.off, cell + 1, ok)
        end = dr.select(ok, end, k)
        T = dr.select(active, mi.Color3f(1.0), mi.Color3f(0.0))
        c = dr.zeros(mi.UInt32, n)
        tmin = mi.Float(0.0)

        def cond(k, c, T):
            return (k < end) & (dr.max(T) > 0)

        def body(k, c, T):
            live = k < end
            e = dr.gather(mi.Array2f, self.ent, k, live)
            go = live & (e.y <= lim)
            q = dr.reinterpret_array(mi.UInt32, e.x)

            tq, _ = bvh.intersect(q, o, d, tmin, smax, go)
            h = go & (tq < smax)
            T = dr.select(h, T * dr.gather(mi.Color3f, bvh.st, q, h), T)
            c = dr.select(go, c + 1, c)
            return dr.select(go, k + 1, end), c, T

        k, c, T = dr.while_loop((k, c, T), cond, body, label="links1_lightbuffer")
        if cost is not None:
            cost += c
        return T

    def nearest(self, o, d, tmin, tmax, active, cost):
        """The nearest quadric hit of rays leaving this buffer's point (a camera's eye) along
        ``d`` within (tmin, tmax): the BVH's ``nearest`` (same exact test, ties to the lower
        slot) over the ray's cell list, which is ordered by how near each bound comes to the
        point: the walk stops at the first entry beyond the best hit. -> (t, row, part, found)."""
        import drjit as dr
        import mitsuba as mi
        from .util import INF
        bvh = self.bvh
        n = dr.width(o)
        cell, _, ok = self.cell(o, -d, active)        # cell() looks from the point along -d
        k = dr.gather(mi.UInt32, self.off, cell, ok)
        end = dr.select(ok, dr.gather(mi.UInt32, self.off, cell + 1, ok), k)
        res = (mi.Float(tmax), dr.zeros(mi.UInt32, n), dr.zeros(mi.UInt32, n), dr.zeros(mi.Bool, n))
        c = dr.zeros(mi.UInt32, n)

        def cond(k, c, res):
            return k < end

        def body(k, c, res):
            live = k < end
            e = dr.gather(mi.Array2f, self.ent, k, live)
            go = live & (e.y <= res[0])      # a hit on the entry lies at least its key away
            res = bvh.offer(dr.reinterpret_array(mi.UInt32, e.x), o, d, tmin, res, go)   # the walk's rule
            return dr.select(go, k + 1, end), dr.select(go, c + 1, c), res

        k, c, res = dr.while_loop((k, c, res), cond, body, label="links1_eyebuffer")
        if cost is not None:
            cost += c
        t, q, part, found = res
        return dr.select(found, t, INF), q, part, found
