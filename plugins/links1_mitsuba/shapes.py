"""links1 shapes for Mitsuba: analytic quadrics and blobs intersected in Dr.Jit by
``links1_whitted``, and bicubic patches tessellated into a real :class:`mitsuba.Mesh`.

Mitsuba 3.9.1 cannot take shapes written in Python, so :mod:`links1_mitsuba.loader` takes
``links1_quadric`` and ``links1_blob`` nodes out of the parsed scene and hands their
:class:`QuadricSpec` / :class:`BlobSpec` to the integrator, which intersects them next to
``scene.ray_intersect``. Numerically stable forms follow docs/numerics.md.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from links1.geometry.shapes import quadric_bounds
from links1.scene.params import blob_centers, clip_plane, default, read, transform_problem

from .registered import check_properties


def table_value(spec, k):
    """Entry ``k`` of ``spec``'s ``"values"`` table (``spec.tables()``), one gather. Outside a
    frozen recording and a symbolic scope (the derivative pass, traced each time: each shape
    reads its ~20-100 constants in every intersection and shadow test, and Dr.Jit copies a
    gather at a literal index from a table into a one-value array at once: 585 copies an
    iteration for the inverse benchmark's blob) the gathered value is kept per table
    (``spec._values_cache``, a :class:`~.util.Hidden` that frozen launches do not walk) and
    reused; a frozen recording gathers anew (what it reads must be its inputs). Called ~1000
    times a derivative pass for a 6-centre blob: the cached case is kept short."""
    import drjit as dr
    tab = spec._tables["values"] if spec._tables is not None else spec.tables()["values"]
    flag, JF = dr.flag, dr.JitFlag
    if flag(JF.FreezingScope) or flag(JF.SymbolicScope):
        import mitsuba as mi
        return dr.gather(mi.Float, tab, k)
    c = spec._values_cache
    if c is not None and c.table is tab:
        v = c.values.get(k)
        if v is not None:
            return v
    else:
        from .util import Hidden
        c = spec._values_cache = Hidden()
        c.table, c.values = tab, {}
    import mitsuba as mi
    v = c.values[k] = dr.gather(mi.Float, tab, k)
    return v

INF = float("inf")
#: Blob march: probe step relative to the largest S (float32 analogue of the core's).
PROBE_REL = 1e-4
#: Largest number of secant refinements of a bracketed blob root.
MAX_REFINE = 24
#: From this many centres on, the ``exact`` solver sums each field evaluation over the ray's
#: candidate centres only (found once per ray with a hierarchy of boxes over the 3S spheres).
LIST_MIN_CENTRES = 24
#: Candidate centres per ray held in registers (the field sum is unrolled over them); a ray
#: crossing more sums over its list in local memory (a loop), beyond :data:`LIST_CAP` over all.
SLOTS = 32
#: Slots summed together; a packet skips a group no lane of it fills.
SLOT_GROUP = 8
#: Candidate centres per ray held in local memory.
LIST_CAP = 64
#: Centres per leaf of the candidate search's hierarchy (at most 15).
LEAF_CENTRES = 4
#: :meth:`BlobSpec._consts` columns in the packets of a centre's row in the candidate
#: search's table: ``(x, y, z, 9S²)``, ``(w, S, 3S, 1/(3S²))``, ``(2|w|/(3S), 2|w|/(3S²),
#: 1/(6S²), −2/(3S²))``.
_ROW_PACKETS = [0, 1, 2, 5, 3, 4, 7, 6, 10, 11, 8, 9]


def _matrix(props, name="to_world"):
    if (name in props):
        return np.array(props[name].matrix, dtype=np.float64).reshape(4, 4)
    return None


def shape_label(plugin: str, name: str, where: str | None = None) -> str:
    """How a message names a links1 shape: ``FILE:LINE: links1_quadric`` where its place in
    the file is known, its id where it has one (never an empty ``''``)."""
    named = f"{plugin} '{name}'" if name else plugin
    return f"{where}: {named}" if where else named


@dataclass
class QuadricSpec:
    """``links1_quadric``: unit sphere or unit infinite cylinder (axis z) in object space,
    mapped by ``to_world``; clip planes ``n·x ≤ h`` in object space; ``capped`` closes the
    cut with the planes (eq. 3.4–3.5)."""

    slot: int
    name: str
    kind: str
    to_world: np.ndarray
    clips: list = field(default_factory=list)
    capped: bool = False
    emission: np.ndarray | None = None
    #: ``FILE:LINE`` of its element (set by the loader), for messages after the load
    where: str | None = field(default=None, repr=False, compare=False)
    _tables: dict | None = field(default=None, init=False, repr=False, compare=False)
    _values_cache: object = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self):
        problem = transform_problem(self.to_world)
        if problem is not None:
            raise ValueError(f"{shape_label('links1_quadric', self.name, self.where)}: {problem}")
        self.inv = np.linalg.inv(self.to_world).tolist()
        self.normal_mat = np.linalg.inv(self.to_world)[:3, :3].T.tolist()  # object → world normals
        self.clips = [(np.asarray(n, dtype=np.float64).tolist(), float(h)) for n, h in self.clips]

    @classmethod
    def from_props(cls, slot, props):
        check_properties("shape", "links1_quadric", props)
        kind = read("links1_quadric", "kind", str(props["kind"]) if ("kind" in props) else None)
        m = _matrix(props)
        clips, k = [], 0
        while (f"clip_{k}" in props):
            v = props[f"clip_{k}"]
            try:
                n, h = clip_plane(k, [float(v[0]), float(v[1]), float(v[2])],
                                  float(props[f"clip_{k}_offset"]) if (f"clip_{k}_offset" in props)
                                  else default("links1_quadric", "clip_offset"))
            except ValueError as exc:
                raise ValueError(f"links1_quadric: {exc}") from None
            clips.append((n, h))
            k += 1
        for key in props.keys():
            if re.fullmatch(r"clip_\d+(_offset)?", key) and int(key.split("_")[1]) >= k:
                raise ValueError(f"links1_quadric: '{key}' without the planes before it")
        capped = read("links1_quadric", "capped", bool(props["capped"]) if ("capped" in props) else None)
        return cls(slot, props.id(), kind, np.eye(4) if m is None else m, clips, capped)

    def bounds(self):
        """World AABB: the core's rule (:func:`links1.geometry.shapes.quadric_bounds`);
        infinite for a cylinder no clip plane bounds along its axis."""
        return quadric_bounds(self.kind, self.to_world, self.clips)

    # ------------------------------------------------------------------ Dr.Jit
    def tables(self):
        """The Dr.Jit table of the constants a ``params.update()`` may change (built once):
        the 3x4 inverse transform, the normal matrix (3x3) and the clip offsets ``h``. The
        kernels gather them instead of taking them as literals, so a new ``to_world`` or
        offset replays the same kernels; the planes' normals, fixed by
        the file, stay literals."""
        if self._tables is None:
            import mitsuba as mi

            from .util import table
            vals = np.concatenate([np.asarray(self.inv)[:3].ravel(), np.asarray(self.normal_mat).ravel(),
                                   [h for _, h in self.clips]])
            self._tables = {"values": table(mi.Float, vals)}
        return self._tables

    def _value(self, k):
        return table_value(self, k)

    def _inv(self):
        return [[self._value(4 * i + j) for j in range(4)] for i in range(3)]

    def _offset(self, j):
        return self._value(21 + j)

    def _to_object(self, o, d):
        import mitsuba as mi
        a = self._inv()
        u = mi.Vector3f(*[a[i][0] * o.x + a[i][1] * o.y + a[i][2] * o.z + a[i][3] for i in range(3)])
        v = mi.Vector3f(*[a[i][0] * d.x + a[i][1] * d.y + a[i][2] * d.z for i in range(3)])
        return u, v

    def _qform(self, x, y):
        import drjit as dr
        if self.kind == "sphere":
            return dr.dot(x, y)
        return x.x * y.x + x.y * y.y

    def _inside_clips(self, x, skip=-1):
        import mitsuba as mi
        ok = mi.Bool(True)
        for j, (n, _) in enumerate(self.clips):
            if j != skip:
                ok &= n[0] * x.x + n[1] * x.y + n[2] * x.z <= self._offset(j)
        return ok

    def intersect(self, o, d, tmin, tmax, active):
        """Nearest ``t`` in (tmin, tmax) (inf on a miss) and the part hit (0 side, 1+j cap j)."""
        import drjit as dr
        import mitsuba as mi
        from .util import quadric_roots
        u, v = self._to_object(o, d)
        hit, tn, tf = quadric_roots(self._qform, u, v)   # eq. (3.5)
        hit &= active
        ok_n = hit & (tn > tmin) & (tn < tmax) & self._inside_clips(u + v * tn)
        ok_f = hit & (tf > tmin) & (tf < tmax) & self._inside_clips(u + v * tf)
        t = dr.select(ok_n, tn, dr.select(ok_f, tf, INF))
        prim = dr.zeros(mi.UInt32, dr.width(t))
        if self.capped:
            for j, (n, _) in enumerate(self.clips):
                den = n[0] * v.x + n[1] * v.y + n[2] * v.z
                num = self._offset(j) - (n[0] * u.x + n[1] * u.y + n[2] * u.z)
                tc = num / dr.select(den != 0, den, 1.0)
                x = u + v * tc
                ok = active & (den != 0) & (tc > tmin) & (tc < tmax) & (tc < t) \
                    & (self._qform(x, x) <= 1.0) & self._inside_clips(x, skip=j)
                t = dr.select(ok, tc, t)
                prim = dr.select(ok, j + 1, prim)
        return t, prim

    def normal(self, o, d, t, prim, reuse=False):
        """Outward world normal at the hit ``o + t d`` (side or cap). ``reuse`` (state of the
        nearest-hit search, see :meth:`BlobSpec.normal`): a quadric's normal is closed-form."""
        import drjit as dr
        import mitsuba as mi
        u, v = self._to_object(o, d)
        x = u + v * t
        n_obj = mi.Vector3f(x.x, x.y, x.z if self.kind == "sphere" else 0.0)
        for j, (n, h) in enumerate(self.clips if self.capped else []):
            n_obj = dr.select(prim == j + 1, mi.Vector3f(*[float(c) for c in n]), n_obj)
        m = [[self._value(12 + 3 * i + j) for j in range(3)] for i in range(3)]
        nw = mi.Vector3f(*[m[i][0] * n_obj.x + m[i][1] * n_obj.y + m[i][2] * n_obj.z for i in range(3)])
        return dr.normalize(nw)

    def uv(self, o, d, t, prim):
        """The core's uv of the hit (links1.geometry.shapes.Quadric.uv): Mitsuba's sphere / cylinder
        parameterisation of the object-space point."""
        u, v = self._to_object(o, d)
        return quadric_uv(u + v * t, 1.0 if self.kind == "sphere" else 0.0)

    def nbytes(self) -> int:
        return 16 * 8 + len(self.clips) * 32


def quadric_uv(x, qz):
    """uv of object-space points ``x`` on a unit sphere (``qz`` = 1) or cylinder (0):
    ``(φ/2π, θ/π)`` or ``(φ/2π, z)``, φ = atan2(y, x) in [0, 2π) (links1.geometry.shapes.Quadric.uv)."""
    import drjit as dr
    import mitsuba as mi
    phi = dr.atan2(x.y, x.x)
    phi = dr.select(phi < 0, phi + 2.0 * math.pi, phi) / (2.0 * math.pi)
    cos_theta = dr.clip(x.z / dr.norm(x), -1.0, 1.0)
    return mi.Point2f(phi, dr.select(qz > 0, dr.acos(cos_theta) / math.pi, x.z))


def _depth_first(lo, hi, first, count):
    """Packed node table of :meth:`BlobSpec._collect`: the nodes of a bvh.py ``build``
    (children of node k at first[k], first[k] + 1) renumbered depth-first, left child first,
    8 floats each (see :meth:`BlobSpec.tables`)."""
    pre, work = [], [0]
    while work:
        k = work.pop()
        pre.append(k)
        if count[k] == 0:
            work += [int(first[k]) + 1, int(first[k])]
    size = {}
    for k in reversed(pre):
        size[k] = 1 if count[k] > 0 else 1 + size[int(first[k])] + size[int(first[k]) + 1]
    out = np.zeros((len(pre), 8))
    for at, k in enumerate(pre):
        skip = at + size[k]
        out[at] = [first[k], 0, 0, skip, 0, 0, 0, count[k]] if count[k] > 0 else [*lo[k], skip, *hi[k], 0]
    return out


@dataclass
class BlobSpec:
    """``links1_blob``: weight-function surface ``Σ w_i P(r_i) = threshold`` (eq. 3.6–3.9).

    ``centers`` (N, 5) rows ``x y z w S`` in object space; ``to_world`` optional. The
    ``exact`` solver steps along the ray with the Lipschitz/curvature bound of
    docs/numerics.md (never jumps over a root, Newton-fast near one); ``paper`` samples the
    span ``samples`` times per crossed centre and solves a quadratic per segment. With
    :data:`LIST_MIN_CENTRES` centres or more, ``exact`` sums each field evaluation over the
    ray's candidate centres only (its line crosses their 3S sphere; the others add exact
    zeros), found once per ray (:meth:`_collect`), as the core does."""

    slot: int
    name: str
    centers: np.ndarray
    threshold: float
    solver: str = "exact"
    samples: int = 8
    to_world: np.ndarray | None = None
    emission: np.ndarray | None = None
    max_steps: int = 256
    #: ``FILE:LINE`` of its element (set by the loader), for messages after the load
    where: str | None = field(default=None, repr=False, compare=False)
    _tables: dict | None = field(default=None, init=False, repr=False, compare=False)
    _values_cache: object = field(default=None, init=False, repr=False, compare=False)
    # the last nearest-hit search's ray (o, d) and candidate lists, for :meth:`normal`
    _line: tuple | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self):
        m = np.eye(4) if self.to_world is None else self.to_world
        self.inv = np.linalg.inv(m).tolist()
        self.normal_mat = np.linalg.inv(m)[:3, :3].T.tolist()
        self.centers = np.asarray(self.centers, dtype=np.float64)

    @classmethod
    def from_props(cls, slot, props):
        check_properties("shape", "links1_blob", props)
        try:
            c = blob_centers(str(props["centers"]) if ("centers" in props) else "")
        except ValueError as exc:
            raise ValueError(f"links1_blob: {exc}") from None
        thr = read("links1_blob", "threshold", float(props["threshold"]) if ("threshold" in props) else None)
        solver = read("links1_blob", "solver", str(props["solver"]) if ("solver" in props) else None)
        samples = read("links1_blob", "samples", int(props["samples"]) if ("samples" in props) else None)
        m = _matrix(props)
        if m is not None and (problem := transform_problem(m)) is not None:
            raise ValueError(f"links1_blob: {problem}")
        return cls(slot, props.id(), c, thr, solver, samples, _matrix(props))

    def bounds(self):
        c = self.centers
        lo = (c[:, :3] - 3 * c[:, 4:5]).min(0)
        hi = (c[:, :3] + 3 * c[:, 4:5]).max(0)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        m = np.eye(4) if self.to_world is None else self.to_world
        w = corners @ m[:3, :3].T + m[:3, 3]
        return w.min(0), w.max(0)

    def nbytes(self) -> int:
        return int(self.centers.nbytes) + 64

    # ------------------------------------------------------------------ Dr.Jit
    def _consts(self):
        """Per-centre constants, one row each: x y z w S 9S² 1/(3S²) 3S 1/(6S²) −2/(3S²)
        2|w|/(3S) 2|w|/(3S²) (float64, rounded once to float32 wherever they are used)."""
        x, y, z, w, S = self.centers.T
        inv3s2 = 1.0 / (3.0 * S * S)
        return np.c_[x, y, z, w, S, 9.0 * S * S, inv3s2, 3.0 * S, 0.5 * inv3s2, -2.0 * inv3s2,
                     np.abs(w) * 2.0 / (3.0 * S), np.abs(w) * 2.0 / (3.0 * S * S)]

    def _values(self):
        """The constants a ``params.update()`` may change, one flat float64 row: the
        :meth:`_consts` rows (12 per centre), the 3x4 inverse transform, the normal matrix
        (3x3), the threshold and the march's probe step. The kernels gather them from a
        Dr.Jit table (:meth:`tables`, ``"values"``) instead of taking them as literals, so new
        values (same count) replay the same kernels; float32 rounding of
        each is that of the literal it replaces (same bits)."""
        probe = PROBE_REL * float(self.centers[:, 4].max())
        return np.concatenate([self._consts().ravel(), np.asarray(self.inv)[:3].ravel(),
                               np.asarray(self.normal_mat).ravel(), [float(self.threshold), probe]])

    def _value(self, k):
        """Entry ``k`` of the ``"values"`` table (:meth:`_values`): :func:`table_value`."""
        return table_value(self, k)

    def _crow(self, i):
        """Centre ``i``'s :meth:`_consts` row, gathered (12 Floats)."""
        return [self._value(12 * i + c) for c in range(12)]

    def _mats(self):
        """The inverse transform's 3x4 rows and the normal matrix's 3x3, gathered."""
        base = 12 * len(self.centers)
        a = [[self._value(base + 4 * i + j) for j in range(4)] for i in range(3)]
        m = [[self._value(base + 12 + 3 * i + j) for j in range(3)] for i in range(3)]
        return a, m

    def _threshold(self):
        return self._value(12 * len(self.centers) + 21)

    def _probe(self):
        return self._value(12 * len(self.centers) + 22)

    def _unit_ray(self, o, d):
        """Object-space origin, unit direction and the length scale of ``d``."""
        import drjit as dr
        import mitsuba as mi
        a = self._mats()[0]
        u = mi.Vector3f(*[a[i][0] * o.x + a[i][1] * o.y + a[i][2] * o.z + a[i][3] for i in range(3)])
        v = mi.Vector3f(*[a[i][0] * d.x + a[i][1] * d.y + a[i][2] * d.z for i in range(3)])
        scale = dr.norm(v)
        return u, v / scale, scale

    @staticmethod
    def _chord(u, v, row, enter, leave, Lb, Gb):
        """One centre against the ray's line: (τ, h², the span and the derivative bounds
        updated where the line crosses its 3S sphere)."""
        import drjit as dr
        import mitsuba as mi
        x, y, z, _, _, R2, _, _, _, _, lb, gb = row
        rel = mi.Vector3f(x, y, z) - u
        tau = dr.dot(rel, v)
        h2 = dr.squared_norm(dr.cross(rel, v))   # no cancellation (docs/numerics.md)
        cross = h2 < R2
        half = dr.sqrt(dr.maximum(R2 - h2, 0.0))
        enter = dr.select(cross, dr.minimum(enter, tau - half), enter)
        leave = dr.select(cross, dr.maximum(leave, tau + half), leave)
        return tau, h2, enter, leave, Lb + dr.select(cross, lb, 0.0), Gb + dr.select(cross, gb, 0.0)

    def _setup(self, o, d, tmin, tmax):
        """Object-space unit ray and per-centre (τ, h², constants) plus the span and bounds."""
        import drjit as dr
        import mitsuba as mi
        u, v, scale = self._unit_ray(o, d)
        s_lo, s_hi = tmin * scale, tmax * scale
        enter, leave = mi.Float(INF), mi.Float(-INF)
        Lb, Gb = mi.Float(0.0), mi.Float(0.0)
        per = []
        for i in range(len(self.centers)):
            row = self._crow(i)
            tau, h2, enter, leave, Lb, Gb = self._chord(u, v, row, enter, leave, Lb, Gb)
            per.append((tau, h2, *row[3:5], *row[6:10]))
        start = dr.maximum(s_lo, enter)
        end = dr.minimum(s_hi, leave)
        return scale, per, start, end, Lb, Gb

    # ---------------------------------------------- candidate centres (many centres)
    def uses_lists(self) -> bool:
        """Whether the ``exact`` solver sums over per-ray candidate lists (many centres)."""
        return self.solver == "exact" and len(self.centers) >= LIST_MIN_CENTRES

    def tables(self):
        """Dr.Jit tables of the blob, built once: ``"values"``, the constants of
        :meth:`_values` (every blob); and with :data:`LIST_MIN_CENTRES` centres or more
        those of the candidate search: a hierarchy of boxes over the centres' 3S spheres (up to
        :data:`LEAF_CENTRES` centres per leaf, bvh.py's SAH build) in depth-first order, and
        the constants of :meth:`_consts` in its leaf order, so that the walk meets the
        candidates in increasing row. Both are packets of 4 floats, read with packet gathers:
        a centre's row as ``(x, y, z, 9S²)`` (all the line test reads), ``(w, S, 3S,
        1/(3S²))`` and ``(2|w|/(3S), 2|w|/(3S²), 1/(6S²), −2/(3S²))``; an inner node as
        ``(lo, skip)`` and ``(hi, 0)``, a leaf as ``(first, 0, 0, skip)`` and ``(0, 0, 0,
        count)``, where ``skip`` is the node after its subtree (small integers, exact in
        float32)."""
        if self._tables is None:
            import mitsuba as mi

            from .util import table
            self._tables = {"values": table(mi.Float, self._values())}
        if self.uses_lists() and "rows" not in self._tables:
            import mitsuba as mi

            from .bvh import build
            from .util import table
            k = self._consts()
            c, R = k[:, :3], k[:, 7]
            # padded so that a sphere the float32 line test finds crossed is never culled
            pad = (1e-3 * R + 1e-5 * np.abs(c).max(1))[:, None]
            order, nlo, nhi, first, count = build(c - R[:, None] - pad, c + R[:, None] + pad,
                                                  leaf=LEAF_CENTRES)
            self._tables.update(rows=table(mi.Float, k[order][:, _ROW_PACKETS]),
                                nodes=table(mi.Float, _depth_first(nlo, nhi, first, count)))
        return self._tables

    def _row(self, idx, act):
        """Row ``idx`` of the leaf-ordered constants, in :meth:`_consts`'s column order
        (three packet gathers; a packet no caller reads is never loaded)."""
        import drjit as dr
        import mitsuba as mi
        tab = self.tables()["rows"]
        vals = [None] * 12
        for j in range(3):
            pk = dr.gather(mi.Array4f, tab, 3 * idx + j, act)
            for col, v in zip(_ROW_PACKETS[4 * j:4 * j + 4], (pk.x, pk.y, pk.z, pk.w)):
                vals[col] = v
        return vals

    def _collect(self, hit_box, hit_centre, active):
        """Each lane's candidate centres (rows of the leaf-ordered table, increasing) in local
        memory (up to :data:`LIST_CAP`), their number, and whether there were more (the lane
        then sums over all centres).
        ``hit_box(lo, hi, act)`` culls subtrees, ``hit_centre(row, act)`` decides a leaf's
        centres. Stackless: the nodes are in depth-first order, so a crossed inner node goes
        on to the next node (its left child) and anything else to the node after its
        subtree; the walk ends past the last node."""
        import drjit as dr
        import mitsuba as mi
        tab = self.tables()["nodes"]
        end = dr.width(tab) // 8
        n = dr.width(active)
        lst = dr.alloc_local(mi.UInt32, LIST_CAP + 1, mi.UInt32(0))
        k = dr.select(active, mi.UInt32(0), mi.UInt32(end))
        cnt = dr.zeros(mi.UInt32, n)
        ovf = dr.zeros(mi.Bool, n)

        def cond(k, lst, cnt, ovf):
            return k < end

        def body(k, lst, cnt, ovf):
            act = k < end
            lo = dr.gather(mi.Array4f, tab, 2 * k, act)
            hi = dr.gather(mi.Array4f, tab, 2 * k + 1, act)
            num = mi.UInt32(hi.w)
            leaf = act & (num > 0)
            fst = mi.UInt32(dr.select(leaf, lo.x, 0.0))
            for i in range(LEAF_CENTRES):
                take = leaf & (i < num)
                take &= hit_centre(fst + i, take)
                add = take & (cnt < LIST_CAP)
                ovf = ovf | (take & ~add)
                # unmasked (a masked write costs a branch per lane): the entry at cnt is kept
                # only where cnt moves on, and a full list writes to its spare last entry
                lst.write(fst + i, dr.minimum(cnt, LIST_CAP))
                cnt = dr.select(add, cnt + 1, cnt)
            down = hit_box([lo.x, lo.y, lo.z], [hi.x, hi.y, hi.z], act & ~leaf)
            k = dr.select(down, k + 1, mi.UInt32(lo.w))
            return k, lst, cnt, ovf

        _, lst, cnt, ovf = dr.while_loop((k, lst, cnt, ovf), cond, body, label="links1_blob_collect")
        return lst, cnt, ovf

    def _each(self, lst, cnt, ovf, state, fn):
        """Loop ``state = fn(row, state)`` over the lane's candidates in increasing row
        (over all centres where the list overflowed)."""
        import drjit as dr
        import mitsuba as mi
        total = dr.select(ovf, mi.UInt32(len(self.centers)), cnt)

        def cond(j, lst, *st):
            return j < total

        def body(j, lst, *st):
            act = j < total
            idx = dr.select(ovf, j, lst.read(j, act & ~ovf))
            return (j + 1, lst, *fn(self._row(idx, act), *st))

        out = dr.while_loop((dr.zeros(mi.UInt32, dr.width(cnt)), lst, *state), cond, body, label="links1_blob_sum")
        return out[2:]

    def _line_candidates(self, u, v, active):
        """:meth:`_collect` for the line ``u + s v``: the centres whose 3S sphere it crosses,
        the only ones whose term ``w_i P(r_i)`` of ``W`` (eq. 3.6/3.7) can be non-zero on the
        line (``P = 0`` from ``r = 3S`` on, eq. 3.9); the root of ``W = T`` (eq. 3.8) is
        sought over their span."""
        import drjit as dr
        import mitsuba as mi
        from .bvh import slab
        inv_v = mi.Vector3f(1.0 / v.x, 1.0 / v.y, 1.0 / v.z)

        def hit_box(lo, hi, act):
            return slab(lo, hi, u, inv_v, mi.Float(-INF), mi.Float(INF), act)[0]

        def hit_centre(idx, act):
            row = self._row(idx, act)
            rel = mi.Vector3f(*row[:3]) - u
            return dr.squared_norm(dr.cross(rel, v)) < row[5]

        return self._collect(hit_box, hit_centre, active)

    def _setup_lists(self, u, v, active):
        """The candidate lists of the rays' lines, the first :data:`SLOTS` of them in
        registers, and the span and the bounds over them: the sums of :meth:`_setup`, over
        the centres that add non-zero terms, in the hierarchy's leaf order (so the same to
        float32 rounding, not bit for bit)."""
        import drjit as dr
        import mitsuba as mi
        n = dr.width(active)
        lst, cnt, ovf = self._line_candidates(u, v, active)
        many = ovf | (cnt > SLOTS)
        st = (dr.full(mi.Float, INF, n), dr.full(mi.Float, -INF, n), dr.zeros(mi.Float, n), dr.zeros(mi.Float, n))
        slots = []
        for g in range(0, SLOTS, SLOT_GROUP):
            def group(*st, g=g):
                out = []
                for j in range(g, g + SLOT_GROUP):
                    # an empty slot reads zeros: no crossing, and w = 0 adds exactly zero
                    row = self._row(lst.read(j), (j < cnt) & ~many)
                    tau, h2, *st = self._chord(u, v, row, *st)
                    out += [tau, h2, *row[3:5], *row[6:10]]
                return (*st, *out)

            def empty(*st):   # slots no lane of the packet fills: zeros, as an empty slot
                return (*st, *[dr.zeros(mi.Float, n) for _ in range(8 * SLOT_GROUP)])
            # the next slots only in packets where some lane has that many candidates
            res = group(*st) if g == 0 else dr.if_stmt(st, (cnt > g) & ~many, group, empty)
            st = res[:4]
            slots += [tuple(res[4 + 8 * j:12 + 8 * j]) for j in range(SLOT_GROUP)]

        def span(row, enter, leave, Lb, Gb):
            return self._chord(u, v, row, enter, leave, Lb, Gb)[2:]

        def by_list(*st):
            return self._each(lst, cnt, ovf, st, span)

        st = dr.if_stmt(tuple(st), many, by_list, lambda *st: st)
        return (lst, cnt, ovf, many, slots), *st

    def _field_lists(self, u, v, cands, s):
        """:meth:`_field` over the lane's candidate centres (the same terms, in leaf order)."""
        import drjit as dr
        import mitsuba as mi
        lst, cnt, ovf, many, slots = cands
        W, dW = BlobSpec._field(slots[:SLOT_GROUP], s)
        for g in range(SLOT_GROUP, len(slots), SLOT_GROUP):
            # the next slots only in packets where some lane has that many candidates
            def more(W, dW, g=g):
                return BlobSpec._field(slots[g:g + SLOT_GROUP], s, W, dW)
            W, dW = dr.if_stmt((W, dW), (cnt > g) & ~many, more, lambda W, dW: (W, dW))

        def term(row, W, dW):
            tau, h2 = self._chord(u, v, row, 0.0, 0.0, 0.0, 0.0)[:2]
            Wk, dWk = BlobSpec._term(s, tau, h2, *row[3:5], *row[6:10])
            return W + Wk, dW + dWk

        def by_list(W, dW):
            return self._each(lst, cnt, ovf, (dr.zeros(mi.Float, dr.width(s)), dr.zeros(mi.Float, dr.width(s))), term)

        return dr.if_stmt((W, dW), many, by_list, lambda W, dW: (W, dW))

    @staticmethod
    def _term(s, tau, h2, w, S, inv3s2, S3, half, m2):
        """One centre's ``w P(r)`` and ``w dP/ds`` at ``s`` (eq. 3.9); the constants are the
        centre's row of :meth:`_consts` (Python floats or gathered Floats: the same float32
        values, so both give the same bits)."""
        import drjit as dr
        dt = s - tau
        r2 = dr.square(dt) + h2
        r = dr.sqrt(r2)
        inner = r < S
        outer = r < S3
        P = dr.select(inner, 1.0 - r2 * inv3s2, dr.select(outer, dr.square(r - S3) * half, 0.0))  # eq. (3.9)
        g = dr.select(inner, m2, dr.select(outer, (1.0 - S3 / dr.maximum(r, 1e-30)) * inv3s2, 0.0))
        return w * P, w * g * dt

    @staticmethod
    def _field(per, s, W=0.0, dW=0.0):
        """W(s) and dW/ds along the unit object-space ray (eq. 3.6–3.9), the terms of
        ``per`` added in order to ``W``, ``dW``."""
        import mitsuba as mi
        W = mi.Float(W)
        dW = mi.Float(dW)
        for tau, h2, *c in per:
            Wk, dWk = BlobSpec._term(s, tau, h2, *c)
            W += Wk
            dW += dWk
        return W, dW

    def intersect(self, o, d, tmin, tmax, active, cost=None, any_hit=False):
        """Nearest root of ``W = threshold`` in (tmin, tmax): ``(t, prim=0)``; ``cost`` += evaluations.
        ``any_hit`` (shadow rays): the first bracketed root is enough, its exact place is not
        refined (the returned t is then a point past the root, still inside the interval)."""
        import drjit as dr
        import mitsuba as mi
        if self.uses_lists():
            u, v, scale = self._unit_ray(o, d)
            cands, enter, leave, Lb, Gb = self._setup_lists(u, v, active)
            # kept for the normal at this ray's hit (raytree.py calls normal(o, d, ...) next)
            self._line = None if any_hit else (o, d, cands[:3])
            start, end = dr.maximum(tmin * scale, enter), dr.minimum(tmax * scale, leave)
            per = None

            def field_at(s):
                return self._field_lists(u, v, cands, s)
        else:
            scale, per, start, end, Lb, Gb = self._setup(o, d, tmin, tmax)

            def field_at(s):
                return BlobSpec._field(per, s)
        s_lo, s_hi = tmin * scale, tmax * scale   # the segment, as in _setup
        T = self._threshold()
        run = active & (start < end)
        eps = 1e-6 * max(self.threshold, 1.0)

        def solve(start, end, Lb, Gb):
            if self.solver == "paper":
                return self._paper(per, s_lo, s_hi, run)
            W0, dW0 = field_at(start)
            inside = (W0 > T) | ((W0 == T) & (dW0 > 0))
            sgn = dr.select(inside, -1.0, 1.0)
            n_eval = dr.select(run, mi.UInt32(1), mi.UInt32(0))
            return self._exact(field_at, start, end, sgn, run, n_eval, Lb, Gb, eps, any_hit)

        def skip(start, end, Lb, Gb):
            return dr.full(mi.Float, INF, dr.width(start)), dr.zeros(mi.UInt32, dr.width(start))

        # symbolic conditional: a packet of rays that all miss the centres' spheres skips the solver
        t_obj, n_eval = dr.if_stmt((start, end, Lb, Gb), run, solve, skip)
        if cost is not None:
            cost += n_eval
        t = t_obj / scale
        return dr.select(dr.isfinite(t_obj), t, INF), dr.zeros(mi.UInt32, dr.width(t))

    def _exact(self, field_at, start, end, sgn, run, n_eval, Lb, Gb, eps, any_hit=False):
        """March with steps that never jump over a root (docs/numerics.md, step bounds); once the step
        falls below ``probe`` it probes ``max(2h, probe)`` ahead; a sign change brackets the
        root, refined by secant steps with the Illinois safeguard (as the core). A ray that
        grazes the surface never brackets a root: a miss, as in the float64 core."""
        import drjit as dr
        import mitsuba as mi
        T = self._threshold()
        probe = self._probe()
        Lb = dr.maximum(Lb, 1e-30)
        Gb = dr.maximum(Gb, 1e-30)
        max_steps = self.max_steps
        n = dr.width(start)
        s = mi.Float(start)
        s_prev = mi.Float(start)
        f_prev = dr.full(mi.Float, 1.0, n)
        found = dr.zeros(mi.Bool, n)
        it = dr.zeros(mi.UInt32, n)

        def cond(s, s_prev, f_prev, found, run, it, n_eval):
            return run

        def body(s, s_prev, f_prev, found, run, it, n_eval):
            W, dW = field_at(s)
            n_eval += dr.select(run, mi.UInt32(1), 0)
            F = sgn * (T - W)
            Fp = -sgn * dW
            root = run & (F <= 0) & (it > 0)
            found = found | root
            Fpos = dr.maximum(F, 0.0)
            disc = dr.safe_sqrt(dr.square(Fp) + 2.0 * Gb * Fpos)
            h2 = dr.select(Fp < 0, 2.0 * Fpos / dr.maximum(disc - Fp, 1e-30), (Fp + disc) / Gb)
            h = dr.maximum(Fpos / Lb, h2)
            step = dr.select(h < probe, dr.maximum(2.0 * h, probe), h)
            it += 1
            go = run & ~root
            s_prev = dr.select(go, s, s_prev)
            f_prev = dr.select(go, F, f_prev)
            s = dr.select(go, s + step, s)
            run = go & (s < end) & (it < max_steps)
            return s, s_prev, f_prev, found, run, it, n_eval

        s, s_prev, f_prev, found, run, it, n_eval = dr.while_loop(
            (s, s_prev, f_prev, found, run, it, n_eval), cond, body)
        if any_hit:
            return dr.select(found, s, INF), n_eval
        # bracket [a, b] with F(a) > 0 >= F(b): secant steps with the Illinois safeguard
        a, b = mi.Float(s_prev), mi.Float(s)
        fa = f_prev
        Wb, _ = field_at(b)
        fb = sgn * (T - Wb)
        last = dr.zeros(mi.Int32, n)
        k = dr.zeros(mi.UInt32, n)
        act = found & (fb != 0) & (a < b)

        def cond2(a, b, fa, fb, last, k, act, n_eval):
            return act

        def body2(a, b, fa, fb, last, k, act, n_eval):
            x = dr.clip(a + fa * ((b - a) / (fa - fb)), a, b)
            W, _ = field_at(x)
            n_eval += dr.select(act, mi.UInt32(1), 0)
            fx = sgn * (T - W)
            up = fx > 0
            na = dr.select(up, x, a)
            nb = dr.select(up, b, x)
            nfa = dr.select(up, fx, dr.select(last == -1, 0.5 * fa, fa))
            nfb = dr.select(up, dr.select(last == 1, 0.5 * fb, fb), fx)
            a = dr.select(act, na, a)
            b = dr.select(act, nb, b)
            fa = dr.select(act, nfa, fa)
            fb = dr.select(act, nfb, fb)
            last = dr.select(act, dr.select(up, 1, -1), last)
            k += 1
            act = act & (fx != 0) & (b - a > 2e-7 * (1.0 + dr.abs(b))) & (k < MAX_REFINE)
            return a, b, fa, fb, last, k, act, n_eval

        a, b, fa, fb, last, k, act, n_eval = dr.while_loop(
            (a, b, fa, fb, last, k, act, n_eval), cond2, body2)
        # final estimate: secant on the bracket (b itself when F(b) == 0)
        x = dr.select(fb == 0, b, dr.clip(a + fa * ((b - a) / dr.select(fa != fb, fa - fb, 1.0)), a, b))
        return dr.select(found, x, INF), n_eval

    def _paper(self, per, s_lo, s_hi, run):
        """The paper's span sampling and piecewise quadratic interpolation (3-2-3), the
        float64 core's algorithm (links1/geometry/blob.py ``_solve_paper``) in float32.

        Every positive centre's chord (cut to the ray segment) gets ``samples`` evenly spaced
        points (``linspace(0, 1, samples)``); the samples of all chords, in increasing order
        (a k-way merge of the chords' already sorted samples), are taken in triples (0,1,2),
        (2,3,4), ...; the quadratic through each (divided differences, Newton form) gives the
        first root of ``W* = T`` on ``[t_2j, t_2j+2]``. With an even count and no root yet,
        the last interval uses the triple (c-3, c-2, c-1); two samples give a line. One
        field evaluation per sample (the core's count)."""
        import drjit as dr
        import mitsuba as mi
        T = self._threshold()
        M = int(self.samples)
        step = float(np.linspace(0.0, 1.0, M)[1]) if M > 1 else 0.0
        n = dr.width(s_lo)
        hi_cap = dr.minimum(s_hi, float(np.finfo(np.float32).max))
        bases, widths, nxs, js = [], [], [], []
        cnt = dr.zeros(mi.UInt32, n)
        for i, (tau, h2, w, S, *_) in enumerate(per):
            if not self.centers[i, 3] > 0:   # the sign of a weight is structure (a literal)
                continue
            R2 = self._value(12 * i + 5)      # 9S² (_consts)
            half = dr.sqrt(dr.maximum(R2 - h2, 0.0))
            cross = h2 < R2
            lo = dr.maximum(dr.select(cross, tau - half, INF), s_lo)
            hi = dr.minimum(dr.select(cross, tau + half, -INF), hi_cap)
            valid = run & (lo < hi)
            base = dr.select(valid, lo, INF)
            width = dr.select(valid, hi - lo, 0.0)
            bases.append(base)
            widths.append(width)
            nxs.append(mi.Float(base))                       # next sample of this chord
            js.append(dr.zeros(mi.UInt32, n))                # its index in 0..M-1
            cnt += dr.select(valid, mi.UInt32(M), 0)
        if not bases:
            return dr.full(mi.Float, INF, n), dr.zeros(mi.UInt32, n)

        i = dr.zeros(mi.UInt32, n)
        x0, x1, x2 = dr.zeros(mi.Float, n), dr.zeros(mi.Float, n), dr.zeros(mi.Float, n)
        y0, y1, y2 = dr.zeros(mi.Float, n), dr.zeros(mi.Float, n), dr.zeros(mi.Float, n)
        best = dr.full(mi.Float, INF, n)
        active = cnt > 0

        def cond(i, nxs, js, x0, x1, x2, y0, y1, y2, best, active):
            return active

        def body(i, nxs, js, x0, x1, x2, y0, y1, y2, best, active):
            # the smallest pending sample (k-way merge of the chords' sorted samples)
            t = nxs[0]
            for nx in nxs[1:]:
                t = dr.minimum(t, nx)
            taken = dr.zeros(mi.Bool, dr.width(t))
            nxs, js = list(nxs), list(js)
            for k in range(len(nxs)):
                pick = active & ~taken & (nxs[k] == t)
                taken = taken | pick
                j = js[k] + 1
                f = dr.select(j >= M - 1, 1.0, mi.Float(j) * step)
                nx = dr.select(j < M, bases[k] + widths[k] * f, INF)
                nxs[k] = dr.select(pick, nx, nxs[k])
                js[k] = dr.select(pick, j, js[k])
            W, _ = BlobSpec._field(per, t)
            y = W - T
            # sliding window of the last three samples
            x0, x1, x2 = x1, x2, mi.Float(t)
            y0, y1, y2 = y1, y2, y
            tri = active & (i >= 2) & ((i & 1) == 0) & (best == INF)
            r = _quad_root32(x0, x1, x2, y0, y1, y2, x0, x2)
            best = dr.select(tri, r, best)
            i = i + dr.select(active, mi.UInt32(1), 0)
            active = active & (i < cnt)
            return i, nxs, js, x0, x1, x2, y0, y1, y2, best, active

        i, nxs, js, x0, x1, x2, y0, y1, y2, best, active = dr.while_loop(
            (i, nxs, js, x0, x1, x2, y0, y1, y2, best, active), cond, body)
        # tail of an even count: the last interval [t_c-2, t_c-1] (two samples: a line)
        tail = (cnt >= 2) & ((cnt & 1) == 0) & (best == INF)
        line = cnt == 2
        # (c-3, c-2, c-1) on [t_c-2, t_c-1]; two samples: (t0, t1, t1) on [t0, t1]
        tx0, tx1 = dr.select(line, x1, x0), dr.select(line, x2, x1)
        ty0, ty1 = dr.select(line, y1, y0), dr.select(line, y2, y1)
        r = _quad_root32(tx0, tx1, x2, ty0, ty1, y2, x1, x2)
        best = dr.select(tail, r, best)
        ok = dr.isfinite(best) & (best > s_lo) & (best < s_hi)
        return dr.select(ok, best, INF), cnt

    def normal(self, o, d, t, prim, reuse=False):
        """Outward normal ``-∇W/|∇W|`` (fallback ``-d`` where the gradient vanishes).
        ``reuse``: sum over the candidates of the last nearest-hit :meth:`intersect` of the same
        ``o``, ``d`` (no walk); only for a caller that evaluates the normal in the kernel of
        that search (its candidate list is a local array of that kernel), as raytree.py does."""
        import drjit as dr
        import mitsuba as mi
        a, m = self._mats()
        p = o + d * t
        x = mi.Vector3f(*[a[i][0] * p.x + a[i][1] * p.y + a[i][2] * p.z + a[i][3] for i in range(3)])

        def grad(row, g):
            cx, cy, cz, w, S, _, inv3s2, S3, _, m2 = row[:10]
            rel = x - mi.Vector3f(cx, cy, cz)
            r = dr.norm(rel)
            gr = dr.select(r < S, m2, dr.select(r < S3, (1.0 - S3 / dr.maximum(r, 1e-30)) * inv3s2, 0.0))
            return (g + rel * (w * gr),)

        line, self._line = self._line, None
        if reuse and self.uses_lists() and line is not None and line[0] is o and line[1] is d:
            # the nearest-hit search's candidates of this ray: every centre whose 3S sphere
            # its line crosses, so every centre that adds a non-zero term at the hit point,
            # in the same increasing row as the point walk below (the others add exact zeros)
            # (only where there is a hit: a ray that misses sums nothing)
            lst, cnt, ovf = line[2]
            hit = dr.isfinite(t)
            g, = self._each(lst, dr.select(hit, cnt, 0), ovf & hit, (dr.zeros(mi.Vector3f, dr.width(x)),), grad)
        elif self.uses_lists():
            # the centres whose 3S sphere holds the point (the others add exactly zero)
            def hit_box(lo, hi, act):
                return act & (lo[0] <= x.x) & (x.x <= hi[0]) & (lo[1] <= x.y) & (x.y <= hi[1]) \
                    & (lo[2] <= x.z) & (x.z <= hi[2])

            def hit_centre(idx, act):
                # the point within the 3S sphere (padded: a term r < 3S in float32 is kept)
                row = self._row(idx, act)
                return dr.squared_norm(x - mi.Vector3f(*row[:3])) < row[5] * (1.0 + 1e-4)

            cands = self._collect(hit_box, hit_centre, dr.isfinite(t))
            g, = self._each(*cands, (dr.zeros(mi.Vector3f, dr.width(x)),), grad)
        else:
            g = mi.Vector3f(0.0)
            for i in range(len(self.centers)):
                g, = grad(self._crow(i), g)
        nw = -mi.Vector3f(*[m[i][0] * g.x + m[i][1] * g.y + m[i][2] * g.z for i in range(3)])
        ln = dr.norm(nw)
        return dr.select(ln > 1e-20, nw / dr.maximum(ln, 1e-30), -d)


