"""``links1_point`` (eq. 3.10) and ``links1_spot`` (3-3-1 iii) as Mitsuba emitters."""
from __future__ import annotations

import math

import numpy as np

from links1.scene.params import default, param, read

from .registered import check_properties
from .util import Hidden, read_rgb as _rgb

FALLOFFS = param("links1_point", "falloff").choices


def _vec(props, name, default):
    if (name in props):
        v = props[name]
        return np.array([float(v[0]), float(v[1]), float(v[2])])
    return None if default is None else np.asarray(default, dtype=np.float64)


def _to_world(props):
    if ("to_world" in props):
        return np.array(props["to_world"].matrix, dtype=np.float64).reshape(4, 4)
    return None


def _unit(v, what):
    n = float(np.linalg.norm(v))
    if not (math.isfinite(n) and n > 0):
        raise ValueError(f"{what} must be a finite non-zero vector, got {list(v)}")
    return v / n


def point_params(props) -> dict:
    check_properties("emitter", "links1_point", props)
    pos = _vec(props, "position", default("links1_point", "position"))
    direction = _vec(props, "direction", default("links1_point", "direction"))
    m = _to_world(props)
    if m is not None:
        pos = m[:3, :3] @ pos + m[:3, 3]
        direction = m[:3, :3] @ direction
    falloff = read("links1_point", "falloff", str(props["falloff"]) if "falloff" in props else None)
    return dict(position=read("links1_point", "position", pos),
                direction=_unit(read("links1_point", "direction", direction), "links1_point: direction"),
                L1=read("links1_point", "L1", _rgb(props, "L1", None)),
                L2=read("links1_point", "L2", _rgb(props, "L2", None)), falloff=falloff)


def spot_params(props) -> dict:
    check_properties("emitter", "links1_spot", props)
    origin = _vec(props, "origin", default("links1_spot", "origin"))
    direction = read("links1_spot", "direction", _vec(props, "direction", None))
    m = _to_world(props)
    if m is not None:
        origin = m[:3, :3] @ origin + m[:3, 3]
        direction = m[:3, :3] @ direction
    radius = read("links1_spot", "radius", float(props["radius"]) if "radius" in props else None)
    return dict(origin=read("links1_spot", "origin", origin),
                direction=_unit(read("links1_spot", "direction", direction), "links1_spot: direction"),
                radius=radius, intensity=read("links1_spot", "intensity", _rgb(props, "intensity", None)))


