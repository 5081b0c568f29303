"""Gradients of ``links1_whitted``: ``render_forward`` and ``render_backward``, as
Mitsuba's ``ADIntegrator`` has them, so ``mi.render(scene, params)`` followed by
``dr.backward(loss)`` (or ``dr.forward``) differentiates the whole Whitted ray tree.

How. The primal frame (``mi.render`` evaluates it under ``dr.suspend_grad``) is the usual frozen
launch, bit for bit the image of a render without gradients. The derivative pass renders the
frame again with automatic differentiation (:meth:`Gradients._render_ad`). Where the caller
chooses it (``Tuning.keep_graph``, off by default), the frame does not depend on the seed
(spp 1 at the pixel centres, analytic lights only: the primal's ``seed`` and the pass's
``seed_grad`` give the same rays), some parameter has gradients enabled and the frame is one
block, ``render()`` renders the derivative pass's frame instead of the primal, returns its
values and keeps its graph, which ``render_backward`` then propagates
(:meth:`Gradients.render_keeping_graph`): one render an iteration instead of two. That frame
equals the primal to float32 rounding (its tree is summed level by level, the megakernel's
depth first: 1-2 ulp in some pixels of a glass scene, ``tests/plugins/test_gradients.py``).

* the tables are the primal ones (``prepare``) with the *attached* Dr.Jit values of the
  parameters that have gradients enabled put in (:meth:`Gradients._ad_tables`): every
  ``links1_phong`` coefficient (``ambient``, ``diffuse``, ``specular``, ``exponent``,
  ``reflectance``, ``transmittance``), the ``links1_point`` light (``position``, ``direction``,
  ``L1``, ``L2``), the ``links1_spot`` light (``origin``, ``intensity``) and Mitsuba's ``point``
  light (``position``, ``intensity``). Mitsuba's own BSDFs (``diffuse.reflectance``, textures
  ...) are differentiated by Mitsuba itself: ``bsdf.eval`` reads their attached values;
* the launch is not frozen (gradients cannot flow through a frozen function's outputs) and the
  ray tree is traced level by level in Python (:func:`.raytree_ad.trace_tree_ad`: every mirror
  and refraction child of a level is compacted into the next level's rays, and each level's
  ``weight · I_o`` is added to its sample by a differentiable scatter), because the primal's
  megakernel keeps its pending refraction rays in ``dr.alloc_local`` memory, which Dr.Jit
  cannot differentiate; the film's loops run in evaluated mode (reverse-mode AD needs it).

What is differentiated: the *interior* derivative. Which surface a ray hits, which side of a
shadow edge a point lies on, whether a branch is traced (``min_weight``, a zero reflectance)
and the refracted direction (``ior``) are held fixed; silhouettes and shadow edges moving with
a light or a shape are left out, as Mitsuba's non-projective integrators leave them out (a
gradient with respect to a light's position is then the derivative of the shading at fixed
visibility: right away from shadow edges, biased where a pixel straddles one). Not
differentiated (zero gradient): the geometry of Mitsuba's shapes, area and environment lights
and the cameras. The links1 shapes' geometry is differentiated (:mod:`links1_mitsuba.geometry`,
:func:`.intersect.moving_hits`): the hit moves with the surface by implicit differentiation of
its equation, silhouettes and shadow edges still held fixed.

Cost: the derivative pass keeps a ray tree on Dr.Jit's AD tape (no path replay as Mitsuba's
PRB), so reverse mode goes over the film in blocks of rows (:func:`row_blocks`) of at most
:data:`AD_BLOCK_LANES` samples: each block is rendered with AD, its part of the image gradient
propagated, and its graph freed before the next (forward mode renders one block: see
:meth:`Gradients.render_forward`). A block renders the samples of its filter border too
(``film.sample_window``), so its
pixels are the full frame's and the loss ``Σ g_p I_p`` splits exactly by blocks; memory is
bounded by one block's tree (~0.75 KiB a sample for scenes/fig11.xml at max_depth 5), not the
frame's (docs/benchmarks.md, inverse rendering). A 256² frame at spp 1 is one block. Where
the pass traces the samples that see something alone (``raytree_ad.trace_tree_ad``: no
environment, no child ray) and the filter is the box, the blocks count the lanes on the tape
(:func:`seeing_blocks`, the rows' hits found first): a frame most of whose camera rays escape
is fewer blocks.

:class:`Gradients` is one part of the ``Engine`` (engine.py), over its tables and launches;
its methods name ``mi.Float``, ``mi.Ray3f``, ... when called, so the class serves every
Mitsuba variant.
"""
from __future__ import annotations