def _quad_root32(x0, x1, x2, y0, y1, y2, a, b):
    """Smallest t in [a, b] where the quadratic through (x_i, y_i) is zero (inf if none):
    links1/geometry/blob.py ``_quad_root``, the same arithmetic in Dr.Jit float32."""
    import drjit as dr
    d01 = dr.select(x1 != x0, (y1 - y0) / dr.select(x1 != x0, x1 - x0, 1.0), 0.0)
    d12 = dr.select(x2 != x1, (y2 - y1) / dr.select(x2 != x1, x2 - x1, 1.0), d01)
    c2 = dr.select(x2 != x0, (d12 - d01) / dr.select(x2 != x0, x2 - x0, 1.0), 0.0)
    # Newton form around a: f(a + s) = f(a) + f'(a) s + c2 s^2.
    fa = y0 + (a - x0) * (d01 + c2 * (a - x1))
    fpa = d01 + c2 * ((a - x0) + (a - x1))
    disc = fpa * fpa - 4.0 * c2 * fa
    sq = dr.sqrt(dr.maximum(disc, 0.0))
    q = -0.5 * (fpa + dr.copysign(sq, fpa))
    r1 = dr.select(q != 0, fa / dr.select(q != 0, q, 1.0), dr.select(fa == 0, 0.0, INF))
    r2 = dr.select(c2 != 0, q / dr.select(c2 != 0, c2, 1.0), INF)
    lin = dr.select(fpa != 0, -fa / dr.select(fpa != 0, fpa, 1.0), dr.select(fa == 0, 0.0, INF))
    quad = c2 != 0
    r1 = dr.select(quad, dr.select(disc >= 0, r1, INF), lin)
    r2 = dr.select(quad & (disc >= 0), r2, INF)
    L = b - a
    tol = 1e-12 * dr.abs(L)
    ok1 = (r1 >= -tol) & (r1 <= L + tol)
    ok2 = (r2 >= -tol) & (r2 <= L + tol)
    s = dr.minimum(dr.select(ok1, r1, INF), dr.select(ok2, r2, INF))
    s = dr.clip(s, 0.0, dr.select(dr.isfinite(L), L, 0.0))
    return dr.select(ok1 | ok2, a + s, INF)


