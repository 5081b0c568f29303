"""The geometry of the links1 shapes in ``mi.traverse`` and its derivatives.

``links1_quadric`` and ``links1_blob`` are not Mitsuba shapes: ``links1_whitted`` holds them
(:class:`~links1_mitsuba.shapes.QuadricSpec`, :class:`~links1_mitsuba.blob.BlobSpec`). Their
parameters are listed under the integrator, as their BSDFs are
(``links1_whitted.<shape id>.<parameter>``), as Dr.Jit values (:func:`hold`):

* ``links1_quadric``: ``to_world`` (an ``AffineTransform4f``, as a Mitsuba shape's) and
  ``clip_<k>_offset`` (a ``Float`` per clip plane, ``h`` of ``n·x ≤ h`` in object space);
* ``links1_blob``: ``centers`` (``Point3f``, one lane per centre, object space), ``weights``
  and ``radii`` (``Float``, the ``w_i`` and ``S_i`` of eq. 3.6–3.9), ``threshold`` (``T`` of
  eq. 3.8) and ``to_world``.

``params.update()`` hands the new values to :func:`updated`, which checks them as the loader
checks a file's (links1.scene.params) and returns a new spec; the integrator's tables (BVH, blob
candidate tables) are then built again at the next frame.

Derivatives (:func:`surface_ad`): the *interior* derivative of a hit. The nearest hit (which
surface, which root) is found on primal values; the hit distance is then re-attached by
implicit differentiation of the surface equation ``F(o + t d; θ) = 0``:

    dt = −(∂F/∂θ dθ + ∂F/∂o do + ∂F/∂d dd) / (∂F/∂t),

written as ``t − (F − detach(F)) / detach(∂F/∂t)`` (its value is the primal ``t`` bit for bit).
For a quadric ``F = |A(x − m)|² − 1`` (eq. 3.4–3.5; in object space ``|u|² − 1`` with
``u = M⁻¹x``, cylinder without ``z``) — the closed-form root moving with the surface; on a
cap ``F = n·u − h``. For a blob ``F = W(x) − T`` with ``W = Σ w_i P(|x − c_i|)`` (eq. 3.6–3.9).
The normal is recomputed from the attached values (a quadric's ``M⁻ᵀ ∇F``, a blob's ``−∇W``),
so the shading and the mirror and refraction rays follow the surface. ``M⁻¹`` is attached as
``M₀⁻¹ − M₀⁻¹ (M − M₀) M₀⁻¹`` (``M₀`` the primal matrix: the exact first derivative of the
inverse, and the primal's float32 inverse as its value).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from links1.scene.params import MAX_EXTENT, check, check_finite, read, transform_problem

from .shapes import shape_label

#: a blob's parameters in ``mi.traverse`` (a quadric's: ``to_world`` and its clip offsets)
BLOB_KEYS = ("centers", "weights", "radii", "threshold", "to_world")


def param_names(spec) -> list:
    """The names of ``spec``'s parameters in ``mi.traverse`` (after ``<shape id>.``)."""
    if spec.__class__.__name__ == "QuadricSpec":
        return ["to_world"] + [f"clip_{k}_offset" for k in range(len(spec.clips))]
    return list(BLOB_KEYS)


def hold(spec) -> dict:
    """``{name: Dr.Jit value}`` of ``spec``'s parameters (float32, what ``traverse`` hands out),
    evaluated arrays (never literals, which a kernel would take as constants)."""
    import drjit as dr
    import mitsuba as mi
    if spec.__class__.__name__ == "QuadricSpec":
        h = {"to_world": mi.Transform4f(np.asarray(spec.to_world, dtype=np.float64).tolist())}
        for k, (_, off) in enumerate(spec.clips):
            h[f"clip_{k}_offset"] = dr.opaque(mi.Float, float(off))   # not a literal (a kernel constant)
        return h
    c = spec.centers
    m = np.eye(4) if spec.to_world is None else spec.to_world
    return {"centers": mi.Point3f(c[:, 0], c[:, 1], c[:, 2]), "weights": mi.Float(c[:, 3]),
            "radii": mi.Float(c[:, 4]), "threshold": dr.opaque(mi.Float, float(spec.threshold)),
            "to_world": mi.Transform4f(np.asarray(m, dtype=np.float64).tolist())}


