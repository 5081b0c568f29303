"""One home for the rules a scene's values must follow, read by both loaders.

The core's reader (:mod:`links1.scene.loader`, :mod:`links1.scene.xmlparse`) and the Mitsuba plugins
(``links1_mitsuba``: the loader and the plugin constructors in ``shapes.py``,
``emitters.py``, ``bsdfs.py``, ``integrator.py``) take the parameters of the links1 plugins,
their defaults and their ranges from :data:`PLUGINS` (a table in the spirit of pbrt's
``ParameterDictionary``), and the rules Mitsuba applies to every scene from the functions
below: numbers finite and within float32's reach, RGB reflectances of BSDFs in [0, 1],
invertible transforms, film and sample counts that fit the sample ids and memory, nesting
depth. Nothing here imports Mitsuba or numpy-heavy modules of the core.

Each check returns the value or raises :class:`ValueError` with a message that names the
parameter; the callers add file, line and element.
"""
from __future__ import annotations

import difflib
import math
import os
import re
from dataclasses import dataclass

import numpy as np

from ..errors import UsageError

#: Largest magnitude of a coordinate, a scale factor or a translation in a scene, and the
#: smallest scale factor: the float32 renderer squares them (ray-quadric tests, inverses),
#: and 1e15² = 1e30 is still well inside float32's 3.4e38.
MAX_EXTENT = 1e15
MIN_SCALE = 1e-15
#: Largest ratio of a transform's scale factors (its condition number): beyond it the
#: float32 inverse has no correct digit.
MAX_ANISOTROPY = 1e12
#: Largest magnitude of any other number (colours, intensities, exponents, ...): summed
#: over lights and samples it must stay finite in float32.
MAX_VALUE = 1e30
#: Camera samples: Mitsuba's sample ids are 32-bit (``width · height · spp < 2³²``).
MAX_SAMPLE_IDS = 2 ** 32
#: Deepest element nesting in a scene file (Mitsuba's own scenes use < 10).
MAX_NESTING = 64
#: Largest subdivision count of a links1_bicubic patch: n → 2n² triangles a patch (256: the
#: 8-patch vase of scenes/bicubic.xml becomes a million triangles, ~0.7 GB and 11 s at 24²
#: in either renderer; 1024 would need ~11 GB).
MAX_SUBDIVISIONS = 256
#: Most shadow rays per light and hit.
MAX_LIGHT_SAMPLES = 4096
#: Most surface interactions per ray-tree branch.
MAX_MAX_DEPTH = 1024


@dataclass(frozen=True)
class Param:
    """One parameter of a links1 plugin: its kind (``float``, ``int``, ``rgb``, ``string``,
    ``bool``, ``point``, ``vector``), default (:data:`REQUIRED` if it must be given, None if
    optional without a value), closed range ``[lo, hi]`` (``lo_open``: ``> lo``), allowed
    strings (``choices``)."""

    kind: str
    default: object = None
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    choices: tuple | None = None

    def check(self, name: str, value):
        """``value`` if it obeys this parameter's rules, else ValueError naming ``name``."""
        if self.choices is not None:
            v = str(value).strip().lower()
            if v not in self.choices:
                raise ValueError(f"'{name}' must be one of {', '.join(self.choices)}, got '{value}'")
            return v
        if self.kind in ("string", "bool"):
            return value
        if self.kind == "int":
            v = int(value)
            rng = f"[{self.lo:g}, {self.hi:g}]" if self.hi is not None else f">= {self.lo:g}"
            if (self.lo is not None and v < self.lo) or (self.hi is not None and v > self.hi):
                raise ValueError(f"'{name}' must be {'in ' if self.hi is not None else ''}{rng}, got {v}")
            return v
        arr = np.atleast_1d(np.asarray(value, dtype=np.float64))
        if self.kind == "rgb" and arr.size == 1:
            arr = np.full(3, arr[0])
        check_finite(name, arr, MAX_EXTENT if self.kind in ("point", "vector") else MAX_VALUE)
        bad = np.zeros(arr.shape, dtype=bool)
        if self.lo is not None:
            bad |= ~(arr > self.lo) if self.lo_open else ~(arr >= self.lo)
        if self.hi is not None:
            bad |= ~(arr <= self.hi)
        if np.any(bad):
            lo = "" if self.lo is None else (f"> {self.lo:g}" if self.lo_open else f">= {self.lo:g}")
            if self.hi is not None:
                lo = f"in {'(' if self.lo_open else '['}{self.lo:g}, {self.hi:g}]"
            shown = arr.tolist() if arr.size > 1 else float(arr[0])
            if self.kind == "rgb" and self.hi == 1:
                raise ValueError(f"invalid RGB reflectance {shown} for '{name}': must be in [0, 1] (as Mitsuba)")
            raise ValueError(f"'{name}' must be {lo}, got {shown}")
        return float(arr[0]) if self.kind in ("float",) else arr