# ---------------------------------------------------------------------- bicubic patches
def tessellate_bicubic(props, base_dir=None):
    """Vertices, faces and normals of a ``links1_bicubic`` node, with ``links1.geometry.meshes``."""
    import os
    try:
        from links1.geometry import meshes
    except ImportError as exc:  # pragma: no cover
        raise RuntimeError("links1_bicubic needs links1.geometry.meshes (tessellation)") from exc
    check_properties("shape", "links1_bicubic", props)
    has_file = ("filename" in props)
    has_inline = ("control_points" in props)
    if has_file == has_inline:
        raise ValueError("links1_bicubic needs exactly one of 'filename' and 'control_points'")
    if has_file:
        fn = str(props["filename"])
        if not os.path.isabs(fn) and base_dir:
            fn = os.path.join(base_dir, fn)
        elif not os.path.isabs(fn):
            # mi.load_file / load_string: Mitsuba's file resolver holds the scene's folder
            import mitsuba as mi
            fn = str(mi.file_resolver().resolve(fn))
        patches = meshes.read_patches(fn)
    else:
        patches = meshes.parse_patches(str(props["control_points"]), "<control_points>", with_count=False)
    sub = read("links1_bicubic", "subdivisions", int(props["subdivisions"]) if ("subdivisions" in props) else None)
    v, f, n = meshes.tessellate_patches(patches, sub)
    if ("flip_normals" in props) and bool(props["flip_normals"]):
        f, n = meshes.flip(f, n)
    m = _matrix(props)
    if m is not None:
        if (problem := transform_problem(m)) is not None:
            raise ValueError(f"links1_bicubic: {problem}")
        v, n = meshes.transform_mesh(m, v, n)
    if ("face_normals" in props) and bool(props["face_normals"]):
        n = None
    return v, f, n


