"""An analytic oracle for the golden images, written apart from links1's renderers.

It reads a scene's XML itself (``xml.etree``, ``$name`` defaults), builds camera rays from
Mitsuba's documented ``perspective`` conventions (``fov`` along x, ``lookat``; image x runs
against the camera's left axis) and evaluates, in closed form, the light paths it can be
sure of:

* a primary ray that misses everything: the background (``constant`` emitter, else black);
  a surface in a scene with a ``constant`` emitter is unknown (the environment lights it by
  Monte Carlo sampling);
* a primary ray whose first hit is an *exact* shape (``rectangle``, ``sphere``, ``cube``,
  ``obj`` triangles, an unclipped ``links1_quadric`` ellipsoid) with an opaque,
  non-mirroring material, shaded directly: eq. 3.11 for ``links1_phong``
  (``dic + Σ L (drc cos θ + src (cos φ)^n)``, paper units, no fall-off for the paper's
  lights) or albedo/π for Mitsuba's ``diffuse`` (inverse-square ``point``); shadow rays
  through exact shapes, an opaque one blocking the light, a transparent ``links1_phong``
  one scaling it by its transmittance once per object (3-3-3).

Everything else (clipped quadrics, blobs, bicubic patches) is only known by a bounding
ball (3S around each blob centre, the control points' box, the unclipped ellipsoid): a
pixel whose camera or shadow rays come near one is *unknown* and not checked. So are
pixels whose first hit mirrors or refracts.

``probe(scene_path, res, params)`` -> (values (H, W, 3) float64, known (H, W) bool) at the
pixel centres, or ``probe(..., sub=k)`` on a k×k grid of points in each pixel
(shape (H, W, k*k, 3)), for golden images rendered with several samples per pixel.
"""
from __future__ import annotations

import math
import os
import re
import xml.etree.ElementTree as ET

import numpy as np

EPS = 1e-6          # ray offset (scene units ~1-10)
MARGIN = 1e-3       # bounding balls are grown by this much
UNKNOWN = object()


# ------------------------------------------------------------------------------ XML reading

def _subst(text, params):
    return re.sub(r"\$(\w+)", lambda m: str(params[m.group(1)]), text)


def _floats(s):
    return [float(v) for v in re.split(r"[,\s]+", s.strip()) if v]


def _rgb(node, name, default):
    for c in node:
        if c.get("name") == name and c.tag in ("rgb", "float", "spectrum"):
            v = _floats(c.get("value"))
            return np.array(v * 3 if len(v) == 1 else v, dtype=float)
    return None if default is None else np.full(3, float(default))


def _float(node, name, default):
    for c in node:
        if c.get("name") == name and c.tag in ("float", "integer"):
            return float(c.get("value"))
    return default


def _vec(node, name):
    for c in node:
        if c.get("name") == name and c.tag in ("point", "vector"):
            if c.get("value") is not None:
                return np.array(_floats(c.get("value")))
            return np.array([float(c.get(k, 0)) for k in "xyz"])
    return None


def _rotation(axis, deg):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    x, y, z = a
    return np.array([[c + x * x * (1 - c), x * y * (1 - c) - z * s, x * z * (1 - c) + y * s],
                     [y * x * (1 - c) + z * s, c + y * y * (1 - c), y * z * (1 - c) - x * s],
                     [z * x * (1 - c) - y * s, z * y * (1 - c) + x * s, c + z * z * (1 - c)]])


def _transform(node):
    """4x4 matrix of a ``<transform name="to_world">`` child (identity if none); each
    element applies after the previous ones (Mitsuba's order)."""
    m = np.eye(4)
    for t in node:
        if t.tag != "transform" or t.get("name") != "to_world":
            continue
        for op in t:
            e = np.eye(4)
            if op.tag == "scale":
                if op.get("value") is not None:
                    e[:3, :3] *= float(op.get("value"))
                else:
                    e[:3, :3] = np.diag([float(op.get(k, 1)) for k in "xyz"])
            elif op.tag == "translate":
                e[:3, 3] = [float(op.get(k, 0)) for k in "xyz"]
            elif op.tag == "rotate":
                e[:3, :3] = _rotation([float(op.get(k, 0)) for k in "xyz"], float(op.get("angle")))
            else:
                raise NotImplementedError(f"oracle: transform <{op.tag}>")
            m = e @ m
    return m


