"""Dr.Jit helpers shared by the parts of ``links1_whitted``: the sample pattern's hash
(``mix32``, ``unit_float``), colour / vector literals, gathers, the next float up; aligned numpy
tables and checked index tables.

The Dr.Jit helpers name ``mi.Float``, ``mi.Color3f``, ... when called, so they serve whichever
Mitsuba variant is set at that time (importing this module needs none).
"""
from __future__ import annotations

import warnings

import drjit as dr
import mitsuba as mi
import numpy as np

from links1.maths.sampling import _M1 as _M1_NP
from links1.maths.sampling import _M2 as _M2_NP

INF = float("inf")
#: the multipliers of the sample pattern's hash, written once in links1.maths.sampling (as Python
#: ints: a Dr.Jit UInt32 times a numpy scalar is not the literal product)
_M1, _M2 = int(_M1_NP), int(_M2_NP)


_KINDS: dict = {}


#: Mitsuba's meshes whose surface is their triangles and whose record is
#: ``Mesh::compute_surface_interaction`` itself (Mitsuba 3.9.1's mesh.cpp; not
#: ``EllipsoidsMesh``, whose own call changes it): the kernel's record (tables) and the
#: core's occluder rules (shadow_plan) take these
PLAIN_MESHES = ("Mesh", "OBJMesh", "PLYMesh", "SerializedMesh", "Cube", "Rectangle")


def kind_of(obj) -> str:
    """The name a Mitsuba object's ``to_string`` starts with (``"Rectangle"``, ``"PointLight"``,
    ``"Mask"``, ``"Links1Point"``), as ``str(obj).split("[")[0]`` gives it, without printing the
    object each time: a native shape's or emitter's ``to_string`` reads its transforms and
    its BSDF's values back from the device (one synchronising read each: 78 a table rebuild
    of a 3-shape scene). Made once per class (``type`` and ``class_name()``: Python plugins
    share a ``class_name()`` and differ in ``type``)."""
    key = (type(obj), obj.class_name())
    k = _KINDS.get(key)
    if k is None:
        # (one line: a few plugins' to_string is not "Name[...]", principled's is
        # "Principled BSDF :\nbase_color: ...")
        k = _KINDS[key] = str(obj).split("[")[0].splitlines()[0].strip().rstrip(":").strip()
    return k


def spread(v, n):
    """An attached one-lane Dr.Jit value (a derivative pass's parameter) gathered at ``n``
    lanes; anything else as it is. Read by ``n`` lanes as it is, a one-lane value's reverse-mode
    derivative is a horizontal sum per component, each a kernel of its own that recomputes
    what reads it (a light's shading, a quadric's hit: three per position or colour, twelve
    per transform); a gather's is a scatter-add, and the scatter-adds of a pass share one."""
    if n <= 1 or not dr.is_array_v(v) or not dr.grad_enabled(v) or dr.width(v) != 1:
        return v
    return dr.gather(type(v), v, dr.zeros(mi.UInt32, n))


def udiv(a, b):
    """``a // b`` of two ``UInt32`` arrays (``b`` >= 1 in every lane, not a literal), exact.

    The LLVM backend has no vector integer division: it divides lane by lane (three divisions
    by a run-time spp took 6.3 ms of 4M lanes where this takes 1.2 ms). There the quotient is
    ``floor(a / b)`` in float64, which is exact for 32-bit operands: with ``a = q b + r``, the
    division's rounding error is at most ``(q + 1) 2^-53`` and ``(q + 1) b <= a + b < 2^33``,
    so it is below ``1 / b``, the distance from ``a / b`` to the next integer when ``r > 0``
    (and ``q`` itself is exact when ``r = 0``). A literal divisor would become a reciprocal
    multiply (not correctly rounded): literals keep ``//``, which LLVM turns into a multiply
    and a shift. The CUDA backend keeps ``//``."""
    if dr.backend_v(a) != dr.JitBackend.LLVM or not isinstance(b, type(a)) or b.state == dr.VarState.Literal:
        return a // b
    return type(a)(dr.floor(mi.Float64(a) / mi.Float64(b)))


def checked_index(values, n: int, what: str, *, sentinel: int | None = None) -> np.ndarray:
    """``values`` as an index table into ``n`` rows, checked when it is built: every
    entry in ``[0, n)`` (or the ``sentinel``, e.g. -1 for "none", which the kernels mask).
    A gather out of range in an LLVM/CUDA kernel reads foreign memory or crashes the
    process; a table that breaks the rule is a bug in links1, stopped here with its name."""
    a = np.asarray(values)
    bad = (a < 0) | (a >= n)
    if sentinel is not None:
        bad &= a != sentinel
    if np.any(bad):
        k = int(np.flatnonzero(bad.ravel())[0])
        raise RuntimeError(f"links1_whitted: index table '{what}' holds {a.ravel()[k]} at {k}, "
                           f"outside [0, {n}) (an internal inconsistency)")
    return a


