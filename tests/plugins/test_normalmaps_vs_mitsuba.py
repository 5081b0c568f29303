"""The core's ``normalmap`` and ``bumpmap`` (:mod:`links1.shading.normalmaps`) and ``pplastic``
(:class:`links1.shading.glossy.PolarizedPlastic`) against Mitsuba's own plugins.

The wrappers are judged where Mitsuba computes the surface interaction itself: the same rays
hit a textured rectangle (a mesh with texcoords), a sphere and a disk in both, and at each hit
Mitsuba's ``bsdf.eval``/``pdf``/``sample`` (its ``dp_du``, ``dp_dv``, shading frame) are
compared with the core's material bound to its own hit. A render under a point light then
compares both renderers with Mitsuba's ``direct``.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from links1_app.renderers import make_renderer

from tests.scenes import perspective, scene

from .conftest import assert_both_match_mitsuba_direct
from .test_glossy_bsdfs_vs_mitsuba import check_against_mitsuba

pytestmark = pytest.mark.mitsuba

N = 2000

NESTED = {"diffuse": '<bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.5, 0.3"/></bsdf>',
          "roughconductor": '<bsdf type="roughconductor"><float name="alpha" value="0.2"/></bsdf>',
          "twosided_diffuse": '<bsdf type="twosided"><bsdf type="diffuse"/></bsdf>'}
WRAP = {"normalmap": ('<bsdf type="normalmap"><texture name="normalmap" type="bitmap">'
                      '<string name="filename" value="{d}/normals.png"/><boolean name="raw" value="true"/>'
                      '</texture>{nested}</bsdf>'),
        "bumpmap": ('<bsdf type="bumpmap"><texture type="bitmap"><string name="filename" value="{d}/height.png"/>'
                    '<boolean name="raw" value="true"/></texture><float name="scale" value="0.02"/>{nested}</bsdf>')}
SHAPES = {"rectangle": ('<shape type="rectangle"><transform name="to_world"><scale x="2" y="1.3"/>'
                        '<rotate x="1" angle="-70"/><rotate z="1" angle="20"/></transform>{bsdf}</shape>'),
          "sphere": ('<shape type="sphere"><point name="center" x="0.1" y="-0.2" z="0"/>'
                     '<float name="radius" value="1.1"/>{bsdf}</shape>'),
          "disk": ('<shape type="disk"><transform name="to_world"><scale x="1.5" y="1.1"/>'
                   '<rotate x="1" angle="-60"/></transform>{bsdf}</shape>')}
CASES = [("rectangle", "normalmap", "diffuse"), ("rectangle", "bumpmap", "roughconductor"),
         ("sphere", "normalmap", "roughconductor"), ("sphere", "bumpmap", "diffuse"),
         ("disk", "normalmap", "twosided_diffuse"), ("disk", "bumpmap", "diffuse"),
         ("rectangle", "twosided_normalmap", "roughconductor")]


def write_maps(d) -> None:
    """A smooth 24x16 normal map and height map, 8-bit PNG (read ``raw``)."""
    from PIL import Image
    yy, xx = np.mgrid[0:16, 0:24]
    n = np.stack([0.5 * np.sin(xx / 3.0), 0.4 * np.cos(yy / 2.5), np.ones(xx.shape)], -1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    Image.fromarray(np.round((n * 0.5 + 0.5) * 255).astype(np.uint8)).save(f"{d}/normals.png")
    h = 0.5 + 0.5 * np.sin(xx / 2.0) * np.cos(yy / 3.0)
    Image.fromarray(np.round(h * 255).astype(np.uint8)).save(f"{d}/height.png")


@pytest.fixture(scope="module")
def maps(tmp_path_factory):
    d = tmp_path_factory.mktemp("maps")
    write_maps(d)
    return str(d)


def _bsdf_xml(d, wrap, nested):
    if wrap.startswith("twosided_"):
        return f'<bsdf type="twosided">{_bsdf_xml(d, wrap[len("twosided_"):], nested)}</bsdf>'
    return WRAP[wrap].format(d=d, nested=NESTED[nested])


def _f32(a):
    return a.astype(np.float32).astype(np.float64)   # what Mitsuba receives


def _rel(a, b, floor=1e-3):
    err = np.abs(a - b) / np.maximum(np.abs(b), floor)
    return err.max(axis=1) if err.ndim > 1 else err


def _core_at_hits(xml, o, d, si):
    """The core's hits of rays ``o, d`` in scene ``xml``, the same as Mitsuba's ``si``: their
    indices ``g`` (more than half the rays), surface records and the material bound to them."""
    from links1.scene.loader import load_string
    from links1.tracing.integrator import Hits, WhittedIntegrator
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        core = load_string(xml)
    it = WhittedIntegrator(core, max_depth=1)
    hits = it.intersect(o, d, np.zeros(N), np.full(N, np.inf), np.zeros(N, dtype=np.int64))
    assert np.array_equal(hits.valid, np.array(si.is_valid()))
    g = np.nonzero(hits.valid)[0]
    assert g.size > N // 2
    sub = Hits(hits.t[g], hits.shape[g], hits.prim[g])
    return g, it.surface(o[g], d[g], sub), it._bound(it._materials[0], o[g], d[g], sub, np.arange(g.size))


@pytest.mark.slow
@pytest.mark.parametrize("shape,wrap,nested", CASES)
def test_eval_pdf_sample_at_mitsubas_hits(maps, shape, wrap, nested, variant):
    """At the hits of the same rays: f·cos and the density equal Mitsuba's to float32 rounding
    (all within 2e-3, the 99th percentile within 2e-5: the bump map's gradient jumps at texel
    edges, where float32 uv may fall on the other side), and BSDF samples drawn with the same
    sample values are the same directions with the same weights and densities."""
    import mitsuba as mi
    rng = np.random.default_rng(3)
    xml = f'<scene version="3.0.0">{SHAPES[shape].format(bsdf=_bsdf_xml(maps, wrap, nested))}</scene>'
    o = np.tile([0.3, 4.0, 2.5], (N, 1))
    d = rng.uniform(-1, 1, (N, 3)) * [1.5, 1.0, 1.0] - o
    d = _f32(d / np.linalg.norm(d, axis=1, keepdims=True))
    if wrap.startswith("twosided"):
        o[::2] *= [1, -1, -1]           # half the rays from below
        d[::2] *= [1, -1, -1]
    light = rng.normal(size=(N, 3))
    light = _f32(light / np.linalg.norm(light, axis=1, keepdims=True))
    u1, u2 = _f32(rng.random(N)), _f32(rng.random((N, 2)))

    sc = mi.load_string(xml)
    si = sc.ray_intersect(mi.Ray3f(mi.Point3f(*o.T), mi.Vector3f(*d.T)))
    bsdf, ctx = si.bsdf(), mi.BSDFContext()
    wo_local = si.to_local(mi.Vector3f(*light.T))
    E = np.array(bsdf.eval(ctx, si, wo_local), dtype=np.float64).T
    P = np.array(bsdf.pdf(ctx, si, wo_local), dtype=np.float64)
    bs, bw = bsdf.sample(ctx, si, mi.Float(u1), mi.Point2f(*u2.T))
    SW, SP = np.array(bw, dtype=np.float64).T, np.array(bs.pdf, dtype=np.float64)
    SWO = np.array(si.to_world(bs.wo), dtype=np.float64).T

    g, rec, mat = _core_at_hits(xml, o, d, si)
    wo = -d[g]
    nf = np.where((np.sum(rec.ng * wo, axis=1) > 0)[:, None], rec.ns, -rec.ns)

    e, p = mat.eval(wo, light[g], nf, rec.ns), mat.pdf(wo, light[g], nf, rec.ns)
    lit = np.any(E[g] > 0, axis=1)
    assert lit.sum() > g.size // 4
    for name, ours, theirs in (("eval", e, E[g]), ("pdf", p, P[g])):
        err = _rel(ours, theirs)
        assert err.max() < 2e-3 and np.quantile(err, 0.99) < 2e-5, (name, err.max(), np.quantile(err, 0.99))
    wi, w, ps = mat.sample(wo, nf, rec.ns, u1[g], u2[g])
    drawn = np.any(SW[g] > 0, axis=1)
    assert drawn.sum() > g.size // 2
    assert np.count_nonzero(drawn != (ps > 0)) <= g.size // 200
    both = drawn & (ps > 0)
    close = np.max(np.abs(wi - SWO[g]), axis=1)[both]
    assert np.quantile(close, 0.99) < 1e-4, np.quantile(close, 0.99)
    assert np.quantile(_rel(w, SW[g])[both], 0.99) < 1e-3
    assert np.quantile(_rel(ps, SP[g])[both], 0.99) < 1e-3


PPLASTIC = {
    "pplastic": '<bsdf type="pplastic"/>',
    "pplastic_ggx": ('<bsdf type="pplastic"><string name="distribution" value="ggx"/><float name="alpha" value="0.3"/>'
                     '<rgb name="diffuse_reflectance" value="0.8, 0.2, 0.1"/><float name="int_ior" value="1.7"/>'
                     '<rgb name="specular_reflectance" value="0.6, 0.7, 0.8"/></bsdf>'),
    "pplastic_anisotropic": ('<bsdf type="pplastic"><float name="alpha_u" value="0.05"/><float name="alpha_v" value="0.3"/>'
                             '<boolean name="sample_visible" value="false"/></bsdf>'),
}


@pytest.mark.parametrize("case", list(PPLASTIC))
def test_pplastic_matches_mitsubas_rgb_eval(case, variant):
    """``pplastic`` in an RGB variant: f·cos, the density and BSDF samples on random direction
    pairs equal Mitsuba's to float32 rounding (not approximated: tests/core/test_normalmaps.py)."""
    check_against_mitsuba(PPLASTIC[case], lambda viewer, light: (viewer[:, 2] > 0) & (light[:, 2] > 0))


