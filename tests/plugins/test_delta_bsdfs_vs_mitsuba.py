"""Every Mitsuba BSDF with a delta lobe, in both renderers, against Mitsuba's ``path``.

Each scene holds one object with a delta BSDF (``dielectric``, ``thindielectric`` as a sphere
and as a tilted sheet, ``conductor``, ``plastic``'s specular coat, ``twosided`` and ``mask``
around them, ``null``) in front of a striped backdrop of area emitters under a ``constant``
environment. There is no diffuse surface besides plastic's own base, so every light path
is eye → delta vertices → emitter (plus NEE at plastic's base, which a lone convex object
receives from the emitters only): Whitted with ``max_depth`` k and ``path`` with ``max_depth``
k (rr_depth beyond it) estimate the same light paths, and a missing or wrong lobe shows.

Judged as the issue asks: links1's relMSE against a high-spp ``path`` reference is at most
twice ``path``'s own relMSE at the same spp (a different seed). A lost lobe is a bias far above that bound.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from tests.scenes import integrator, perspective, scene, whitted

pytestmark = pytest.mark.mitsuba

RES = 24
SPP = 16
REF_SPP = 1024
DEPTH = 6

BACKDROP = """
  <emitter type="constant"><rgb name="radiance" value="0.25, 0.3, 0.35"/></emitter>
