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


#: The Mitsuba variants the plugin suite runs on: every test that can run on both takes the
#: ``variant`` fixture (or ``renderer_kind`` / ``kind_with_mitsuba``, renderer x variant); the
#: cuda_ad_rgb cases skip at once where no GPU is (variant_problem). On a GPU machine,
#: ``python -m pytest tests/plugins -k cuda_ad_rgb`` runs exactly the CUDA cases (docs/guide.md).
VARIANTS = ("llvm_ad_rgb", "cuda_ad_rgb")


def variant_marks(v: str) -> list:
    """The marks of a test case on variant ``v``: ``mitsuba``, and ``gpu`` for a CUDA one."""
    return [pytest.mark.mitsuba] + ([pytest.mark.gpu] if v.startswith("cuda") else [])


def use_variant(v: str) -> str:
    """Register the links1 plugins for ``v`` and make it the active variant, or skip saying why
    ``v`` cannot run here (no GPU: at once, without starting a probe)."""
    why = variant_problem(v)
    if why:
        pytest.skip(f"{v} unavailable: {why}")
    import links1_mitsuba
    return links1_mitsuba.register(v)


def _variant_param(v):
    return pytest.param(v, marks=variant_marks(v), id=v)


@pytest.fixture(params=[_variant_param(v) for v in VARIANTS])
def variant(request):
    """Each test runs on llvm_ad_rgb and, where a GPU exists, on cuda_ad_rgb (validation e)."""
    return use_variant(request.param)


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
    """llvm_ad_rgb only, for a test that says why in its docstring: a path that exists on LLVM
    only (shadow_split's sub-scenes, host-mapped table alignment), or a test of the core whose
    reference is a Mitsuba render (no variant changes the core). Every other test that
    renders with Mitsuba takes ``variant`` (or ``renderer_kind`` / ``kind_with_mitsuba``)."""
    return use_variant("llvm_ad_rgb")


def _kind_params(core_marks):
    return [pytest.param(("core", "llvm_ad_rgb"), marks=core_marks, id="core")] + [
        pytest.param(("mitsuba", v), marks=variant_marks(v), id=f"mitsuba-{v}") for v in VARIANTS]


@pytest.fixture(params=_kind_params([]))
def renderer_kind(request):
    """Each renderer in turn: ``"core"``, then ``"mitsuba"`` on llvm_ad_rgb and on cuda_ad_rgb
    (each skipped where it cannot run; that variant is the active one). The core case needs
    no Mitsuba. A test that runs the command line passes ``cli_variant(kind)`` on to it."""
    kind, v = request.param
    if kind == "mitsuba":
        use_variant(v)
    return kind


@pytest.fixture(params=_kind_params([pytest.mark.mitsuba]))
def kind_with_mitsuba(request):
    """As ``renderer_kind``, for tests whose references are Mitsuba's own renders: the core case
    runs once, with llvm_ad_rgb active (the core does not depend on the variant), the
    ``"mitsuba"`` case on each variant."""
    kind, v = request.param
    use_variant(v)
    return kind


def cli_variant(kind: str) -> list[str]:
    """``--variant`` and the active variant for a ``links1 render --renderer mitsuba`` run (its
    worker processes would otherwise take the machine's default), nothing for the core."""
    if kind != "mitsuba":
        return []
    import mitsuba as mi
    return ["--variant", mi.variant()]


def data(name: str) -> str:
    return os.path.join(DATA, name)


#: mitsuba_direct's frames, by variant, scene file (path, size, modification time) and arguments
_DIRECT_FRAMES: dict = {}


def mitsuba_direct(path, spp: int, seed: int, **options):
    """Mitsuba's own ``direct`` integrator on the scene file ``path`` -> (h, w, 3) float64
    (``options``: ``make_renderer`` options such as ``params``, ``width``, ``height``). Rendered
    once per variant, file and arguments: the core's and the plugin's cases of a test compare
    with the same frames (a copy each)."""
    import mitsuba as mi

    st = os.stat(path)
    key = (mi.variant(), os.path.abspath(str(path)), st.st_size, st.st_mtime_ns, spp, seed, repr(sorted(options.items())))
    if key not in _DIRECT_FRAMES:
        _DIRECT_FRAMES[key] = _render_direct(path, spp, seed, **options)
    return _DIRECT_FRAMES[key].copy()


def _render_direct(path, spp: int, seed: int, **options):
    import mitsuba as mi
    import numpy as np

    from links1_app.renderers import make_renderer
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

    from links1.imaging.diff import relmse
    from links1_app.renderers import make_renderer
    ref = mitsuba_direct(path, spp * ref_factor, seed=1, **options)
    theirs = relmse(mitsuba_direct(path, spp, seed=2, **options), ref)
    ours = np.asarray(make_renderer(kind, path, spp=spp, max_depth=1, **options).render(), dtype=np.float64)[..., :3]
    assert np.all(np.isfinite(ours))
    err = relmse(ours, ref)
    assert err <= 2 * theirs, f"{kind} {os.path.basename(str(path))}: relMSE {err:.3g} vs Mitsuba direct's own {theirs:.3g}"
    return ours, ref


def render_direct(kind, path, spp: int):
    """``kind``'s render (max_depth 1: direct light) of ``path`` at ``spp`` -> (h, w, 3) float64,
    the core's warnings silenced (the default ``render`` of :func:`assert_both_match_mitsuba_direct`)."""
    import warnings

    import numpy as np

    from links1_app.renderers import make_renderer
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return np.asarray(make_renderer(kind, path, spp=spp, max_depth=1).render(), dtype=np.float64)[..., :3]


def assert_both_match_mitsuba_direct(path, spp: int, render=render_direct, ref_factor: int = 16,
                                     factor: float = 1.5):
    """The core's and the plugin's renders of ``path`` at ``spp`` (``render(kind, path, spp)``
    -> (h, w, 3), :func:`render_direct` by default) are each within ``factor`` times the relMSE of Mitsuba's ``direct`` at the same
    spp, all against Mitsuba's ``direct`` at ``ref_factor`` times the spp; and the core equals the
    plugin (relMSE <= 1e-4: the same samples)."""
    from links1.imaging.diff import relmse
    ref = mitsuba_direct(path, spp * ref_factor, seed=1)
    theirs = relmse(mitsuba_direct(path, spp, seed=2), ref)
    core, plugin = render("core", path, spp), render("mitsuba", path, spp)
    for kind, img in (("core", core), ("mitsuba", plugin)):
        err = relmse(img, ref)
        assert err <= factor * theirs, f"{kind}: relMSE {err:.3g} vs Mitsuba direct's own {theirs:.3g}"
    assert relmse(plugin, core) <= 1e-4
