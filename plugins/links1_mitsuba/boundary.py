"""The visibility ("boundary") term of ``links1_whitted``'s derivatives (``projective``):
what the camera rays see changes where an outline moves.

With a box filter a pixel is the integral of the radiance ``f`` over its square (pixel units),
and its derivative is the interior term (gradients.py: every sample's hit moving with its
surface) plus the integral along the outlines inside the square of the jump of ``f`` times the
outline's normal speed. By the coarea formula the outline's integral is an integral over rows
of a sum over the row's crossings, and also one over columns; for a row at height ``y``

    d/dθ ∫ f(x, y) dx = Σ_c (f(x_c⁻) − f(x_c⁺)) dx_c/dθ,

``x_c`` the crossings and ``f(x_c∓)`` the radiance just left and right of each. The pixels
near an outline are found first (:func:`_active`: what their corners see); per sample of
such a pixel: a random row and a random column of its square (:func:`_crossings`), each
queried at :data:`POINTS` points for what it sees (the nearest hit's slot), every interval
whose ends see different slots bisected (:data:`BISECT_STEPS`; a blob's camera crossings searched
by its margin's secant, :func:`_narrowed`) to its crossing, ``f`` on both
sides traced by the primal ray tree (``trace_points``, detached). A crossing on a row counts
with weight ``ν_x²``, on a column ``ν_y²`` (``ν`` the outline's unit normal on the screen):
the weights sum to 1 (unbiased), and the weighted terms stay bounded where an outline runs
along a row (``dx_c/dθ`` unbounded there).

The crossing's speed. The ray through the crossing grazes the silhouette shape (the side with
the nearer hit) at ``q = O(x) + s D(x)``; ``m`` is the surface's outward unit normal at ``q``
(``⊥ D``). At first order the ray at ``x`` still grazes the moved surface where
``m·∂q/∂x (x − x_c) = V_n``, so ``dx_c/dθ = V_n / a_x`` with ``a = (m·∂q/∂x, m·∂q/∂y)`` (at
fixed ``s``; ``ν = a/|a|``) and ``V_n`` the surface's normal velocity at ``q``:
``−(∂G/∂θ)/|∇G|`` for the links1 shapes' implicit surfaces ``G = 0``
(:func:`links1_mitsuba.geometry.implicit`), ``m·∂p/∂θ`` for a Mitsuba sphere (``p`` its point
``q`` moving with it: ``mi.RayFlags.FollowShape``, as Mitsuba's projective integrators). The
row's weighted term is then ``(f⁻ − f⁺) V_n a_x / |a|²`` (a column's: ``a_y``): the detached
``(f⁻ − f⁺) a_x / |a|²`` times the attached ``V_n``, whose value is 0, so the term adds to the
derivative pass's frame its derivative alone.

Edges: where the grazing point lies on a links1 quadric's rim (its side ``G₁ = 0`` cut by a
clip plane ``G₂ = 0``) or on a Mitsuba mesh triangle's edge (within :data:`RIM` of it), ``m``
is ``τ × D`` normalised (``τ`` the edge's tangent) and ``V_n`` the edge's velocity along it
(:func:`_normal_speed`). The sign of ``m`` cancels in ``V_n / a_x``.

Shadow edges of delta lights (point, spot, directional, ``links1_point``, ``links1_spot``): each
query point also records, per light, the nearest occluder of the shadow segment from its hit
(:func:`_status`); where that changes along a line and the slot seen does not, the crossing
is a shadow edge: the shadow ray of the side with the nearer occluder grazes it at
``q = p + s L`` (``p`` the receiver's point, ``L`` the unit direction to the light), ``m`` and
``V_n`` as above at ``q``, and ``a = m·∂q/∂(x, y)`` at fixed ``s`` through ``p``'s and ``L``'s
change with the pixel. The shadow ray moves too: its point at ``s`` by ``δp + s δL``, ``p``
moving along its camera ray with a links1 receiver (``δt = −δG/(∇G·e)``) and ``L`` with ``p``
and the light; ``V_n`` loses ``m·`` that (:func:`_moving_receiver`).

Terminators: a links1 shape's side lit by a light ends where it turns away from it,
``h = N·L = 0`` (eq. 3.11 shades ``N·L > 0`` alone), and the Phong highlight is not 0 there
where the light comes from behind (a jump). A query point records :data:`UNLIT` for such a
light there, so the change is a crossing of that light; it moves where ``h`` at the pixel
changes: ``dx_c/dθ = −δh/h_x``, i.e. ``a = ∇h`` on the screen and ``V_n = −δh``
(:func:`_terminator`). Near it float32's grazing shadow segments meet the surface a chord
away (:data:`ATTACHED`): not an occluder there.

Cuts: where two surfaces cut (a blob sunk into a floor), the camera crossing's two sides hit
them at one point (:data:`CUT`); ``m ⊥ D`` and the curve's tangent ``n₁ × n₂``, and with
``m = α n₁ + β n₂``, ``V_n = −α δĜ₁ − β δĜ₂`` (``Ĝ = G/|∇G|`` of a links1 shape; a Mitsuba
shape held fixed), as a quadric's rim; its sides' radiance :data:`CUT_SIDE_STEP` out.

What a query point sees is the slot of its hit, a blob's made distinct per lobe (its dominant
centre, :func:`_lobe`): one lobe hiding another is a crossing too.

Left out (biased there, as docs/method.md §6 says): crossings that do not change what is seen
(a mesh in front of itself, a lobe in front of part of itself, an occluder's edge behind
another occluder of the same shadow ray), grazes that are neither a smooth silhouette
(``|m·D|`` below :data:`GRAZE`) nor an edge above, a moving Mitsuba shape's share of a cut,
Mitsuba shapes other than spheres and meshes, the terminators of Mitsuba's shapes and a
Mitsuba receiver's own motion under a shadow edge, outlines and shadows seen in mirrors or
through glass, pairs of crossings closer than ``1/(POINTS − 1)`` pixel on one line, and
outlines (shadow edges, terminators) that enter and leave a pixel between its corners (a
light's shadow rays are traced on the lines of the pixels whose corners' occluders of it
differ). Box filter only.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from links1.maths.sampling import mix32

from . import geometry, intersect
from .camera import rays_at
from .film import widen
from .lights import DIRECTED, POSITIONED
from .util import INF, aligned, kind_of

#: points a row (a column) of a pixel is queried at, its ends included
POINTS = 8
#: most bisection steps from an interval of 1/(POINTS − 1) pixel to its crossing: 1/7 · 2⁻²²
#: pixel, below float32's resolution of film coordinates from 0.3 pixel on; a crossing stops
#: earlier where its interval is one float32 step (at film coordinate x, about
#: 23 − log2(7x) steps: 16 at x = 32, 13 at x = 256)
BISECT_STEPS = 22
#: how far (pixels) from a crossing its two sides' radiance is traced: the primal ray tree's
#: intersection rounds otherwise than the bisection's queries on the last few ulps
SIDE_STEP = 1e-3
#: the same on the curve where two surfaces cut (:data:`CUT`): there the two hits are at one
#: depth, and which is the nearer flips on the last ulps for a while on either side
CUT_SIDE_STEP = 2e-2
#: largest |m·D| at a crossing's grazing point taken as a smooth silhouette
GRAZE = 0.05
#: a grazing point within RIM·t of a links1 quadric's rim or of a mesh triangle's edge (t its
#: distance from the camera) is on that edge
RIM = 1e-4
#: a camera crossing whose two sides' hits lie within CUT·t of each other is on the curve where
#: two surfaces cut (a blob sunk into a floor): what is seen changes from one to the other
#: there, no ray grazes (an outline's far side lies farther off)
CUT = 1e-3
#: the step (pixels) of the central differences of q(x, y) at fixed s: a camera ray's, and a
#: shadow ray's (its receiver's point at the shifted pixel, which must see the same surface)
DQ_STEP = 0.25
DQ_SHADOW = 0.01
#: a shadow segment starts SHADOW_EPS·t from its receiver's point (t: the camera ray's
#: distance) and stops SHADOW_EPS of its length short of a light
SHADOW_EPS = 1e-4
#: a shadow segment whose occluder is its receiver's own surface within ATTACHED·t of the
#: receiver's point is a chord of the surface at its terminator (a few SHADOW_EPS·t long,
#: float32's grazing shadow rays; a shadow one part of a surface casts on another lies 10⁻² t
#: and more away): on a links1 shape not an occluder (the renderer's shadow rays leave it
#: lit, :data:`UNLIT` ends its lit side), on a Mitsuba sphere left out (its terminator is
#: not followed), on a mesh followed as the edge it lies on
ATTACHED = 2e-3
#: what a query point records for a light that its links1 shape's side faces away from
#: (``N·L ≤ 0``, :func:`_terminator`): the shading's lit side ends there (eq. 3.11), a jump
#: where the Phong highlight is not 0 (not recorded on a surface without one,
#: :func:`_highlight`: no jump); its shadow segment is not traced
UNLIT = -3
#: the slots' stride of a blob's lobes in what a query point sees (:func:`_lobe`)
LOBES = 1 << 20
#: most sample lanes (pixels times spp) of a block of rows the term is made for at once in
#: reverse mode (gradients.py; its graph is a few values a crossing, the derivative pass's a
#: ray tree a sample: its blocks are smaller)
BLOCK_LANES = 1 << 21
#: whether a blob's camera crossings (its outline, a change of its lobe) are searched with its
#: margin's secant (:func:`_narrowed`); False: halvings alone
GUIDED = True
#: whether the ends' values (:func:`_edges`) are made in one kernel before they are put back in
#: the crossings' order; False: each gather evaluates its value alone (a kernel per value, each
#: making the shared terms again)
EDGES_ONE_KERNEL = True
#: Newton steps toward the field's maximum along the ray of a guided crossing's ends
#: (:func:`_ray_margin`; a query in its search takes one, from the previous query's maximum)
NEWTON = 3
#: a guided query's step past its secant root, relative to the secant's correction (at least
#: two float32 steps of the line parameter), so that the queries straddle the crossing
NUDGE = 1.0 / 16.0
#: salts of the boundary pass's random numbers (rows, columns, light-sample keys)
_SALT_ROW, _SALT_COL, _SALT_KEY = 0x6A09E667, 0xBB67AE85, 0x3C6EF372


def check_filter(P):
    """Refuse a reconstruction filter other than the box (the term integrates over squares)."""
    rf = P.rfilter
    if not (getattr(rf, "is_box", False) and rf.border == 0):
        raise NotImplementedError("links1_whitted: projective=true needs the film's box reconstruction "
                                  "filter (<rfilter type=\"box\"/>)")


# ---------------------------------------------------------------- the engine's entry points
def _rays(P, x, y, key):
    """Camera rays through film pixel coordinates ``(x, y)`` (floats, row 0 at the top)."""
    W, H = P.film_size
    return rays_at(P, x / W, y / H, key)


def _seen(P, scene, x, y, key, active=True):
    """``(o, d, t, slot, prim, (shape, triangle), n)`` of the camera rays through ``(x, y)``:
    the nearest hit (primal; ``prim``: a links1 quadric's part, 0 its side; ``shape`` and
    ``triangle``: Mitsuba's hit shape and primitive, ``n`` its geometric normal there); on
    lanes ``active`` (elsewhere no hit)."""
    o, d, tmin, tmax = _rays(P, x, y, key)
    act = dr.full(mi.Bool, True, dr.width(x)) & active
    cost = dr.zeros(mi.UInt32, dr.width(x))
    t, slot, si, prim = intersect.nearest(P, scene, o, d, tmin, tmax, act, cost)
    return (o, d, t, _lobe(P, slot, o + d * dr.select(dr.isfinite(t), t, 0.0)), prim, (si.shape, si.prim_index),
            mi.Vector3f(si.n))


def _lobe(P, slot, x):
    """``slot`` made distinct per lobe of a blob (its dominant centre at the hit ``x``,
    :func:`geometry.dominant_centre`: ``slot + LOBES · (centre + 1)``), so that a lobe hiding
    another lobe of the same blob is a change of what is seen; :func:`_slot` undoes it."""
    for sp in P.custom:
        if sp.__class__.__name__ == "BlobSpec":
            on = slot == sp.slot
            slot = dr.select(on, slot + LOBES * mi.Int32(geometry.dominant_centre(mi, dr, sp, x) + 1), slot)
    return slot


def _slot(ident):
    """The slot of an identity :func:`_lobe` made (-1 stays)."""
    return dr.select(ident >= 0, ident % LOBES, ident)


def _dev(t, a):
    """The Dr.Jit array of type ``t`` of numpy ``a`` in 64-byte aligned memory
    (:func:`links1_mitsuba.util.aligned`): a kernel reading an array made from numpy memory is
    compiled again for each alignment it meets (16-byte aligned or not, at random)."""
    return t(aligned(a, {dr.VarType.Float32: np.float32, dr.VarType.Int32: np.int32, dr.VarType.UInt32: np.uint32,
                         dr.VarType.Bool: np.bool_}[dr.type_v(t)]))


def _unit(x):
    """:func:`links1_mitsuba.util.unit_float` of a numpy ``uint32`` array (float32: exact)."""
    return (x >> np.uint32(8)).astype(np.float32) * np.float32(2.0 ** -24)


# ---------------------------------------------------------------- the term
def boundary_image(trace_points, scene, P, Q, sensor, win, spp, seed, stage=None):
    """The boundary term of the window ``win = (x0, y0, w, h)``: a ``TensorXf (h, w, 3)`` of
    value 0 whose derivative is the term (see the module's docstring); ``P``: the primal
    tables, ``Q``: the derivative pass's (``Q.geo_ad``: the attached links1 shapes);
    ``trace_points(xf, yf, keys)``: the primal ray tree through film positions of ``P``
    (``Launches.trace_points``); ``stage(fn, *args, key=...)``: ``fn(P, scene, *args)`` for the term's
    stages (:func:`_seen_slots`, :func:`_line_kinds`, :func:`_bisected`, :func:`_edges`), frozen by
    the launches (``Launches.frozen_stage``: recorded once, replayed every frame); None: traced
    here."""
    check_filter(P)
    x0, y0, w, h = win
    # (the lights followed are a Python choice of the stages' traces: a recording's key)
    lights_key = tuple(k for k, _, _ in _lights(P))
    frozen = stage
    run = (lambda fn, *args: frozen(fn, *args, key=lights_key)) if frozen is not None else \
        (lambda fn, *args: fn(P, scene, *args))

    def stage(fn, *args):
        # a blob keeps its last nearest-hit search's candidate lists for the normal at its hit
        # (BlobSpec._line); the queries take no normal, so they are dropped around a stage: a
        # recording that let go of another's arrays (or left its own) aborts the process
        _drop_lines(P)
        out = run(fn, *args)
        _drop_lines(P)
        return out
    with dr.suspend_grad():
        cr = _crossings(trace_points, scene, P, sensor, win, spp, seed, stage)
    out = dr.zeros(mi.Float, w * h * 3)
    if cr is not None:
        with dr.resume_grad():
            vn = _normal_speed(scene, P, Q, cr)
            if vn is not None:
                val = cr["weight"] * vn
                for c in range(3):
                    dr.scatter_add(out, val[c], cr["pixel"] * 3 + c)
    return mi.TensorXf(out / float(spp), shape=(h, w, 3))


def _crossings(trace_points, scene, P, sensor, win, spp, seed, stage):
    """The crossings of the window's sample rows and columns, bisected, with the detached
    part of their terms, or None where there are none: ``{pixel, weight (Color3f), q, m,
    slot, valid, part, tri, light, p, ts}`` (``q``: the grazing point, on the silhouette shape
    or, for a shadow edge of light ``light`` (-1: none), on its occluder, ``ts`` from the
    receiver's point ``p``; the rest: :func:`_outline`)."""
    x0, y0, w, h = win
    lts = _lights(P)
    # the pixels whose lines are queried: those whose corners do not all see the same (and
    # per light, those whose corners' occluders differ: its shadow rays are traced there alone)
    near = _active(P, win, lts, stage).reshape(1 + len(lts), -1)
    pix = np.nonzero(near.any(axis=0))[0]
    n = pix.size * spp
    if n == 0:
        return None
    pix, i = np.repeat(pix, spp), np.tile(np.arange(spp), pix.size)
    px, py = x0 + pix % w, y0 + pix // w
    s0 = int(seed) & 0xFFFFFFFF
    # the film's sample ids: a sample's lines do not depend on the window it is rendered in
    sid = ((py * P.film_size[0] + px) * spp + i).astype(np.uint32)
    u_row = _unit(mix32(mix32(s0 ^ _SALT_ROW) ^ sid))
    u_col = _unit(mix32(mix32(s0 ^ _SALT_COL) ^ sid))
    keys = mix32(mix32(s0 ^ _SALT_KEY) ^ sid)
    # lanes 0..n-1: rows (x varies), n..2n-1: columns (y varies); POINTS points each
    k = np.arange(POINTS) / (POINTS - 1)
    along = np.concatenate([px, py]).astype(np.float64)[:, None] + k[None, :]
    fixed = np.concatenate([py + u_row, px + u_col])
    is_col = np.repeat(np.array([False, True]), n)
    lane_key = np.concatenate([keys, keys])

    rep = lambda v: np.repeat(v, POINTS)   # noqa: E731
    x, y = _at(_dev(mi.Float, along.ravel()), _dev(mi.Bool, rep(is_col)), _dev(mi.Float, rep(fixed)))
    on = [_dev(mi.Bool, rep(np.tile(near[1 + j, pix], 2))) for j in range(len(lts))]
    seen, occluders = stage(_seen_slots, x, y, _dev(mi.UInt32, rep(lane_key)), on)
    dr.eval(seen, *occluders)   # one kernel (each alone would trace the camera rays again)
    kind, o_all = stage(_line_kinds, dr.arange(mi.UInt32, 2 * n * POINTS), seen, *occluders)
    c_all = seen
    # the crossings: the intervals whose kind is a signal, lane by lane (a line's lanes are
    # its POINTS points; the interval from point k is lane k's), as numpy: lines li, points ki
    at = dr.compress(kind >= 0)
    if dr.width(at) == 0:
        return None
    kinds, at_h = dr.gather(mi.Int32, kind, at).numpy(), at.numpy()
    li, ki = at_h // POINTS, at_h % POINTS
    # the bisection and the ends take the crossings by kind (the camera's, then each light's
    # shadow edges: a packet of lanes of one kind traces that kind's rays alone), a camera
    # crossing between two lobes of one blob after the others (most are a change of dominant
    # centre on one sheet of the surface, whose queries do not graze: packets of lanes that cost
    # alike), and _edges puts its values back in the crossings' order (``back``); lanes are
    # independent: the same values as in that order
    ends = [dr.gather(mi.Int32, c_all, at + j).numpy() for j in (0, 1)]
    lobes = (kinds == 0) & (ends[0] >= LOBES) & (ends[1] >= LOBES) & (ends[0] % LOBES == ends[1] % LOBES)
    order = np.argsort(2 * kinds + lobes, kind="stable")
    back = np.argsort(order)
    ls, ks = li[order], ki[order]
    kd = _dev(mi.Int32, kinds[order])
    key, colm, fxd = _dev(mi.UInt32, lane_key[ls]), _dev(mi.Bool, is_col[ls]), _dev(mi.Float, fixed[ls])
    lo_d, hi_d = _dev(mi.Float, along[ls, ks]), _dev(mi.Float, along[ls, ks + 1])
    at_s = _dev(mi.UInt32, at_h[order])
    c_lo, o_lo = dr.gather(mi.Int32, c_all, at_s), dr.gather(mi.Int32, o_all, at_s)
    c_hi = dr.gather(mi.Int32, c_all, at_s + 1)
    lo_d, hi_d = stage(_bisected if GUIDED else _bisected_plain, lo_d, hi_d, colm, fxd, key, kd, c_lo, o_lo, c_hi)
    edge = stage(_edges, lo_d, hi_d, colm, fxd, key, kd, _dev(mi.UInt32, back), EDGES_ONE_KERNEL)
    # f on both sides, SIDE_STEP pixels out: the primal ray tree (one launch for both ends), of
    # the valid crossings alone (the others' weight is 0: their jump is taken as 0)
    m_ = li.size
    valid_h = widen(edge[_EDGE.index("valid")], m_).numpy()
    ok = np.nonzero(valid_h)[0]
    # which kinds of valid crossings there are (the velocity traces each kind's part alone)
    kinds_h = {k: bool(np.any(valid_h & widen(edge[_EDGE.index(k)], m_).numpy())) for k in ("att", "cut")}
    kinds_h["shadow"] = bool(np.any(valid_h & (kinds > 0)))
    jump = np.zeros((m_, 3))
    if ok.size:
        # the ends' film coordinates made on the host from the evaluated ends (as at(): the
        # same float32 values; reading xl ... would run a kernel each), in the crossings' order
        cl, f32 = is_col[li[ok]], np.float32(fixed[li[ok]])
        lo_h, hi_h = lo_d.numpy()[back][ok], hi_d.numpy()[back][ok]
        ends_h = [(np.where(cl, f32, e), np.where(cl, e, f32)) for e in (lo_h, hi_h)]
        step = np.where(widen(edge[_EDGE.index("cut")], m_).numpy()[ok], CUT_SIDE_STEP, SIDE_STEP)
        xs = np.concatenate([ends_h[0][0] - step * ~cl, ends_h[1][0] + step * ~cl])
        ys = np.concatenate([ends_h[0][1] - step * cl, ends_h[1][1] + step * cl])
        keys_h = lane_key[li[ok]].astype(np.uint32)
        f = trace_points(xs / P.film_size[0], ys / P.film_size[1], np.concatenate([keys_h, keys_h]))[0]
        jump[ok] = f[:ok.size] - f[ok.size:]
    jump_c = mi.Color3f(*[_dev(mi.Float, jump[:, c]) for c in range(3)])
    # (a frozen stage returns a value that is the same on every lane at its recorded width)
    edge = {k: (tuple(widen(u, m_) for u in v) if k == "tri" else widen(v, m_)) for k, v in zip(_EDGE, edge)}
    edge.update(pixel=_dev(mi.UInt32, pix[li % n]), weight=jump_c * edge.pop("coef"), lights=lts,
                tri=edge.pop("tri", None), kinds=kinds_h)
    dr.eval(edge["pixel"], edge["weight"], edge["q"], edge["m"], edge["slot"], edge["valid"], edge["part"],
            edge["light"], edge["p"])
    return edge


#: the values :func:`_edges` returns, in its order (``tri``: with Mitsuba meshes only)
_EDGE = ("q", "m", "valid", "part", "slot", "light", "p", "ts", "att", "e", "rslot", "rprim", "cut", "n1", "n2", "coef",
         "tri")


def _edges(P, scene, lo, hi, colm, fxd, key, kd, back, one=True):
    """A stage of the term: what the bisected crossings ``[lo, hi]`` (:func:`_bisected`) are,
    all but the radiance on their sides: what both ends see (:func:`_status`), where the ray
    grazes (:func:`_grazes`), the outline there (:func:`_outline`: its normal ``m``, ``valid``,
    ``part``, a mesh edge's ``tri``), and the detached factor ``a_x / |a|²`` (a column's
    ``a_y``) of the crossing's weight (``coef``; 0 where not ``valid``), with ``a`` the screen
    gradient of ``m·q`` (:func:`_screen_gradient`); the values of :data:`_EDGE`, in order, lane
    ``i`` of each that of the crossing ``back[i]``; ``one``: made in one kernel before they are
    put back in order (:data:`EDGES_ONE_KERNEL`)."""
    lts = _lights(P)
    (xl, yl), (xh, yh) = _at(lo, colm, fxd), _at(hi, colm, fxd)
    ends = [_status(P, scene, xa, ya, key, lts, only=kd) for xa, ya in ((xl, yl), (xh, yh))]
    dr.eval(ends)   # (what both ends see: one kernel)
    g = _grazes(ends, kd, (xl, yl), (xh, yh), lts)
    # the outline's normal m at q, and the screen-space gradient a of m·q at fixed distances
    edge = _outline(scene, P, g["q"], g["d"], g["t"], g["slot"], g["prim"], g["hit"], g["ok"])
    # a terminator is followed on the links1 shapes (:func:`_terminator`); a chord at one on a
    # Mitsuba sphere is left out, on a mesh (whose terminator lies on its edges) followed as
    # its edge (:data:`ATTACHED`)
    custom = _custom_lanes(P, g["rslot"])
    att = g["ok"] & g["att"]
    g["att"] = att
    # where two surfaces cut, the curve's normal on the screen: m ⊥ the curve's tangent n1 × n2
    # and ⊥ D (as a quadric's rim, :func:`_outline`)
    n1 = _unit_normal(P, g["slot"], g["prim"], g["q"], g["n1"])
    n2 = _unit_normal(P, g["rslot"], g["rprim"], g["q"], g["n2"])
    mc = dr.cross(dr.cross(n1, n2), g["d"])
    cut = g["ok"] & g["cut"]
    cut_ok = cut & (dr.squared_norm(mc) > 1e-8)
    edge["m"] = dr.select(cut_ok, dr.normalize(mc), edge["m"])
    edge["valid"] = dr.select(cut, cut_ok, edge["valid"])
    (ax, ay), seen_same = _screen_gradient(P, scene, edge["m"], g, key, lts)
    a2 = dr.select(seen_same, ax * ax + ay * ay, 0.0)
    valid = dr.select(att, custom, edge["valid"] & ~(g["chord"] & ~custom & ~_mesh_lanes(P, g["slot"]))) & (a2 > 0)
    coef = dr.select(valid, dr.select(colm, ay, ax) / dr.select(valid, a2, 1.0), 0.0)
    part = dr.select(cut, mi.UInt32(g["prim"]), edge["part"])   # (a cut's: the near surface's part)
    out = [g["q"], edge["m"], valid, part, g["slot"], g["light"], g["p"], g["t"], att, g["e"], g["rslot"],
           g["rprim"], cut, n1, n2, coef]
    if one:
        dr.eval(*out, *(edge["tri"] or ()))
    out = [dr.gather(type(v), v, back) for v in out]
    return out if edge["tri"] is None else out + [[dr.gather(type(v), v, back) for v in edge["tri"]]]


def _drop_lines(P):
    """Forget the candidate lists each blob of ``P`` keeps from its last nearest-hit search
    (``BlobSpec._line``)."""
    for sp in P.custom:
        if getattr(sp, "_line", None) is not None:
            sp._line = None


def _at(a, colm, fxd):
    """Film coordinates ``(x, y)`` of points at ``a`` along rows (``colm`` False: ``y`` is
    ``fxd``) or columns (``x`` is ``fxd``)."""
    return dr.select(colm, fxd, a), dr.select(colm, a, fxd)


def _seen_slots(P, scene, x, y, key, on=None):
    """A stage of the term (``boundary_image``'s ``stage``): what the points ``(x, y)`` see,
    the camera ray's slot and each light's occluder (:func:`_status`; ``on``: per light, the
    lanes its shadow segments are traced on, None: all)."""
    cam, shadows = _status(P, scene, x, y, key, _lights(P), on=on)
    return cam[3], [s_[2] for s_ in shadows]


def _line_kinds(P, scene, lane, *sig):
    """A stage of the term: per lane of the lines' points (:data:`POINTS` lanes a line, in
    order; ``lane``: the lanes' indices) and what they see, ``sig`` (:func:`_seen_slots`: the
    camera ray's slot, then each light's occluder), the interval from its point to the next of
    its line: ``kind``, the first of those signals that differs at its ends (-1: none, and on a
    line's last point), and the value of signal ``kind`` at its first point. (A stage apart
    from the queries: with them in one frozen function, a later traced corner query failed to
    compile in Dr.Jit 1.5's LLVM backend, a vcall's function defined twice in one module.)"""
    inner = lane % POINTS != POINTS - 1
    kind = dr.full(mi.Int32, -1, dr.width(lane))
    for j in reversed(range(len(sig))):
        kind = dr.select(inner & (sig[j] != dr.gather(mi.Int32, sig[j], lane + 1, inner)), j, kind)
    return kind, _pick(kind, list(sig))


def _bisected(P, scene, lo, hi, colm, fxd, key, kd, c_lo, o_lo, c_hi):
    """A stage of the term: the crossings' intervals ``[lo, hi]`` along their rows or columns
    (:func:`_at`) narrowed to their crossing, a blob's camera crossings guided by its margin
    (:func:`_narrowed`)."""
    return _narrowed(P, scene, lo, hi, colm, fxd, key, kd, c_lo, o_lo, c_hi, True)[:2]


def _bisected_plain(P, scene, lo, hi, colm, fxd, key, kd, c_lo, o_lo, c_hi):
    """:func:`_bisected` by halvings alone (:data:`GUIDED` False)."""
    return _narrowed(P, scene, lo, hi, colm, fxd, key, kd, c_lo, o_lo, c_hi, False)[:2]


#: the state of a lane whose margin has lost its crossing (:func:`_narrowed`): midpoints on
LOST = 1 << 8


def _narrowed(P, scene, lo, hi, colm, fxd, key, kd, c_lo, o_lo, c_hi, guided):
    """The crossings' intervals ``[lo, hi]`` narrowed to float32 resolution, ``lo`` keeping
    what the interval's first point sees (the camera ray's slot ``c_lo`` and, for a shadow
    edge of light ``kd − 1``, its occluder ``o_lo``; ``c_hi``: the last point's slot), and the
    queries each lane made: ``(lo, hi, steps)``. One symbolic loop (a kernel); a lane stops
    where its interval's midpoint rounds to an end (float32: a further step would query an
    end again and change nothing).

    Each step queries one point ``x`` and keeps the part of the interval whose ends see
    differently, so every result is an interval of one float32 step whose first end sees what
    the first point does and whose last end sees something else. Unguided, ``x`` is the
    midpoint (bisection). Guided (``guided``: a blob's camera crossings, :func:`_guides`),
    ``x`` is the secant root of the margins ``g`` (:func:`_margin`, continuous across the
    crossing, 0 on it) of the last two points queried (first the interval's ends), moved on
    past it by :data:`NUDGE` of the secant's correction, so that the queries straddle the
    crossing; midpoints where the secant root is not inside the interval, after two guided
    steps that did not halve it, once it is within 8 float32 steps, and for good once a
    margin's sign is not its side's (the crossing is not the margin's: the blob hidden
    behind another surface, a cut of two surfaces); at most ``2 BISECT_STEPS`` queries. The
    margin chooses where a lane queries, not what it keeps: a result differs from the
    bisection's only where the interval holds more than one crossing, or where what the
    queries see flips back and forth near it (grazing rays; near a seam of lobes, the dominant
    centre of the float32 hit), and then it is another of those flips."""
    lts = _lights(P)
    n = dr.width(lo)
    guide = _guides(P, kd, c_lo, c_hi) if guided else None
    cap = mi.UInt32(BISECT_STEPS) if guide is None else dr.select(guide[0] != 0, 2 * BISECT_STEPS, BISECT_STEPS)
    nan = dr.full(mi.Float, dr.nan, n)
    ga, gb, sg, slow0 = nan, nan, nan, dr.zeros(mi.UInt32, n)
    if guide is not None:
        # a camera crossing's ends: their rays' margins (what they see is known: not queried)
        ends = []
        for x in (lo, hi):
            o, d, _, _ = _rays(P, *_at(x, colm, fxd), key)
            ends.append(_margin(P, guide, (o, d, dr.full(mi.Float, INF, n), dr.full(mi.Int32, -1, n)), nan, NEWTON))
        ga, gb, sg = ends[0][0], ends[1][0], ends[1][1]
        slow0 = dr.select((ga < 0) | (gb > 0), LOST, 0)

    def halve(lo_, hi_, i, xa, ga, xb, gb, sg, slow):
        mid = 0.5 * (lo_ + hi_)
        x = mid
        if guide is not None:
            den = gb - ga
            sec = dr.isfinite(ga) & dr.isfinite(gb) & (den != 0) & (slow < 2) & (hi_ - lo_ > dr.abs(mid) * 2.0 ** -20)
            xs = xb - gb * (xb - xa) / dr.select(sec, den, 1.0)
            nudge = dr.maximum(NUDGE * dr.abs(xs - xb), dr.abs(mid) * 2.0 ** -22)
            xs = dr.select(xs > xb, xs + nudge, xs - nudge)
            sec &= (xs > lo_) & (xs < hi_)
            x = dr.select(sec, xs, mid)
        cm, sm = _status(P, scene, *_at(x, colm, fxd), key, lts, only=kd)
        same = (cm[3] == c_lo) & ((kd == 0) | (_pick(kd, [cm[3]] + [s_[2] for s_ in sm]) == o_lo))
        lo2, hi2 = dr.select(same, x, lo_), dr.select(same, hi_, x)
        if guide is not None:
            g, sg = _margin(P, guide, cm, sg)
            xa, ga, xb, gb = xb, gb, x, g
            slow = dr.select(sec, dr.select(hi2 - lo2 > 0.5 * (hi_ - lo_), slow + 1, 0), 0)
            # a margin whose sign is not the side's: no guide on from here (midpoints)
            slow = dr.select(((g > 0) & ~same) | ((g < 0) & same) | (slow >= LOST), LOST, slow)
        return lo2, hi2, i + 1, xa, ga, xb, gb, sg, slow

    def going(lo_, hi_, i, *_):
        mid = 0.5 * (lo_ + hi_)
        return (i < cap) & (mid != lo_) & (mid != hi_)

    out = dr.while_loop((lo, hi, dr.zeros(mi.UInt32, n), mi.Float(lo), ga, mi.Float(hi), gb, sg, mi.UInt32(slow0)),
                        going, halve, label="links1_bisect")
    return out[0], out[1], out[2]


def _guides(P, kd, c_lo, c_hi):
    """Per crossing, the blob whose margin guides its search (:func:`_narrowed`, camera
    crossings alone): ``(mode, spec index, centre a, centre b)``, ``mode`` +1 where the
    interval's first point's camera ray meets the blob and the last point's does not, −1 the
    other way, 2 where both see the blob, lobes of centres ``a`` and ``b`` (:func:`_lobe`), 0
    no guide (:func:`_guided_blobs`)."""
    n = dr.width(kd)
    mode, which = dr.zeros(mi.Float, n), dr.zeros(mi.UInt32, n)
    cam = kd == 0
    for k, sp in _guided_blobs(P):
        a, b = _slot(c_lo) == sp.slot, _slot(c_hi) == sp.slot
        m_ = dr.select(cam & a & ~b, 1.0, dr.select(cam & b & ~a, -1.0, dr.select(cam & a & b, 2.0, 0.0)))
        which = dr.select(m_ != 0, k, which)
        mode = dr.select(m_ != 0, m_, mode)
    return mode, which, mi.Int32(c_lo // LOBES - 1), mi.Int32(c_hi // LOBES - 1)


def _guided_blobs(P):
    """``(index in P.custom, spec)`` of the blobs whose margin guides a search (:func:`_guides`,
    :func:`_margin`): not those whose field sums candidate lists (many centres: the margin
    would sum every centre)."""
    return [(k, sp) for k, sp in enumerate(P.custom)
            if sp.__class__.__name__ == "BlobSpec" and not sp.uses_lists()]


def _margin(P, guide, cm, sg, steps=1):
    """The guided lanes' margin (:func:`_guides`) at a query's camera ray ``cm``
    (:func:`_seen`), positive on the side of the interval's first point, NaN where there is
    none, and ``sg`` carried on (:func:`_ray_margin`). A blob's outline (``mode`` ±1): ``±(W −
    T)`` at the field's maximum along the ray (eq. 3.6–3.9), continuous across the outline and
    0 on it. A change of lobe (``mode`` 2): ``w_a P(r_a) − w_b P(r_b)`` at the ray's hit (eq.
    3.9; the two centres' terms), continuous where the hit is (one sheet of the surface); NaN
    where the ray's hit is not on the blob."""
    mode, which, ca, cb = guide
    o, d, t, seen = cm[0], cm[1], cm[2], _slot(cm[3])
    n = dr.width(o)
    g, s_out = dr.full(mi.Float, dr.nan, n), sg
    for k, sp in _guided_blobs(P):
        hit = (seen == sp.slot) & dr.isfinite(t)
        out = (which == k) & ((mode == 1) | (mode == -1))
        w_, s_ = dr.if_stmt((o, d, t, hit, sg), out, lambda *a: _ray_margin(sp, *a, steps=steps),
                            lambda *a: (dr.nan * a[2], a[4]))
        g = dr.select(out, mode * w_, g)
        s_out = dr.select(out, s_, s_out)
        lobe = (which == k) & (mode == 2) & hit
        g = dr.select(lobe, dr.if_stmt((o, d, t, ca, cb), lobe, lambda *a: _lobe_margin(sp, *a),
                                       lambda *a: dr.nan * a[2]), g)
    return g, s_out


def _ray_margin(sp, o, d, t, hit, sg, steps=1):
    """``(max_s W − T, s)`` of blob ``sp`` along the ray ``o + t d``: from ``sg`` (the place
    of the maximum on the previous query's ray, object units along the unit object ray), or
    from the ray's hit on the blob (``hit``), else (``steps`` > 1) from the closest approach
    to a centre with the largest field; then ``steps`` Newton steps on ``dW/ds = 0``, the last
    one's quadratic model's maximum ``W − (dW)²/(2 d²W)`` as the value (where ``d²W/ds² < 0``;
    else ``W``) and its place as ``s``: exact to second order in the place's error (eq. 3.6–3.9)."""
    scale, per, _, _, _, _ = sp._setup(o, d, 0.0, INF)
    s = dr.select(hit, t * scale, sg)
    if steps > 1:
        # a cold start (the ends of a crossing): the closest approach to a centre where the
        # field is largest
        best, s0 = dr.full(mi.Float, -INF, dr.width(o)), dr.zeros(mi.Float, dr.width(o))
        for tau, *_ in per:
            W = _field2(per, tau)[0]
            better = W > best
            best, s0 = dr.select(better, W, best), dr.select(better, tau, s0)
        s = dr.select(dr.isnan(s), s0, s)
    for _ in range(steps):
        W, dW, d2W = _field2(per, s)
        cap = d2W < 0
        step = -dW / dr.select(cap, d2W, -1.0)
        s = dr.select(cap, s + step, s)
        W = dr.select(cap, W + 0.5 * dW * step, W)
    return W - sp._threshold(), s


def _lobe_margin(sp, o, d, t, ca, cb):
    """``w_a P(r_a) − w_b P(r_b)`` of blob ``sp``'s centres ``ca``, ``cb`` at ``o + t d`` (eq. 3.9)."""
    u = geometry._affine(mi, geometry._inverse_of(mi, dr, sp, sp._mats()[0], {}, None), o + d * t)
    ta, tb = dr.zeros(mi.Float, dr.width(o)), dr.zeros(mi.Float, dr.width(o))
    for i, term in enumerate(geometry._blob_terms(mi, dr, sp, {}, dr.width(o))):
        v = geometry.blob_field(mi, dr, [term], u)[0]
        ta, tb = dr.select(ca == i, v, ta), dr.select(cb == i, v, tb)
    return ta - tb


def _field2(per, s):
    """A blob's field along its unit object-space ray at ``s`` (:meth:`BlobSpec._setup`'s
    ``per``) with its first and second derivatives in ``s`` (eq. 3.9 differentiated twice)."""
    W, dW, d2W = mi.Float(0.0), mi.Float(0.0), mi.Float(0.0)
    for tau, h2, w, S, inv3s2, S3, half, m2, _ in per:
        dt = s - tau
        r2 = dr.square(dt) + h2
        r = dr.sqrt(r2)
        inner, outer = r < S, r < S3
        rr = dr.maximum(r, 1e-30)
        P_ = dr.select(inner, 1.0 - r2 * inv3s2, dr.select(outer, dr.square(r - S3) * half, 0.0))
        g1 = dr.select(inner, m2, dr.select(outer, (1.0 - S3 / rr) * inv3s2, 0.0))
        g2 = dr.select(inner, m2, dr.select(outer, ((1.0 - S3 / rr) + S3 * dr.square(dt) / (rr * r2)) * inv3s2, 0.0))
        W += w * P_
        dW += w * g1 * dt
        d2W += w * g2
    return W, dW, d2W


def _active(P, win, lts, stage):
    """``(1 + len(lts), h, w)`` bools: the window's pixels whose four corners do not all see
    the same, per signal (the slot seen; each light's occluder): the only ones whose lines
    can cross an outline or a shadow edge of that signal, unless it enters and leaves the
    pixel between its corners (docs/method.md §6)."""
    x0, y0, w, h = win
    # the corners' film positions, row by row, made on the device (whole numbers: exact in
    # float32; a grid made in numpy and copied to aligned memory cost ~1 ms a 256² window)
    i = dr.arange(mi.UInt32, (w + 1) * (h + 1))
    row = i // (w + 1)
    gx, gy, keys = mi.Float(i - row * (w + 1)) + float(x0), mi.Float(row) + float(y0), dr.zeros(mi.UInt32, dr.width(i))
    dr.make_opaque(gx, gy, keys)
    seen, occluders = stage(_seen_slots, gx, gy, keys)
    dr.eval(seen, *occluders)
    out = np.zeros((1 + len(lts), h, w), dtype=bool)
    for j, v in enumerate([seen, *occluders]):
        g = v.numpy().reshape(h + 1, w + 1)
        c = g[:-1, :-1]
        out[j] = (g[:-1, 1:] != c) | (g[1:, :-1] != c) | (g[1:, 1:] != c)
    return out


def _pick(kd, values):
    """``values[kd]`` lane by lane."""
    out = values[0]
    for j in range(1, len(values)):
        out = dr.select(kd == j, values[j], out)
    return out


def _grazes(ends, kd, lo_xy, hi_xy, lts):
    """Where each bisected crossing's ray grazes: ``{q, d, t, slot, prim, hit, ok, light, p,
    x, y}``. A camera crossing (the ends see different slots): the camera ray of the side with
    the nearer hit, at that hit. A shadow edge of light ``kd − 1`` (the same slot, another
    occluder): the shadow ray of the side whose occluder is nearer, at that occluder; ``att``
    where a links1 shape's side faces the light on one side and away on the other (its
    terminator, :data:`UNLIT`: ``slot`` the receiver's), ``chord`` where the occluder is the
    receiver's own surface at its point (:data:`ATTACHED`), ``e`` the camera ray's direction at
    the receiver, ``rslot`` and ``rprim`` the receiver's slot and part; ``cut`` where the
    camera crossing is on the curve where two surfaces cut (:data:`CUT`; ``rslot`` and ``rprim``
    the far side's surface, ``n1`` and ``n2`` the Mitsuba shapes' normals of the near and far
    side)."""
    (cl, sl), (ch, sh) = ends
    near_lo = cl[2] <= ch[2]
    sel = lambda m_, a, b: type(a)(dr.select(m_, a, b)) if not isinstance(a, tuple) else \
        tuple(dr.select(m_, u, v) for u, v in zip(a, b))   # noqa: E731
    cam = [sel(near_lo, a, b) for a, b in zip(cl, ch)]
    o, d, t, slot, prim, hit, ng = cam
    far = [sel(near_lo, b, a) for a, b in zip(cl, ch)]
    slot = _slot(slot)   # (a blob's lobe: its slot)
    cam_ok = dr.isfinite(t) & (cl[3] != ch[3])
    # the curve where two surfaces cut: both sides' hits at one point
    cut = cam_ok & dr.isfinite(far[2]) & (dr.norm(d * t - far[1] * far[2]) <= CUT * t)
    g = {"q": o + d * dr.select(cam_ok, t, 0.0), "d": d, "t": t, "slot": slot, "prim": prim, "hit": hit,
         "ok": cam_ok, "light": dr.full(mi.Int32, -1, dr.width(t)), "p": o + d * dr.select(cam_ok, t, 0.0),
         "x": dr.select(near_lo, lo_xy[0], hi_xy[0]), "y": dr.select(near_lo, lo_xy[1], hi_xy[1]),
         "att": dr.zeros(mi.Bool, dr.width(t)), "chord": dr.zeros(mi.Bool, dr.width(t)), "e": d,
         "rslot": dr.select(cut, _slot(far[3]), slot), "rprim": dr.select(cut, far[4], prim), "cut": cut,
         "n1": ng, "n2": mi.Vector3f(far[6])}
    for j in range(len(lts)):
        (sd_l, ts_l, ss_l, pr_l, hit_l), (sd_h, ts_h, ss_h, pr_h, hit_h) = sl[j], sh[j]
        lo_side = (ss_l >= 0) & ((ss_h < 0) | (ts_l <= ts_h))
        on = (kd == j + 1) & (cl[3] == ch[3]) & (ss_l != ss_h) & dr.isfinite(cl[2]) & dr.isfinite(ch[2])
        # a links1 shape's terminator: lit (and unshadowed) on one side, facing away on the other
        # (against a cast shadow neither side has this light's term: no jump)
        att = ((ss_l == UNLIT) & (ss_h == -1)) | ((ss_h == UNLIT) & (ss_l == -1))
        on &= att | ((ss_l != UNLIT) & (ss_h != UNLIT))
        p = dr.select(lo_side, cl[0] + cl[1] * cl[2], ch[0] + ch[1] * ch[2])
        sd, ts = dr.select(lo_side, sd_l, sd_h), dr.select(lo_side, ts_l, ts_h)
        ts = dr.select(att, 0.0, ts)
        on &= dr.isfinite(ts)
        occ = dr.select(att, _slot(cl[3]), dr.select(lo_side, ss_l, ss_h))
        # a chord of the receiver's own surface at its terminator (ATTACHED: Mitsuba's shapes)
        chord = ~att & (occ == _slot(cl[3])) & (ts <= ATTACHED * dr.select(lo_side, cl[2], ch[2]))
        vals = {"q": p + sd * dr.select(on, ts, 0.0), "d": sd, "t": ts, "slot": occ,
                "prim": dr.select(lo_side, pr_l, pr_h),
                "hit": sel(lo_side, hit_l, hit_h), "ok": on,
                "light": mi.Int32(j), "p": p, "x": dr.select(lo_side, lo_xy[0], hi_xy[0]),
                "y": dr.select(lo_side, lo_xy[1], hi_xy[1]), "att": att, "chord": chord,
                "e": sel(lo_side, mi.Vector3f(cl[1]), mi.Vector3f(ch[1])), "rslot": _slot(cl[3]),
                "rprim": dr.select(lo_side, cl[4], ch[4]), "cut": dr.zeros(mi.Bool, dr.width(ts))}
        for k_, v in vals.items():
            g[k_] = sel(on, v, g[k_])
        g["ok"] = g["ok"] | on
    return g


def _screen_gradient(P, scene, m, g, key, lts):
    """``a = (m·∂q/∂x, m·∂q/∂y)`` at the grazes ``g``: a camera ray's ``q = O + s D`` at fixed
    ``s`` (central differences of the camera rays, :data:`DQ_STEP` pixels); a shadow ray's
    ``q = p + s L`` at fixed ``s``, ``p`` the receiver's point seen at the shifted pixel and
    ``L`` its direction to the light (central differences of :data:`DQ_SHADOW` pixels); at a
    links1 shape's terminator (``g["att"]``) the gradient of ``h = N·L`` at the receiver's point
    seen (:func:`_terminator`), whose zero the terminator is. And where a shadow edge's or a
    terminator's shifted pixels all see its receiver (else no gradient there: near the
    receiver's own outline)."""
    a = []
    shadow = g["light"] >= 0
    same = dr.full(mi.Bool, True, dr.width(shadow))
    for dx, dy in ((1.0, 0.0), (0.0, 1.0)):
        qs = []
        for sgn in (1.0, -1.0):
            o, d, _, _ = _rays(P, g["x"] + sgn * dx * DQ_STEP, g["y"] + sgn * dy * DQ_STEP, key)
            q_cam = o + d * g["t"]
            o2, d2, t2, s2, prim2, _, _ = _seen(P, scene, g["x"] + sgn * dx * DQ_SHADOW,
                                                g["y"] + sgn * dy * DQ_SHADOW, key, shadow)
            same &= _slot(s2) == g["rslot"]
            p2 = o2 + d2 * dr.select(dr.isfinite(t2), t2, 0.0)
            L2 = _toward_all(lts, g["light"], p2)
            q_sh = p2 + L2 * g["t"]
            qs.append((q_cam, q_sh, _terminator(P, {}, g["rslot"], prim2, p2, L2, d2)))
        da_cam = dr.dot(m, qs[0][0] - qs[1][0]) / (2.0 * DQ_STEP)
        da_sh = dr.dot(m, qs[0][1] - qs[1][1]) / (2.0 * DQ_SHADOW)
        da_h = (qs[0][2] - qs[1][2]) / (2.0 * DQ_SHADOW)
        a.append(dr.select(g["att"], da_h, dr.select(shadow, da_sh, da_cam)))
    return a, same | ~shadow


def _terminator(P, held, slot, prim, p, L, e):
    """``h = N·L`` at points ``p`` of part ``prim`` of the links1 shape of ``slot`` (``N`` its
    unit normal ``∇G/|∇G|`` (:func:`_implicit_part`) turned toward the camera ray ``e`` that
    met it, with the attached parameters ``held[slot]``; 0 elsewhere): the shading's lit side
    is ``h > 0`` (eq. 3.11), so a terminator lies where ``h = 0``."""
    n, on = _links1_normal(P, held, slot, prim, p)
    return dr.select(on, dr.dot(dr.select(dr.dot(n, e) > 0, -n, n), L), 0.0)


def _links1_normal(P, held, slot, prim, p):
    """The unit normal ``∇G/|∇G|`` (:func:`_implicit_part`, the attached parameters
    ``held[slot]``) at points ``p`` of part ``prim`` of the links1 shape of ``slot``, and
    where ``slot`` is one."""
    n, on = mi.Vector3f(0.0), dr.zeros(mi.Bool, dr.width(p))
    for sp in P.custom:
        _, gn = _implicit_part(sp, held.get(sp.slot, {}), p, prim)
        mine = slot == sp.slot
        n, on = dr.select(mine, dr.normalize(gn), n), on | mine
    return n, on


def _implicit_part(sp, held, p, prim):
    """``(G, ∇G)`` of :func:`links1_mitsuba.geometry.implicit` of the part ``prim`` (per lane: a
    links1 quadric's side 0 or clip plane ``j + 1``) of the shape ``sp``."""
    G, gn = geometry.implicit(mi, dr, sp, held, p)
    for j in range(len(getattr(sp, "clips", []))):
        Gj, gj = geometry.implicit(mi, dr, sp, held, p, part=j + 1)
        G, gn = dr.select(prim == j + 1, Gj, G), dr.select(prim == j + 1, gj, gn)
    return G, gn


def _highlight(P, slot, on):
    """Whether the surface of ``slot`` (on lanes ``on``) may jump where it turns from a light:
    a ``links1_phong`` with a highlight (``specular`` > 0: eq. 3.11's ``(R·V)^n`` need not be 0
    where ``N·L`` is; its diffuse term is), any other BSDF. (From the tables, so that a frozen
    stage follows a changed material.)"""
    spe = dr.gather(mi.Color3f, P.spe, slot, on)
    phong = dr.gather(mi.Bool, P.is_phong, slot, on) if P.any_phong else dr.zeros(mi.Bool, dr.width(slot))
    return ~phong | (dr.max(spe) > 0)


def _unit_normal(P, slot, prim, q, n):
    """The unit normal at ``q`` of the surface of ``slot`` (part ``prim``): a links1 shape's
    ``∇G/|∇G|`` (:func:`_implicit_part`), a Mitsuba shape's ``n`` (its hit's, normalised)."""
    own, on = _links1_normal(P, {}, slot, prim, q)
    return dr.select(on, own, dr.normalize(n))


def _custom_lanes(P, slot):
    """Where ``slot`` is a links1 shape's."""
    on = dr.zeros(mi.Bool, dr.width(slot))
    for sp in P.custom:
        on |= slot == sp.slot
    return on


def _lights(P):
    """``[(k, at, record)]``: the delta lights whose shadow edges are followed, ``k`` their
    place in ``P.lights``: at a position (``at``: a point light, a spot) or along a direction
    (directional, ``links1_spot``: light travels along ``direction``); none where no surface
    of the scene takes light (every one a ``links1_phong`` without ``diffuse`` and
    ``specular``: a shadow or a terminator changes nothing)."""
    if P.all_phong and not (P.phong_np["dif"].any() or P.phong_np["spe"].any()):
        return []
    return [(k, isinstance(rec, POSITIONED), rec) for k, rec in enumerate(P.lights)
            if isinstance(rec, POSITIONED + DIRECTED)]


def _vec(v):
    return mi.Vector3f(v) if dr.is_array_v(v) else mi.Vector3f(*[float(c) for c in np.ravel(v)])


def _toward(lt, p, record=None):
    """The unit direction from ``p`` to light ``lt`` and the shadow segment's length."""
    _, at_, rec = lt
    rec = rec if record is None else record
    if at_:
        v = _vec(rec.position) - p
        dist = dr.norm(v)
        return v / dr.maximum(dist, 1e-30), dist * (1.0 - SHADOW_EPS)
    return -dr.normalize(_vec(rec.direction)), dr.full(mi.Float, INF, dr.width(p))


def _toward_all(lts, light, p):
    out = mi.Vector3f(0.0)
    for j, lt in enumerate(lts):
        out = dr.select(light == j, _toward(lt, p)[0], out)
    return out


def _status(P, scene, x, y, key, lts, only=None, on=None):
    """What the camera rays through ``(x, y)`` see (:func:`_seen`) and, per light ``j`` of
    ``lts`` (with ``only``, an ``Int32`` per lane: on the lanes where it is ``j + 1``; with
    ``on``, a ``Bool`` per light: on its lanes), the nearest occluder of the shadow segment
    from the hit: ``(dir, s, slot (-1: none or not traced, -2: no hit, :data:`UNLIT`: a links1
    shape's side facing away from the light), prim, (shape, triangle))``."""
    cam = _seen(P, scene, x, y, key)
    o, d, t = cam[0], cam[1], cam[2]
    hit = dr.isfinite(t)
    p = o + d * dr.select(hit, t, 0.0)
    rslot = _slot(cam[3])
    custom = _custom_lanes(P, rslot)
    out = []
    for j, lt in enumerate(lts):
        sd, smax = _toward(lt, p)
        act = hit if only is None else hit & (only == j + 1)
        act = act if on is None else act & on[j]
        unlit = act & custom & _highlight(P, rslot, act & custom) & (_terminator(P, {}, rslot, cam[4], p, sd, d) <= 0)
        act &= ~unlit
        cost = dr.zeros(mi.UInt32, dr.width(p))
        ts, ss, si, pr = intersect.nearest(P, scene, p, sd, dr.select(act, SHADOW_EPS * t, 0.0),
                                           dr.select(act, smax, 0.0), act, cost)
        act &= ~(custom & (ss == rslot) & (ts <= ATTACHED * t))   # (a chord at the terminator)
        out.append((sd, dr.select(act, ts, INF), dr.select(hit, dr.select(act, ss, dr.select(unlit, UNLIT, -1)), -2),
                    pr, (si.shape, si.prim_index)))
    return cam, out


def _slots_of(P, test):
    """The slots of Mitsuba's shapes for which ``test(shape)`` holds."""
    return sorted(sl for s_, sl in zip(P.shape_list, P.slot_list) if test(s_))


def _is_sphere(s_):
    return kind_of(s_) == "Sphere"


def _is_mesh(s_):
    return s_.is_mesh()


def _outline(scene, P, q, d, t, slot, prim, hit, ok):
    """What the outline is at each crossing's grazing point ``q`` (detached): ``{m, valid,
    part, tri}`` with ``m`` its unit normal ``⊥ D`` (an edge's ``τ × D``), ``valid`` where it
    is a silhouette this module follows, ``part`` ``j + 1`` on a links1 quadric's rim with
    clip plane ``j`` (0: a smooth silhouette), ``tri`` a Mitsuba mesh edge's ``(shape, end
    vertices a and b, λ)`` with ``q = (1 − λ) a + λ b``."""
    n = dr.width(q)
    m = dr.zeros(mi.Vector3f, n)
    valid = dr.zeros(mi.Bool, n)
    part = dr.zeros(mi.UInt32, n)
    tol = RIM * t
    # (every family's lanes computed, none skipped by a test of the lanes: a frozen stage,
    # :func:`_edges`, replays what its recording traced)
    for sp in P.custom:
        on = ok & (slot == sp.slot)
        G1, g1 = geometry.implicit(mi, dr, sp, {}, q)
        m1 = dr.normalize(g1)
        smooth = on & (prim == 0) & (dr.abs(dr.dot(m1, d)) < GRAZE)
        m = dr.select(smooth, m1, m)
        valid |= smooth
        on_side = on & (dr.abs(G1) < tol * dr.norm(g1))
        for j in range(len(getattr(sp, "clips", []))):
            G2, g2 = geometry.implicit(mi, dr, sp, {}, q, part=j + 1)
            rim = on_side & (dr.abs(G2) < tol * dr.norm(g2))
            m2 = dr.cross(dr.cross(g1, g2), d)
            rim &= dr.squared_norm(m2) > 0
            m = dr.select(rim, dr.normalize(m2), m)
            part = dr.select(rim, j + 1, part)
            valid |= rim
    for sl in _slots_of(P, _is_sphere):
        on = ok & (slot == sl)
        si = _sphere_hit(scene, P, q, sl, on)
        smooth = on & si.is_valid() & (dr.abs(dr.dot(si.n, d)) < GRAZE)
        m = dr.select(smooth, si.n, m)
        valid |= smooth
    tri = None
    meshes = _slots_of(P, _is_mesh)
    if meshes:
        on = dr.zeros(mi.Bool, n)
        for sl in meshes:
            on |= ok & (slot == sl)
        tri, tau, near = _mesh_edge(q, hit, on, tol)
        m_e = dr.cross(tau, d)
        near &= dr.squared_norm(m_e) > 0
        m = dr.select(near, dr.normalize(m_e), m)
        valid |= near
    return {"m": m, "valid": valid, "part": part, "tri": tri}


def _mesh_edge(q, hit, on, tol):
    """The edge of the hit triangle nearest to ``q`` on lanes ``on``: ``((shape, a, b, λ), τ,
    near)`` with ``a``, ``b`` its end vertices' indices, ``τ = b − a``, ``near`` where ``q``
    lies within ``tol`` of it."""
    shape, prim = hit
    mesh = mi.MeshPtr(shape)
    fi = mesh.face_indices(prim, on)
    v = [mesh.vertex_position(fi[k], on) for k in range(3)]
    best = dr.full(mi.Float, INF, dr.width(q))
    a_i, b_i, lam, tau = dr.zeros(mi.UInt32, dr.width(q)), dr.zeros(mi.UInt32, dr.width(q)), mi.Float(0.0), mi.Vector3f(0.0)
    for ka, kb in ((0, 1), (1, 2), (2, 0)):
        e = v[kb] - v[ka]
        e2 = dr.maximum(dr.squared_norm(e), 1e-30)
        l_ = dr.clip(dr.dot(q - v[ka], e) / e2, 0.0, 1.0)
        dist = dr.norm(q - (v[ka] + e * l_))
        better = dist < best
        best = dr.select(better, dist, best)
        a_i, b_i = dr.select(better, fi[ka], a_i), dr.select(better, fi[kb], b_i)
        lam = dr.select(better, l_, lam)
        tau = dr.select(better, e, tau)
    return (shape, a_i, b_i, lam), tau, on & (best < tol)


def _sphere_hit(scene, P, q, sl, on, flags=mi.RayFlags.All):
    """The hit on the Mitsuba sphere of slot ``sl`` of a ray aimed at its point ``q`` from
    outside along the radius (a head-on hit, robust where the camera ray grazes): ``q`` itself
    (with ``FollowShape`` in ``flags``: ``q`` moving with the sphere)."""
    shape = P.shape_list[P.slot_list.index(sl)]
    with dr.suspend_grad():
        bb = shape.bbox()
        c = mi.Point3f(bb.center())
        r = 2.0 * dr.norm(mi.Vector3f(bb.extents()))
    qd = dr.detach(q)
    out = dr.normalize(qd - c)
    ray = mi.Ray3f(qd + out * r, -out)
    return shape.ray_intersect(ray, flags, on)   # (the shape alone: another may be in the way)


def _normal_speed(scene, P, Q, cr):
    """The attached normal velocity ``V_n = m·v`` (value 0) of the outline at each crossing's
    grazing point, or None where no silhouette shape has attached parameters. A smooth
    silhouette of an implicit surface: ``v·∇G = −δG``, so ``V_n = −δG/|∇G|``; a quadric's rim
    (side ``G₁``, clip plane ``G₂``): ``m = α∇G₁ + β∇G₂`` (``m ⊥ τ``), so ``V_n = −α δG₁ − β δG₂``;
    a Mitsuba sphere's point moving with it (``FollowShape``), a mesh edge's point moving with
    its two vertices."""
    q, m, slot, valid, part, att = cr["q"], cr["m"], cr["slot"], cr["valid"], cr["part"], cr["att"]
    vn = dr.zeros(mi.Float, dr.width(q))
    any_ = False
    cut = valid & cr["cut"]
    valid = valid & ~cut
    for sl, (sp, held) in (Q.geo_ad or {}).items():
        on = valid & ~att & (slot == sl)
        G1, g1 = geometry.implicit(mi, dr, sp, held, q)
        d1, g1 = G1 - dr.detach(G1), dr.detach(g1)
        vn = dr.select(on & (part == 0), -d1 / dr.norm(g1), vn)
        for j in range(len(getattr(sp, "clips", []))):
            G2, g2 = geometry.implicit(mi, dr, sp, held, q, part=j + 1)
            speed, ok = _meeting_speed(m, g1, d1, dr.detach(g2), G2 - dr.detach(G2))
            vn = dr.select(on & (part == j + 1) & ok, speed, vn)
        any_ = True
    for sl in _slots_of(P, _is_sphere):
        on = valid & (slot == sl)
        si = _sphere_hit(scene, P, q, sl, on, mi.RayFlags.All | mi.RayFlags.FollowShape)
        if not dr.grad_enabled(si.p):
            continue
        vn = dr.select(on & si.is_valid(), dr.dot(m, si.p - dr.detach(si.p)), vn)
        any_ = True
    if cr["tri"] is not None:
        shape, a_i, b_i, lam = cr["tri"]
        mesh = mi.MeshPtr(shape)
        on = valid & _mesh_lanes(P, slot)
        p = mesh.vertex_position(a_i, on) * (1.0 - lam) + mesh.vertex_position(b_i, on) * lam
        if dr.grad_enabled(p):
            vn = dr.select(on, dr.dot(m, p - dr.detach(p)), vn)
            any_ = True
    # a shadow edge also moves with its receiver and its light: the shadow ray from the
    # receiver's point p (moving along its camera ray as its surface moves) toward the light
    # moves at the grazing point by δp + s δL; a terminator (``h = N·L = 0`` on the receiver,
    # :func:`_terminator`) moves where ``h`` at the pixel changes: ``dx_c/dθ = −δh / h_x``, so
    # its ``V_n`` is ``−δh`` (``a``: ``∇h``)
    held = {sl: h_ for sl, (_, h_) in (Q.geo_ad or {}).items()}
    kinds = cr["kinds"]
    if (held or any(_attached_light(Q.lights[k]) for k, _, _ in cr["lights"])) and kinds["shadow"]:
        pa = _moving_receiver(P, held, cr)
        L = mi.Vector3f(0.0)
        for j, (k, at_, _) in enumerate(cr["lights"]):
            L = dr.select(cr["light"] == j, _toward((k, at_, Q.lights[k]), pa)[0], L)
        q_ray = pa + L * dr.select(att, 0.0, cr["ts"])
        shadow = valid & ~att & (cr["light"] >= 0)
        vn = dr.select(shadow, vn - dr.dot(m, q_ray - dr.detach(q_ray)), vn)
        if kinds["att"]:
            h = _terminator(P, held, cr["rslot"], cr["rprim"], pa, L, cr["e"])
            vn = dr.select(valid & att, -(h - dr.detach(h)), vn)
        any_ = True
    # where two surfaces cut: m = α n₁ + β n₂ (m ⊥ the curve), so V_n = −α δĜ₁ − β δĜ₂ with
    # Ĝᵢ = Gᵢ/|∇Gᵢ| (a links1 shape's implicit surface; a Mitsuba shape's held fixed: 0)
    if held and kinds["cut"]:
        speed, ok = _meeting_speed(m, cr["n1"], _unit_speed(P, held, slot, part, q),
                                   cr["n2"], _unit_speed(P, held, cr["rslot"], cr["rprim"], q))
        vn = dr.select(cut & ok, speed, vn)
        any_ = True
    return vn if any_ else None


def _meeting_speed(m, g1, d1, g2, d2):
    """The normal velocity ``V_n = m·v`` of the curve where two surfaces ``G₁ = 0`` and
    ``G₂ = 0`` meet (a quadric's rim, two surfaces that cut), ``m`` its unit normal ``⊥`` the
    curve: ``∇Gᵢ·v = −δGᵢ`` and ``m = α∇G₁ + β∇G₂``, so ``V_n = −α δG₁ − β δG₂``; ``g``: the
    detached gradients, ``d``: the attached ``δG`` (value 0). With where it is defined (the
    gradients not parallel)."""
    a11, a12, a22 = dr.dot(g1, g1), dr.dot(g1, g2), dr.dot(g2, g2)
    b1, b2 = dr.dot(m, g1), dr.dot(m, g2)
    det = a11 * a22 - a12 * a12
    ok = det > 0
    det = dr.select(ok, det, 1.0)
    return -((b1 * a22 - b2 * a12) * d1 + (a11 * b2 - a12 * b1) * d2) / det, ok


def _unit_speed(P, held, slot, prim, q):
    """``δG / |∇G|`` (value 0) at ``q`` of the links1 shape of ``slot`` (part ``prim``) with
    attached parameters in ``held``; 0 elsewhere."""
    out = dr.zeros(mi.Float, dr.width(q))
    for sp in P.custom:
        if sp.slot in held:
            G, gn = _implicit_part(sp, held[sp.slot], q, prim)
            out = dr.select(slot == sp.slot, (G - dr.detach(G)) / dr.norm(dr.detach(gn)), out)
    return out


def _moving_receiver(P, held, cr):
    """The receiver's point of each crossing (``p``, attached): where its camera ray
    (direction ``e``) meets its links1 shape as the shape moves (the hit's implicit derivative
    ``δt = −δG / (∇G·e)``; the other shapes' receivers held fixed)."""
    p, e, slot, prim = cr["p"], cr["e"], cr["rslot"], cr["rprim"]
    pa = mi.Point3f(p)
    for sp in P.custom:
        if sp.slot not in held:
            continue
        G, gn = _implicit_part(sp, held[sp.slot], p, prim)
        dG, gn = G - dr.detach(G), dr.detach(gn)
        den = dr.dot(gn, e)
        pa = dr.select(slot == sp.slot, p - e * dG / dr.select(den != 0, den, 1.0), pa)
    return pa


def _attached_light(rec):
    """Whether a light record's position or direction has gradients."""
    return any(dr.is_array_v(getattr(rec, f, None)) and dr.grad_enabled(getattr(rec, f))
               for f in ("position", "direction", "origin", "axis"))


def _mesh_lanes(P, slot):
    on = dr.zeros(mi.Bool, dr.width(slot))
    for sl in _slots_of(P, _is_mesh):
        on |= slot == sl
    return on
