"""Every committed scene renders to the same bits as before the restructuring and 24.

The digests in ``data/image_digests.json`` were taken from images rendered at commit d1e62a4,
before the plugin's parts became module classes, before the core's one
dependency direction and its subpackages and before the film of a batch
became one kernel: every ``scenes/*.xml`` at 48x40, spp 2, with the ``depth``,
``normal`` and ``cost`` AOVs, by the core and by the Mitsuba plugin (and by the plugin as a
batch of two windows, which must equal the full frame); a scene added since has the digests of
the commit that added it, and an image changed on purpose since says by which commit and in which
channels (``changed_since`` in the file). A digest is the SHA-256 of the image
rounded to float32 (the precision of a written EXR), so a float64 difference of an ulp in the
core passes only where it cannot change a stored pixel.

The core computes in float64 numpy, the same bits on any x86-64 machine. The plugin's kernels
are compiled by LLVM for the machine's vector unit, and approximate instructions differ between
them (``rsqrt14`` on AVX-512 against ``rsqrtps`` on AVX2), so its digests are compared on a
machine with the same vector unit as the one that made them and skipped, saying so, elsewhere
(the plugin-against-core tests bound the difference there).

``python -m tests.plugins.test_image_identity OUT.json`` writes new digests (after an intended
change of the images, and only then).
"""
from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
DIGESTS = Path(__file__).with_name("data") / "image_digests.json"
SIZE, SPP, AOVS = (48, 40), 2, ("depth", "normal", "cost")
#: the batch of two windows the plugin renders besides the full frame
BATCH = [(0, 0, 17, 40), (17, 0, 31, 40)]


def digest(image) -> str:
    a = np.ascontiguousarray(np.asarray(image, dtype=np.float64).astype(np.float32))
    return hashlib.sha256(repr(a.shape).encode() + a.tobytes()).hexdigest()


def vector_unit() -> str:
    """``avx512f`` or ``avx2`` (or the machine type): what the plugin's kernels are compiled for."""
    try:
        flags = set(Path("/proc/cpuinfo").read_text().split())
    except OSError:
        flags = set()
    for f in ("avx512f", "avx2"):
        if f in flags:
            return f
    import platform
    return platform.machine()


def render(scene: str, kind: str) -> dict:
    """The images of one scene by one renderer, by name (see the module docstring)."""
    from links1_app import make_renderer
    r = make_renderer(kind, str(ROOT / "scenes" / scene), spp=SPP, width=SIZE[0], height=SIZE[1],
                      aovs=AOVS)
    name = Path(scene).stem
    out = {f"{name}/{kind}": r.render()}
    if kind == "mitsuba":
        out[f"{name}/{kind}/batch"] = np.concatenate(r.render_batch(BATCH), axis=1)
    return out


SCENES = sorted(p.name for p in (ROOT / "scenes").glob("*.xml"))


def _stored() -> dict:
    return json.loads(DIGESTS.read_text())


def test_digests_cover_every_scene():
    """A scene added to scenes/ gets digests too (or this test names it)."""
    stored = _stored()["images"]
    missing = [s for s in SCENES for k in ("core", "mitsuba") if f"{Path(s).stem}/{k}" not in stored]
    assert not missing, f"no digest for {missing}: write them with python -m tests.plugins.test_image_identity"


@pytest.mark.slow
@pytest.mark.parametrize("scene", SCENES)
def test_core_images_unchanged(scene):
    stored = _stored()["images"]
    for name, img in render(scene, "core").items():
        assert digest(img) == stored[name], f"{name} differs from the image rendered at {_stored()['commit']}"


@pytest.mark.slow
@pytest.mark.parametrize("scene", SCENES)
def test_plugin_images_unchanged(scene, llvm):
    """LLVM only: the digests were made by the LLVM backend (a CUDA image differs by float32
    roundings the plugin-against-core tests bound)."""
    made_on = _stored()["vector_unit"]
    if vector_unit() != made_on:
        pytest.skip(f"digests made on {made_on}, this machine has {vector_unit()}: LLVM kernels differ by an ulp")
    stored = _stored()["images"]
    for name, img in render(scene, "mitsuba").items():
        assert digest(img) == stored[name], f"{name} differs from the image rendered at {_stored()['commit']}"


def write(out: Path, images: dict | None = None, commit: str = "") -> None:
    """Digests of every scene's images (``images``: name -> array, e.g. loaded from an npz)."""
    if images is None:
        import mitsuba as mi
        mi.set_variant("llvm_ad_rgb")
        images = {}
        for s in SCENES:
            for kind in ("core", "mitsuba"):
                images.update(render(s, kind))
    out.write_text(json.dumps({"commit": commit, "vector_unit": vector_unit(), "size": SIZE, "spp": SPP,
                               "aovs": AOVS, "images": {k: digest(v) for k, v in sorted(images.items())}},
                              indent=1) + "\n")


if __name__ == "__main__":
    write(Path(sys.argv[1]), commit=sys.argv[2] if len(sys.argv) > 2 else "")
