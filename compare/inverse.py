"""Inverse rendering with ``links1_whitted``'s gradients: a benchmark.

    python -m compare.inverse [--width 64] [--iters 100] [--blob-iters 400] [--outline-iters 400]
                              [--big 256] [--rounds 25] [--outline-rounds 9] [--trials 3]
                              [--variant llvm_ad_rgb]
                              [--only light phong blob quadric blob_floor quadric_outline
                                      blob_floor_off quadric_outline_off]

From a target image rendered with known values, starting from perturbed ones, ``mi.ad.Adam``
on the L2 image loss (``dr.mean(dr.square(img - target))``) recovers

* (a) ``light``: a ``links1_point`` light's ``position``, ``L1`` and ``L2`` (eq. 3.10) above a
  Phong floor with a highlight and a diffuse wall (nothing casts a shadow: a moving shadow
  edge is a visibility term links1_whitted does not differentiate);
* (b) ``phong``: a ``links1_phong`` sphere's ``diffuse`` and ``specular`` colours;
* (c) ``blob``: the centres and weights of a 6-centre ``links1_blob`` (eq. 3.6–3.9), six lobes
  (:data:`BLOB_CENTRES`) in the dark, lit from the front and from behind, fitted in five views
  at once (sensors 1–5; sensor 0 only pictures it) on the *masked* loss: the pixels that see
  the blob in both the target and the current frame (its silhouette moves, and its derivative is
  the visibility term links1_whitted leaves out: with it in the loss the centres drifted while
  the loss fell). A first version fitted the test's blob of overlapping centres in one view:
  its centres and weights trade against each other (the loss fell 1000x, the error did not);
* (d) ``quadric``: a ``links1_quadric`` sphere's translation (``to_world`` =
  translate(t) · scale, t optimised);

and, with ``projective=true`` (the visibility term of the derivatives, docs/method.md §6),
two cases whose outlines carry the information:

* (e) ``blob_floor``: the centres, weights and threshold ``T`` of a 4-centre blob
  (:data:`FLOOR_LOBES`) over the Phong floor, in ONE view, on the unmasked loss: its outline
  against the floor, its shading and its shadows on the floor. ``W(x) = T`` is unchanged when
  every weight and ``T`` are scaled alike, so the first lobe's weight is held at its value
  (:class:`BlobGaugeCase`; with it free the fit stalls where that scale is off, 1–5 % of the
  ranges);
* (f) ``quadric_outline``: a ``links1_quadric`` sphere of one constant colour (``ambient``
  only) before black, placed from its outline alone (translation ``t``): without the visibility
  term its gradient is 0.

These two render their frames at spp 4 (the visibility term is an estimate over random rows
and columns of each pixel) and their derivative pass at spp 1 (``mi.render``'s ``spp_grad``,
a case's :func:`spp_grad`; its samples are ``seed_grad``'s, other than the frame's) with
``max_depth`` 2; ``blob_floor_off`` and ``quadric_outline_off`` are the same fits without
the visibility term, for contrast.

Every other render is spp 1 with a box filter (the sample at the pixel centre: deterministic),
``max_depth`` 3, the given ``--width`` square. Parameter error = the worst component's
``|x − x*| / range``, with the range of each parameter stated in the results (the interval the
perturbed start is drawn from, or [0, 1] for colours); issue target: ≤ 1 % of the range.

Time per iteration (render with gradients + loss + ``dr.backward`` + Adam step +
``params.update``; the blob case: its five views) against the primal frame (``mi.render``
without gradients, evaluated and synced), wall-clock medians in one process; with ``--big N``
every case is also timed in one view at N² for the same ratio, ``--rounds``
rounds of an iteration and a primal frame interleaved (:func:`timing_only`), each case in a
Python process of its own (:func:`_timed_apart`), ``--trials`` such processes a case, the
cases taking turns (the median trial reported, :func:`_over_trials`). Each
iteration runs with ``dr.JitFlag.KernelHistory``: the kernels compiled in it (found in none of
Dr.Jit's caches) and their code generation + LLVM time are reported (``kernels_compiled``,
``compile_ms``). Writes ``compare/results/inverse.{json,md,png}`` and the figure to
``docs/images/inverse.png`` (docs/guide.md).

Every iteration renders with ``seed=0`` (with spp 1 the sample is the pixel centre whatever the
seed; at spp 4 the same samples every iteration, and the derivative pass its own, Mitsuba's
``seed_grad``). New values of a blob's or a quadric's parameters replay the same kernels (the shapes
gather them from Dr.Jit tables: ``tables()`` in ``plugins/links1_mitsuba/shapes.py`` and ``blob.py``; as
literals, each blob iteration would compile ~100 kernels, ~23 s).
"""
from __future__ import annotations

import argparse
import os
import shutil
import time

from pathlib import Path

import numpy as np

from compare.common import command_line, machine_info, machine_markdown, md_table, pyplot, write_results

#: where the figure goes for docs/guide.md (with the blob case)
DOC_IMAGE = Path(__file__).resolve().parent.parent / "docs" / "images" / "inverse.png"