REQUIRED = object()
_UNIT = dict(lo=0.0, hi=1.0)
_NONNEG = dict(lo=0.0)

#: The links1 plugins' parameters: ``(tag, type) -> {name: Param}``. Parameters whose name
#: is a pattern (``clip_<k>``) are checked by their plugins.
PLUGINS: dict = {
    ("integrator", "links1_whitted"): {
        "max_depth": Param("int", 5, lo=-1, hi=MAX_MAX_DEPTH),   # -1: unlimited (capped to 5 by the core)
        "seed": Param("int", 0, lo=0, hi=2 ** 32 - 1),
        "min_weight": Param("float", 1.0 / 255.0, **_UNIT),  # POV-Ray's adc_bailout
        "light_samples": Param("int", 1, lo=1, hi=MAX_LIGHT_SAMPLES),
        "projective": Param("bool", False),   # derivatives: the visibility term (plugin only)
    },
    ("bsdf", "links1_phong"): {   # eq. 3.11 / 3.16; colours are reflectances (Mitsuba: [0, 1])
        "ambient": Param("rgb", 0.0, **_UNIT),
        "diffuse": Param("rgb", 0.5, **_UNIT),
        "specular": Param("rgb", 0.0, **_UNIT),
        "exponent": Param("float", 20.0, lo=0.0),
        "reflectance": Param("rgb", None, **_UNIT),           # = specular
        "transmittance": Param("rgb", 0.0, **_UNIT),
        "ior": Param("float", 1.0, lo=0.0, lo_open=True),
    },
    ("emitter", "links1_point"): {   # eq. 3.10
        "position": Param("point", (0.0, 0.0, 0.0)),
        "direction": Param("vector", (0.0, 0.0, 1.0)),
        "L1": Param("rgb", 1.0, **_NONNEG),
        "L2": Param("rgb", 0.0),
        "falloff": Param("string", "none", choices=("none", "inverse_square")),
    },
    ("emitter", "links1_spot"): {    # 3-3-1 iii
        "origin": Param("point", (0.0, 0.0, 0.0)),
        "direction": Param("vector", REQUIRED),
        "radius": Param("float", REQUIRED, lo=0.0, lo_open=True),
        "intensity": Param("rgb", 1.0, **_NONNEG),
    },
    ("shape", "links1_quadric"): {   # eq. 3.4-3.5
        "kind": Param("string", REQUIRED, choices=("sphere", "cylinder")),
        "capped": Param("bool", False),
        "clip_offset": Param("float", 0.0),                   # clip_<k>_offset
    },
    ("shape", "links1_blob"): {      # eq. 3.6-3.9
        "centers": Param("string", REQUIRED),
        "threshold": Param("float", REQUIRED, lo=0.0, lo_open=True),
        "solver": Param("string", "exact", choices=("exact", "paper")),
        "samples": Param("int", 8, lo=1, hi=4096),
    },
    ("shape", "links1_bicubic"): {
        "subdivisions": Param("int", 8, lo=1, hi=MAX_SUBDIVISIONS),
        "face_normals": Param("bool", False),
        "flip_normals": Param("bool", False),
    },
}