SCENE = scene(perspective("0, 2.5, 6", "0, 0.5, 0", fov=40, width=48, height=36, spp=None), """
  <emitter type="point"><point name="position" x="1.5" y="4" z="3"/><rgb name="intensity" value="30, 28, 25"/></emitter>
  <shape type="rectangle"><transform name="to_world"><scale value="3"/><rotate x="1" angle="-90"/></transform>
    {floor}</shape>
  <shape type="sphere"><point name="center" x="-1.1" y="0.8" z="0"/><float name="radius" value="0.8"/>{left}</shape>
  <shape type="sphere"><point name="center" x="1.0" y="0.8" z="0"/><float name="radius" value="0.8"/>{right}</shape>""")


def _render(kind, path, spp):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        img = np.asarray(make_renderer(kind, path, spp=spp, max_depth=1).render(), dtype=np.float64)[..., :3]
    assert not [w for w in caught if "not supported" in str(w.message)], kind   # nothing approximated
    return img


@pytest.mark.slow
def test_point_light_render_matches_direct_and_the_plugin(maps, tmp_path, variant):
    """A floor under a normal map around roughplastic, a bump-mapped diffuse sphere and a
    pplastic sphere under a point light (delta light: evaluated exactly): each renderer within
    1.5x the relMSE of Mitsuba's ``direct`` at the same spp against a 16x reference, and the
    core equal to the plugin (relMSE <= 1e-4)."""
    floor = _bsdf_xml(maps, "normalmap", "diffuse").replace(
        NESTED["diffuse"], '<bsdf type="roughplastic"><float name="alpha" value="0.15"/></bsdf>')
    path = tmp_path / "maps.xml"
    path.write_text(SCENE.format(floor=floor, left=_bsdf_xml(maps, "bumpmap", "diffuse"),
                                 right='<bsdf type="pplastic"><float name="alpha" value="0.2"/></bsdf>'))
    assert_both_match_mitsuba_direct(str(path), 16, _render)


