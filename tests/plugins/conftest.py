"""Fixtures for the Mitsuba plugin tests: skip with a clear reason when Mitsuba cannot run."""
from __future__ import annotations

import functools
import os

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "data")
ROOT = os.path.dirname(os.path.dirname(HERE))
SCENES = os.path.join(ROOT, "scenes")


@functools.lru_cache(maxsize=None)
def variant_problem(variant: str) -> str | None:
    """None if ``variant`` runs kernels here, else why not (probed in a subprocess)."""
    try:
        import mitsuba  # noqa: F401
        import drjit  # noqa: F401
    except Exception as exc:  # pragma: no cover - environment dependent
        return f"mitsuba/drjit cannot be imported: {exc}"
    import mitsuba as mi
    if variant not in mi.variants():
        return f"variant {variant} is not in this Mitsuba build"
    if variant.startswith("cuda") and not os.path.exists("/dev/nvidiactl"):
        return "no CUDA GPU on this machine"
    from links1_mitsuba import probe_variant
    return probe_variant(variant)


def _variant_param(v):
    marks = [pytest.mark.mitsuba]
    if v.startswith("cuda"):
        marks.append(pytest.mark.gpu)
    return pytest.param(v, marks=marks, id=v)


@pytest.fixture(params=[_variant_param("llvm_ad_rgb"), _variant_param("cuda_ad_rgb")])
def variant(request):
    """Each test runs on llvm_ad_rgb and, where a GPU exists, on cuda_ad_rgb (validation e)."""
    why = variant_problem(request.param)
    if why:
        pytest.skip(f"{request.param} unavailable: {why}")
    import links1_mitsuba
    return links1_mitsuba.register(request.param)


@pytest.fixture(scope="module")
def scalar_rgb():
    """Mitsuba's scalar_rgb variant (needs no LLVM), for tests that read what Mitsuba loads."""
    import mitsuba as mi
    try:
        mi.set_variant("scalar_rgb")
    except Exception as exc:  # pragma: no cover - depends on the wheel
        pytest.skip(f"mitsuba scalar_rgb unavailable: {exc}")
    return mi


@pytest.fixture
def llvm():
    why = variant_problem("llvm_ad_rgb")
    if why:
        pytest.skip(f"llvm_ad_rgb unavailable: {why}")
    import links1_mitsuba
    return links1_mitsuba.register("llvm_ad_rgb")


@pytest.fixture(params=["core", pytest.param("mitsuba", marks=pytest.mark.mitsuba)])
def renderer_kind(request):
    """Each renderer in turn: ``"core"``, then ``"mitsuba"`` (skipped where llvm_ad_rgb cannot run)."""
    if request.param == "mitsuba":
        request.getfixturevalue("llvm")
    return request.param


def data(name: str) -> str:
    return os.path.join(DATA, name)


def mitsuba_direct(path, spp: int, seed: int, **options):
    """Mitsuba's own ``direct`` integrator on the scene file ``path`` -> (h, w, 3) float64
    (``options``: ``make_renderer`` options such as ``params``, ``width``, ``height``)."""
    import mitsuba as mi
    import numpy as np

    from links1.render import make_renderer
    r = make_renderer("mitsuba", path, integrator="scene", spp=spp, **options)
    # the whole film of the chosen sensor (``options["sensor"]``), as the renderers' render()
    W, H = r.film_size
    prm = mi.traverse(r.sensor)
    prm["film.crop_offset"] = [0, 0]
    prm["film.crop_size"] = [W, H]
    prm.update()
    return np.array(mi.render(r.scene, integrator=mi.load_dict({"type": "direct"}), sensor=r.sensor, spp=spp,
                              seed=seed), dtype=np.float64)[..., :3]


def assert_matches_mitsuba_direct(kind, path, spp: int = 16, ref_factor: int = 16, **options):
    """``kind``'s render (max_depth 1: direct light) of ``path`` at ``spp`` is within 2x the
    relMSE of Mitsuba's ``direct`` at the same spp, both against Mitsuba's ``direct`` at
    ``ref_factor`` times the spp. Returns (ours, reference)."""
    import numpy as np

    from links1.diff import relmse
    from links1.render import make_renderer
    ref = mitsuba_direct(path, spp * ref_factor, seed=1, **options)
    theirs = relmse(mitsuba_direct(path, spp, seed=2, **options), ref)
    ours = np.asarray(make_renderer(kind, path, spp=spp, max_depth=1, **options).render(), dtype=np.float64)[..., :3]
    assert np.all(np.isfinite(ours))
    err = relmse(ours, ref)
    assert err <= 2 * theirs, f"{kind} {os.path.basename(str(path))}: relMSE {err:.3g} vs Mitsuba direct's own {theirs:.3g}"
    return ours, ref