#: Names a links1 plugin takes besides its checked parameters above: read by the plugin without
#: a rule of its own (``aovs``, ``filename``), or by the Mitsuba base class it derives from
#: (``mi.SamplingIntegrator``: ``block_size`` ...; ``mi.Emitter``: ``sampling_weight``;
#: ``mi.Mesh``: ``flip_normals``, ``silhouette_sampling_weight``). With :data:`PLUGINS` this is
#: everything each one takes: any other name is an error, as Mitsuba refuses a property no
#: plugin reads ("unreferenced property").
OTHER_NAMES: dict = {
    ("integrator", "links1_whitted"): ("aovs", "adaptive", "adaptive_depth", "block_size",
                                       "hide_emitters", "samples_per_pass", "timeout"),
    ("bsdf", "links1_phong"): (),
    ("emitter", "links1_point"): ("to_world", "sampling_weight"),
    ("emitter", "links1_spot"): ("to_world", "sampling_weight"),
    ("shape", "links1_quadric"): ("to_world",),
    ("shape", "links1_blob"): ("to_world",),
    ("shape", "links1_bicubic"): ("to_world", "filename", "control_points", "silhouette_sampling_weight"),
}
#: Parameters named by a pattern: ``clip_<k>`` and ``clip_<k>_offset`` (k = 0, 1, ...).
_PATTERNS = {"links1_quadric": re.compile(r"clip_\d+(_offset)?")}


def is_links1(plugin: str | None) -> bool:
    """Whether ``plugin`` (a type such as ``links1_phong``) is one of links1's plugins."""
    return any(t == plugin for _, t in PLUGINS)


def takes(plugin: str, name: str) -> bool:
    """Whether links1 plugin ``plugin`` takes a parameter called ``name``."""
    for (tag, t), table in PLUGINS.items():
        if t == plugin:
            pattern = _PATTERNS.get(plugin)
            return (name in table and name != "clip_offset") or name in OTHER_NAMES[(tag, t)] or \
                bool(pattern and pattern.fullmatch(name))
    raise KeyError(plugin)


def names_of(plugin: str) -> list:
    """Every parameter name links1 plugin ``plugin`` takes (patterns as their first instance)."""
    for (tag, t), table in PLUGINS.items():
        if t == plugin:
            names = [n for n in table if n != "clip_offset"] + list(OTHER_NAMES[(tag, t)])
            return names + (["clip_0", "clip_0_offset"] if plugin in _PATTERNS else [])
    raise KeyError(plugin)


def unknown_parameter(tag: str, plugin: str | None, name: str, known) -> str:
    """The message for a parameter ``name`` that plugin ``plugin`` (of element ``tag``) does not
    take, naming the closest of the ``known`` names where one is close (a typo)."""
    close = difflib.get_close_matches(name, sorted(known), n=1)
    hint = f" (did you mean '{close[0]}'?)" if close else ""
    owner = "links1's" if is_links1(plugin) else "Mitsuba's"
    return (f"unknown parameter '{name}'{hint}: {owner} {tag} '{plugin or tag}' does not take it "
            "(Mitsuba refuses unreferenced properties)")


def unknown_in(tag: str, plugin: str, names) -> tuple | None:
    """``(name, message)`` for the first of ``names`` that links1 plugin ``plugin`` does not
    take (:func:`unknown_parameter`), else None: the rule both renderers and every loader apply."""
    for name in names:
        if not takes(plugin, name):
            return name, unknown_parameter(tag, plugin, name, names_of(plugin))
    return None


def param(plugin: str, name: str) -> Param:
    """The rules of parameter ``name`` of links1 plugin ``plugin`` (its type, e.g. ``links1_phong``)."""
    for (_, t), table in PLUGINS.items():
        if t == plugin:
            return table[name]
    raise KeyError(plugin)


