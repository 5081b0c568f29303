"""The core's in-memory scene: what the XML loader builds and the integrator renders."""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, fields

import numpy as np

from . import params
from ..errors import SceneError, UsageError
from ..geometry.accel import Accel
from ..sensor.camera import Camera


@dataclass
class Scene:
    """A loaded scene.

    Attributes
    ----------
    camera : Camera      the camera rendered (the file's first sensor unless :meth:`use_sensor`)
    sensors : list       ``(camera, spp)`` of every sensor in file order (a ``SceneError`` for one
                         the core cannot render); ``[]``: only ``camera``
    shapes : list of links1.geometry.base.Shape (``shape.index`` is its position here: the ``id`` AOV)
    lights : list of links1.shading.lights.Light
    spp : int            sample count from the scene's sampler (default 1)
    max_depth : int      surface interactions along one branch of the ray tree (default 5)
    background : (3,)    radiance of rays that escape (Mitsuba ``constant`` emitters)
    environments : list  ``EnvironmentMap`` lights (also in ``lights``): escaping rays add them
    integrator : str     the integrator the file names (the core always traces LINKS-1 Whitted)
    light_samples : int  shadow rays per sampled light and hit (``links1_whitted``'s, default 1)
    min_weight : float   ray-tree weight threshold (``links1_whitted``'s, default 1/255)
    path : str | None    the scene file
    """

    camera: Camera
    sensors: list = field(default_factory=list)
    shapes: list = field(default_factory=list)
    lights: list = field(default_factory=list)
    spp: int = 1
    max_depth: int = params.default("links1_whitted", "max_depth")
    background: np.ndarray = field(default_factory=lambda: np.zeros(3))
    integrator: str = "links1_whitted"
    light_samples: int = 1
    min_weight: float = params.default("links1_whitted", "min_weight")
    environments: list = field(default_factory=list)  # envmap lights: escaping rays add their eval
    path: str | None = None
    #: what is built from the shapes and lights on first use (the BVH, the integrator's plan),
    #: each with the content key it was built for (:meth:`cached`)
    _caches: dict = field(default_factory=dict, init=False, repr=False, compare=False)
    #: the content key fixed by :meth:`pin_content` (None: computed at every use)
    _pinned_key: bytes | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self):
        self._index_shapes()

    def _index_shapes(self):
        for i, s in enumerate(self.shapes):
            s.index = i

    def sensor_count(self) -> int:
        return max(len(self.sensors), 1)

    def use_sensor(self, k: int) -> None:
        """Render from the file's sensor ``k`` (0-based, file order): its camera (film size,
        crop window, filter) and sample count become ``camera`` and ``spp``. Raises
        ``SceneError`` naming the file and the number of sensors for a ``k`` out of range, and
        the sensor's own error for one the core cannot render."""
        sensors = self.sensors or [(self.camera, self.spp)]
        if not 0 <= k < len(sensors):
            raise SceneError(sensor_range_message(k, len(sensors)), file=self.path)
        if isinstance(sensors[k], Exception):
            raise sensors[k]
        self.camera, self.spp = sensors[k]

    def content_key(self) -> bytes:
        """A digest of everything the caches are built from: the shapes (geometry, materials,
        textures), the lights and the background. Changing any of them after a render (in place
        or by replacing list items) changes the key, unless the scene is pinned."""
        if self._pinned_key is not None:
            return self._pinned_key
        return content_key((self.shapes, self.lights, self.environments, self.background))

    def pin_content(self) -> bytes:
        """Compute the content key once and keep it: for an owner that renders the same,
        unchanged scene many times (a partition node renders one window per call, and hashing
        300 quadrics costs ~15 ms, half a 32x32 window's launch). Changes made after pinning
        are not seen by the caches; :meth:`unpin_content` goes back to hashing at every use."""
        self._pinned_key = None
        self._pinned_key = self.content_key()
        return self._pinned_key

    def unpin_content(self) -> None:
        self._pinned_key = None

    def take(self, other: "Scene") -> None:
        """Become ``other`` in place (its camera, sensors, shapes, lights, settings), keeping the
        caches: what was built for content ``other`` shares (a camera move: the BVH, the
        integrator's plan) is found again by its key, the rest is built on first use. A pinned
        scene is pinned to its new content."""
        pinned = self._pinned_key is not None
        for f in fields(self):
            if f.init:
                setattr(self, f.name, getattr(other, f.name))
        self._index_shapes()
        self._pinned_key = None
        if pinned:
            self.pin_content()

    def cached(self, name: str, build, key: bytes | None = None):
        """``build()`` once per content of the scene: the value kept under ``name`` while the
        scene's :meth:`content_key` is the one it was built for (no ``id(scene)`` keys, nothing
        stale after the scene is changed)."""
        key = self.content_key() if key is None else key
        hit = self._caches.get(name)
        if hit is not None and hit[0] == key:
            return hit[1]
        self._index_shapes()
        value = build()
        self._caches[name] = (key, value)
        return value

    @property
    def accel(self):
        """The hierarchical bounding boxes over all shapes (paper 3-2-4), built on first use
        and again whenever the shapes change."""
        return self.cached("accel", lambda: Accel(self.shapes))

    def __repr__(self) -> str:
        c = self.camera
        return (f"Scene(path={self.path!r}, film={c.width}x{c.height}, shapes={len(self.shapes)}, "
                f"lights={len(self.lights)}, spp={self.spp}, max_depth={self.max_depth})")


