"""The corpus: real Mitsuba 3 scenes (tests/corpus/manifest.py, SOURCES.md) in both renderers.

Per scene, what tests/corpus/manifest.py states:

* ``direct`` (diffuse surfaces under delta lights or an environment, direct light only: what
  links1_whitted at max_depth 1 renders without approximation): the core and links1_whitted at
  max_depth 1 and Mitsuba's ``direct`` at the same spp are each compared with Mitsuba's ``direct`` at 16x the
  spp; both renderers' relative MSE must be within 2x Mitsuba's own.
* ``renders``: both renderers give a finite image, and every approximation the entry names is
  in a one-line scene warning (``FILE:LINE: ...``).

Scenes are rendered small (32 pixels wide, the file's field of view kept).
"""
from __future__ import annotations

import os
import warnings

import numpy as np
import pytest

from links1.diff import relmse
from links1.render import make_renderer
from tests.corpus.manifest import SCENES

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


def _mitsuba_direct(path, sc, spp, seed):
    import mitsuba as mi
    r = make_renderer("mitsuba", path, params=dict(sc.params), width=WIDTH, height=HEIGHT,
                      integrator="scene", spp=spp)
    direct = mi.load_dict({"type": "direct"})
    return np.array(mi.render(r.scene, integrator=direct, spp=spp, seed=seed), dtype=np.float64)[..., :3]


def _params(expect):
    out = []
    for sc in SCENES:
        if sc.expect != expect:
            continue
        for kind in ("core", "mitsuba"):
            marks = [pytest.mark.xfail(strict=True, reason=sc.xfail[kind])] if kind in sc.xfail else []
            out.append(pytest.param(sc, kind, id=f"{sc.id}-{kind}", marks=marks))
    return out


@pytest.mark.parametrize("sc,kind", _params("direct"))
def test_delta_light_scene_matches_mitsuba_direct(sc, kind, llvm):
    path = _path(sc)
    ref = _mitsuba_direct(path, sc, SPP * REF_FACTOR, seed=1)
    theirs = relmse(_mitsuba_direct(path, sc, SPP, seed=2), ref)
    ours, _ = _render(kind, sc, path, spp=SPP, max_depth=1)
    assert np.all(np.isfinite(ours))
    err = relmse(ours, ref)
    assert err <= 2 * theirs, f"{sc.id} {kind}: relMSE {err:.3g} vs Mitsuba direct's own {theirs:.3g}"


@pytest.mark.parametrize("sc,kind", _params("renders"))
def test_scene_renders_and_names_its_approximations(sc, kind, llvm):
    path = _path(sc)
    img, messages = _render(kind, sc, path, spp=4)
    assert img.shape[:2] == (HEIGHT, WIDTH)
    assert np.all(np.isfinite(img)), f"{sc.id} {kind}: NaN or Inf in the image"
    assert all("\n" not in m for m in messages), messages
    if kind == "core":
        for needle in sc.warns:
            hits = [m for m in messages if needle in m and os.path.basename(path).split(".")[0] in m
                    or needle in m and ".xml:" in m]
            assert hits, f"{sc.id}: no one-line warning names '{needle}': {messages}"
