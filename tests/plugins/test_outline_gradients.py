"""Interior derivatives next to a shape's outline, per pixel, at several samples a pixel.

The pixels within a few pixels of a shape's outline see it at grazing angles (``∂F/∂t`` small:
the hit distance's derivative ``−(∂F/∂θ)/(∂F/∂t)`` large), partly covered by it. Each pixel's
forward-mode derivative is compared with its own central differences, on the pixels whose
differences are stable in the step (steps 1e-4, 3e-4, 1e-3 within 1 %: no sample of the pixel
crosses a silhouette or a shadow edge, the frame is smooth there): within 2 % on every one.

``mi.render(scene, params, seed=s)`` traces the derivative pass with another seed,
``seed_grad`` (``mi.sample_tea_32(s, 1)[0]`` unless given; Mitsuba decorrelates the two so
that a loss's gradient is unbiased). At spp > 1 its samples are not the primal frame's, so
a pixel's derivative is to be compared with finite differences of frames rendered with
``seed=seed_grad``: against frames of ``seed=s`` a pixel the outline crosses holds other
samples (some on the shape in one, on the floor in the other) and the two disagree by any
factor, though both are right (measured on this file's round blob, d pixel / d centre over
the outline ring: AD and FD at ``seed_grad`` agree within 1.1 % on every stable channel; AD
against FD at ``seed`` differs by more than 2 % on 551 of 785, by up to 4.1x). The blob and
quadric tests fail if the hit's derivative errs on grazing samples only (``|∂F/∂t|`` clamped
to at least 0.5).
"""
from __future__ import annotations

import numpy as np
import pytest

from tests.scenes import perspective, scene, whitted

pytestmark = pytest.mark.mitsuba

SEED, SEED_GRAD = 3, 77
STEPS = (1e-4, 3e-4, 1e-3)

CAMERA = perspective("0, 2.2, 7", "0, 1.1, 0", fov=32, width=64, height=48, spp=4)

FLOOR = """<shape type="rectangle" id="floor"><transform name="to_world"><scale value="5"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf></shape>"""

LIGHTS = """<emitter type="links1_point" id="lp"><point name="position" x="2" y="4" z="3"/><rgb name="L1" value="6"/>
    <rgb name="L2" value="4"/><string name="falloff" value="inverse_square"/></emitter>
  <emitter type="point" id="mp"><point name="position" x="-2" y="3" z="4"/><rgb name="intensity" value="6"/></emitter>"""

PHONG = """<bsdf type="links1_phong"><rgb name="diffuse" value="0.5, 0.4, 0.3"/><rgb name="reflectance" value="0"/></bsdf>"""

# two-centre blobs (weights 1, ranges 0.9, threshold 0.5): close centres (a convex outline),
# and far ones, scaled and tilted (a thin waist between them: a concave outline too)
BLOB = f"""<shape type="links1_blob" id="obj">
    <string name="centers" value="-0.45 1.2 0 1 0.9,  0.45 1.2 0 1 0.9"/><float name="threshold" value="0.5"/>
    {PHONG}</shape>"""

BLOB_WAIST = f"""<shape type="links1_blob" id="obj">
    <string name="centers" value="-1.4 0 0 1 0.9,  1.4 0 0 1 0.9"/><float name="threshold" value="0.5"/>
    <transform name="to_world"><scale value="0.6"/><rotate z="1" angle="10"/><translate y="1.2"/></transform>
    {PHONG}</shape>"""

QUADRIC = f"""<shape type="links1_quadric" id="obj"><string name="kind" value="sphere"/>
    <transform name="to_world"><scale x="1.3" y="0.9" z="0.9"/><translate x="0.1" y="1.1" z="0"/></transform>
    {PHONG}</shape>"""

MITSUBA_SPHERE = f"""<shape type="sphere" id="obj"><point name="center" x="0.1" y="1.1" z="0"/><float name="radius" value="1"/>
    {PHONG}</shape>"""

MITSUBA_MESH = f"""<shape type="cube" id="obj">
    <transform name="to_world"><scale value="0.8"/><rotate y="1" angle="35"/><rotate x="1" angle="20"/><translate y="1.2"/></transform>
    {PHONG}</shape>"""


def load(tmp_path, body):
    import links1_mitsuba as lm
    path = tmp_path / "scene.xml"
    path.write_text(scene(whitted(3) + CAMERA, f"{FLOOR}\n  {body}\n  {LIGHTS}"))
    return lm.load_file(str(path))


def frame(scene, seed):
    import mitsuba as mi
    return np.array(mi.render(scene, seed=seed), dtype=np.float64)


def outline_ring(scene, key, width=3):
    """The pixels within ``width`` pixels of the outline of the shape whose BSDF is ``key``
    (the pixels its diffuse colour changes, and their complement, each grown by ``width``)."""
    import mitsuba as mi
    params = mi.traverse(scene)
    before = frame(scene, SEED_GRAD)
    old = mi.Color3f(params[key])
    params[key] = mi.Color3f(0.9, 0.05, 0.7)
    params.update()
    seen = np.abs(frame(scene, SEED_GRAD) - before).sum(-1) > 0
    params[key] = old
    params.update()

    def grow(m):
        for _ in range(width):
            p = np.pad(m, 1, constant_values=False)
            m = m | p[:-2, 1:-1] | p[2:, 1:-1] | p[1:-1, :-2] | p[1:-1, 2:]
        return m
    return seen, grow(seen) & grow(~seen)