def content_key(obj) -> bytes:
    """A 16-byte digest of ``obj``'s content: numbers, strings, arrays (dtype, shape, bytes),
    sequences, dicts and the public attributes of objects, recursively (an object met twice
    is hashed once; attributes starting with ``_`` are caches and are left out)."""
    h = hashlib.blake2b(digest_size=16)
    seen = {}

    def walk(o):
        if o is None or isinstance(o, (bool, int, float, complex, str, bytes, np.generic)):
            h.update(f"{type(o).__name__}:{o!r};".encode())
            return
        if isinstance(o, np.ndarray):
            h.update(f"nd:{o.dtype.str}:{o.shape};".encode())
            h.update(np.ascontiguousarray(o).tobytes())
            return
        if id(o) in seen:  # shared (a material on many shapes) or a cycle
            h.update(f"ref:{seen[id(o)]};".encode())
            return
        seen[id(o)] = len(seen)
        if isinstance(o, (list, tuple)):
            h.update(f"seq:{len(o)}[".encode())
            for x in o:
                walk(x)
            h.update(b"]")
        elif isinstance(o, dict):
            h.update(f"dict:{len(o)}{{".encode())
            for k in sorted(o, key=repr):
                walk(k)
                walk(o[k])
            h.update(b"}")
        else:
            h.update(f"obj:{type(o).__module__}.{type(o).__qualname__}(".encode())
            attrs = getattr(o, "__dict__", None)
            if attrs is None:
                attrs = {k: getattr(o, k) for k in getattr(type(o), "__slots__", ()) if hasattr(o, k)}
            for k in sorted(attrs):
                if not k.startswith("_") and not callable(attrs[k]):
                    h.update(k.encode())
                    walk(attrs[k])
            h.update(b")")

    walk(obj)
    return h.digest()


def sensor_range_message(k: int, count: int) -> str:
    """The one message for a sensor index outside a scene's ``count`` sensors (both renderers)."""
    if count == 0:
        return f"sensor {k} does not exist: the scene has no sensor (add a <sensor type='perspective'>)"
    return (f"sensor {k} does not exist: the scene has {count} sensor{'s' if count != 1 else ''} "
            f"(--sensor 0{'..' + str(count - 1) if count > 1 else ''})")


def check_sensor_index(path, sensor, count: int) -> int:
    """``sensor`` (None: 0) as an index into a scene's ``count`` sensors, or a one-line error
    naming the scene file and how many sensors it has (both renderers)."""
    k = 0 if sensor is None else sensor
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)):
        raise UsageError(f"sensor must be an integer index, got {sensor!r}")
    k = int(k)
    if not 0 <= k < count:
        raise SceneError(sensor_range_message(k, count), file=str(path))
    return k