def _expand(root, params, base):
    """Inline ``<include>`` and substitute ``$name`` (scene defaults, then ``params``)."""
    vals = {d.get("name"): d.get("value") for d in root.iter("default")}
    vals.update({k: str(v) for k, v in params.items()})
    out = []
    for child in root:
        if child.tag == "include":
            inc = ET.parse(os.path.join(base, child.get("filename"))).getroot()
            out.extend(list(inc))
        elif child.tag != "default":
            out.append(child)
    for node in out:
        for e in node.iter():
            for k, v in list(e.attrib.items()):
                if "$" in v:
                    e.set(k, _subst(v, vals))
    return out


# ------------------------------------------------------------------------------ materials

class Material:
    """kind 'phong' (links1_phong) or 'diffuse' (Mitsuba's); mirror/glass marks it unknown."""

    def __init__(self, node, named):
        t = node.get("type")
        if t == "twosided":
            node = next(c for c in node if c.tag == "bsdf")
            t = node.get("type")
        self.kind, self.transmittance, self.opaque_unknown = t, np.zeros(3), False
        if t == "links1_phong":
            self.ambient = _rgb(node, "ambient", 0.0)
            self.diffuse = _rgb(node, "diffuse", 0.5)
            self.specular = _rgb(node, "specular", 0.0)
            self.exponent = _float(node, "exponent", 20.0)
            self.reflectance = _rgb(node, "reflectance", None)
            if self.reflectance is None:
                self.reflectance = self.specular
            self.transmittance = _rgb(node, "transmittance", 0.0)
            self.simple = not (self.reflectance.any() or self.transmittance.any())
        elif t == "diffuse":
            self.albedo = _rgb(node, "reflectance", 0.5)
            self.simple = True
        else:  # conductor, dielectric, ...: mirrors/refracts; blocks shadow rays (Mitsuba's NEE)
            self.simple = False


def _material(shape, named):
    for c in shape:
        if c.tag == "ref":
            return named[c.get("id")]
        if c.tag == "bsdf":
            return Material(c, named)
    return None


# ------------------------------------------------------------------------------ shapes

class Shape:
    """``hit(o, d) -> (t, n)`` arrays (t = inf where missed); ``unknown``: bounding ball."""
    material = None
    unknown = False


class Ball(Shape):
    """A sphere; as ``unknown`` it is the bounding ball of a shape not modelled exactly."""

    def __init__(self, c, r, material=None, unknown=False):
        self.c, self.r, self.material, self.unknown = np.asarray(c, float), float(r), material, unknown

    def hit(self, o, d):
        oc = o - self.c
        b = np.einsum("ij,ij->i", oc, d)
        c = np.einsum("ij,ij->i", oc, oc) - self.r ** 2
        disc = b * b - c
        s = np.sqrt(np.maximum(disc, 0))
        t0, t1 = -b - s, -b + s
        t = np.where(t0 > EPS, t0, np.where(t1 > EPS, t1, np.inf))
        t = np.where(disc >= 0, t, np.inf)
        with np.errstate(invalid="ignore"):   # inf * 0 on misses: their normals are unused
            n = (o + t[:, None] * d - self.c) / self.r
        return t, n


class Ellipsoid(Shape):
    def __init__(self, m, material):
        self.m, self.inv, self.material = m, np.linalg.inv(m), material

    def hit(self, o, d):
        ol = o @ self.inv[:3, :3].T + self.inv[:3, 3]
        dl = d @ self.inv[:3, :3].T
        a = np.einsum("ij,ij->i", dl, dl)
        b = np.einsum("ij,ij->i", ol, dl)
        c = np.einsum("ij,ij->i", ol, ol) - 1
        disc = b * b - a * c
        s = np.sqrt(np.maximum(disc, 0))
        t0, t1 = (-b - s) / a, (-b + s) / a
        t = np.where(t0 > EPS, t0, np.where(t1 > EPS, t1, np.inf))
        t = np.where(disc >= 0, t, np.inf)
        with np.errstate(invalid="ignore"):   # inf * 0 on misses: their normals are unused
            n = (ol + t[:, None] * dl) @ self.inv[:3, :3]          # inverse-transpose
            return t, n / np.linalg.norm(n, axis=1, keepdims=True)