INTEGRATOR = """<integrator type="links1_whitted"><integer name="max_depth" value="3"/></integrator>"""

#: the outline cases' integrator: the visibility term on (``projective``) or off
OUTLINE_INTEGRATOR = """<integrator type="links1_whitted"><integer name="max_depth" value="2"/>
    <boolean name="projective" value="{projective}"/></integrator>"""

CAMERA = """<sensor type="perspective"><float name="fov" value="{fov}"/>
    <transform name="to_world"><lookat origin="{origin}" target="{target}" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="{w}"/><integer name="height" value="{w}"/><rfilter type="box"/></film>
    <sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler></sensor>"""

FLOOR = """<shape type="rectangle" id="floor"><transform name="to_world"><scale value="5"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.6, 0.5, 0.4"/><rgb name="specular" value="0.4"/>
      <float name="exponent" value="8"/><rgb name="reflectance" value="{refl}"/></bsdf></shape>"""

LIGHTS = """<emitter type="links1_point" id="lp"><point name="position" x="2" y="4" z="3"/><rgb name="L1" value="0.6"/>
    <rgb name="L2" value="0.4"/><string name="falloff" value="inverse_square"/></emitter>
  <emitter type="point" id="mp"><point name="position" x="-2" y="3" z="4"/><rgb name="intensity" value="6"/></emitter>"""

#: the blob case's centres (x y z w S): six lobes on the axes of an octahedron around (0.1, 1.55,
#: 0.05), each a bump of its own (overlapping centres trade places with weights: ill-conditioned)
BLOB_CENTRES = [[0.1 + 1.0 * a[0], 1.55 + 1.0 * a[1], 0.05 + 1.0 * a[2], w, S] for a, w, S in (
    ((1, 0, 0), 1.0, 0.55), ((-1, 0, 0), 0.9, 0.6), ((0, 1, 0), 0.8, 0.5), ((0, -1, 0), 1.0, 0.55),
    ((0, 0, 1), 0.75, 0.5), ((0, 0, -1), 0.9, 0.6))]

#: the blob case's fitted views (sensors 1...): the whole blob from five sides
BLOB_FOV = 36
BLOB_ORIGINS = ["0.1, 2.0, 5", "5, 2.2, 0", "-4.9, 1.2, 0.5", "0.6, 6.5, 0.6", "0.4, 1.0, -5"]

#: the blob_floor case's centres (x y z w S): four lobes in a cross facing the camera, each seen
#: (a view of the 6-centre blob hides the lobe behind it: one view does not determine it)
FLOOR_LOBES = [[0.1 + a[0], 1.55 + a[1], 0.05 + a[2], w, S] for a, w, S in (
    ((1, 0, 0), 1.0, 0.55), ((-1, 0, 0), 0.9, 0.6), ((0, 1, 0), 0.8, 0.5), ((0, -1, 0), 1.0, 0.55))]


def blob_xml(centres):
    """A ``links1_blob`` ``blob`` of ``centres`` (rows x y z w S), threshold 0.5, Phong."""
    rows = ", ".join(" ".join(f"{x:g}" for x in r) for r in centres)
    return f"""
  <shape type="links1_blob" id="blob"><string name="centers" value="{rows}"/><float name="threshold" value="0.5"/>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.5, 0.4, 0.3"/><rgb name="specular" value="0.3"/>
      <rgb name="reflectance" value="0"/><float name="exponent" value="10"/></bsdf></shape>"""


