"""The corpus: real Mitsuba 3 scenes (tests/corpus/manifest.py, SOURCES.md) in both renderers.

Per scene, what tests/corpus/manifest.py states:

* ``direct`` (diffuse surfaces under delta lights or an environment, direct light only: what
  links1_whitted at max_depth 1 renders without approximation): the core and links1_whitted at
  max_depth 1 and Mitsuba's ``direct`` at the same spp are each compared with Mitsuba's ``direct`` at 16x the
  spp; both renderers' relative MSE must be within 2x Mitsuba's own.
* ``renders``: both renderers give a finite image (the core at 4 spp, links1_whitted the frame
  of its Whitted-reference test below), and every approximation the entry names is in a
  one-line scene warning (``FILE:LINE: ...``).

And every scene: links1_whitted (its default depth) against ``whitted_reference``, Mitsuba's
own sampling restricted to Whitted's light paths (tests/corpus/whitted_reference.py) at 16x the
spp: its relMSE within 1.5x the reference's own at equal spp.

Scenes are rendered small (32 pixels wide, the file's field of view kept).
"""
from __future__ import annotations

import os
import warnings

import numpy as np
import pytest

from links1_app.renderers import make_renderer
from tests.corpus.manifest import SCENES

from .conftest import VARIANTS, assert_matches_mitsuba_direct, use_variant, variant_marks

pytestmark = [pytest.mark.mitsuba, pytest.mark.slow]

WIDTH, HEIGHT = 32, 24
SPP, REF_FACTOR = 16, 16


def _path(sc) -> str:
    path = sc.local_path
    if not os.path.exists(path):
        pytest.skip(f"{sc.id}: not committed (licence: {sc.licence}); tools/fetch_corpus.py copies it "
                    "into tests/corpus/external/")
    return path


def _render(kind, sc, path, **opts):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = make_renderer(kind, path, params=dict(sc.params), width=WIDTH, height=HEIGHT, **opts)
        img = np.asarray(r.render(), dtype=np.float64)[..., :3]
    return img, [str(w.message) for w in caught]


#: links1_whitted's frame of each scene at SPP and its warnings (``_render``), by scene and
#: variant: the Whitted-reference test and the renders test judge the same frame (the file
#: loaded and rendered once)
_PLUGIN_FRAMES: dict = {}


def _plugin_frame(sc, path):
    import mitsuba as mi
    key = (sc.id, mi.variant())
    if key not in _PLUGIN_FRAMES:
        _PLUGIN_FRAMES[key] = _render("mitsuba", sc, path, spp=SPP)
    img, messages = _PLUGIN_FRAMES[key]
    return img.copy(), list(messages)


def _params(expect):
    """(scene, renderer, variant) per scene: the core once (with llvm_ad_rgb for Mitsuba's
    references: no variant changes the core), links1_whitted on each variant."""
    out = []
    for sc in SCENES:
        if sc.expect != expect:
            continue
        for kind, v in (("core", "llvm_ad_rgb"), *(("mitsuba", v) for v in VARIANTS)):
            marks = [pytest.mark.xfail(strict=True, reason=sc.xfail[kind])] if kind in sc.xfail else []
            marks += variant_marks(v) if kind == "mitsuba" else []
            name = kind if kind == "core" else f"{kind}-{v}"
            out.append(pytest.param(sc, kind, v, id=f"{sc.id}-{name}", marks=marks))
    return out


@pytest.mark.parametrize("sc,kind,variant_name", _params("direct"))
def test_delta_light_scene_matches_mitsuba_direct(sc, kind, variant_name):
    use_variant(variant_name)
    assert_matches_mitsuba_direct(kind, _path(sc), spp=SPP, ref_factor=REF_FACTOR, params=dict(sc.params),
                                  width=WIDTH, height=HEIGHT)


