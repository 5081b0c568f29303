"""links1 shapes for Mitsuba: what the shape specs share (their constants table's reader
:func:`table_value`, :func:`shape_label`, the ``to_world`` of a node) and the analytic quadric
(:class:`QuadricSpec`), intersected in Dr.Jit by ``links1_whitted``. The blob is
:mod:`links1_mitsuba.blob`, the bicubic patch mesh :mod:`links1_mitsuba.bicubic`.

Mitsuba 3.9.1 cannot take shapes written in Python, so :mod:`links1_mitsuba.loader` takes
``links1_quadric`` and ``links1_blob`` nodes out of the parsed scene and hands their
:class:`QuadricSpec` / :class:`~links1_mitsuba.blob.BlobSpec` to the integrator, which
intersects them next to ``scene.ray_intersect``. Numerically stable forms follow
docs/numerics.md.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from links1.geometry.quadrics import quadric_bounds
from links1.scene.params import clip_plane, default, read, transform_problem

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
        """World AABB: the core's rule (:func:`links1.geometry.quadrics.quadric_bounds`);
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

    def literals(self) -> tuple:
        """The values its kernels take as Python literals (the others they gather from
        :meth:`tables`): the kind, the caps and the clip planes' normals. A geometry update
        that changes none of these (of any shape) replays the frozen launches
        (``launch.literal_key``)."""
        return (self.kind, bool(self.capped), tuple(tuple(n) for n, _ in self.clips))

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