SCENES = {
    # (a) a links1_point over a Phong floor and a diffuse wall, no occluder
    "light": dict(camera=dict(fov=50, origin="0, 3, 6", target="0, 0.5, 0"), body=FLOOR.format(refl=0) + """
  <shape type="rectangle" id="wall"><transform name="to_world"><scale value="5"/><translate z="-2"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.4, 0.5, 0.6"/></bsdf></shape>
  <emitter type="links1_point" id="lp"><point name="position" x="0.6" y="2.5" z="0.8"/><rgb name="L1" value="0.5, 0.45, 0.4"/>
    <rgb name="L2" value="0.6, 0.5, 0.3"/><vector name="direction" x="0.3" y="-0.7" z="1"/></emitter>
  <emitter type="point" id="mp"><point name="position" x="-1.5" y="2" z="1.5"/><rgb name="intensity" value="2"/></emitter>"""),
    # (b) a links1_phong sphere (Mitsuba sphere) with a highlight, on the floor
    "phong": dict(camera=dict(fov=40, origin="0, 2.5, 5", target="0, 0.8, 0"), body=FLOOR.format(refl=0) + """
  <shape type="sphere" id="ball"><point name="center" x="0" y="1" z="0"/><float name="radius" value="1"/>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.7, 0.3, 0.2"/><rgb name="specular" value="0.5, 0.5, 0.6"/>
      <float name="exponent" value="20"/></bsdf></shape>""" + LIGHTS),
    # (c) the 6-centre blob of tests/plugins/test_geometry_gradients.py in the dark (no floor: the
    # masked loss below), lit from the front and from behind, seen from five sides (sensor 0 pictures it)
    "blob": dict(camera=dict(fov=50, origin="0, 2.6, 5", target="0.1, 1.5, 0"),
                 views=[dict(fov=BLOB_FOV, origin=o, target="0.1, 1.55, 0.05") for o in BLOB_ORIGINS],
                 masked=True, body=blob_xml(BLOB_CENTRES) + LIGHTS + """
  <emitter type="links1_point" id="back"><point name="position" x="-1" y="-2" z="-4"/><rgb name="L1" value="0.5"/>
    <rgb name="L2" value="0.3"/><string name="falloff" value="inverse_square"/></emitter>"""),
    # (d) a links1_quadric sphere (scale 1.2) over a mirror-ish floor
    "quadric": dict(camera=dict(fov=40, origin="0, 3, 6", target="0, 0.8, 0"), body=FLOOR.format(refl=0.2) + """
  <shape type="links1_quadric" id="ball"><string name="kind" value="sphere"/>
    <transform name="to_world"><scale value="1.2"/><translate x="0.2" y="1.4" z="0.3"/></transform>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.5, 0.4, 0.3"/><rgb name="specular" value="0.3"/>
      <rgb name="reflectance" value="0"/><float name="exponent" value="12"/></bsdf></shape>""" + LIGHTS),
    # (e) the 4-centre blob over the floor, one view (spp 4: the visibility term's rows and columns)
    "blob_floor": dict(camera=dict(fov=50, origin="0, 2.6, 5", target="0.1, 1.3, 0"), spp=4, spp_grad=1,
                       projective=True,
                       body=FLOOR.format(refl=0) + blob_xml(FLOOR_LOBES) + LIGHTS),
    # (f) a constant-colour quadric sphere before black: only its outline moves
    "quadric_outline": dict(camera=dict(fov=40, origin="0, 2.5, 6", target="0, 1, 0"), spp=4, spp_grad=1,
                            projective=True, body="""
  <shape type="links1_quadric" id="ball"><string name="kind" value="sphere"/>
    <transform name="to_world"><scale value="1.2"/><translate x="0.2" y="1.4" z="0.3"/></transform>
    <bsdf type="links1_phong"><rgb name="ambient" value="0.9, 0.7, 0.5"/><rgb name="diffuse" value="0"/>
      <rgb name="specular" value="0"/></bsdf></shape>"""),
}

#: a case run with the visibility term off: its scene is the case's without this suffix
OFF = "_off"


def scene_of(case):
    """The scene of ``case`` and whether the derivatives add the visibility term (``OFF``)."""
    base = case.removesuffix(OFF)
    return SCENES[base], SCENES[base].get("projective", False) and not case.endswith(OFF)


def spp_grad(case):
    """The samples a pixel of ``case``'s derivative pass (``mi.render``'s ``spp_grad``; 0: the
    frame's own)."""
    return scene_of(case)[0].get("spp_grad", 0)


def load(case, width):
    import links1_mitsuba as lm
    from links1_mitsuba import tuning
    # mi.render(scene, params) of these spp-1, analytic-light frames keeps the derivative
    # pass's graph for dr.backward (one render an iteration): an explicit choice
    tuning.set_tuning(keep_graph=True)
    s, projective = scene_of(case)
    # (a scene may name its own integrator and sample count: compare/inverse_outline.py)
    cams = "".join(CAMERA.format(w=width, spp=s.get("spp", 1), **c) for c in [s["camera"], *s.get("views", [])])
    if "projective" in s:
        integrator = OUTLINE_INTEGRATOR.format(projective=str(projective).lower())
    else:
        integrator = s.get("integrator", INTEGRATOR)
    xml = f'<scene version="3.0.0">{integrator}{cams}{s["body"]}</scene>'
    return lm.load_string(xml)


# ----------------------------------------------------------------------------- the cases
class Case:
    """Optimised variables (name -> numpy truth, start, range, lr), how they enter the scene."""

    def __init__(self, name, scene, variables, lr, iters):
        self.name, self.scene, self.vars, self.lr, self.iters = name, scene, variables, lr, iters

    def setup(self, mi, params):
        pass

    def set_values(self, mi, params, values):
        """Put numpy ``values`` (name -> array) into the scene (no gradients)."""
        for k, v in values.items():
            params[k] = to_dr(mi, params[k], v)
        params.update()

    def apply(self, mi, params, opt):
        """After an Adam step: clamp, write the optimiser's variables into the scene."""
        params.update(opt)

    def read(self, opt):
        return {k: np.array(opt[k], dtype=np.float64) for k in self.vars}


def to_dr(mi, like, v):
    v = np.asarray(v, dtype=np.float64)
    if v.ndim == 2:
        return type(like)(*[mi.Float(list(map(float, row))) for row in v])
    if type(like).__name__ in ("Color3f", "Point3f", "Vector3f") and v.size == 3 and dr_width(like) == 1:
        return type(like)(*map(float, v))
    return type(like)(list(map(float, v.ravel())))