def define_bicubic():
    """``Links1Bicubic`` for the variant in use: a subclass of its ``mi.Mesh``, made per variant."""
    import drjit as dr
    import mitsuba as mi

    class Links1Bicubic(mi.Mesh):
        r"""Bicubic Bézier patches (``links1_bicubic``) tessellated into a Mitsuba mesh (eq. 3.3).

        ==============  =======  ==========================================  =========
        Parameter       Type     Meaning                                     Default
        ==============  =======  ==========================================  =========
        filename        string   a ``.patch`` file (see ``links1.geometry.meshes``)   —
        control_points  string   inline: 48 numbers per patch                —
        subdivisions    integer  grid cells per patch side                   8
        to_world        trafo    object → world                              identity
        flip_normals    boolean  reverse the winding and normals             false
        face_normals    boolean  flat shading (no vertex normals)            false
        ==============  =======  ==========================================  =========
        """

        def __init__(self, props):
            base = props["_links1_base_dir"] if ("_links1_base_dir" in props) else None
            v, f, n = tessellate_bicubic(props, base)
            for key in ("subdivisions", "flip_normals", "face_normals", "filename", "control_points"):
                if (key in props):
                    props.mark_queried(key) if hasattr(props, "mark_queried") else None
            super().__init__(props.id() or "links1_bicubic", len(v), len(f), props,
                             has_vertex_normals=n is not None)
            prm = mi.traverse(self)
            prm["vertex_positions"] = mi.Float(np.asarray(v, dtype=np.float32).ravel())
            prm["faces"] = mi.UInt32(np.asarray(f, dtype=np.uint32).ravel())
            if n is not None:
                prm["vertex_normals"] = mi.Float(np.asarray(n, dtype=np.float32).ravel())
            prm.update()
            self._nbytes = int(v.nbytes // 2 + f.nbytes // 2 + (0 if n is None else n.nbytes // 2))

        def to_string(self):
            return f"Links1Bicubic[id={self.id()!r}, vertices={self.vertex_count()}, faces={self.face_count()}]"

    return Links1Bicubic