def default(plugin: str, name: str):
    """The default of a links1 plugin's parameter (None: optional without a value)."""
    d = param(plugin, name).default
    return None if d is REQUIRED else d


def check(plugin: str, name: str, value):
    """``value`` checked by the rules of ``plugin``'s parameter ``name``."""
    return param(plugin, name).check(name, value)


def read(plugin: str, name: str, value):
    """A links1 plugin's parameter as read from a scene (``value`` None: not given): its
    default, or ``value`` checked; ValueError ``"<plugin>: ..."`` (the Mitsuba plugins'
    constructors; the core's reader is ``links1.scene.properties._Props.links1``)."""
    prm = param(plugin, name)
    if value is None:
        if prm.default is REQUIRED:
            raise ValueError(f"{plugin}: '{name}' is required")
        if prm.default is None:
            return None
        value = prm.default
    try:
        return prm.check(name, value)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{plugin}: {exc}") from None


def blob_centers(text: str) -> np.ndarray:
    """``links1_blob``'s ``centers``: groups of five numbers ``x y z w S`` (eq. 3.9), finite,
    within :data:`MAX_EXTENT`, ranges ``S > 0`` -> an (n, 5) array."""
    toks = [t for t in str(text).replace(",", " ").split() if t]
    if not toks:
        raise ValueError("'centers' is empty (groups of five numbers x y z w S)")
    if len(toks) % 5:
        raise ValueError(f"'centers' must hold groups of five numbers x y z w S, got {len(toks)} numbers")
    try:
        c = np.array([float(t) for t in toks], dtype=np.float64).reshape(-1, 5)
    except ValueError:
        raise ValueError("'centers' must contain only numbers") from None
    if not np.all(np.isfinite(c)):
        raise ValueError("'centers' must contain only finite numbers")
    check_finite("centers", c, MAX_EXTENT)
    bad = np.nonzero(~(c[:, 4] > 0))[0]
    if bad.size:
        raise ValueError(f"centre {int(bad[0])}: the range S must be > 0, got {c[bad[0], 4]:g}")
    return c


def clip_plane(k: int, normal, offset) -> tuple:
    """``links1_quadric``'s ``clip_<k>`` (a non-zero normal) and ``clip_<k>_offset``."""
    n = np.asarray(normal, dtype=np.float64)
    check_finite(f"clip_{k}", n, MAX_EXTENT)
    if not np.linalg.norm(n) > 0:
        raise ValueError(f"clip_{k}: the plane normal must be non-zero")
    return n, check("links1_quadric", "clip_offset", offset)


# --------------------------------------------------------------------------- general rules
def check_finite(name: str, values, limit: float = MAX_VALUE) -> None:
    """Every number finite and of magnitude <= ``limit``."""
    a = np.asarray(values, dtype=np.float64)
    if not np.all(np.isfinite(a)):
        raise ValueError(f"'{name}' must be finite, got {a.tolist() if a.size > 1 else float(a)}")
    if a.size and float(np.max(np.abs(a))) > limit:
        raise ValueError(f"'{name}' is out of range: |value| must be <= {limit:g}, "
                         f"got {a.tolist() if a.size > 1 else float(a)}")


def check_reflectance(name: str, rgb) -> np.ndarray:
    """An RGB reflectance of a BSDF: Mitsuba refuses values outside [0, 1] ("Invalid RGB
    reflectance value ... must be in the range [0, 1]")."""
    a = np.asarray(rgb, dtype=np.float64)
    check_finite(name, a)
    if np.any(a < 0) or np.any(a > 1):
        raise ValueError(f"invalid RGB reflectance {a.tolist()} for '{name}': must be in [0, 1] (as Mitsuba)")
    return a