def dr_width(x):
    import drjit as dr
    return dr.width(x)


class QuadricCase(Case):
    """``links1_whitted.ball.to_world = translate(t) · scale(1.2)``: t is the variable."""
    KEY = "links1_whitted.ball.to_world"

    def setup(self, mi, params):
        self.scale = mi.Transform4f().scale(1.2)

    def set_values(self, mi, params, values):
        t = values["t"]
        params[self.KEY] = mi.Transform4f().translate(mi.Vector3f(*map(float, t))) @ self.scale
        params.update()

    def apply(self, mi, params, opt):
        params[self.KEY] = mi.Transform4f().translate(opt["t"]) @ self.scale
        params.update()


class BlobGaugeCase(Case):
    """A blob's centres, weights and threshold with its first weight held at its value: the
    level set ``Σ w_i P(r_i) = T`` (eq. 3.6–3.8) is the same for every ``(λ w, λ T)``, so one of
    them fixes the scale (the gauge) and the others are then determined."""
    KEY = "links1_whitted.blob.weights"

    def apply(self, mi, params, opt):
        w = np.array(opt[self.KEY], dtype=np.float32)
        w[0] = self.vars[self.KEY]["truth"][0]
        opt[self.KEY] = mi.Float(w)
        params.update(opt)


def make_cases(iters):
    rng = np.random.default_rng(23)
    cases = []
    # (a) the light: position within ±0.5 of the truth per axis (range 1), L1/L2 in [0, 1]
    pos = np.array([0.6, 2.5, 0.8])
    cases.append(("light", Case, {
        "lp.position": dict(truth=pos, start=pos + np.array([0.4, -0.35, 0.4]), range=1.0, lo=None),
        "lp.L1.value": dict(truth=np.array([0.5, 0.45, 0.4]), start=np.array([0.3, 0.3, 0.3]), range=1.0, lo=0.0),
        "lp.L2.value": dict(truth=np.array([0.6, 0.5, 0.3]), start=np.array([0.3, 0.3, 0.3]), range=1.0, lo=0.0),
    }, {"lp.position": 0.06, "lp.L1.value": 0.05, "lp.L2.value": 0.05}))
    # (b) the material: colours in [0, 1]
    cases.append(("phong", Case, {
        "ball.bsdf.diffuse.value": dict(truth=np.array([0.7, 0.3, 0.2]), start=np.array([0.3, 0.5, 0.6]), range=1.0, lo=0.0),
        "ball.bsdf.specular.value": dict(truth=np.array([0.5, 0.5, 0.6]), start=np.array([0.2, 0.2, 0.2]), range=1.0, lo=0.0),
    }, {"ball.bsdf.diffuse.value": 0.02, "ball.bsdf.specular.value": 0.02}))
    # (c) the blob: each centre moved within ±0.1 per axis (range 0.2), weights within ±0.15 (range 0.3)
    c0 = np.array(BLOB_CENTRES)[:, :3].T
    w0 = np.array(BLOB_CENTRES)[:, 3]
    cases.append(("blob", Case, {
        "links1_whitted.blob.centers": dict(truth=c0, start=c0 + rng.uniform(-0.1, 0.1, c0.shape), range=0.2, lo=None),
        "links1_whitted.blob.weights": dict(truth=w0, start=w0 + rng.uniform(-0.15, 0.15, w0.shape), range=0.3, lo=0.05),
    }, {"links1_whitted.blob.centers": 0.01, "links1_whitted.blob.weights": 0.015}))
    # (d) the quadric: translation within ±0.25 per axis (range 0.5)
    t0 = np.array([0.2, 1.4, 0.3])
    cases.append(("quadric", QuadricCase, {
        "t": dict(truth=t0, start=t0 + np.array([0.2, -0.15, 0.2]), range=0.5, lo=None),
    }, {"t": 0.01}))
    # (e) the blob over the floor: centres ±0.1 per axis (range 0.2), weights but the first ±0.15
    # (range 0.3), threshold 0.5 + 0.03 (range 0.1)
    c0 = np.array(FLOOR_LOBES)[:, :3].T
    w0 = np.array(FLOOR_LOBES)[:, 3]
    rng = np.random.default_rng(31)
    blob_floor = {
        "links1_whitted.blob.centers": dict(truth=c0, start=c0 + rng.uniform(-0.1, 0.1, c0.shape), range=0.2, lo=None),
        "links1_whitted.blob.weights": dict(truth=w0, start=w0 + np.r_[0, rng.uniform(-0.15, 0.15, w0.size - 1)],
                                            range=0.3, lo=0.05),
        "links1_whitted.blob.threshold": dict(truth=np.array([0.5]), start=np.array([0.53]), range=0.1, lo=0.05)}
    blob_lr = {"links1_whitted.blob.centers": 0.01, "links1_whitted.blob.weights": 0.03,
               "links1_whitted.blob.threshold": 0.012}
    # (f) the outline: translation within ±0.25 per axis (range 0.5), as (d)
    outline = {"t": dict(truth=t0, start=t0 + np.array([0.2, -0.15, 0.2]), range=0.5, lo=None)}
    for suffix in ("", OFF):
        cases.append(("blob_floor" + suffix, BlobGaugeCase, blob_floor, blob_lr))
        cases.append(("quadric_outline" + suffix, QuadricCase, outline, {"t": 0.01}))
    return [(n, cls, v, lr, iters.get(n.removesuffix(OFF), iters["default"])) for n, cls, v, lr in cases]