def aligned(a, dtype) -> np.ndarray:
    """A 64-byte aligned contiguous copy of ``a`` as ``dtype``. A Dr.Jit array made from a
    numpy array maps its memory, and numpy aligns it to 16 bytes only. Two costs follow:
    (1) a frozen function records again whenever the alignment of such an input changes
    (drjit.freeze's documentation): unaligned inputs made ``trace_points`` re-record at random
    (7 recordings in 12 calls of 3 adaptive frames), and window launches too (the sample ids:
    2 of 8 fresh processes of tests/plugins/test_renderer_api.py recorded again, 0 of 10
    aligned); (2) packet gathers from a table straddle cache lines at random (:func:`table`)."""
    a = np.asarray(a, dtype=dtype)
    out = aligned_empty(a.size, dtype)
    out[:] = a.ravel()
    return out


def aligned_empty(n, dtype) -> np.ndarray:
    """An uninitialised 64-byte aligned array of ``n`` values (see :func:`aligned`)."""
    dtype = np.dtype(dtype)
    buf = np.empty(n * dtype.itemsize + 64, dtype=np.uint8)
    start = -buf.ctypes.data % 64
    return buf[start:start + n * dtype.itemsize].view(dtype)


def is_aligned(a) -> bool:
    return a.flags.c_contiguous and a.ctypes.data % 64 == 0


def table(mi_type, a):
    """A Dr.Jit table of ``a`` (flattened) in 64-byte aligned memory (:func:`aligned`): with
    numpy's 16-byte alignment packet gathers straddle cache lines at random, and the same walk
    took 35 to 62 ms from one table instance to the next (many.xml's camera rays, 512², one
    thread); the blob candidate walk likewise, 4.0 ms aligned against 5.4-7.9 ms not
    (blob-1000 at 128², one thread). The one home of the aligned tables (the BVH, the blob
    tables, light buffers)."""
    dtype = np.uint32 if mi_type.__name__.startswith("UInt") else np.float32
    return mi_type(aligned(np.ascontiguousarray(a).ravel(), dtype))


def mix32(x):
    """lowbias32 on UInt32 (wrapping), as links1.maths.sampling.mix32."""
    x = x ^ (x >> 16)
    x = x * _M1
    x = x ^ (x >> 15)
    x = x * _M2
    x = x ^ (x >> 16)
    return x


def unit_float(x):
    """A float in [0, 1) from the top 24 bits of a ``UInt32`` (links1.maths.sampling)."""
    return mi.Float(x >> 8) * (2.0 ** -24)


def color3(v):
    """``mi.Color3f`` of an RGB value: three Python floats (literals) or a Dr.Jit value."""
    if dr.is_array_v(v):   # a Dr.Jit value (attached, in a derivative pass: gradients.py)
        return mi.Color3f(v)
    return mi.Color3f(float(v[0]), float(v[1]), float(v[2]))


def vector3(v):
    """``mi.Vector3f`` of a 3-vector, as :func:`color3`."""
    if dr.is_array_v(v):
        return mi.Vector3f(v)
    return mi.Vector3f(float(v[0]), float(v[1]), float(v[2]))


def gather3(table, idx, active=True):
    return dr.gather(mi.Color3f, table, idx, active)


def next_up(x):
    """The next float32 above positive ``x`` (infinity stays): a strict ``t < limit`` test
    against ``next_up(t)`` accepts a tie at ``t``."""
    return dr.select(dr.isfinite(x) & (x >= 0), dr.reinterpret_array(
        mi.Float, dr.reinterpret_array(mi.UInt32, x) + 1), x)


class Hidden:
    """State kept out of :func:`drjit.freeze`'s input traversal: the plugin's one way to hide
    state from a frozen launch.

    Freeze walks every input of a frozen launch on every call, and through the scene each
    Python plugin's ``__dict__`` (``links1_whitted``, ``links1_phong``, ``links1_point``,
    ``links1_spot``); an object that has traversal callbacks is walked through them, and these
    walk nothing. ``launch.frozen_inputs``, which gathers the per-scene tables' Dr.Jit arrays
    as the launch's ``tables`` input, follows the same rule. So whatever a frozen launch must
    not take as an input, or need not walk on every call, lives in a ``Hidden``:

    - the integrator's per-scene state (``Links1Whitted._hidden``, reached through
      :func:`hidden_attr` properties): the tables (their arrays reach the launch as its
      ``tables`` input), the shape specs (thousands in big scenes: walking them each call would
      cost more than rendering a small window), the recordings, the camera sample of the last
      camera rays, the ray counters;
    - a Python plugin's read parameters (``links1_phong``, ``links1_point``, ``links1_spot``:
      ``_held``; their values reach the launches through the tables; 3,000 Mitsuba spheres
      sharing one ``links1_phong``: 365 -> 100 ms a frame);
    - :class:`~links1_mitsuba.paramwatch.ParamWatch` (a subclass): the old values it pins.

    A ``Hidden`` is also how a frozen launch gets its engine, tables and scene as an argument
    (``Launches._call_frozen``): freeze keys it on its type alone and walks nothing of it."""

    def __init__(self, **kw):
        self.__dict__.update(kw)

    def _traverse_1_cb_ro(self, fn):
        pass

    def _traverse_1_cb_rw(self, fn):
        pass