def seen(held: dict) -> dict:
    """The Dr.Jit variables of each held value (``params.update()`` gives a changed value new
    ones) and another reference to them (so that their indices are not reused while kept)."""
    import drjit as dr
    out = {}
    for k, v in held.items():
        pin = v.matrix if hasattr(v, "matrix") else v
        out[k] = (tuple(dr.detail.collect_indices(v)), type(pin)(pin))   # a copy: the old variables
    return out


def changed(held: dict, before: dict) -> list:
    """The names of the held values changed since ``before`` (:func:`seen`)."""
    import drjit as dr
    return [k for k, v in held.items() if tuple(dr.detail.collect_indices(v)) != before[k][0]]


def _matrix_of(v) -> np.ndarray:
    import drjit as dr
    # evaluated first: numpy would read an unevaluated matrix entry by entry (a kernel each)
    dr.eval(v.matrix)
    return np.array(v.matrix, dtype=np.float64).reshape(4, 4)


def _keep(old, new):
    """``new`` (float32 values read back) with the float64 ``old`` wherever ``new`` is
    ``old`` rounded to float32: numbers a ``params.update()`` did not change keep the precision
    the file gave them (the frame is then the frame of the file with the new values)."""
    old, new = np.asarray(old, dtype=np.float64), np.asarray(new, dtype=np.float64)
    return np.where(old.astype(np.float32).astype(np.float64) == new, old, new)


def updated(spec, held: dict, names) -> object:
    """A new spec with the parameters ``names`` (changed by ``params.update()``) read from
    ``held``, checked as the loader checks them; ValueError naming the shape (``FILE:LINE``
    where the loader knows its element) otherwise."""
    names = set(names)
    plugin = "links1_quadric" if spec.__class__.__name__ == "QuadricSpec" else "links1_blob"
    what = shape_label(plugin, spec.name, spec.where)
    kw = {}
    try:
        if "to_world" in names:
            m = _keep(np.eye(4) if spec.to_world is None else spec.to_world, _matrix_of(held["to_world"]))
            problem = transform_problem(m)
            if problem is not None:
                raise ValueError(problem)
            kw["to_world"] = m
        if spec.__class__.__name__ == "QuadricSpec":
            clips = list(spec.clips)
            for k in range(len(clips)):
                key = f"clip_{k}_offset"
                if key in names:
                    h = float(_keep(clips[k][1], np.array(held[key], dtype=np.float64).ravel()[0]))
                    clips[k] = (clips[k][0], check("links1_quadric", "clip_offset", h))
            kw["clips"] = clips
        else:
            c = spec.centers.copy()
            n = len(c)
            if "centers" in names:
                x = np.array(held["centers"], dtype=np.float64).reshape(3, -1).T   # (3, N) -> (N, 3)
                if x.shape != (n, 3):
                    raise ValueError(f"centers: {n} centres expected, got {x.shape[0]} (the count is fixed)")
                check_finite("centers", x, MAX_EXTENT)
                c[:, :3] = _keep(c[:, :3], x)
            for key, col in (("weights", 3), ("radii", 4)):
                if key in names:
                    v = np.array(held[key], dtype=np.float64).ravel()
                    if v.shape != (n,):
                        raise ValueError(f"{key}: {n} values expected, got {v.size} (the count is fixed)")
                    check_finite(key, v, MAX_EXTENT)
                    c[:, col] = _keep(c[:, col], v)
            bad = np.nonzero(~(c[:, 4] > 0))[0]
            if bad.size:
                raise ValueError(f"radii: centre {int(bad[0])}: the range S must be > 0, got {c[bad[0], 4]:g}")
            kw["centers"] = c
            if "threshold" in names:
                kw["threshold"] = read("links1_blob", "threshold", float(_keep(
                    spec.threshold, np.array(held["threshold"], dtype=np.float64).ravel()[0])))
    except ValueError as exc:
        raise ValueError(f"{what}: {exc}") from None
    new = dataclasses.replace(spec, **kw)
    new.emission = spec.emission
    return new