def define_emitters():
    """``{"links1_point": class, "links1_spot": class}`` for the variant in use: subclasses of
    that variant's ``mi.Emitter`` (and their ``TRAVERSED`` table names its ``mi.Point3f``, ...),
    so they are made per variant (``_registry.register``), unlike the integrator's mixins."""
    import drjit as dr
    import mitsuba as mi

    def c3(v):
        return mi.Color3f(float(v[0]), float(v[1]), float(v[2]))

    def v3(v):
        return mi.Vector3f(float(v[0]), float(v[1]), float(v[2]))

    #: each light's parameters in ``mi.traverse``: (name, key, Dr.Jit type, flags). Colours as
    #: Mitsuba names an emitter's (``<id>.L1.value`` as ``point``'s ``intensity.value``), points
    #: and vectors as ``point``'s ``position``; moving a light moves shadow edges, which
    #: ``links1_whitted``'s gradients leave out (Discontinuous, as Mitsuba marks such parameters)
    D, DD = mi.ParamFlags.Differentiable, mi.ParamFlags.Differentiable | mi.ParamFlags.Discontinuous
    TRAVERSED = {
        "links1_point": (("position", "position", mi.Point3f, DD), ("direction", "direction", mi.Vector3f, DD),
                         ("L1", "L1.value", mi.Color3f, D), ("L2", "L2.value", mi.Color3f, D)),
        "links1_spot": (("origin", "origin", mi.Point3f, DD), ("direction", "direction", mi.Vector3f, DD),
                        ("radius", "radius", mi.Float, DD), ("intensity", "intensity.value", mi.Color3f, D)),
    }

    class _DeltaEmitter(mi.Emitter):
        """What both links1 lights share: delta lights have no density and emit nothing
        a ray could hit; their parameters in ``mi.traverse`` (``TRAVERSED``): the Python values
        (``params``, what links1_whitted's tables read) and their Dr.Jit values (``values``,
        what ``traverse`` hands out and its gradient launches read), kept in step by
        ``parameters_changed``."""

        _kind = None
        _check = None

        def _hold(self, params):
            vals = {}
            for name, _, tp, _ in TRAVERSED[self._kind]:
                v = params[name]
                vals[name] = tp(float(v)) if tp is mi.Float else tp(*[float(c) for c in v])
            self._held = Hidden(params=params, values=vals)     # see util.Hidden

        values = property(lambda self: self._held.values)

        def traverse(self, callback):
            for name, key, _, flags in TRAVERSED[self._kind]:
                callback.put(key, self._held.values[name], flags)

        def parameters_changed(self, keys):
            """``params.update()``: the Python values follow the Dr.Jit ones, checked as the
            loader checks them (links1.scene.params; a direction is normalised)."""
            p = dict(self.params)
            for name, _, tp, _ in TRAVERSED[self._kind]:
                a = np.array(self._held.values[name], dtype=np.float64).ravel()
                v = float(a[0]) if tp is mi.Float else np.broadcast_to(a, (3,)).copy()
                v = read(self._kind, name, v)
                if name == "direction":
                    v = _unit(v, f"{self._kind}: direction")
                p[name] = v
            self._held.params = p

        def pdf_direction(self, it, ds, active=True):
            return mi.Float(0.0)

        def eval_direction(self, it, ds, active=True):
            return mi.Color3f(0.0)

        def eval(self, si, active=True):
            return mi.Color3f(0.0)

    class Links1Point(_DeltaEmitter):
        r"""LINKS-1 point light with a cosine lobe (``links1_point``), eq. (3.10).

        ``L_s = L1 + L2 cos θ`` for ``|θ| ≤ 90°`` and ``L1`` beyond, θ measured from ``direction``.

        ==========  ======  =====================================================  ===========
        Parameter   Type    Meaning                                                Default
        ==========  ======  =====================================================  ===========
        position    point   where the light is                                     (0, 0, 0)
        direction   vector  direction of maximum strength                          (0, 0, 1)
        L1          rgb     isotropic strength                                     1
        L2          rgb     strength of the cosine lobe                            0
        falloff     string  ``none`` (paper) or ``inverse_square`` (physical)      none
        to_world    trafo   applied to position and direction                      identity
        ==========  ======  =====================================================  ===========

        A delta-position emitter: Mitsuba's ``direct`` and ``path`` sample it like ``point``
        (``falloff=inverse_square``, ``L2=0`` is Mitsuba's ``point`` with ``intensity=L1``).
        """

        _kind = "links1_point"

        def __init__(self, props):
            super().__init__(props)
            self._hold(point_params(props))
            self.m_flags = mi.EmitterFlags.DeltaPosition

        params = property(lambda self: self._held.params)
        _pos = property(lambda self: self.params["position"])
        _dir = property(lambda self: self.params["direction"])
        _L1 = property(lambda self: self.params["L1"])
        _L2 = property(lambda self: self.params["L2"])
        _inv_sq = property(lambda self: self.params["falloff"] == "inverse_square")

        def _strength(self, to_light, dist):
            wi = to_light / dr.maximum(dist, 1e-30)
            cos_theta = -dr.dot(wi, v3(self._dir))
            L = c3(self._L1) + c3(self._L2) * dr.maximum(cos_theta, 0.0)  # eq. (3.10)
            if self._inv_sq:
                L = L / dr.square(dist)
            return wi, L

        def sample_direction(self, it, sample, active=True):
            p = mi.Point3f(*[float(x) for x in self._pos])
            to_light = p - it.p
            dist = dr.norm(to_light)
            wi, L = self._strength(to_light, dist)
            ds = dr.zeros(mi.DirectionSample3f)
            ds.p = p
            ds.n = mi.Normal3f(0.0)
            ds.time = it.time
            ds.pdf = mi.Float(1.0)
            ds.delta = mi.Bool(True)
            ds.d = wi
            ds.dist = dist
            ds.emitter = mi.EmitterPtr(self)
            return ds, dr.select(active & (dist > 0), L, 0.0)

        def sample_position(self, time, sample, active=True):
            ps = dr.zeros(mi.PositionSample3f)
            ps.p = mi.Point3f(*[float(x) for x in self._pos])
            ps.time = time
            ps.pdf = mi.Float(1.0)
            ps.delta = mi.Bool(True)
            return ps, mi.Float(1.0)

        def sample_ray(self, time, sample1, sample2, sample3, active=True):
            d = mi.warp.square_to_uniform_sphere(sample3)
            cos_theta = dr.dot(d, v3(self._dir))
            L = c3(self._L1) + c3(self._L2) * dr.maximum(cos_theta, 0.0)
            ray = mi.Ray3f(mi.Point3f(*[float(x) for x in self._pos]), d, time)
            return ray, L * (4.0 * math.pi)

        def bbox(self):
            p = mi.ScalarPoint3f(*[float(x) for x in self._pos])
            return mi.ScalarBoundingBox3f(p, p)

        def to_string(self):
            p = self.params
            return (f"Links1Point[position={p['position'].tolist()}, direction={p['direction'].tolist()}, "
                    f"L1={p['L1'].tolist()}, L2={p['L2'].tolist()}, falloff={p['falloff']}]")

    class Links1Spot(_DeltaEmitter):
        r"""LINKS-1 spotlight (``links1_spot``): parallel light inside a semi-infinite cylinder.

        ==========  ======  =====================================================  ===========
        Parameter   Type    Meaning                                                Default
        ==========  ======  =====================================================  ===========
        origin      point   centre of the cylinder's base disc                     (0, 0, 0)
        direction   vector  direction the light travels (cylinder axis)            required
        radius      float   radius of the cylinder                                 required
        intensity   rgb     strength inside the cylinder (no distance fall-off)    1
        to_world    trafo   applied to origin and direction                        identity
        ==========  ======  =====================================================  ===========

        Points behind the base plane or farther than ``radius`` from the axis are unlit;
        shadow rays end at the base plane. A delta-direction emitter (like ``directional``).
        """

        _kind = "links1_spot"

        def __init__(self, props):
            super().__init__(props)
            self._hold(spot_params(props))
            self.m_flags = mi.EmitterFlags.DeltaDirection

        params = property(lambda self: self._held.params)
        _o = property(lambda self: self.params["origin"])
        _d = property(lambda self: self.params["direction"])
        _r = property(lambda self: self.params["radius"])
        _I = property(lambda self: self.params["intensity"])

        def sample_direction(self, it, sample, active=True):
            axis = v3(self._d)
            rel = it.p - mi.Point3f(*[float(x) for x in self._o])
            s = dr.dot(rel, axis)
            radial = rel - s * axis
            inside = (s > 0) & (dr.squared_norm(radial) <= self._r * self._r)
            ds = dr.zeros(mi.DirectionSample3f)
            ds.p = it.p - axis * s
            ds.n = mi.Normal3f(axis)
            ds.time = it.time
            ds.pdf = mi.Float(1.0)
            ds.delta = mi.Bool(True)
            ds.d = -axis
            ds.dist = dr.select(inside, s, 0.0)
            ds.emitter = mi.EmitterPtr(self)
            return ds, dr.select(active & inside, c3(self._I), 0.0)

        def sample_position(self, time, sample, active=True):
            frame = mi.Frame3f(v3(self._d))
            q = mi.warp.square_to_uniform_disk_concentric(sample) * self._r
            ps = dr.zeros(mi.PositionSample3f)
            ps.p = mi.Point3f(*[float(x) for x in self._o]) + frame.s * q.x + frame.t * q.y
            ps.n = mi.Normal3f(v3(self._d))
            ps.time = time
            ps.pdf = mi.Float(1.0 / (math.pi * self._r * self._r))
            return ps, mi.Float(math.pi * self._r * self._r)

        def sample_ray(self, time, sample1, sample2, sample3, active=True):
            ps, w = self.sample_position(time, sample2, active)
            ray = mi.Ray3f(ps.p, v3(self._d), time)
            return ray, c3(self._I) * w

        def bbox(self):
            return mi.ScalarBoundingBox3f()

        def to_string(self):
            p = self.params
            return (f"Links1Spot[origin={p['origin'].tolist()}, direction={p['direction'].tolist()}, "
                    f"radius={p['radius']}, intensity={p['intensity'].tolist()}]")

    return {"links1_point": Links1Point, "links1_spot": Links1Spot}