class Triangles(Shape):
    def __init__(self, v, f, material):
        self.a, self.e1, self.e2, self.material = v[f[:, 0]], v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]], material
        n = np.cross(self.e1, self.e2)
        self.n = n / np.linalg.norm(n, axis=1, keepdims=True)

    def hit(self, o, d):
        best, bn = np.full(len(o), np.inf), np.zeros((len(o), 3))
        for a, e1, e2, nf in zip(self.a, self.e1, self.e2, self.n):   # Moller-Trumbore
            p = np.cross(d, e2)
            det = p @ e1
            ok = np.abs(det) > 1e-12
            inv = np.where(ok, 1 / np.where(ok, det, 1), 0)
            s = o - a
            u = np.einsum("ij,ij->i", s, p) * inv
            q = np.cross(s, e1)
            v = np.einsum("ij,ij->i", d, q) * inv
            t = (q @ e2) * inv
            h = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > EPS) & (t < best)
            best = np.where(h, t, best)
            bn[h] = nf
        return best, bn


def _quad(m):
    """rectangle [-1,1]² at z=0 (or a cube's face) -> 2 triangles' vertices."""
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    return v @ m[:3, :3].T + m[:3, 3], np.array([[0, 1, 2], [0, 2, 3]])


def _cube(m):
    c = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    f = np.array([t for a, b, c_, d in faces for t in ((a, b, c_), (a, c_, d))])
    return c @ m[:3, :3].T + m[:3, 3], f


def _obj(path):
    v, f = [], []
    with open(path) as fh:
        for line in fh:
            w = line.split()
            if w and w[0] == "v":
                v.append([float(x) for x in w[1:4]])
            elif w and w[0] == "f":
                idx = [int(x.split("/")[0]) - 1 for x in w[1:]]
                f += [(idx[0], idx[i], idx[i + 1]) for i in range(1, len(idx) - 1)]
    return np.array(v), np.array(f)


def _ball_of_points(p):
    lo, hi = p.min(0), p.max(0)
    return Ball((lo + hi) / 2, np.linalg.norm(hi - lo) / 2 + MARGIN, unknown=True)


def _shape(node, named, base):
    t, mat, m = node.get("type"), _material(node, named), _transform(node)
    if t == "rectangle":
        return Triangles(*_quad(m), mat)
    if t == "cube":
        return Triangles(*_cube(m), mat)
    if t == "obj":
        v, f = _obj(os.path.join(base, next(c.get("value") for c in node if c.get("name") == "filename")))
        return Triangles(v @ m[:3, :3].T + m[:3, 3], f, mat)
    if t == "sphere":
        c, r = _vec(node, "center"), _float(node, "radius", 1.0)
        if c is None:
            c = np.zeros(3)
        c = m[:3, :3] @ c + m[:3, 3]
        return Ball(c, r * abs(np.linalg.det(m[:3, :3])) ** (1 / 3), mat)
    if t == "links1_quadric":
        kind = next((c.get("value") for c in node if c.get("name") == "kind"), "sphere")
        assert kind == "sphere", "oracle: cylinders are not modelled"
        clipped = any((c.get("name") or "").startswith("clip_") for c in node)
        if not clipped:
            return Ellipsoid(m, mat)
        return Ball(m[:3, 3], np.linalg.svd(m[:3, :3], compute_uv=False).max() + MARGIN, unknown=True)
    if t == "links1_blob":
        g = np.array(_floats(next(c.get("value") for c in node if c.get("name") == "centers"))).reshape(-1, 5)
        c = g[:, :3] @ m[:3, :3].T + m[:3, 3]
        r = 3 * g[:, 4] * np.linalg.svd(m[:3, :3], compute_uv=False).max()
        return [Ball(ci, ri + MARGIN, unknown=True) for ci, ri in zip(c, r)]
    if t == "links1_bicubic":
        with open(os.path.join(base, next(c.get("value") for c in node if c.get("name") == "filename"))) as fh:
            nums = [float(x) for line in fh if not line.startswith("#") for x in line.split()]
        p = np.array(nums[1:]).reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]
        return _ball_of_points(p)
    raise NotImplementedError(f"oracle: shape {t}")