# ---------------------------------------------------------------------------- derivatives
def _attached(dr, held, names):
    return any(dr.grad_enabled(held[k]) for k in names if k in held)


def _inverse(mi, dr, rows, T):
    """``M⁻¹`` as a Matrix4f: the primal's (``rows``, its 3x4 rows gathered from the spec's
    table: not literals, so a new ``to_world`` replays the same kernels) with the derivative
    of ``T``'s matrix attached, ``M₀⁻¹ − M₀⁻¹ (M − M₀) M₀⁻¹``."""
    inv0 = mi.Matrix4f(*[mi.Float(x) for r in rows for x in r], 0.0, 0.0, 0.0, 1.0)
    if T is None or not dr.grad_enabled(T.matrix):
        return inv0
    M = T.matrix
    return inv0 - inv0 @ (M - dr.detach(M)) @ inv0


def _affine(mi, A, x, w=1.0):
    """``A[:3,:3] x + w A[:3,3]`` (``w`` 0: a direction)."""
    return mi.Vector3f(*[A[i, 0] * x.x + A[i, 1] * x.y + A[i, 2] * x.z + (A[i, 3] * w if w else 0.0)
                         for i in range(3)])


def _transposed(mi, A, g):
    """``A[:3,:3]ᵀ g`` (a normal from object to world space through ``A = M⁻¹``)."""
    return mi.Vector3f(*[A[0, j] * g.x + A[1, j] * g.y + A[2, j] * g.z for j in range(3)])


def _reattach(dr, t, F, Ft, m):
    """``t`` with the implicit derivative ``−dF/(∂F/∂t)`` (value unchanged) on lanes ``m``."""
    Ft = dr.detach(Ft)
    ok = m & (Ft != 0)
    return dr.select(ok, t - (F - dr.detach(F)) / dr.select(ok, Ft, 1.0), t)


def surface_ad(mi, dr, spec, held, o, d, t, prim, m, memo=None):
    """The hit ``o + t d`` of ``spec`` on lanes ``m`` (``t``: primal, detached) as attached
    values: ``(t, n)``, the distance moving with the surface and the outward unit normal.
    ``memo``: a dict kept for one derivative pass, which then makes each shape's attached
    ``M⁻¹`` once for all its levels (:func:`_inverse_of`)."""
    if spec.__class__.__name__ == "QuadricSpec":
        return _quadric_ad(mi, dr, spec, held, o, d, t, prim, m, memo)
    return _blob_ad(mi, dr, spec, held, o, d, t, m, memo)


def _inverse_of(mi, dr, spec, rows, held, memo):
    """:func:`_inverse` of ``spec`` (its primal rows ``rows``, ``held``'s ``to_world``), once
    per ``memo`` (None: every call)."""
    key = id(spec)
    if memo is not None and key in memo:
        return memo[key]
    A = _inverse(mi, dr, rows, held.get("to_world"))
    if memo is not None:
        memo[key] = A
    return A


