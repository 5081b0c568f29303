"""Golden images: every scene in scenes/ rendered by the core, against a stored baseline.

Uses the project's own regression tool (the ``links1_baseline`` fixture of
links1_app.pytest_plugin). Regenerate with ``pytest tests/core/test_golden.py --links1-update-baselines``
after an intended change, and look at the new images before committing them.

A baseline only says the core has not changed, so each one (the stored file, or the one
just written by ``--links1-update-baselines``) is also checked against an independent
reference, named in ``REFERENCES``: the analytic oracle of ``tests/core/oracle.py`` (its
own XML reading, camera rays and closed-form hits and shading), on every pixel whose light
paths it can be sure of.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from links1.imaging.image import read_exr

from . import oracle

ROOT = Path(__file__).resolve().parents[2]
SCENES = sorted(p.name for p in (ROOT / "scenes").glob("*.xml"))
RES = 64

#: scene -> (what the analytic oracle can check there, least fraction of pixels it must cover)
REFERENCES = {
    "lights.xml": ("every pixel: floor and three spheres under a parallel, a cosine-lobe point "
                   "and a cylinder spot light (eq. 3.10, 3.11), sphere shadows", 0.99),
    "mitsuba_direct.xml": ("every pixel: Mitsuba diffuse (albedo/π), inverse-square point and "
                           "directional light, sphere and cube shadows (what Mitsuba's direct renders)", 0.99),
    "mitsuba_glass.xml": ("the floor: direct light, the mirror and glass spheres blocking shadow rays "
                          "as in Mitsuba's path (mirror and glass pixels not checked)", 0.7),
    "shadows.xml": ("floor and pane-free pixels: transparent shadows, t1 t2 ... per object "
                    "(3-3-3) through two panes and a glass sphere", 0.75),
    "many.xml": ("floor and 300 unclipped ellipsoid quadrics (eq. 3.4-3.5) with shadows", 0.9),
    "fig4.xml": ("the floor where no ray nears the clipped ellipsoid's bounding ball", 0.35),
    "fig6a.xml": ("the floor where no ray nears a blob centre's 3S ball", 0.12),
    "fig6b.xml": ("the floor where no ray nears a blob centre's 3S ball", 0.12),
    "blobs_moving.xml": ("the floor where no ray nears a blob centre's 3S ball (the moving blob "
                         "of the sequence example at its default frame)", 0.12),
    "bicubic.xml": ("the floor where no ray nears the patches' control-point box", 0.1),
    "delta_bsdfs.xml": ("the striped wall and the floor seen directly: Mitsuba diffuse under a "
                        "directional and a point light, every delta-BSDF object blocking shadow rays "
                        "(Mitsuba's binary shadow tests; the objects themselves not checked)", 0.7),
    "fig11.xml": ("the background (constant emitter); surfaces are lit by sampling the "
                  "environment (Monte Carlo), not checked", 0.3),
}


def _spp(scene):
    return 4 if scene == "fig11.xml" else 1


def test_every_scene_has_a_golden_test_and_a_reference():
    assert len(SCENES) >= 9  # the paper figures, lights, bicubic, shadows, many, Mitsuba-only
    assert sorted(REFERENCES) == SCENES


def check_against_oracle(scene: str, image: np.ndarray, spp: int):
    """Assert that ``image`` (H, W, ≥3) agrees with the oracle on the pixels it knows."""
    what, least = REFERENCES[scene]
    sub = 1 if spp == 1 else 4
    expect, known = oracle.probe(str(ROOT / "scenes" / scene), {"res": RES}, sub=sub)
    img = image[..., :3].astype(np.float64)
    if sub == 1:  # one sample at the pixel centre
        err = np.abs(img - expect).max(-1)
    else:  # a pixel's mean lies within the range of its values over the pixel
        err = np.maximum(expect.min(2) - img, img - expect.max(2)).clip(0).max(-1)
    assert known.mean() >= least, f"{scene}: the oracle knows only {known.mean():.0%} of the pixels ({what})"
    tol = 2e-6 + 2e-6 * np.abs(img).max(-1)   # float32 storage of float64 values
    bad = known & (err > tol)
    ys, xs = np.nonzero(bad)
    assert not bad.any(), (f"{scene}: {bad.sum()} of {known.sum()} checked pixels differ from the "
                           f"analytic oracle ({what}); worst {err[bad].max():.3g} at "
                           f"{list(zip(xs.tolist(), ys.tolist()))[:5]} (x, y)")
    return known


@pytest.mark.slow
@pytest.mark.parametrize("scene", SCENES)
def test_scene_matches_baseline(links1_baseline, scene):
    spp = _spp(scene)
    name = f"{Path(scene).stem}_spp{spp}"
    links1_baseline.check_scene(str(ROOT / "scenes" / scene), renderer="core", spp=spp,
                                params={"res": RES}, metric="relmse", threshold=1e-8, name=name)
    baseline, _ = read_exr(links1_baseline.path(name))
    check_against_oracle(scene, baseline, spp)


def test_oracle_sees_lit_shadowed_and_tinted_pixels():
    """The oracle's coverage is not only easy pixels: on shadows.xml it checks pixels in full
    light, in one pane's tinted shadow and in the overlap of both (t1 t2, 3-3-3)."""
    sc = oracle.Scene(str(ROOT / "scenes" / "shadows.xml"), {"res": RES})
    d = sc.camera_rays(1)
    o = np.broadcast_to(sc.eye, d.shape)
    t, idx, n = sc.nearest(o, d)
    floor = idx == 0
    p = o[floor] + t[floor, None] * d[floor]
    light = sc.lights[0]
    wi, dist, _ = light.arrive(p)
    T, ok = sc.transmission(p + 1e-5 * np.array([0, 1, 0]), wi, dist)
    T = T[ok]
    full = np.all(T == 1, axis=1)
    one = np.isclose(T, [0.9, 0.3, 0.3]).all(1) | np.isclose(T, [0.3, 0.4, 0.9]).all(1)
    both = np.isclose(T, [0.27, 0.12, 0.27]).all(1)
    assert full.sum() > 100 and one.sum() > 20 and both.sum() > 5, (full.sum(), one.sum(), both.sum())


@pytest.mark.parametrize("scene,change", [("lights.xml", {"fov": 45.2}), ("shadows.xml", {"eye": "0, 6, 8.02"}),
                                          ("mitsuba_direct.xml", "0.1% brighter")])
def test_oracle_rejects_a_slightly_wrong_image(scene, change):
    """The check can fail: the core's image of a slightly different view, or one 0.1 % too
    bright, is rejected; the right one passes."""
    from links1_app.renderers import make_renderer
    path = str(ROOT / "scenes" / scene)
    right = make_renderer("core", path, spp=1, params={"res": RES}).render()
    check_against_oracle(scene, right, 1)
    if isinstance(change, dict):
        wrong = make_renderer("core", path, spp=1, params={"res": RES, **change}).render()
    else:
        wrong = right * 1.001
    with pytest.raises(AssertionError, match="differ from the analytic oracle"):
        check_against_oracle(scene, wrong, 1)