import copy
import functools

import drjit as dr
import mitsuba as mi

from links1.tracing.aovs import channel_names

from . import boundary, geometry, raytree_ad
from .config import Config
from .launch import Launches
from .lights import params_of
from .raytree import Tracer
from .prepared import CameraView
from .tables import PHONG_TABLES, Tables
from .registered import plugin_class
from .sceneshapes import SceneShapes
from .util import kind_of
from .views import render_request


#: (parameter, field of the light's ``primal.lights`` record) of the links1 lights' differentiable
#: values: a ``links1_point``'s :class:`~.lights.PointRecord`, a ``links1_spot``'s
#: :class:`~.lights.CylinderSpotRecord`
LINKS1_POINT_FIELDS = (("position", "position"), ("direction", "axis"), ("L1", "L1"), ("L2", "L2"))
LINKS1_SPOT_FIELDS = (("origin", "origin"), ("intensity", "intensity"))


#: Most sample lanes (pixels of a block and of its filter border, times spp) the derivative
#: pass puts on Dr.Jit's AD tape at once (see the module's docstring): 256² at spp 2 is one
#: block; 1024² at spp 1 eight (~0.7 KiB a lane at max_depth 5: ~90 MiB a block).
AD_BLOCK_LANES = 1 << 17
#: most samples a block of :func:`seeing_blocks` has, in :data:`AD_BLOCK_LANES`
SEEING_CAP = 4