def _quadric_ad(mi, dr, spec, held, o, d, t, prim, m, memo=None):
    from .util import spread     # (attached one-lane values at the lanes: one scatter-add kernel)
    A = spread(_inverse_of(mi, dr, spec, spec._inv(), held, memo), dr.width(o))
    sphere = spec.kind == "sphere"
    td = dr.detach(t)
    x = o + d * td
    u = _affine(mi, A, x)
    v = _affine(mi, A, d, 0.0)
    # side: F = |u|² − 1 (cylinder: without z), eq. (3.4)-(3.5)
    zz = 1.0 if sphere else 0.0
    F = dr.square(u.x) + dr.square(u.y) + zz * dr.square(u.z) - 1.0
    Ft = 2.0 * (u.x * v.x + u.y * v.y + zz * u.z * v.z)
    n_obj = mi.Vector3f(u.x, u.y, u.z * zz)
    for j, (nc, h) in enumerate(spec.clips if spec.capped else []):
        cap = prim == j + 1
        hh = held.get(f"clip_{j}_offset")
        hh = spread(hh, dr.width(o)) if hh is not None and dr.grad_enabled(hh) else spec._offset(j)
        Fc = nc[0] * u.x + nc[1] * u.y + nc[2] * u.z - hh
        Fct = nc[0] * v.x + nc[1] * v.y + nc[2] * v.z
        F = dr.select(cap, Fc, F)
        Ft = dr.select(cap, Fct, Ft)
        n_obj = dr.select(cap, mi.Vector3f(*[float(c) for c in nc]), n_obj)
    t_new = _reattach(dr, td, F, Ft, m)
    # the normal at the moving hit: M⁻ᵀ n_obj at u(t)
    u = _affine(mi, A, o + d * t_new)
    side = mi.Vector3f(u.x, u.y, u.z * zz)
    if spec.capped:
        n_obj = dr.select(prim == 0, side, n_obj)
    else:
        n_obj = side
    return t_new, dr.normalize(_transposed(mi, A, n_obj))


def _blob_terms(mi, dr, spec, held, n):
    """Per centre ``(c, w, S)``: attached Dr.Jit values where the parameter has gradients,
    else the spec's (float64 rounded to float32, gathered from its table as the primal's).
    The attached ones are gathered at ``n`` lanes (``dr.full``), not one: a width-1 value read by ``n``
    lanes has a horizontal sum as its reverse-mode derivative, one kernel per value (each
    recomputing the field), where ``n``-lane gathers scatter-add into the parameter's
    gradient, and the scatters of a level share a kernel."""
    cen, wts, rad = (held.get(k) for k in ("centers", "weights", "radii"))
    gc = cen is not None and dr.grad_enabled(cen)
    gw = wts is not None and dr.grad_enabled(wts)
    gs = rad is not None and dr.grad_enabled(rad)
    out = []
    for i in range(len(spec.centers)):
        x, y, z, w, S = spec._crow(i)[:5]
        idx = dr.full(mi.UInt32, i, n)
        c = mi.Vector3f(*[dr.gather(mi.Float, cen[k], idx) for k in range(3)]) if gc else mi.Vector3f(x, y, z)
        out.append((c, dr.gather(mi.Float, wts, idx) if gw else w, dr.gather(mi.Float, rad, idx) if gs else S))
    return out


def blob_field(mi, dr, terms, x):
    """``W(x)`` and ``∇W(x)`` in object space (eq. 3.6–3.9)."""
    W = mi.Float(0.0)
    g = mi.Vector3f(0.0)
    for c, w, S in terms:
        rel = x - c
        r2 = dr.squared_norm(rel)
        r = dr.sqrt(r2)
        S3 = 3.0 * S
        inv3s2 = 1.0 / (3.0 * dr.square(S))
        inner, outer = r < S, r < S3
        P = dr.select(inner, 1.0 - r2 * inv3s2, dr.select(outer, dr.square(r - S3) * (0.5 * inv3s2), 0.0))
        gr = dr.select(inner, -2.0 * inv3s2,
                       dr.select(outer, (1.0 - S3 / dr.select(outer, r, 1.0)) * inv3s2, 0.0))
        W += w * P
        g += rel * (w * gr)
    return W, g