# ------------------------------------------------------------------------------ lights

class Light:
    def __init__(self, node):
        self.type = node.get("type")
        if self.type == "directional":
            d = _vec(node, "direction")
            self.d, self.E = d / np.linalg.norm(d), _rgb(node, "irradiance", 1.0)
        elif self.type == "links1_point":
            d = _vec(node, "direction")
            self.p, self.axis = _vec(node, "position"), d / np.linalg.norm(d)
            self.L1, self.L2 = _rgb(node, "L1", 1.0), _rgb(node, "L2", 0.0)
            assert next((c.get("value") for c in node if c.get("name") == "falloff"), "none") == "none"
        elif self.type == "links1_spot":
            d = _vec(node, "direction")
            self.o, self.d = _vec(node, "origin"), d / np.linalg.norm(d)
            self.r, self.I = _float(node, "radius", 1.0), _rgb(node, "intensity", 1.0)
        elif self.type == "point":
            self.p, self.I = _vec(node, "position"), _rgb(node, "intensity", 1.0)
        else:
            raise NotImplementedError(f"oracle: emitter {self.type}")

    def arrive(self, p):
        """-> (direction to the light, distance, strength L_s at p) per point."""
        n = len(p)
        if self.type == "directional":
            return np.broadcast_to(-self.d, (n, 3)), np.full(n, np.inf), np.broadcast_to(self.E, (n, 3))
        if self.type == "links1_spot":  # parallel light inside a semi-infinite cylinder
            rel = p - self.o
            along = rel @ self.d
            radial = np.linalg.norm(rel - along[:, None] * self.d, axis=1)
            inside = (along > 0) & (radial <= self.r)
            return (np.broadcast_to(-self.d, (n, 3)), np.where(inside, along, 0.0),
                    np.where(inside[:, None], self.I, 0.0))
        to = self.p - p
        dist = np.linalg.norm(to, axis=1)
        wi = to / dist[:, None]
        if self.type == "point":  # Mitsuba's isotropic point light: intensity / d²
            return wi, dist, self.I / (dist ** 2)[:, None]
        cos = -wi @ self.axis  # eq. 3.10: L1 + L2 cos θ inside ±90°, L1 beyond
        return wi, dist, self.L1 + np.where(cos > 0, cos, 0.0)[:, None] * self.L2


# ------------------------------------------------------------------------------ the oracle