def err_of(case, values):
    """name -> worst component's |x − x*| / range; and the overall worst."""
    e = {k: float(np.max(np.abs(np.asarray(values[k]).reshape(np.shape(d["truth"])) - d["truth"])) / d["range"])
         for k, d in case.vars.items()}
    return e, max(e.values())


def sync(x):
    import drjit as dr
    dr.eval(x)
    dr.sync_thread()


def primal_times(mi, scene, n):
    ts = []
    for i in range(n + 1):
        t0 = time.perf_counter()
        img = mi.render(scene, seed=i)
        sync(img)
        ts.append(time.perf_counter() - t0)
    return ts[1:]          # the first: compilation


def run_case(mi, dr, name, cls, variables, lrs, iters, width, log):
    scene = load(name, width)
    case = cls(name, scene, variables, lrs, iters)
    params = mi.traverse(scene)
    case.setup(mi, params)
    # the target: rendered with the known values (the file's values; set anyway)
    case.set_values(mi, params, {k: d["truth"] for k, d in variables.items()})
    views = range(len(scene.sensors()))
    fit = [k for k in views if k > 0] or [0]   # sensor 0 only pictures a case with more views
    masked = scene_of(name)[0].get("masked", False)
    targets = [mi.render(scene, sensor=k, seed=0) for k in views]
    sync(targets)
    target_on = [np.asarray(t).sum(-1) > 0 for t in targets]
    target_np = np.array(targets[0])
    primal = primal_times(mi, scene, 5)
    # the start
    case.set_values(mi, params, {k: d["start"] for k, d in variables.items()})
    start_np = np.array(mi.render(scene, seed=0))
    opt = optimizer(mi, case, params, variables, lrs)
    errs, worst, losses, its, comp, ncomp = [], [], [], [], [], []
    e, w = err_of(case, case.read(opt))
    errs.append(e)
    worst.append(w)
    for it in range(iters):
        hist = dr.scoped_set_flag(dr.JitFlag.KernelHistory, True)
        hist.__enter__()
        t0 = time.perf_counter()
        loss = 0.0
        for k in fit:   # the views' losses, each differentiated at once (one AD graph at a time)
            img = mi.render(scene, params, sensor=k, seed=0, spp_grad=spp_grad(name))
            err = dr.square(img - targets[k])
            if masked:   # only pixels on the blob in both images: no silhouette term (left out)
                m = (np.asarray(img).sum(-1) > 0) & target_on[k]
                # the mean over the mask's pixels: weights 1/count in an array (a divisor given
                # as a Python number would be a literal, new kernel code as the count changes)
                wm = np.repeat(m[..., None], 3, -1) / (max(int(m.sum()), 1) * 3 * len(fit))
                loss_k = dr.sum(err * mi.TensorXf(wm.astype(np.float32)), axis=None)
            else:
                loss_k = dr.mean(err, axis=None) / len(fit)
            dr.backward(loss_k)
            loss += float(np.asarray(loss_k).ravel()[0])
        opt.step()
        for k, d in variables.items():
            if d["lo"] is not None:
                opt[k] = dr.maximum(opt[k], d["lo"])
        case.apply(mi, params, opt)
        sync(opt[next(iter(variables))])
        its.append(time.perf_counter() - t0)
        h = dr.kernel_history()
        hist.__exit__(None, None, None)
        # kernels compiled (found in none of Dr.Jit's caches): their code generation + LLVM time
        built = [k for k in h if "cache_hit" in k and not k["cache_hit"]]
        comp.append(sum(k["codegen_time"] + k["backend_time"] for k in built))
        ncomp.append(len(built))
        losses.append(loss)
        e, w = err_of(case, case.read(opt))
        errs.append(e)
        worst.append(w)
        if it % 20 == 0 or it == iters - 1 or os.environ.get("INVERSE_VERBOSE"):
            log(f"  {name} it {it:3d} loss {losses[-1]:.3e} worst err {w:.4f} ({its[-1] * 1e3:.0f} ms, compiled {ncomp[-1]} kernels, {comp[-1]:.0f} ms)")
    result_np = np.array(mi.render(scene, seed=0))
    final = case.read(opt)
    med_it = float(np.median(its[1:]))
    med_pr = float(np.median(primal))
    first_ok = next((i for i, w in enumerate(worst) if all(x <= 0.01 for x in worst[i:])), None)
    return dict(
        case=name, width=width, iters=iters, learning_rates=lrs, spp=scene_of(name)[0].get("spp", 1),
        projective=scene_of(name)[1],
        ranges={k: d["range"] for k, d in variables.items()},
        truth={k: d["truth"] for k, d in variables.items()},
        start={k: d["start"] for k, d in variables.items()},
        final={k: np.asarray(final[k]).reshape(np.shape(variables[k]["truth"])) for k in variables},
        error_per_param=errs, worst_error=worst, loss=losses,
        final_error=errs[-1], final_worst_error=worst[-1], within_1pct=bool(worst[-1] <= 0.01),
        iterations_to_1pct=first_ok,
        primal_ms=[t * 1e3 for t in primal], iteration_ms=[t * 1e3 for t in its],
        primal_median_ms=med_pr * 1e3, iteration_median_ms=med_it * 1e3, compile_ms=comp, ratio=med_it / med_pr,
        kernels_compiled=ncomp,
        compile_median_ms=float(np.median(comp[1:])),
        iteration_less_compile_median_ms=float(np.median(np.array(its[1:]) * 1e3 - np.array(comp[1:]))),
        ratio_less_compile=float(np.median(np.array(its[1:]) * 1e3 - np.array(comp[1:]))) / (med_pr * 1e3),
    ), (target_np, start_np, result_np)