def _blob_ad(mi, dr, spec, held, o, d, t, m, memo=None):
    A = _inverse_of(mi, dr, spec, spec._mats()[0], held, memo)
    terms = _blob_terms(mi, dr, spec, held, dr.width(t))
    T = held.get("threshold", spec.threshold)
    T = T if dr.grad_enabled(T) else spec._threshold()
    td = dr.detach(t)
    x = _affine(mi, A, o + d * td)
    v = _affine(mi, A, d, 0.0)
    W, g = blob_field(mi, dr, terms, x)
    t_new = _reattach(dr, td, W - T, dr.dot(g, v), m)
    _, g = blob_field(mi, dr, terms, _affine(mi, A, o + d * t_new))
    nw = -_transposed(mi, A, g)
    ln = dr.norm(nw)
    return t_new, dr.select(ln > 1e-20, nw / dr.maximum(ln, 1e-30), -d)


def implicit(mi, dr, spec, held, x, memo=None, part=0):
    """The surface of ``spec`` as ``G(x; θ) = 0`` at world points ``x``, attached to its
    parameters: ``(G, ∇G)`` with ``∇G`` in world space pointing outward (a quadric's side
    ``|u|² − 1``, eq. 3.4; a blob's ``T − W``, eq. 3.6–3.9; ``part`` ``j + 1``: a quadric's
    clip plane ``j``, ``n·u − h``). Its normal velocity, ``−(G − detach G) / |∇G|``, is what
    a silhouette moves with (:mod:`.boundary`)."""
    n = dr.width(x)
    if spec.__class__.__name__ == "QuadricSpec":
        from .util import spread     # (as _quadric_ad: util needs a Mitsuba variant set)
        A = spread(_inverse_of(mi, dr, spec, spec._inv(), held, memo), n)
        u = _affine(mi, A, x)
        if part:
            nc = spec.clips[part - 1][0]
            hh = held.get(f"clip_{part - 1}_offset")
            hh = spread(hh, n) if hh is not None and dr.grad_enabled(hh) else spec._offset(part - 1)
            G = nc[0] * u.x + nc[1] * u.y + nc[2] * u.z - hh
            return G, _transposed(mi, A, mi.Vector3f(*[float(c) for c in nc]))
        zz = 1.0 if spec.kind == "sphere" else 0.0
        G = dr.square(u.x) + dr.square(u.y) + zz * dr.square(u.z) - 1.0
        return G, 2.0 * _transposed(mi, A, mi.Vector3f(u.x, u.y, u.z * zz))
    A = _inverse_of(mi, dr, spec, spec._mats()[0], held, memo)
    T = held.get("threshold", spec.threshold)
    T = T if dr.grad_enabled(T) else spec._threshold()
    W, g = blob_field(mi, dr, _blob_terms(mi, dr, spec, held, n), _affine(mi, A, x))
    return T - W, -_transposed(mi, A, g)


def dominant_centre(mi, dr, spec, x):
    """The centre whose term ``w_i P(|x − c_i|)`` of a blob's field (eq. 3.6–3.9) is the
    largest at world points ``x`` (primal): across the curve where one lobe of a blob hides
    another it changes, where the slot seen does not (:mod:`.boundary`)."""
    A = _inverse_of(mi, dr, spec, spec._mats()[0], {}, None)
    u = _affine(mi, A, x)
    best, idx = dr.full(mi.Float, -INF_TERM, dr.width(x)), dr.zeros(mi.UInt32, dr.width(x))
    for i, (c, w, S) in enumerate(_blob_terms(mi, dr, spec, {}, dr.width(x))):
        v, _ = blob_field(mi, dr, [(c, w, S)], u)
        better = v > best
        best, idx = dr.select(better, v, best), dr.select(better, i, idx)
    return idx


#: below any term of a blob's field (a negative weight's least)
INF_TERM = 1e30


def attached_specs(dr, custom, geo) -> dict:
    """``{slot: (spec, held)}`` of the specs whose parameters have gradients enabled."""
    out = {}
    for sp in custom:
        h = (geo or {}).get(sp.slot)
        if h is not None and _attached(dr, h, h.keys()):
            out[sp.slot] = (sp, h)
    return out