class Scene:
    def __init__(self, path, params):
        base = os.path.dirname(os.path.abspath(path))
        nodes = _expand(ET.parse(path).getroot(), params, base)
        named = {n.get("id"): Material(n, None) for n in nodes if n.tag == "bsdf"}
        self.shapes, self.lights, self.background, self.env_lit = [], [], np.zeros(3), False
        for n in nodes:
            if n.tag == "shape":
                s = _shape(n, named, base)
                self.shapes += s if isinstance(s, list) else [s]
            elif n.tag == "emitter":
                if n.get("type") == "constant":
                    self.background, self.env_lit = _rgb(n, "radiance", 1.0), True
                else:
                    self.lights.append(Light(n))
            elif n.tag == "sensor":
                self.fov = _float(n, "fov", None)
                look = next(t for t in n.iter("lookat"))
                self.eye, self.target = (np.array(_floats(look.get(k))) for k in ("origin", "target"))
                self.up = np.array(_floats(look.get("up")))
                film = next(n.iter("film"))
                self.w, self.h = int(_float(film, "width", 768)), int(_float(film, "height", 576))

    def camera_rays(self, sub):
        """Rays through a sub×sub grid of points in each pixel (centres for sub=1)."""
        k = (np.arange(sub) + 0.5) / sub
        x = (np.arange(self.w)[:, None] + k[None, :]).ravel()
        y = (np.arange(self.h)[:, None] + k[None, :]).ravel()
        X, Y = np.meshgrid(x, y)            # (H*sub, W*sub)
        return self.rays_through(X, Y).reshape(-1, 3)

    def rays_through(self, X, Y):
        """Unit directions of the camera rays through film positions ``(X, Y)`` (pixels, row 0
        at the top; any shape) -> shape + (3,)."""
        fwd = (self.target - self.eye) / np.linalg.norm(self.target - self.eye)
        left = np.cross(self.up, fwd)
        left /= np.linalg.norm(left)
        up = np.cross(fwd, left)
        tx = math.tan(math.radians(self.fov) / 2)
        cx = (1 - 2 * X / self.w) * tx                  # + = the camera's left
        cy = (1 - 2 * Y / self.h) * tx * self.h / self.w
        d = cx[..., None] * left + cy[..., None] * up + fwd
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def nearest(self, o, d):
        t, idx, n = np.full(len(o), np.inf), np.full(len(o), -1), np.zeros((len(o), 3))
        for i, s in enumerate(self.shapes):
            ts, ns = s.hit(o, d)
            closer = ts < t
            t, idx = np.where(closer, ts, t), np.where(closer, i, idx)
            n[closer] = ns[closer]
        return t, idx, n

    def shade(self, d):
        """Radiance and whether it is known, for camera rays ``d`` from the eye."""
        o = np.broadcast_to(self.eye, d.shape).copy()
        t, idx, n = self.nearest(o, d)
        out, known = np.zeros((len(d), 3)), np.ones(len(d), bool)
        miss = idx < 0
        out[miss] = self.background
        for i, s in enumerate(self.shapes):
            # an environment lights surfaces by sampling (Monte Carlo): not modelled
            if s.unknown or s.material is None or not s.material.simple or self.env_lit:
                known[idx == i] = False
        sel = np.flatnonzero(known & ~miss)       # exact, opaque, non-mirroring first hits
        p = o[sel] + t[sel, None] * d[sel]
        nn = n[sel] * np.where(np.einsum("ij,ij->i", n[sel], d[sel]) > 0, -1.0, 1.0)[:, None]
        v = -d[sel]
        mats = [self.shapes[i].material for i in idx[sel]]
        phong = np.array([m.kind == "links1_phong" for m in mats], bool)
        ones = np.zeros(3)

        def table(name):
            return np.array([getattr(m, name, ones) for m in mats]).reshape(len(sel), 3)
        ambient, diffuse, specular, albedo = (table(k) for k in ("ambient", "diffuse", "specular", "albedo"))
        exponent = np.array([getattr(m, "exponent", 1.0) for m in mats])
        col = ambient.copy()
        for light in self.lights:
            wi, dist, L = light.arrive(p)
            cos = np.einsum("ij,ij->i", nn, wi)
            T, ok = self.transmission(p + nn * EPS * 10, wi, dist)
            known[sel[~ok & (cos > 0) & (L.max(1) > 0)]] = False
            lit = (cos > 0)[:, None] * T * L
            r = 2 * cos[:, None] * nn - wi
            cphi = np.maximum(np.einsum("ij,ij->i", r, v), 0.0)
            col += np.where(phong[:, None],
                            lit * (diffuse * cos[:, None] + specular * (cphi ** exponent)[:, None]),  # eq. 3.11
                            lit * albedo / math.pi * cos[:, None])   # Mitsuba's diffuse: albedo / π
        out[sel] = col
        return out, known

    def transmission(self, p, wi, dist):
        """Product of the transmittances of the exact shapes between p and the light (0 for
        an opaque one; each object once) and whether it is known (no bounding ball met)."""
        T, ok = np.ones((len(p), 3)), np.ones(len(p), bool)
        for s in self.shapes:
            ts, _ = s.hit(p, wi)
            on = ts < dist
            if not on.any():
                continue
            if s.unknown:
                ok &= ~on
            elif s.material is not None and s.material.kind == "links1_phong" and s.material.transmittance.any():
                T[on] *= s.material.transmittance
            else:
                T[on] = 0.0
        return T, ok


def probe(path, params, sub=1):
    sc = Scene(path, params)
    val, known = sc.shade(sc.camera_rays(sub))
    W, H = sc.w, sc.h
    val = val.reshape(H, sub, W, sub, 3).transpose(0, 2, 1, 3, 4).reshape(H, W, sub * sub, 3)
    known = known.reshape(H, sub, W, sub).transpose(0, 2, 1, 3).reshape(H, W, sub * sub).all(-1)
    return (val[:, :, 0] if sub == 1 else val), known