def optimizer(mi, case, params, variables, lrs):
    """Adam over the case's variables at their start (in the scene), each with its learning
    rate, written into the scene (``case.apply``)."""
    opt = mi.ad.Adam(lr=0.01)
    for k, d in variables.items():
        if k == "t":
            opt[k] = mi.Vector3f(*map(float, d["start"]))
        else:
            opt[k] = type(params[k])(params[k])
        opt.set_learning_rate({k: lrs[k]})
    case.apply(mi, params, opt)
    return opt


def timing_only(mi, dr, name, cls, variables, lrs, width, n, log):
    """``n`` rounds at ``width``² (after 3 warm-up ones) for the iteration / primal ratio.

    A round: an iteration, a timed iteration, a primal frame, a timed primal frame. The two
    are interleaved, so that a machine whose speed drifts (other jobs on a shared one) slows
    both alike; each timed one is the second of its pair: the timed iteration pays for the
    previous iteration's ``params.update()`` (re-prepared at its render, as in a loop of
    iterations), the timed primal frame renders an unchanged scene (the first one of the pair
    re-prepared it). Medians of each, and of the rounds' own ratios."""
    scene = load(name, width)
    case = cls(name, scene, variables, lrs, n)
    params = mi.traverse(scene)
    case.setup(mi, params)
    target = mi.render(scene, seed=0)
    sync(target)
    case.set_values(mi, params, {k: d["start"] for k, d in variables.items()})
    opt = optimizer(mi, case, params, variables, lrs)

    def iteration():
        img = mi.render(scene, params, seed=0, spp_grad=spp_grad(name))
        dr.backward(dr.mean(dr.square(img - target), axis=None))
        opt.step()
        case.apply(mi, params, opt)
        sync(opt[next(iter(variables))])

    def frame():
        sync(mi.render(scene, seed=0))

    def timed(f):
        t0 = time.perf_counter()
        f()
        return time.perf_counter() - t0
    its, primal = [], []
    for r in range(n + 3):   # the first rounds trace and compile (freeze recordings, kernel look-ups)
        iteration()
        ti = timed(iteration)
        frame()
        tp = timed(frame)
        if r >= 3:
            its.append(ti)
            primal.append(tp)
    r = dict(case=name, width=width, primal_ms=[t * 1e3 for t in primal], iteration_ms=[t * 1e3 for t in its],
             primal_median_ms=float(np.median(primal)) * 1e3, iteration_median_ms=float(np.median(its)) * 1e3,
             ratio_of_rounds=float(np.median(np.array(its) / np.array(primal))))
    r["ratio"] = r["iteration_median_ms"] / r["primal_median_ms"]
    log(_timing_line(r))
    return r


def _timing_line(r, where=""):
    return (f"  {r['case']} at {r['width']}²: primal {r['primal_median_ms']:.2f} ms, iteration "
            f"{r['iteration_median_ms']:.2f} ms, ratio {r['ratio']:.2f} (of the rounds: {r['ratio_of_rounds']:.2f}{where})")


def _timed_apart(name, a, log):
    """:func:`timing_only` of case ``name`` in a fresh Python process (``--time-case``)."""
    import json
    import subprocess
    import sys
    rounds = a.outline_rounds if scene_of(name)[1] else a.rounds   # (the visibility term's iterations are long)
    cmd = [sys.executable, "-m", "compare.inverse", "--time-case", name, "--big", str(a.big),
           "--rounds", str(rounds), "--variant", a.variant]
    out = subprocess.run(cmd, capture_output=True, text=True, cwd=Path(__file__).resolve().parent.parent)
    if out.returncode != 0:
        raise RuntimeError(f"compare.inverse: timing {name} failed:\n{out.stderr[-2000:]}")
    r = json.loads(out.stdout.strip().splitlines()[-1])
    log(_timing_line(r, "; own process"))
    return r