""" + "".join(f"""
  <shape type="rectangle"><transform name="to_world"><scale x="0.5" y="3"/>
    <translate x="{x}" y="0.7" z="-3"/></transform>
    <emitter type="area"><rgb name="radiance" value="{c}"/></emitter></shape>""" for x, c in
    ((-3, "1.6, 0.3, 0.2"), (-1, "0.2, 1.2, 0.3"), (1, "0.3, 0.4, 1.8"), (3, "1.4, 1.3, 0.2")))

SPHERE = '<shape type="sphere"><point name="center" x="0" y="0.7" z="0"/><float name="radius" value="1.1"/>{b}</shape>'
SHEET = ('<shape type="rectangle"><transform name="to_world"><scale value="1.4"/><rotate y="1" angle="{a}"/>'
         '<translate x="0" y="0.7" z="0"/></transform>{b}</shape>')

CASES = {
    "dielectric": SPHERE.format(b='<bsdf type="dielectric"/>'),
    "thindielectric_sphere": SPHERE.format(b='<bsdf type="thindielectric"/>'),
    "thindielectric_sheet": SHEET.format(a=35, b='<bsdf type="thindielectric"><float name="int_ior" value="1.8"/>'
                                         '<rgb name="specular_transmittance" value="0.9, 0.7, 1"/></bsdf>'),
    "conductor": SPHERE.format(b='<bsdf type="conductor"><string name="material" value="none"/>'
                                 '<rgb name="specular_reflectance" value="0.9, 0.6, 0.4"/></bsdf>'),
    "plastic": SPHERE.format(b='<bsdf type="plastic"><rgb name="diffuse_reflectance" value="0.2, 0.3, 0.6"/></bsdf>'),
    "twosided_conductor_back": SHEET.format(a=150, b='<bsdf type="twosided"><bsdf type="conductor"/></bsdf>'),
    "twosided_plastic_back": SHEET.format(a=150, b='<bsdf type="twosided"><bsdf type="plastic"/></bsdf>'),
    "mask_conductor": SPHERE.format(b='<bsdf type="mask"><float name="opacity" value="0.35"/>'
                                      '<bsdf type="conductor"/></bsdf>'),
    "mask_thindielectric": SHEET.format(a=35, b='<bsdf type="mask"><float name="opacity" value="0.6"/>'
                                          '<bsdf type="thindielectric"/></bsdf>'),
    "mask_plastic": SPHERE.format(b='<bsdf type="mask"><float name="opacity" value="0.5"/><bsdf type="plastic"/></bsdf>'),
    "mask_textured_conductor": SHEET.format(a=35, b='<bsdf type="mask"><texture name="opacity" type="checkerboard">'
                                            '<float name="color0" value="0.9"/><float name="color1" value="0.2"/>'
                                            '<transform name="to_uv"><scale value="3"/></transform></texture>'
                                            '<bsdf type="conductor"/></bsdf>'),
    "null": SPHERE.format(b='<bsdf type="null"/>'),
    # a blendbsdf's delta lobes come weighted by the blend's weight (a float, a texture)
    "blend_diffuse_conductor": SPHERE.format(b='<bsdf type="blendbsdf"><float name="weight" value="0.35"/>'
                                               '<bsdf type="diffuse"/><bsdf type="conductor"/></bsdf>'),
    "blend_dielectric_conductor": SPHERE.format(b='<bsdf type="blendbsdf"><texture name="weight" type="checkerboard">'
                                                  '<float name="color0" value="0.8"/><float name="color1" value="0.3"/>'
                                                  '</texture><bsdf type="dielectric"/><bsdf type="conductor">'
                                                  '<string name="material" value="Au"/></bsdf></bsdf>'),
}


def scene_xml(body, method, spp):
    return scene(perspective("0.4, 1.2, 5", "0, 0.7, 0", fov=45, width=RES, spp=spp), method, BACKDROP, body)


WHITTED = whitted(DEPTH, min_weight=0.0, light_samples=4)
PATH = integrator("path", max_depth=DEPTH, rr_depth=DEPTH + 5)


def rel_mse(a, b):
    return float(np.sum((a - b) ** 2) / max(np.sum(b ** 2), 1e-30))


def path_image(body, variant, spp, seed):
    import mitsuba as mi
    from links1_mitsuba import load_string
    sc = load_string(scene_xml(body, PATH, spp), links1_integrator="scene", variant=variant)
    return np.array(mi.render(sc, spp=spp, seed=seed), dtype=np.float64)[..., :3]


def plugin_image(body, variant, spp):
    from links1_mitsuba import load_string
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sc = load_string(scene_xml(body, WHITTED, spp), variant=variant)
    return np.asarray(sc.integrator().render_window(sc, None, spp=spp, seed=3), dtype=np.float64)[..., :3]


def core_image(body, spp):
    from links1.scene.loader import load_string
    from links1.tracing.render import render
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sc = load_string(scene_xml(body, WHITTED, spp))
        return np.asarray(render(sc, spp=spp, seed=3), dtype=np.float64)[..., :3]


@pytest.mark.slow
@pytest.mark.parametrize("case", sorted(CASES))
def test_delta_bsdf_vs_path(variant, case):
    body = CASES[case]
    ref = path_image(body, variant, REF_SPP, seed=1)
    own = rel_mse(path_image(body, variant, SPP, seed=2), ref)   # Mitsuba's own noise at SPP
    plug = plugin_image(body, variant, SPP)
    core = core_image(body, SPP)
    e_plug, e_core = rel_mse(plug, ref), rel_mse(core, ref)
    msg = f"{case}: relMSE plugin {e_plug:.3g}, core {e_core:.3g}, path at spp {SPP} {own:.3g}"
    assert e_plug <= 2.0 * own, msg
    assert e_core <= 2.0 * own, msg
    # the means too (a bias could hide in the noise bound only if path were very noisy)
    assert abs(plug.mean() - ref.mean()) <= 0.02 * ref.mean(), msg
    assert abs(core.mean() - ref.mean()) <= 0.02 * ref.mean(), msg


@pytest.mark.slow
def test_thin_sheet_keeps_its_transmission(variant):
    """A thin sheet under ``constant`` only transmits T' = 1 - R' of the
    background straight through (R' = 2R/(1+R), Mitsuba's thindielectric); with the
    reflection, a grey background is seen unchanged through and off the sheet."""
    body = SHEET.format(a=0, b='<bsdf type="thindielectric"/>')
    xml_bg = '<emitter type="constant"><rgb name="radiance" value="0.529"/></emitter>'
    from links1_mitsuba import load_string
    from links1.scene.loader import load_string as core_load
    from links1.tracing.render import render
    xml = scene_xml(body, WHITTED, 1).replace(BACKDROP, xml_bg)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sc = load_string(xml, variant=variant)
        plug = np.asarray(sc.integrator().render_window(sc, None, spp=1), dtype=np.float64)[..., :3]
        core = np.asarray(render(core_load(xml), spp=1), dtype=np.float64)[..., :3]
    c = RES // 2
    assert np.allclose(plug[c, c], 0.529, rtol=1e-5), plug[c, c]
    assert np.allclose(core[c, c], 0.529, rtol=1e-9), core[c, c]


@pytest.mark.slow
def test_mask_around_dielectric_warns_in_both_renderers(variant):
    """A Whitted node has one transmitted ray: a mask around a refracting dielectric keeps the
    refraction and drops the straight-through part, and both renderers say so."""
    from links1_mitsuba import load_string
    from links1.scene.loader import load_string as core_load
    body = SPHERE.format(b='<bsdf type="mask"><float name="opacity" value="0.5"/><bsdf type="dielectric"/></bsdf>')
    xml = scene_xml(body, WHITTED, 1)
    with pytest.warns(UserWarning, match="straight-through"):
        core_load(xml)
    with pytest.warns(UserWarning, match="straight-through"):
        sc = load_string(xml, variant=variant)
        sc.integrator().render_window(sc, None, spp=1)


def _delta_tree(variant):
    """``scenes/delta_bsdfs.xml`` at 40 px, ``max_depth`` 5, spp 2: ``(tables, trace)``, where
    ``trace(remake=False)`` traces its ray trees (``Tracer.trace_tree``; ``remake``: given the
    camera rays as a function of the lanes) -> radiance, costs and ray counters as numpy."""
    import os
    import drjit as dr
    import mitsuba as mi
    import links1_mitsuba as lm
    from links1.maths.sampling import key_seed, strata
    from links1_mitsuba.camera import camera_rays
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    scene = lm.load_file(os.path.join(root, "scenes", "delta_bsdfs.xml"), variant=variant, res=40)
    scene.integrator().max_depth = 5
    mi.render(scene, spp=1)
    eng = scene.integrator().engine
    tracer = eng._tracer()
    tables = eng.tables.prepare(scene, None, tracer.tuning)
    spp = 2
    n = tables.film_size[0] * tables.film_size[1] * spp
    sid = dr.arange(mi.UInt32, n)
    counts = (dr.opaque(mi.UInt32, spp), dr.opaque(mi.UInt32, strata(spp)))
    seeds = (dr.opaque(mi.UInt32, 0), dr.opaque(mi.UInt32, key_seed(0)))

    def trace(remake=False):
        o, d, tmin, tmax, key, sample = camera_rays(tables, sid, counts, seeds)
        rays = None
        if remake:
            rays = lambda idx: camera_rays(tables, dr.gather(mi.UInt32, sid, idx), counts, seeds)[:5]  # noqa: E731
        rgb, cost, _, _, _, c = tracer.trace_tree(tables, scene, o, d, tmin, tmax, key, False, sample, rays=rays)
        return [np.asarray(rgb), np.asarray(cost)] + [np.asarray(c[k]) for k in ("nsh1", "cr", "ct", "nr", "nt", "nsh2")]
    return tables, trace


def test_branches_skip_only_what_adds_nothing(variant):
    """The ray tree computes a hit's delta lobes under a branch on the slots that can spawn
    (``Prepared.spawns``) and its direct light under one on the slots direct light can reach
    the eye from (``Prepared.shaded``): ``scenes/delta_bsdfs.xml`` (every delta BSDF, diffuse
    and plastic slots, two delta lights) traced with every hit taken into both branches gives
    the same radiance, ray counts and children, bit for bit."""
    import mitsuba as mi
    tables, trace = _delta_tree(variant)
    base = tables.base or tables
    spawns, shaded = np.asarray(base.spawns), np.asarray(base.shaded)
    assert spawns.any() and not spawns.all() and shaded.any() and not shaded.all()
    got = trace()
    base.spawns, base.shaded, base.all_shaded = mi.Bool(np.ones_like(spawns)), mi.Bool(np.ones_like(shaded)), True
    try:
        every = trace()
    finally:
        base.spawns, base.shaded, base.all_shaded = mi.Bool(spawns), mi.Bool(shaded), False
    assert got[4].any() and got[5].any()           # refraction at level 1, mirror rays below it
    for a, b in zip(got, every):
        assert np.array_equal(a, b)


def test_children_remade_from_the_hit(variant):
    """Given the camera rays as a function of the lanes (``trace_tree``'s ``rays``, as the
    launches give them), the camera level stores only the preliminary hits of
    ``scenes/delta_bsdfs.xml``'s spheres and rectangles, compacts the samples whose hit can
    spawn, and the loop's kernel makes their record and children again: the same radiance
    and costs, bit for bit, and the same ray counts (the counters of level 1's children and
    of the loop are arrays of the compacted lanes there) as the tree that stores the children."""
    from links1_mitsuba import intersect
    tables, trace = _delta_tree(variant)
    assert intersect.remakes(tables)
    stored, remade = trace(), trace(remake=True)
    assert stored[4].any() and stored[6].any() and stored[7].any()   # refraction at level 1, both kinds below it
    for a, b in zip(stored[:2], remade[:2]):
        assert np.array_equal(a.view(np.uint32), b.view(np.uint32))
    assert [int(c.astype(np.int64).sum()) for c in stored[2:]] == [int(c.astype(np.int64).sum()) for c in remade[2:]]
    assert np.count_nonzero(stored[3] | stored[4]) == np.count_nonzero(remade[3] | remade[4])