def row_blocks(win, film_size, border, spp, budget=None):
    """The window ``win = (x0, y0, w, h)`` cut into windows of whole rows, each with at most
    ``budget`` (default :data:`AD_BLOCK_LANES`) sample lanes counting the filter's ``border``
    rows and columns around it (clipped to the film), and at least one row each."""
    budget = AD_BLOCK_LANES if budget is None else int(budget)
    x0, y0, w, h = win
    W, H = film_size
    cols = min(W, x0 + w + border) - max(0, x0 - border)
    rows = max(1, budget // max(1, cols * int(spp)) - 2 * border)
    return [(x0, y, w, min(rows, y0 + h - y)) for y in range(y0, y0 + h, rows)]


def seeing_blocks(win, hits, spp, budget=None):
    """The window ``win = (x0, y0, w, h)`` (a box filter's: no border) cut into windows of whole
    rows, each with at most ``budget`` (default :data:`AD_BLOCK_LANES`) lanes on the AD tape,
    as a derivative pass traces them (``raytree_ad``: the samples that see something alone
    where few do; ``hits``: per row, how many of its samples' camera rays hit something), and
    at most :data:`SEEING_CAP` times ``budget`` samples (their rays and film values), at least
    one row each."""
    budget = AD_BLOCK_LANES if budget is None else int(budget)
    x0, y0, w, h = win
    row = w * int(spp)
    blocks, start, lanes, seen = [], 0, 0, 0
    for r in range(h):
        lanes2, seen2 = lanes + row, seen + int(hits[r])
        taped = seen2 if raytree_ad.seeing_alone(lanes2, seen2) else lanes2
        if r > start and (taped > budget or lanes2 > SEEING_CAP * budget):
            blocks.append((x0, y0 + start, w, r - start))
            start, lanes2, seen2 = r, row, int(hits[r])
        lanes, seen = lanes2, seen2
    blocks.append((x0, y0 + start, w, h - start))
    return blocks


def attached(*vals):
    return any(dr.grad_enabled(v) for v in vals)


def put_rows(table, rows, width):
    """``table`` (a flat Float of ``width`` values per slot) with the rows ``{slot: value}``
    (Dr.Jit values, attached) put in by ``select``: a differentiable copy."""
    out = type(table)(table)
    idx = dr.arange(mi.UInt32, dr.width(table))
    for sl, v in rows.items():
        for k in range(width):
            comp = v[k] if width > 1 else v
            out = dr.select(idx == sl * width + k, comp, out)
    return out


def _spawns(primal, slot):
    """Whether a hit on ``slot`` may spawn a mirror or refraction ray (eq. 3.12-3.16): a
    ``links1_phong`` with some reflectance or transmittance, any other BSDF where the scene
    has delta lobes."""
    if not primal.is_phong_np[slot]:
        return primal.any_mitsuba_delta
    return bool(primal.phong_np["refl"][slot].max() > 0 or max(primal.shadow_t_np[slot]) > 0)


def _mitsuba_attached(scene, primal, watched):
    """Whether a parameter of the scene (of Mitsuba's own objects among them) has gradients
    enabled: ``watched`` (the tables ``primal`` were just checked against the scene's parameters,
    ``paramwatch.ParamWatch``), as the watch read them; else by a traversal."""
    if watched:
        return (primal.base if primal.base is not None else primal).watch.attached()
    return any(dr.grad_enabled(v) for _, v in mi.traverse(scene).items())


class Gradients:
    """``render_forward``/``render_backward`` and the differentiable render behind them, with
    the integrator's parameters ``config``, its links1 shapes ``shapes`` (their attached
    geometry), its tables (``prepare``: the primal tables the pass starts from) and launches
    (the pass's unfrozen launch); each entry point is given the frame's switches ``tuning``
    (:class:`~.tuning.Tuning`). It owns the frame a primal render kept for ``render_backward``
    (``kept_graph``)."""

    __slots__ = (
        "config", "shapes", "tables", "launches",
        "kept_graph",      # (image, sensor, window, tables) of render_keeping_graph, or None
    )

    def __init__(self, config: Config, shapes: SceneShapes, tables: Tables, launches: Launches):
        self.config = config
        self.shapes = shapes
        self.tables = tables
        self.launches = launches
        self.kept_graph = None

    # -------------------------------------------------------------- Mitsuba entry points
    def render_forward(self, scene, params, sensor, seed, spp, tuning):
        """The image's derivative along the gradients set on the scene's parameters
        (``dr.set_grad``): Mitsuba's ``Integrator.render_forward``. In one block (the whole
        frame's graph at once, unlike :meth:`render_backward`): inside ``mi.render``'s custom
        operation a tangent must cross the edges into the parameters (a parameter made from
        another value) in every block, and a traversal that keeps them for the next block
        (``ADFlag.ClearNone``) left state that a later forward pass in the same process
        tripped over ("... lies outside of the current dr.isolate_grad() scope", seen in CI
        with two scenes alive); one traversal with the default flags, as before the blocks."""
        # a graph the primal kept (for reverse mode) is dropped first: forward propagation
        # from the parameters would enter it, outside this pass's isolation scope
        self.kept_graph = None
        with dr.resume_grad():
            img = self._render_ad(scene, sensor, seed, spp, tuning, mode=dr.ADMode.Forward)
            dr.forward_to(img)
            grad = dr.grad(img)
        extra = len(channel_names(self.config.aovs)) - grad.shape[-1]
        if extra > 0:   # the AOV channels carry no derivative (they are detached): zeros
            grad = dr.concat([grad, dr.zeros(mi.TensorXf, (*grad.shape[:-1], extra))], axis=-1)
        return grad

    def render_backward(self, scene, params, grad_in, sensor, seed, spp, tuning):
        """Propagate the image gradient ``grad_in`` to the scene's parameters that have
        gradients enabled: Mitsuba's ``Integrator.render_backward``. Block by block
        (:func:`row_blocks`): each block's rows of ``grad_in`` propagated, its graph freed.
        A frame whose graph the primal kept (:meth:`render_keeping_graph`) is propagated
        through that graph instead of being rendered again."""
        kept = self._take_kept(scene, sensor, seed, spp, tuning)   # the whole frame as one block
        # (the primal tables prepared once for the pass's parts: the scene does not change in it)
        blocks, primal, ad = ([None], None, None) if kept is not None else self._ad_blocks(scene, sensor, seed, spp,
                                                                                           tuning)
        ad = ad or [None] * len(blocks)
        # projective over several blocks: the visibility term in its own, larger blocks first
        # (its graph is small; each pass over a window has a cost of its own)
        apart = self.config.projective and len(blocks) > 1
        y = 0
        with dr.resume_grad():
            if apart:
                self._backward_boundary(scene, grad_in, sensor, seed, spp, tuning, primal)
            for block, ad_tables in zip(blocks, ad):
                # one block's graph at a time: built, its rows of grad_in propagated, dropped
                img = kept if block is None else self._render_ad(scene, sensor, seed, spp, tuning, window=block,
                                                                 mode=dr.ADMode.Backward, edge=not apart,
                                                                 primal=primal, ad_tables=ad_tables)
                kept = None
                h = img.shape[0]
                g = grad_in if h == grad_in.shape[0] else grad_in[y:y + h]
                y += h
                if g.shape[-1] != img.shape[-1]:   # the AOV channels' gradients go nowhere (detached)
                    g = g[..., :img.shape[-1]]
                dr.set_grad(img, g)
                dr.enqueue(dr.ADMode.Backward, img)
                dr.traverse(dr.ADMode.Backward)
                del img
        dr.eval()

    def _ad_blocks(self, scene, sensor, seed, spp, tuning):
        """The blocks (:func:`row_blocks`) of the frame a derivative pass renders, the primal
        tables it starts from and, where the blocks were counted in the pass's seeing lanes,
        each block's tables of the pass (:meth:`_ad_tables`) holding the hits of its camera
        rays (else None); with more than one block, Dr.Jit's allocation cache is flushed first
        (the primal frame's buffers wait there, in sizes the blocks do not reuse: the peak would
        be the primal's plus a block's)."""
        sensor_, win, spp_, seed_ = render_request(scene, sensor, seed, spp, self.config.seed)
        ad = None
        with dr.suspend_grad():
            primal = self.tables.prepare(scene, sensor_, tuning)
            blocks = row_blocks(win, primal.film_size, primal.rfilter.border, spp_)
            if len(blocks) > 1 and primal.rfilter.border == 0 and raytree_ad.traces_seeing(self.config, primal):
                # blocks counted in the lanes the pass puts on the AD tape (few where few
                # camera rays hit something): the window's camera rays' hits found first, by the
                # pass's own tables, which each block then takes (raytree_ad.SEEING) instead of
                # tracing its camera rays again
                with dr.resume_grad():
                    tables = self._ad_tables(primal, scene)
                hit = self.launches.seeing_hits(tables, scene, win, spp_, seed_)
                lanes = win[2] * win[3] * spp_
                seen = raytree_ad.seeing_of(hit) if lanes <= SEEING_CAP * AD_BLOCK_LANES else None
                m = -1 if seen is None else dr.width(seen[0])
                if 0 <= (m if raytree_ad.seeing_alone(lanes, m) else lanes) <= AD_BLOCK_LANES:
                    blocks, parts = [win], [seen]    # one block: its seeing lanes as found here
                else:
                    blocks = seeing_blocks(win, dr.block_sum(mi.UInt32(hit), win[2] * spp_).numpy(), spp_)
                    row = win[2] * spp_
                    parts = [(None, dr.gather(mi.Bool, hit, dr.arange(mi.UInt32, b[3] * row) + (b[1] - win[1]) * row))
                             for b in blocks]
                ad = []
                for part in parts:   # (a block's own tables: its graph is dropped before the next)
                    if ad:
                        with dr.resume_grad():
                            tables = self._ad_tables(primal, scene)
                    tables.ad_memo[raytree_ad.SEEING] = part
                    ad.append(tables)
        if len(blocks) > 1:
            dr.flush_malloc_cache()
        return blocks, primal, ad

    # -------------------------------------------------------------- the kept graph
    def render_keeping_graph(self, scene, sensor, win, spp, seed, tuning):
        """The frame of ``render()``, made by the derivative pass with its AD graph kept for
        :meth:`render_backward`, or None where the usual primal applies.

        ``mi.render`` with parameters calls ``render()`` (Mitsuba's ``_RenderOp.eval``) and,
        at ``dr.backward``, ``render_backward`` with another seed (``seed_grad``), which renders
        the frame again with AD. Where the frame does not depend on the seed (one sample a
        pixel, at the pixel's centre, and only analytic lights: no light is sampled) both
        renders are the same function of the parameters, so the derivative pass's frame may be
        made once, here, and its graph propagated later: one render an iteration instead of
        two. ``render()`` cannot see whether ``mi.render`` was given parameters, so this is the
        caller's explicit choice (``Tuning.keep_graph``; off: the primal, bit for bit), and then
        only for a frame of one block (:func:`row_blocks`: the graph's memory is bounded as the
        blocks bound it) with some parameter attached. A ``render_backward`` for another
        sensor, window or spp renders its pass again (:meth:`_take_kept`); the next frame or a
        ``render_forward`` drops the graph."""
        self.kept_graph = None
        if not tuning.keep_graph or spp != 1 or self.config.projective:
            return None
        with dr.suspend_grad():
            primal = self.tables.prepare(scene, sensor, tuning)
        if (primal.area_tab or primal.consts
                or len(row_blocks(win, primal.film_size, primal.rfilter.border, spp)) != 1):
            return None
        with dr.resume_grad():
            ad_tables = self._ad_tables(primal, scene)
            if not ad_tables.attached_any:
                return None
            img = self.launches.render_windows_device(ad_tables, scene, Tracer(self.config, tuning), [win], spp=spp,
                                                      seed=seed, dtype=mi.Float, mode=dr.ADMode.Backward)[0]
            dr.eval(img)
        self.kept_graph = (img, sensor, win, primal)
        return dr.detach(img)

    def _take_kept(self, scene, sensor, seed, spp, tuning):
        """The frame :meth:`render_keeping_graph` kept for this request (once), or None."""
        kept = self.kept_graph
        self.kept_graph = None
        if kept is None:
            return None
        img, sensor_k, win_k, primal = kept
        sensor_, win, spp_, _ = render_request(scene, sensor, seed, spp, self.config.seed)
        if sensor_ is not sensor_k or win != win_k or spp_ != 1:
            return None
        with dr.suspend_grad():
            if self.tables.prepare(scene, sensor_, tuning) is not primal:   # the scene changed since
                return None
        return img

    # -------------------------------------------------------------- the differentiable frame
    def _render_ad(self, scene, sensor, seed, spp, tuning, window=None, mode=None, edge=True, primal=None,
                   ad_tables=None):
        """The frame ``render()`` makes (or its ``window``), with Dr.Jit's AD graph from the
        scene's gradient-enabled parameters (see the module's docstring); ``mode``: the
        ``dr.ADMode`` the graph is made for (Forward or Backward: the same frame); ``edge``:
        with the visibility term where ``projective`` (:meth:`_backward_boundary` otherwise);
        ``primal``: the tables ``Tables.prepare`` gave for this request (None: prepared here);
        ``ad_tables``: the pass's tables :meth:`_ad_blocks` made for this window (None: made here)."""
        if self.config.adaptive is not None:
            raise NotImplementedError("links1_whitted: gradients of adaptive anti-aliasing are not "
                                      "implemented (render with spp instead of adaptive)")
        sensor, win, spp, seed = render_request(scene, sensor, seed, spp, self.config.seed)
        win = win if window is None else window
        primal = self._prepared(scene, sensor, tuning, primal)
        ad_tables = self._ad_tables(primal, scene) if ad_tables is None else ad_tables
        tracer = Tracer(self.config, tuning)
        # projective: the visibility term (boundary.py), traced before the interior pass, its
        # sides' radiance by the primal tree (the point launch of the primal tables)
        if edge and self.config.projective:
            edge = self._boundary(scene, primal, ad_tables, tracer, sensor, win, spp, seed)
        else:
            edge = None
        img = self.launches.render_windows_device(ad_tables, scene, tracer, [win], spp=spp, seed=seed, dtype=mi.Float,
                                                  mode=mode or dr.ADMode.Backward)[0]
        return img if edge is None else img + edge

    def _boundary(self, scene, primal, ad_tables, tracer, sensor, win, spp, seed):
        """The visibility term of window ``win`` (boundary.py), its sides' radiance by the primal
        tree (the point launch of the primal tables)."""
        points = functools.partial(self.launches.trace_points, primal, scene, tracer)
        stage = functools.partial(self.launches.frozen_stage, primal, scene, tracer)
        return boundary.boundary_image(points, scene, primal, ad_tables, sensor, win, spp, seed, stage)

    def _backward_boundary(self, scene, grad_in, sensor, seed, spp, tuning, primal=None):
        """Propagate ``grad_in`` through the visibility term alone, in blocks of rows of at most
        :data:`.boundary.BLOCK_LANES` samples (the term of a block is the frame's rows: its lines
        are drawn from the film's sample ids, its pixels chosen by their own neighbourhood);
        ``primal``: as :meth:`_render_ad`'s."""
        sensor, win, spp, seed = render_request(scene, sensor, seed, spp, self.config.seed)
        primal = self._prepared(scene, sensor, tuning, primal)
        ad_tables = self._ad_tables(primal, scene)
        tracer = Tracer(self.config, tuning)
        for block in row_blocks(win, primal.film_size, 0, spp, boundary.BLOCK_LANES):
            edge = self._boundary(scene, primal, ad_tables, tracer, sensor, block, spp, seed)
            y = block[1] - win[1]
            dr.set_grad(edge, grad_in[y:y + block[3], :, :3])
            dr.enqueue(dr.ADMode.Backward, edge)
            dr.traverse(dr.ADMode.Backward)

    def _prepared(self, scene, sensor, tuning, primal=None):
        """``primal`` where given (the tables one derivative pass prepared for its request), else
        the primal tables of ``sensor`` (``Tables.prepare``)."""
        if primal is not None:
            return primal
        with dr.suspend_grad():
            return self.tables.prepare(scene, sensor, tuning)

    def _ad_tables(self, primal, scene):
        """A shallow copy of the tables ``primal`` with the attached values of the parameters
        that have gradients enabled put in (rendered in a derivative ``mode``: the launches
        then trace :func:`.raytree_ad.trace_tree_ad`, the film differentiably)."""
        ad_tables = primal.tables() if isinstance(primal, CameraView) else copy.copy(primal)
        ad_tables.frozen_inputs = None
        Phong = plugin_class("links1_phong")
        bsdfs = primal.keep_alive[3]       # the BSDF of each slot (tables.prepare)
        if len(bsdfs) != primal.nslots:
            raise RuntimeError("links1_whitted: the BSDF table has another size (an internal inconsistency)")
        tabs = {attr: nw for attr, nw in PHONG_TABLES.items() if attr != "ior"}   # (ior: held fixed)
        rows = {name: {} for name, _ in tabs.values()}
        for sl, b in enumerate(bsdfs):
            if isinstance(b, Phong):
                for name, r in rows.items():
                    v = b._held.t_exponent if name == "exponent" else getattr(b._held, name)
                    if attached(v):
                        r[sl] = v
        for attr, (name, width) in tabs.items():
            if rows[name]:
                setattr(ad_tables, attr, put_rows(getattr(primal, attr), rows[name], width))
        ad_tables.any_ambient = primal.any_ambient or bool(rows["ambient"])
        tr = rows["transmittance"]
        if tr:   # shadow transmittance (3-3-3): links1 shapes outside the BVH, split Mitsuba shapes
            ad_tables.shadow_t_np = [tr.get(sl, row) for sl, row in enumerate(primal.shadow_t_np)]
            if primal.shadow_split is not None:
                ad_tables.shadow_split = dict(primal.shadow_split, trans=[
                    (sub, sl, tr.get(sl, st)) for sub, sl, st in primal.shadow_split["trans"]])
        # analytic lights: primal.lights holds one record per such emitter, in the scene's order
        Pt, Sp = plugin_class("links1_point"), plugin_class("links1_spot")
        lights, j, any_light = list(primal.lights), 0, False
        for e in scene.emitters():
            kind = kind_of(e)
            if isinstance(e, (Pt, Sp)):
                # the attached values in their fields of the light's primal.lights record (tables.py)
                new = {}
                for name, field in (LINKS1_POINT_FIELDS if isinstance(e, Pt) else LINKS1_SPOT_FIELDS):
                    v = e.values[name]
                    if attached(v):
                        new[field] = dr.normalize(v) if name == "direction" else v
                        any_light = True
                lights[j] = lights[j]._replace(**new)
            elif kind == "PointLight":
                prm = params_of(primal, e)
                new = {}
                if attached(prm["position"]):
                    new["position"] = mi.Point3f(prm["position"])
                    any_light = True
                if "intensity.value" in prm and attached(prm["intensity.value"]):
                    new["L1"] = mi.Color3f(prm["intensity.value"])
                    any_light = True
                lights[j] = lights[j]._replace(**new)
            elif kind not in ("SpotLight", "DirectionalEmitter"):
                continue
            j += 1
        if j != len(primal.lights):
            raise RuntimeError("links1_whitted: the light table has another size (an internal inconsistency)")
        ad_tables.lights = lights
        # geometry (geometry.py): the links1 shapes whose parameters have gradients; with any,
        # every links1 shape is intersected in the pass's own code (no BVH, no light or eye
        # buffer: their tables hold primal values) and its hits re-attached (intersect.moving_hits)
        ad_tables.geo_ad = geometry.attached_specs(dr, primal.custom, self.shapes.geo) or None
        if ad_tables.geo_ad is not None and primal.bvh is not None:
            ad_tables.bvh, ad_tables.eye_buf, ad_tables.custom_unrolled = None, None, list(primal.custom)
        ad_tables.ad_memo = {}
        ad_tables.fixed_children = (ad_tables.geo_ad is None
                                    or not any(_spawns(primal, sl) for sl in ad_tables.geo_ad))
        ad_tables.attached_any = (any(rows.values()) or ad_tables.geo_ad is not None or any_light
                                  or (not primal.all_phong
                                      and _mitsuba_attached(scene, primal, self.config.verify_scene)))
        return ad_tables
