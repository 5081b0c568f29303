"""Which Mitsuba variants the links1 plugins run on: the RGB JIT variants
render; scalar, spectral and mono variants are refused with one line naming what works, from
``links1 render --variant`` (exit 2, no output) and from the Python API (``register``,
``load_file``) alike, instead of an internal error deep in a frozen launch."""
from __future__ import annotations

import numpy as np
import pytest

from links1_app.cli import main

from .conftest import SCENES, variant_problem

pytestmark = pytest.mark.mitsuba
SCENE = f"{SCENES}/mitsuba_direct.xml"
REFUSED = ["scalar_rgb", "scalar_spectral", "llvm_ad_mono", "llvm_ad_spectral", "llvm_ad_spectral_polarized",
           "cuda_ad_mono", "cuda_ad_spectral"]


@pytest.fixture
def keep_variant():
    """Put back the variant a test changes (the process's other tests render on it)."""
    import mitsuba as mi
    before = mi.variant()
    yield
    if before is not None:
        mi.set_variant(before)


@pytest.mark.parametrize("v", REFUSED)
def test_cli_refuses_non_rgb_and_scalar_variants(tmp_path, capsys, v, keep_variant):
    out = tmp_path / "out.exr"
    assert main(["render", SCENE, "-o", str(out), "--variant", v, "--width", "16", "--height", "16",
                 "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    line = err[0]
    assert line.startswith("links1: error:") and "internal error" not in line
    assert v in line and "llvm_ad_rgb" in line and "cuda_ad_rgb" in line and "--renderer core" in line
    assert ("spectral" if "spectral" in v else "monochrome" if "mono" in v else "JIT") in line
    assert not out.exists()


def test_cli_unknown_variant(tmp_path, capsys, keep_variant):
    assert main(["render", SCENE, "-o", str(tmp_path / "o.exr"), "--variant", "llvm_rgb_typo"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown Mitsuba variant 'llvm_rgb_typo'" in err[0] and "llvm_ad_rgb" in err[0]


@pytest.mark.parametrize("v", ["llvm_ad_rgb", pytest.param("cuda_ad_rgb", marks=pytest.mark.gpu)])
def test_cli_rgb_variants_render(tmp_path, v):
    """Every RGB JIT variant Mitsuba ships renders (cuda_ad_rgb where a GPU is), and gives the
    core's image (the plugin-vs-core criterion, relMSE <= 1e-5)."""
    why = variant_problem(v)
    if why:
        pytest.skip(f"{v} unavailable: {why}")
    from links1.imaging.diff import relmse
    from links1.imaging.image import read_image
    out, core = tmp_path / "m.exr", tmp_path / "c.exr"
    common = [SCENE, "--width", "24", "--height", "24", "--spp", "4", "--no-progress"]
    assert main(["render", *common, "-o", str(out), "--variant", v]) == 0
    assert main(["render", *common, "-o", str(core), "--renderer", "core"]) == 0
    a, b = np.asarray(read_image(str(out))), np.asarray(read_image(str(core)))
    assert a.shape == (24, 24, 3) and a.max() > 0 and relmse(a, b) <= 1e-5


@pytest.mark.parametrize("v", ["llvm_ad_spectral", "llvm_ad_mono", "scalar_rgb"])
def test_python_api_refuses_the_variant(v, keep_variant):
    """``register(v)``, ``register()`` under ``mi.set_variant(v)`` and ``load_file(..., variant=v)``
    (what ``mi.render`` with links1_whitted needs first) raise one clear ValueError."""
    import mitsuba as mi

    import links1_mitsuba
    for call in (lambda: links1_mitsuba.register(v),
                 lambda: (mi.set_variant(v), links1_mitsuba.register()),
                 lambda: links1_mitsuba.load_file(SCENE, variant=v)):
        with pytest.raises(ValueError) as exc:
            call()
        msg = str(exc.value)
        assert "\n" not in msg and v in msg and "llvm_ad_rgb" in msg and "cuda_ad_rgb" in msg
    assert links1_mitsuba.unsupported_variant("llvm_ad_rgb") is None
    assert links1_mitsuba.unsupported_variant("cuda_ad_rgb") is None