def forward_and_fd(scene, key, make):
    """(AD, [FD at each step]) of every pixel's channels with respect to θ at 0, where
    ``params[key] = make(θ)``: forward mode through ``mi.render`` (derivative pass at
    ``SEED_GRAD``), central differences of frames at ``SEED_GRAD``."""
    import drjit as dr
    import mitsuba as mi
    params = mi.traverse(scene)
    fds = []
    for h in STEPS:
        pair = []
        for s in (h, -h):
            params[key] = make(mi.Float(s))
            params.update()
            pair.append(frame(scene, SEED_GRAD))
        fds.append((pair[0] - pair[1]) / (2 * h))
    th = mi.Float(0.0)
    dr.enable_grad(th)
    params[key] = make(th)
    params.update()
    img = mi.render(scene, params, seed=SEED, seed_grad=SEED_GRAD)
    dr.set_grad(th, 1.0)
    dr.forward_to(img)
    ad = np.array(dr.grad(img), dtype=np.float64)
    params[key] = make(mi.Float(0.0))
    params.update()
    return ad, fds


def check_ring(scene, bsdf_key, key, make, floor=0.03, least=15):
    """Every channel of every pixel of the outline ring whose central differences are stable
    (each within 1 % of the others, above ``floor``) has its AD within 2 % of them."""
    seen, ring = outline_ring(scene, bsdf_key)
    ad, (f1, f3, f10) = forward_and_fd(scene, key, make)
    mask = np.repeat(ring[..., None], 3, -1)
    stable = (mask & (np.abs(f10) > floor) & (np.abs(f1 - f10) <= 0.01 * np.abs(f10))
              & (np.abs(f3 - f10) <= 0.01 * np.abs(f10)))
    assert stable.sum() >= least, stable.sum()
    # pixels of the shape that the outline crosses or touches (grazing samples) are among them
    p = np.pad(seen, 1, constant_values=False)
    edge = seen & ~(p[:-2, 1:-1] & p[2:, 1:-1] & p[1:-1, :-2] & p[1:-1, 2:])
    assert (stable & edge[..., None]).sum() >= 3, (stable & edge[..., None]).sum()
    bad = stable & (np.abs(ad - f10) > 0.02 * np.abs(f10))
    where = [(int(y), int(x), int(c), f10[y, x, c], ad[y, x, c]) for y, x, c in zip(*np.nonzero(bad))]
    assert not where, where[:10]


def point_component(mi, dr, p0, lane, comp):
    """``make(θ)`` moving component ``comp`` of lane ``lane`` of the Point3f ``p0`` by θ."""
    arr = np.array(p0, dtype=np.float64).reshape(3, -1)
    n = arr.shape[1]

    def make(th):
        cs = [mi.Float(arr[k]) for k in range(3)]
        cs[comp] = cs[comp] + dr.select(dr.arange(mi.UInt32, n) == lane, th, 0.0)
        return mi.Point3f(*cs)
    return make


@pytest.mark.parametrize("body, comp", [(BLOB, 0), (BLOB_WAIST, 1)], ids=["round", "waist"])
def test_blob_centre_next_to_outline(variant, tmp_path, body, comp):
    """d pixel / d (first centre's x, or y) of a two-centre blob on the pixels next to its
    outline: the hit moves by implicit differentiation of W(x) = T at grazing angles."""
    import drjit as dr
    import mitsuba as mi
    sc = load(tmp_path, body)
    key = "links1_whitted.obj.centers"
    check_ring(sc, "links1_whitted.obj.bsdf.diffuse.value", key,
               point_component(mi, dr, mi.traverse(sc)[key], 0, comp))


def test_quadric_translation_next_to_outline(variant, tmp_path):
    """d pixel / d (x translation) of an ellipsoid (``links1_quadric``) next to its outline."""
    import mitsuba as mi
    sc = load(tmp_path, QUADRIC)
    key = "links1_whitted.obj.to_world"
    base = mi.Transform4f(mi.traverse(sc)[key])
    check_ring(sc, "links1_whitted.obj.bsdf.diffuse.value", key,
               lambda th: mi.Transform4f().translate(mi.Vector3f(th, 0.0, 0.0)) @ base)


@pytest.mark.parametrize("body", [MITSUBA_SPHERE, MITSUBA_MESH], ids=["sphere", "mesh"])
def test_mitsuba_shape_next_to_outline(variant, tmp_path, body):
    """A Mitsuba sphere's and mesh's geometry has no derivative; a light's position does: d pixel
    / d (links1_point's x) on the pixels next to their outlines (grazing shading)."""
    import drjit as dr
    import mitsuba as mi
    sc = load(tmp_path, body)
    key = "lp.position"
    check_ring(sc, "obj.bsdf.diffuse.value", key, point_component(mi, dr, mi.traverse(sc)[key], 0, 0))