def transform_problem(m, what: str = "to_world") -> str | None:
    """Why the affine map ``m`` (4x4) cannot place a shape, or None: every entry finite,
    translations and scale factors (singular values) within [MIN_SCALE, MAX_EXTENT], their
    ratio below MAX_ANISOTROPY. A singular map flattens the shape."""
    m = np.asarray(m, dtype=np.float64)
    if not np.all(np.isfinite(m)):
        return f"{what} has non-finite entries (overflow?)"
    big = float(np.max(np.abs(m))) if m.size else 0.0
    if big > MAX_EXTENT:
        return f"{what} is out of range: its entries must be <= {MAX_EXTENT:g} in magnitude, got {big:g}"
    sv = np.linalg.svd(m[:3, :3], compute_uv=False)
    if not sv[-1] > 0:
        return f"{what} is singular (a scale of 0 flattens the shape)"
    if sv[-1] < MIN_SCALE:
        return f"{what} scales the shape by {sv[-1]:g}, below {MIN_SCALE:g}"
    if sv[0] / sv[-1] > MAX_ANISOTROPY:
        return (f"{what} is nearly singular: its scale factors {sv[0]:g} and {sv[-1]:g} differ by more "
                f"than {MAX_ANISOTROPY:g}x")
    return None


def planar_to_world(m) -> np.ndarray:
    """A rectangle's or disk's ``to_world`` with a usable third column: such a shape lies in
    its local z = 0 plane, so a zero scale along z (``<scale z="0"/>``: zero thickness)
    leaves it the same shape; Mitsuba 3.9.1 renders it with NaN normals (its normal is the
    inverse transpose's image of +z). The z column is replaced by the unit normal of the
    plane (x column × y column), which the shape's geometry does not see and which gives the
    normal Mitsuba gives with a positive z scale. Other maps are returned unchanged."""
    m = np.array(m, dtype=np.float64)
    if not np.all(np.isfinite(m)):
        return m
    x, y, z = m[:3, 0], m[:3, 1], m[:3, 2]
    n = np.cross(x, y)
    nn = float(np.linalg.norm(n))
    scale = max(float(np.linalg.norm(x)), float(np.linalg.norm(y)), 1e-300)
    if nn > 0 and float(np.linalg.norm(z)) <= 1e-12 * scale:
        m[:3, 2] = n / nn * math.sqrt(nn)
    return m


def check_samples(width: int, height: int, spp: int, *, light_samples: int = 1,
                  renderer: str = "core", channels: int = 3) -> None:
    """A film and sample count that fit before anything is allocated: camera samples within
    the 32-bit sample ids (both renderers number samples alike), and the image within
    memory. Raises ValueError saying the size asked for and the limit."""
    w, h, s = int(width), int(height), int(spp)
    samples = w * h * s
    if samples >= MAX_SAMPLE_IDS:
        raise ValueError(f"{w}x{h} pixels x {s} samples = {samples:,} camera samples exceed the "
                         f"32-bit sample ids (limit {MAX_SAMPLE_IDS - 1:,})")
    if samples * int(light_samples) >= MAX_SAMPLE_IDS:
        raise ValueError(f"{samples:,} camera samples x {int(light_samples)} light samples = "
                         f"{samples * int(light_samples):,} shadow-ray samples exceed the "
                         f"32-bit sample ids (limit {MAX_SAMPLE_IDS - 1:,})")
    need = w * h * (channels + 8) * 8    # the float64 image, its layers and accumulators
    avail = _memory_bytes()
    if avail and need > avail // 2:
        raise ValueError(f"a {w}x{h} film needs about {need / 2 ** 30:.1f} GiB, more than half the "
                         f"memory of this machine ({avail / 2 ** 30:.1f} GiB)")


def check_resources(width, height, spp, light_samples=1) -> None:
    """:func:`check_samples` for a renderer about to allocate its film (both renderers): the
    same check, its message as one-line :class:`links1.errors.UsageError`."""
    try:
        check_samples(width, height, spp, light_samples=light_samples)
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def _memory_bytes() -> int | None:
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):   # pragma: no cover - not POSIX
        return None