def hidden_attr(name, holder="_hidden"):
    """A property that keeps attribute ``name`` in the object's :class:`Hidden` ``holder``
    (None until set)."""
    return property(lambda self: getattr(getattr(self, holder), name, None),
                    lambda self, v: setattr(getattr(self, holder), name, v))


#: The property in which the loader hands a links1 plugin its place in the file,
#: ``FILE:LINE: <element>`` (``loader._load``, for the plugins of :data:`PLACED_PLUGINS`),
#: read by :func:`place_in` for the plugin's own messages (links1_point's colour warnings,
#: links1_phong's update errors).
PLACE_PROPERTY = "_links1_place"

#: The plugins whose constructors read :data:`PLACE_PROPERTY` (Mitsuba refuses a property
#: that its plugin does not read)
PLACED_PLUGINS = ("links1_phong", "links1_point", "links1_spot")


def place_in(props) -> str | None:
    """The place the loader gave the object of ``props`` (:data:`PLACE_PROPERTY`), or None
    (an object made otherwise: ``mi.load_dict``, ``mi.load_file``)."""
    return str(props[PLACE_PROPERTY]) if PLACE_PROPERTY in props else None


def place_of(obj, places) -> str | None:
    """``FILE:LINE: <element>`` of a loaded Mitsuba object (from its id, in ``places``: the
    loader's table), or None."""
    if not places:
        return None
    try:
        return places.get(obj if isinstance(obj, str) else obj.id())
    except Exception:
        return None


def read_rgb(props, name, default, *, emitter=True):
    """An RGB parameter as Mitsuba's RGB variants read it: ``rgb``, ``float`` or ``spectrum``
    (:func:`links1.shading.spectra.to_rgb`; ``emitter=False`` for reflectance-like parameters), as a
    numpy RGB (``default``: a number, or None). The one reader of colours and spectra of the
    links1 plugins (``links1_point``/``links1_spot``, ``links1_phong``, the loader's emitting
    links1 shapes). A warning names the object's place (:func:`place_in`)."""
    where = place_in(props)   # (read whatever the colour: Mitsuba checks that it was read)
    if (name in props):
        v = props[name]
        if hasattr(v, "wavelengths") and hasattr(v, "values"):  # a <spectrum>
            from links1.shading.spectra import to_rgb
            rgb, raw = to_rgb(list(v.wavelengths), list(v.values), emitter=emitter)
            if raw is not None:
                where = f"{where} <spectrum name='{name}'>" if where else f"'{name}'"
                warnings.warn(f"{where}: clamping out-of-gamut colour {np.round(raw, 6).tolist()} "
                              f"to {np.round(rgb, 6).tolist()} (as Mitsuba)", stacklevel=3)
            return rgb
        try:
            return np.array([float(v[0]), float(v[1]), float(v[2])])
        except TypeError:
            return np.full(3, float(v))
    return None if default is None else np.full(3, float(default))


def quadric_roots(qform, u, v):
    """The two roots along ``u + t v`` of the unit quadric ``qform(y, y) = 1`` in object space
    (eq. 3.5), from the closest approach ``t0`` (docs/numerics.md: no cancellation for far
    origins) and the stable quadratic formula: ``(hit, t_near, t_far)``, ``hit`` where the
    line meets it. One home for :meth:`links1_mitsuba.shapes.QuadricSpec.intersect` and the
    BVH's quadric rows (:class:`links1_mitsuba.bvh.QuadricBVH`), which must give the same bits."""
    a = qform(v, v)
    ok_a = a > 0
    a_safe = dr.select(ok_a, a, 1.0)
    t0 = -qform(u, v) / a_safe
    u0 = u + v * t0
    b = qform(u0, v)
    c = qform(u0, u0) - 1.0
    disc = dr.square(b) - a * c
    q = -(b + dr.copysign(dr.sqrt(dr.maximum(disc, 0.0)), b))
    r1 = c / dr.select(q != 0, q, 1.0)
    r2 = q / a_safe
    return ok_a & (disc >= 0), t0 + dr.minimum(r1, r2), t0 + dr.maximum(r1, r2)