DELTA_SCENE = scene(perspective("0, 2.5, 6", "0, 0.6, 0", fov=40, width=48, height=36, spp=None), """
  <emitter type="point"><point name="position" x="1.5" y="4" z="3"/><rgb name="intensity" value="30, 28, 25"/></emitter>
  <shape type="rectangle"><transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="diffuse"><texture name="reflectance" type="checkerboard"><rgb name="color0" value="0.8, 0.3, 0.2"/>
    <rgb name="color1" value="0.2, 0.5, 0.8"/><transform name="to_uv"><scale value="8"/></transform></texture></bsdf></shape>
  <shape type="rectangle"><transform name="to_world"><scale x="1.2" y="0.9"/><rotate y="1" angle="-25"/>
    <translate x="0.2" y="1.0" z="-1.6"/></transform>{back}</shape>
  <shape type="sphere"><point name="center" x="-1.1" y="0.8" z="0"/><float name="radius" value="0.8"/>{left}</shape>
  <shape type="sphere"><point name="center" x="1.0" y="0.8" z="0.3"/><float name="radius" value="0.8"/>{right}</shape>""")


@pytest.mark.slow
def test_delta_lobes_turn_with_the_map_as_the_plugin(maps, tmp_path, variant):
    """A mirror (``conductor``) and a glass (``dielectric``) sphere under a normal map and a
    mirror rectangle under a bump map: the core's mirror and refraction rays leave about the
    turned normal, weighted as Mitsuba's ``sample`` weights the nested delta lobes (shadowing
    term, reflections turned below the surface dropped), so the core equals the plugin
    (relMSE <= 1e-4 at the same spp, max_depth 4); about the unturned normal it would not."""
    from links1.imaging.diff import relmse
    path = tmp_path / "delta.xml"
    path.write_text(DELTA_SCENE.format(
        left=_bsdf_xml(maps, "normalmap", "diffuse").replace(
            NESTED["diffuse"], '<bsdf type="conductor"><string name="material" value="Au"/></bsdf>'),
        right=_bsdf_xml(maps, "normalmap", "diffuse").replace(NESTED["diffuse"], '<bsdf type="dielectric"/>'),
        back=_bsdf_xml(maps, "bumpmap", "diffuse").replace(NESTED["diffuse"], '<bsdf type="conductor"/>')))
    imgs = {}
    for kind in ("core", "mitsuba"):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            r = make_renderer(kind, str(path), spp=4, max_depth=4)
            imgs[kind] = np.asarray(r.render(), dtype=np.float64)[..., :3]
        assert not [w for w in caught if "normal" in str(w.message)], kind   # nothing approximated
    assert imgs["core"].mean() > 0.02
    assert relmse(imgs["mitsuba"], imgs["core"]) <= 1e-4, relmse(imgs["mitsuba"], imgs["core"])