def _reference_params():
    out = []
    for sc in SCENES:
        for v in VARIANTS:
            marks = [pytest.mark.xfail(strict=True, reason=sc.vs_reference)] if sc.vs_reference else []
            out.append(pytest.param(sc, v, id=f"{sc.id}-mitsuba-{v}", marks=marks + variant_marks(v)))
    return out


@pytest.mark.parametrize("sc,variant_name", _reference_params())
def test_plugin_matches_whitted_reference(sc, variant_name):
    from links1.imaging.diff import relmse
    from tests.corpus.whitted_reference import render_reference
    use_variant(variant_name)
    path = _path(sc)
    # the depth links1 renders the file at (its integrator's max_depth, a wrapper's nested
    # one, else links1's default), in Mitsuba's counting: one more
    from links1 import load_scene
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        depth = load_scene(path, **dict(sc.params)).max_depth
    kw = dict(width=WIDTH, height=HEIGHT, params=dict(sc.params), max_depth=depth + 1)
    ref = render_reference(path, SPP * REF_FACTOR, seed=1, **kw)
    theirs = relmse(render_reference(path, SPP, seed=2, **kw), ref)
    ours, _ = _plugin_frame(sc, path)
    assert np.all(np.isfinite(ours)), f"{sc.id}: NaN or Inf in the image"
    err = relmse(ours, ref)
    assert err <= 1.5 * theirs, f"{sc.id}: relMSE {err:.3g} vs the reference's own {theirs:.3g} at spp {SPP}"


@pytest.mark.parametrize("sc,kind,variant_name", _params("renders"))
def test_scene_renders_and_names_its_approximations(sc, kind, variant_name):
    use_variant(variant_name)
    path = _path(sc)
    img, messages = _plugin_frame(sc, path) if kind == "mitsuba" else _render(kind, sc, path, spp=4)
    assert img.shape[:2] == (HEIGHT, WIDTH)
    assert np.all(np.isfinite(img)), f"{sc.id} {kind}: NaN or Inf in the image"
    assert all("\n" not in m for m in messages), messages
    if kind == "core":
        for needle in sc.warns:
            hits = [m for m in messages if needle in m and os.path.basename(path).split(".")[0] in m
                    or needle in m and ".xml:" in m]
            assert hits, f"{sc.id}: no one-line warning names '{needle}': {messages}"


def _small(scene):
    """The scene's first sensor at the corpus size (its film's size and crop, through
    ``mi.traverse``: a plain Mitsuba scene has no loader options)."""
    import mitsuba as mi
    p = mi.traverse(scene)
    k = next(x for x in p.keys() if x.endswith("film.size"))
    p[k] = [WIDTH, HEIGHT]
    p[k.replace("film.size", "film.crop_size")] = [WIDTH, HEIGHT]
    p[k.replace("film.size", "film.crop_offset")] = [0, 0]
    p.update()
    return scene


@pytest.mark.parametrize("sc", [pytest.param(sc, id=sc.id) for sc in SCENES])
def test_plain_mitsuba_loading_equals_the_loader(sc):
    """``mi.load_file`` + ``links1_whitted`` renders what ``links1_mitsuba.load_file`` renders,
    to float32 rounding, area lights included: Mitsuba orders a plain scene's shapes by kind, so
    an area light's samples are keyed by its place, not by its shape's slot
    (``links1.shading.lights.number_area_lights``)."""
    import mitsuba as mi

    import links1_mitsuba
    use_variant("llvm_ad_rgb")
    path = _path(sc)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        loaded = _small(links1_mitsuba.load_file(path, **dict(sc.params)))
        plain = _small(mi.load_file(path, **dict(sc.params)))
        integ = mi.load_dict({"type": "links1_whitted", "max_depth": loaded.integrator().max_depth})
        got = np.array(mi.render(plain, integrator=integ, spp=4), dtype=np.float64)
        want = np.array(mi.render(loaded, spp=4), dtype=np.float64)
    assert np.abs(got - want).max() <= 1e-5 * max(1.0, want.max()), (sc.id, np.abs(got - want).max())
