"""The derivative pass's ray tree of ``links1_whitted`` (its one home): the trees of
:meth:`.raytree.Tracer.trace_tree` (the same levels, children, weights, keys and
``min_weight`` rule, :meth:`~.raytree.Tracer.level` and :meth:`~.raytree.Tracer.children`)
traced level by level in Python without local memory, so that Dr.Jit can differentiate them
(gradients.py: why; the primal's megakernel keeps its pending refraction rays in
``dr.alloc_local`` memory, which Dr.Jit cannot differentiate). Called by the launches
(``Launches._launch``) in a derivative mode.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from . import intersect
from .raytree import child_keys
from .util import INF, udiv

#: the derivative pass traces the samples whose camera ray hits something alone where at most
#: this fraction of them does (:func:`trace_tree_ad`)
SEEING_MAX = 0.75
#: the key of the pass's tables' ``ad_memo`` under which the hits of its camera rays wait where
#: the pass found them before tracing (``Gradients._ad_blocks``): ``(lanes, hits)`` as
#: :func:`seeing_of` makes them (``lanes`` None: not compressed yet); :func:`_seeing` takes
#: them instead of tracing the rays again
SEEING = "seeing"
#: where the pass found its camera rays' hits before tracing (:data:`SEEING`), the seeing
#: samples' rays are made from their own sample ids (``rays`` of :func:`trace_tree_ad`) instead
#: of every sample's rays evaluated and gathered: the same values, a kernel over the window fewer
RAYS_OF_SEEING = True
#: in a reverse-mode pass, the seeing lanes' RGB put back in their samples' lanes by a scatter
#: over the seeing lanes (its reverse a gather, made in the next backward kernel) instead of a
#: gather over every lane (its reverse a kernel over every lane); forward mode keeps the gather
SCATTERED_BACK = True
#: in a reverse-mode pass of a box filter, the seeing lanes' RGB summed into their pixels by a
#: scatter-add (:func:`seeing_film`) instead of put back in every lane and reconstructed: its
#: reverse is a gather in the backward kernel; no kernel over every lane or pixel either way
SEEING_FILM = True


def seeing_film(L, lanes, spp, pixels):
    """The box filter's pixels (``pixels`` of them, a flat ``Float`` array of ``3 · pixels``, RGB
    innermost) of samples ``lanes`` (``UInt32``, lane ``pixel · spp + i`` of the launch) of RGB
    ``L``, the others 0: each pixel's samples summed in float64, then over ``spp`` (an opaque
    ``UInt32``), as :func:`.film.reconstruct` makes a box pixel (a sum of at most ``spp``
    float32 values in float64: exact, whatever their order, unless their exponents differ by
    more than 29); differentiable, its reverse a gather."""
    acc = dr.zeros(mi.Float64, 3 * pixels)
    dr.scatter_add(acc, mi.ArrayXf64(*[mi.Float64(L[c]) for c in range(3)]), udiv(lanes, spp))
    return mi.Float(acc / mi.Float64(spp))


def cat(a, b, na, nb):
    """``a`` (``na`` lanes) followed by ``b`` (``nb`` lanes), differentiable (gathers)."""
    if nb == 0:
        return a
    if na == 0:
        return b
    # ``na`` enters as an opaque value, not a literal: the counts change with the geometry
    # (compaction of each level's children), and a literal would make new kernels each time
    n_a = dr.opaque(mi.UInt32, na)
    j = dr.arange(mi.UInt32, na + nb)
    in_a = j < n_a
    ga = dr.gather(type(a), a, dr.select(in_a, j, 0), in_a)
    gb = dr.gather(type(b), b, dr.select(in_a, 0, j - n_a), ~in_a)
    return dr.select(in_a, ga, gb)


def trace_tree_ad(tracer, tables, scene, o, d, tmin, tmax, key, sample, rays=None, backward=False, compact=False):
    """The ray trees of :meth:`.raytree.Tracer.trace_tree` (the same levels, children, weights, keys
    and ``min_weight`` rule) traced level by level without local memory, so that Dr.Jit
    can differentiate them: the children of a level (mirror rays first, then
    refraction rays) are compacted into the next level's rays, and each level's
    ``weight · I_o`` is added to its sample (eq. 3.16). Returns the samples' RGB, evaluated.

    Where no background shines (no environment: a camera ray that escapes sees 0), no ray
    spawns children and at most :data:`SEEING_MAX` of the camera rays hit something, the trees
    of those alone are traced (their nearest hits found first, on primal values) and put back
    in their lanes, the others 0: an escaping camera ray's sample is 0 and carries no
    derivative (its visibility is held; the derivative of the outlines it misses is the
    visibility term's), and the AD kernels and their graph cover the samples that see
    something. ``rays``: a function of lanes (``UInt32``) giving those samples' camera rays as
    ``o, d, tmin, tmax, key, sample`` (:data:`RAYS_OF_SEEING`), or None; ``backward``: the
    graph is made for reverse mode (:data:`SCATTERED_BACK`); ``compact``: where the seeing
    samples alone are traced, return ``(L, lanes)`` instead: their RGB and lanes (for
    :func:`seeing_film`)."""
    seen, made = None, False
    if traces_seeing(tracer.config, tables):
        lanes, hit = (tables.ad_memo or {}).get(SEEING, (None, None))
        made = (RAYS_OF_SEEING and rays is not None and lanes is not None and dr.width(hit) == dr.width(o)
                and seeing_alone(dr.width(o), dr.width(lanes)))
        seen = _seeing(tables, scene, o, d, tmin, tmax, key, sample, made)
    if seen is not None and made:
        o, d, tmin, tmax, key, sample = rays(seen[0])
        # (evaluated in one kernel over the seeing lanes: the level's kernels, its backward
        # one too, would each make the rays again)
        with dr.suspend_grad():
            dr.eval(o, d, tmin, tmax, key, sample[0], sample[1])
    elif seen is not None:
        seeing = seen[0]
        o, d, tmin, tmax, key = (dr.gather(type(v), v, seeing) for v in (o, d, tmin, tmax, key))
        sample = (dr.gather(type(sample[0]), sample[0], seeing), dr.gather(type(sample[1]), sample[1], seeing),
                  sample[2])
    return _trace(tracer, tables, scene, o, d, tmin, tmax, key, sample, seen, backward, compact)


def traces_seeing(config, tables):
    """Whether :func:`trace_tree_ad` may trace the seeing samples alone: no environment and no
    child ray (where children may be spawned, the reverse-mode scatter-adds into a level's
    arrays, then as many lanes as camera rays hit, hold that count in their code: new kernels
    every frame)."""
    return tables.env is None and not (config.max_depth > 1 and tables.any_specular)


def seeing_alone(lanes, seeing):
    """Whether :func:`trace_tree_ad` traces the ``seeing`` of ``lanes`` camera rays alone (where
    :func:`traces_seeing`): some, and at most :data:`SEEING_MAX` of them, hit something."""
    return 0 < seeing <= SEEING_MAX * lanes


def hits(tables, scene, o, d, tmin, tmax):
    """Where the rays ``o + t d`` (``tmin`` to ``tmax``) hit something (primal values)."""
    n = dr.width(o)
    with dr.suspend_grad():
        _, slot, _, _ = intersect.nearest(tables, scene, dr.detach(o), dr.detach(d), tmin, tmax,
                                          dr.full(mi.Bool, True, n), dr.zeros(mi.UInt32, n), ad=True)
    return slot >= 0


def seeing_of(hit):
    """``(lanes, hits)``: the lanes (``UInt32``) where the mask ``hit`` is set, and the mask."""
    with dr.suspend_grad():
        return dr.compress(hit), hit


def _seeing(tables, scene, o, d, tmin, tmax, key, sample, made=False):
    """``(lanes, hits)``: the lanes (``UInt32``) whose camera ray hits something and the mask
    of those, or None (every lane traced) where more than :data:`SEEING_MAX` of them do or
    none does. The rays, their keys and samples are evaluated with the mask, in one kernel (a
    gather evaluates its source alone: a kernel per component otherwise), unless ``made``
    (the seeing lanes' rays made from their sample ids instead: :data:`RAYS_OF_SEEING`)."""
    n = dr.width(o)
    lanes, hit = (tables.ad_memo or {}).pop(SEEING, (None, None))
    if hit is None or dr.width(hit) != n:
        lanes, hit = None, hits(tables, scene, o, d, tmin, tmax)
    if not made:
        with dr.suspend_grad():
            dr.eval(o, d, tmin, tmax, key, sample[0], sample[1], hit)
    seen = seeing_of(hit) if lanes is None else (lanes, hit)
    return seen if seeing_alone(n, dr.width(seen[0])) else None


def _trace(tracer, tables, scene, o, d, tmin, tmax, key, sample, seen=None, backward=False, compact=False):
    """:func:`trace_tree_ad` of the rays ``o, d``: every sample's, or with ``seen`` (``(lanes,
    hits)`` of :func:`_seeing`) those of the samples ``lanes``, the others' RGB 0. Every
    array the trees are summed into has a lane per sample (their scatter-adds' code does not
    change with the number of rays that hit)."""
    spawn = tracer.config.max_depth > 1 and tables.any_specular
    later = []    # a level's shadow tests, evaluated with what its children take (below)
    res = tracer.level(tables, scene, o, d, tmin, tmax, key, 1, spawn, symbolic=False, ad=True,
                       sample=sample, later=later)
    if seen is None:
        n = dr.width(o)
        total = mi.Color3f(res.L)
        own = dr.arange(mi.UInt32, n)
    else:
        # the level's RGB back in its samples' lanes by a gather (a lane's place among the
        # seeing ones: the hits' exclusive prefix sum; each gathered once, so its reverse is a
        # plain scatter, ReduceMode.Permute), differentiable both ways (a scatter's tangent in
        # forward mode was read dirty)
        own, hit = seen
        # (the level's RGB evaluated first, in one kernel with its shadow tests: a gather
        # evaluates its source alone, a kernel per component each recomputing the level)
        dr.eval(res.L, *later)
        later.clear()
        if compact and not spawn:
            return res.L, own
        if backward and SCATTERED_BACK:
            total = dr.zeros(mi.Color3f, dr.width(hit))
            dr.scatter(total, res.L, own, mode=dr.ReduceMode.Permute)
        else:
            at = dr.prefix_sum(mi.UInt32(hit))
            total = dr.select(hit, dr.gather(mi.Color3f, res.L, at, hit, mode=dr.ReduceMode.Permute), 0.0)
    if not spawn:
        dr.eval(total, *later)
        return total
    cr, ct, w_r, w_t = tracer.children(res, res.hit, mi.Color3f(1.0), mi.UInt32(1))
    depth = 2
    while True:
        key_r, key_t = child_keys(key)
        ir, it = dr.compress(cr), dr.compress(ct)
        nr, nt = dr.width(ir), dr.width(it)
        if nr + nt == 0:
            dr.eval(total, *later)
            return total
        # what the children take of this level, made in one kernel (a gather evaluates its
        # source alone: a kernel per component, each recomputing the shared terms), with the
        # level's shadow tests: it runs while the next level is traced
        dr.eval(*([res.o_r, res.dir_r, w_r, key_r] if nr else []),
                *([res.o_t, res.dir_t, w_t, key_t] if nt else []), *later)
        later.clear()

        def pick(x_r, x_t):
            a = dr.gather(type(x_r), x_r, ir) if nr else None
            b = dr.gather(type(x_t), x_t, it) if nt else None
            return cat(a, b, nr, nt)
        own = pick(own, own)
        o, d = pick(res.o_r, res.o_t), pick(res.dir_r, res.dir_t)
        if tables.fixed_children:
            # spawned by surfaces that do not move, from rays that carry no derivative
            # (the camera's; by induction the children's): the AD graph skips their
            # place (zero derivative, computed in every backward kernel otherwise)
            o, d = dr.detach(o), dr.detach(d)
        wgt, key = pick(w_r, w_t), pick(key_r, key_t)
        m = nr + nt
        res = tracer.level(tables, scene, o, d, dr.zeros(mi.Float, m), dr.full(mi.Float, INF, m), key, 0,
                           True, symbolic=False, ad=True, later=later)
        acc = dr.zeros(mi.Color3f, n)
        dr.scatter_add(acc, wgt * res.L, own)
        total = total + acc
        cr, ct, w_r, w_t = tracer.children(res, dr.full(mi.Bool, True, m), wgt, mi.UInt32(depth))
        depth += 1