DELTA_NESTED = {"conductor": '<bsdf type="conductor"><string name="material" value="Au"/></bsdf>',
                "dielectric": '<bsdf type="dielectric"><float name="int_ior" value="1.6"/></bsdf>'}
DELTA_CASES = [("sphere", "normalmap", "conductor", False), ("sphere", "bumpmap", "dielectric", False),
               ("rectangle", "normalmap", "dielectric", True), ("rectangle", "bumpmap", "conductor", False),
               ("rectangle", "twosided_normalmap", "conductor", True), ("disk", "noflip_normalmap", "conductor", False)]


@pytest.mark.slow
@pytest.mark.parametrize("shape,wrap,nested,both_sides", DELTA_CASES)
def test_delta_rays_are_mitsubas_delta_samples(maps, shape, wrap, nested, both_sides, variant):
    """At the hits of the same rays, the core's mirror and refraction rays
    (``WhittedIntegrator.delta_rays``) are the directions and weights Mitsuba's ``sample`` gives
    the nested delta lobes (asked for one lobe at a time, as the plugin asks): the same rays kept
    (to float32 rounding at the edges), directions within 1e-4, weights within 1e-3 (99%)."""
    import mitsuba as mi
    from links1.tracing.integrator import WhittedIntegrator
    rng = np.random.default_rng(5)
    bsdf = _bsdf_xml(maps, wrap.replace("noflip_", ""), "diffuse").replace(NESTED["diffuse"], DELTA_NESTED[nested])
    if wrap.startswith("noflip_"):
        bsdf = bsdf.replace("</texture>", '</texture><boolean name="flip_invalid_normals" value="false"/>', 1)
    xml = f'<scene version="3.0.0">{SHAPES[shape].format(bsdf=bsdf)}</scene>'
    o = np.tile([0.3, 4.0, 2.5], (N, 1))
    d = rng.uniform(-1, 1, (N, 3)) * [1.5, 1.0, 1.0] - o
    d = _f32(d / np.linalg.norm(d, axis=1, keepdims=True))
    if both_sides:
        o[::2] *= [1, -1, -1]           # half the rays from below
        d[::2] *= [1, -1, -1]
    sc = mi.load_string(xml)
    si = sc.ray_intersect(mi.Ray3f(mi.Point3f(*o.T), mi.Vector3f(*d.T)))
    theirs = {}
    for flag in (mi.BSDFFlags.DeltaReflection, mi.BSDFFlags.DeltaTransmission):
        ctx = mi.BSDFContext()
        ctx.type_mask = +flag
        bs, w = si.bsdf().sample(ctx, si, mi.Float(0.5), mi.Point2f(0.5, 0.5))
        W = np.array(w, dtype=np.float64).T
        ok = (np.array(bs.pdf) > 0) & np.any(W > 0, axis=1) & ((np.array(bs.sampled_type) & int(flag)) != 0)
        theirs[flag] = np.where(ok[:, None], W, 0.0), np.array(si.to_world(bs.wo), dtype=np.float64).T

    g, rec, mat = _core_at_hits(xml, o, d, si)
    wo = -d[g]
    front = np.sum(rec.ng * wo, axis=1) > 0
    nf = np.where(front[:, None], rec.ns, -rec.ns)
    r, dir_r, t, dir_t, _ = WhittedIntegrator.delta_rays({0: mat}, [(0, np.arange(g.size))], wo, nf, front, rec.ns)
    for flag, ours, direction in ((mi.BSDFFlags.DeltaReflection, r, dir_r), (mi.BSDFFlags.DeltaTransmission, t, dir_t)):
        W, WO = theirs[flag]
        W, WO = W[g], WO[g]
        mine, drawn = np.any(ours > 0, axis=1), np.any(W > 0, axis=1)
        assert np.count_nonzero(mine != drawn) <= max(2, g.size // 200), (flag, np.count_nonzero(mine != drawn))
        if flag == mi.BSDFFlags.DeltaTransmission and nested == "conductor":
            assert not mine.any()
            continue
        assert drawn.sum() > g.size // 4, flag
        both = mine & drawn
        assert np.quantile(np.max(np.abs(direction[both] - WO[both]), axis=1), 0.99) < 1e-4, flag
        assert np.quantile(_rel(ours[both], W[both]), 0.99) < 1e-3, flag