def _over_trials(runs):
    """One case's timings in several processes (:func:`_timed_apart`) as one: the trial whose
    ratio is the median (an odd count; the lower middle one otherwise), with every trial's
    ratio (``trial_ratios``) and their range."""
    order = sorted(runs, key=lambda r: r["ratio"])
    r = dict(order[(len(order) - 1) // 2])
    r["trial_ratios"] = [t["ratio"] for t in runs]
    r["ratio_min"], r["ratio_max"] = order[0]["ratio"], order[-1]["ratio"]
    return r


def _time_case(a):
    """``--time-case NAME``: that case's :func:`timing_only`, its result as one JSON line."""
    import json
    import links1_mitsuba as lm
    lm.register(a.variant)
    import drjit as dr
    import mitsuba as mi
    for name, cls, variables, lrs, _ in make_cases({"default": 1, "blob": 1}):
        if name == a.time_case:
            r = timing_only(mi, dr, name, cls, variables, lrs, a.big, a.rounds, lambda s: None)
            print(json.dumps(r))
            return 0
    raise SystemExit(f"compare.inverse: no case {a.time_case!r}")


def tonemap(img):
    return np.clip(np.asarray(img)[..., :3], 0, 1) ** (1 / 2.2)


#: the figure's labels of the cases (a case with ``OFF``: its case's, dashed)
LABELS = {"light": "(a) links1_point position, L1, L2", "phong": "(b) links1_phong diffuse, specular",
          "blob": "(c) blob centres, weights (5 views, masked)", "quadric": "(d) quadric translation",
          "blob_floor": "(e) blob centres, weights, T (1 view, floor)",
          "quadric_outline": "(f) quadric translation from its outline"}


def figure(results, images):
    """The error curves of every case, and the target, start and result frames of the
    single-view blob (``images``: case -> (target, start, result))."""
    plt = pyplot()
    fig = plt.figure(figsize=(14, 3.6))
    gs = fig.add_gridspec(1, 4, width_ratios=[1.9, 1, 1, 1])
    ax = fig.add_subplot(gs[0])
    colour = {}
    for r in results:
        base = r["case"].removesuffix(OFF)
        off = r["case"].endswith(OFF)
        line, = ax.semilogy(np.maximum(r["worst_error"], 1e-5), color=colour.get(base), ls="--" if off else "-",
                            lw=1.0 if off else 1.4, label=LABELS[base] + (": projective off" if off else ""))
        colour.setdefault(base, line.get_color())
    ax.axhline(0.01, color="k", ls=":", lw=0.8)
    ax.set_xlabel("Adam iteration")
    ax.set_ylabel("worst parameter error / range")
    ax.legend(fontsize=6)
    ax.set_title(f"links1_whitted inverse rendering ({results[0]['width']}²; (e), (f) projective=true, spp 4)",
                 fontsize=9)
    shown = next((c for c in ("blob_floor", "blob") if c in images), None)
    if shown is not None:
        tag = LABELS[shown][:3]
        for i, (img, title) in enumerate(zip(images[shown], ("target", "start", "result"))):
            a = fig.add_subplot(gs[i + 1])
            a.imshow(tonemap(img))
            a.set_title(f"{tag} {title}", fontsize=9)
            a.axis("off")
    fig.tight_layout()
    return fig


def markdown(results, big, info, cmd):
    out = ["# Inverse rendering with links1_whitted\n", machine_markdown(info, cmd), "",
           "Adam on the L2 image loss, box filter; spp 1 (pixel centres) and `max_depth` 3, but the outline "
           "cases (blob_floor, quadric_outline: `projective=true`, the visibility term; `_off`: the same fit "
           "without it) spp 4 (their derivative pass 1: `mi.render`'s `spp_grad`) and `max_depth` 2. No loss mask but the five-view blob's. Error: the worst "
           "component's |x − x*| / range (ranges below). Times: wall-clock medians in one process; an iteration is "
           "render with gradients + loss + backward + Adam step + `params.update`; the primal frame is "
           "`mi.render` without gradients.\n"]
    rows = []
    for r in results:
        rows.append([r["case"], f"{r['width']}²", r.get("spp", 1), "on" if r.get("projective") else "off",
                     r["iters"], r["worst_error"][0], r["final_worst_error"],
                     "yes" if r["within_1pct"] else "no", r["iterations_to_1pct"], r["primal_median_ms"],
                     r["iteration_median_ms"], r["compile_median_ms"], r["iteration_less_compile_median_ms"],
                     r["ratio"], r["ratio_less_compile"]])
    out.append(md_table(["case", "res", "spp", "visibility term", "iters", "start err", "final err", "≤ 1 %",
                         "iters to ≤ 1 %",
                         "primal ms", "iteration ms", "of which compile ms", "iteration − compile ms",
                         "iter / primal", "(iter − compile) / primal"], rows))
    out.append("\nPer parameter (final error / range; range):\n")
    rows = []
    for r in results:
        for k in r["ranges"]:
            rows.append([r["case"], f"`{k}`", r["ranges"][k], r["error_per_param"][0][k], r["final_error"][k],
                         np.array2string(np.asarray(r["final"][k]), precision=3, separator=", ").replace("\n", " ")])
    out.append(md_table(["case", "parameter", "range", "start err", "final err", "final value"], rows))
    if big:
        out.append("\nTiming at a larger film (same case; rounds of an iteration and a primal frame interleaved, "
                   "each the second of a pair: `timing_only`; each case in a process of its own, `--trials` "
                   "processes a case, the cases taking turns: the trial with the median ratio, and every "
                   "trial's ratio):\n")
        out.append(md_table(["case", "res", "rounds", "primal ms", "iteration ms", "iter / primal",
                             "median of round ratios", "trials' ratios"],
                            [[b["case"], f"{b['width']}²", len(b["iteration_ms"]), b["primal_median_ms"],
                              b["iteration_median_ms"], b["ratio"], b.get("ratio_of_rounds"),
                              ", ".join(f"{x:.2f}" for x in b.get("trial_ratios", [b["ratio"]]))] for b in big]))
    out.append("\nThe compile column: kernels built in that iteration (a parameter that enters a kernel as a "
               "literal makes new kernels after each update; a rerun of the same trajectory finds them in "
               "Dr.Jit's on-disk cache). \"iteration − compile\" is what an iteration costs once cached.\n")
    out.append("\nError against iterations (worst component / range, every 10th iteration):\n")
    n = max(len(r["worst_error"]) for r in results)
    steps = list(range(0, n, 10)) + ([n - 1] if (n - 1) % 10 else [])
    out.append(md_table(["iteration"] + [r["case"] for r in results],
                        [[s] + [r["worst_error"][s] if s < len(r["worst_error"]) else None for r in results]
                         for s in steps]))
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=64)
    ap.add_argument("--iters", type=int, default=100)
    ap.add_argument("--blob-iters", type=int, default=400, help="the blob case's budget")
    ap.add_argument("--outline-iters", type=int, default=400, help="the blob_floor cases' budget")
    ap.add_argument("--big", type=int, default=256, help="also time every case at this width (0: no)")
    ap.add_argument("--rounds", type=int, default=25, help="timing rounds at --big (interleaved iteration / frame)")
    ap.add_argument("--outline-rounds", type=int, default=9, help="timing rounds of the cases with the visibility term")
    ap.add_argument("--trials", type=int, default=3, help="processes timing each case at --big (median reported)")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--only", nargs="*", default=None)
    ap.add_argument("--no-write", action="store_true")
    ap.add_argument("--time-case", default=None, help=argparse.SUPPRESS)   # (one case's timing: _timed_apart)
    a = ap.parse_args(argv)
    if a.time_case:
        return _time_case(a)
    import links1_mitsuba as lm
    lm.register(a.variant)
    import drjit as dr
    import mitsuba as mi
    info = machine_info()
    info["variant"] = a.variant
    cmd = command_line()
    log = (lambda s: print(s, flush=True))
    results, images, big = [], {}, []
    t_all = time.perf_counter()
    budget = {"default": a.iters, "blob": a.blob_iters, "blob_floor": a.outline_iters}
    cases = [c for c in make_cases(budget) if not a.only or c[0] in a.only]
    # the iteration / primal timings first, each case in a process that has rendered nothing
    # else: after the fits they came out ~10 % slower (phong 3.03-3.24x against 2.72x in a fresh
    # one), and the quadric after the other three cases' timings 2.97-3.30x against 2.84-2.91x
    # alone (three runs each), for reasons not found (no scene or integrator is left alive)
    # ``--trials`` times each, the cases taking turns (a slow minute of this shared machine falls
    # on every case alike): the ratio reported is the median over the trials, with its range
    trials = {name: [] for name, *_ in cases}
    for _ in range(a.trials if a.big else 0):
        for name in trials:
            trials[name].append(_timed_apart(name, a, log))
    for name, runs in trials.items():
        if runs:
            big.append(_over_trials(runs))
    for name, cls, variables, lrs, iters in cases:
        log(f"case {name}")
        r, imgs = run_case(mi, dr, name, cls, variables, lrs, iters, a.width, log)
        results.append(r)
        if name in ("blob", "blob_floor"):
            images[name] = imgs
        log("  per parameter: " + ", ".join(f"{k} {v:.4f}" for k, v in r["final_error"].items()))
        log(f"  {name}: final worst error {r['final_worst_error']:.4f}, iteration {r['iteration_median_ms']:.0f} ms"
            f" vs primal {r['primal_median_ms']:.0f} ms (×{r['ratio']:.2f})")
    payload = dict(machine=info, command=cmd, width=a.width, iters=a.iters, results=results, big=big,
                   total_s=time.perf_counter() - t_all)
    if not a.no_write:
        paths = write_results("inverse", payload, markdown(results, big, info, cmd), figure(results, images))
        if images:   # the guide's picture of a blob fit converging
            shutil.copyfile(paths[-1], DOC_IMAGE)
            paths.append(DOC_IMAGE)
        log("wrote " + ", ".join(map(str, paths)))
    log(f"total {payload['total_s']:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
