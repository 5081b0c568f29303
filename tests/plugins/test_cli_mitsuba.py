"""`links1 render` with the default (Mitsuba) renderer: bad scenes are one-line errors, exit 2."""
from __future__ import annotations

import numpy as np
import pytest

from links1_app.cli import main

from .conftest import cli_variant

# every test on each variant (conftest.py): the command line and the plugins render on the
# active one
pytestmark = [pytest.mark.mitsuba, pytest.mark.usefixtures("variant")]


@pytest.mark.parametrize("body,needle", [
    ("<shape type='nosuch'/>", "nosuch"),
    ("<shape type='sphere'><float name='radius' value='-1'/></shape>", "radius"),
    ("<shape type='links1_blob'><string name='centers' value='0 0 0 1'/><float name='threshold' value='0.5'/></shape>",
     "centers"),
    ("<bsdf type='links1_phong' id='x'><float name='ior' value='-1'/></bsdf><shape type='sphere'><ref id='x'/></shape>",
     "ior"),
    ("<shape type='sphere'/>", "no sensor"),
])
def test_bad_scene_one_line_exit_2(tmp_path, capsys, body, needle):
    scene = tmp_path / "bad.xml"
    scene.write_text(f"<scene version='3.0.0'>\n{body}\n</scene>\n")
    out = tmp_path / "out.png"
    out.write_bytes(b"earlier")
    rc = main(["render", str(scene), "--renderer", "mitsuba", "--workers", "0", "-o", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    errors = [ln for ln in err if ln.startswith("links1: error:")]
    assert len(errors) == 1 and needle in errors[0] and "bad.xml" in errors[0]
    assert out.read_bytes() == b"earlier"


def test_scene_without_integrator_renders(tmp_path):
    """A file that names no integrator gets links1_whitted (the loader adds the node)."""
    from links1.imaging.image import read_exr
    scene = tmp_path / "ok.xml"
    scene.write_text("<scene version='3.0.0'><sensor type='perspective'><film type='hdrfilm'>"
                     "<integer name='width' value='8'/><integer name='height' value='6'/></film></sensor>"
                     "<shape type='sphere'><point name='center' x='0' y='0' z='5'/></shape>"
                     "<emitter type='point'><point name='position' x='0' y='0' z='0'/></emitter></scene>")
    out = tmp_path / "ok.exr"
    assert main(["render", str(scene), "--renderer", "mitsuba", "--workers", "0", "-o", str(out)]) == 0
    img, _ = read_exr(str(out))
    assert img.shape[:2] == (6, 8) and img[3, 4, 0] > 0


def _no_integrator_scene(tmp_path, integrator=""):
    scene = tmp_path / f"noint{len(integrator)}.xml"
    scene.write_text(
        "<scene version='3.0.0'>\n" + integrator +
        "<sensor type='perspective'><float name='fov' value='40'/><film type='hdrfilm'>"
        "<integer name='width' value='12'/><integer name='height' value='10'/></film>"
        "<sampler type='independent'><integer name='sample_count' value='4'/></sampler></sensor>\n"
        "<shape type='sphere'><point name='center' x='0' y='0' z='5'/>"
        "<bsdf type='diffuse'><spectrum name='reflectance' value='500:0, 540:1, 545:0'/></bsdf></shape>\n"
        "<emitter type='point'><point name='position' x='0' y='1' z='0'/></emitter></scene>\n")
    return scene


@pytest.mark.slow
def test_integrator_scene_without_integrator_uses_path(tmp_path):
    """--integrator scene on a file without <integrator>: Mitsuba 3.9.1's mi.render refuses
    ('No integrator specified!'); links1 renders it with Mitsuba's 'path' (Mitsuba 2's
    default), says so in one warning line, and gets the same image as an explicit <path>."""
    import subprocess
    import sys

    from links1.imaging.image import read_exr
    imgs, errs = [], []
    for integ in ("", "<integrator type='path'/>\n"):
        scene = _no_integrator_scene(tmp_path, integ)
        out = tmp_path / f"o{len(integ)}.exr"
        res = subprocess.run([sys.executable, "-m", "links1_app.cli", "render", str(scene), "--renderer", "mitsuba",
                              "--integrator", "scene", "--workers", "0", "--no-progress", "-o", str(out),
                              *cli_variant("mitsuba")],
                             capture_output=True, text=True, timeout=300)
        assert res.returncode == 0, res.stderr
        assert all(ln.startswith("links1: ") for ln in res.stderr.splitlines()), res.stderr
        imgs.append(read_exr(str(out))[0])
        errs.append(res.stderr)
    assert f"links1: warning: {tmp_path / 'noint0.xml'}:1: <scene>: the scene names no integrator" in errs[0]
    assert "names no integrator" not in errs[1]
    # Mitsuba's own log warning (the clamped spectrum) is one links1 line too
    assert "links1: warning: mitsuba: Spectrum: clamping out-of-gamut color" in errs[0]
    assert imgs[0].max() > 0
    # the same integrator and seed; Mitsuba's film accumulates samples with threaded atomic
    # adds, so the order of float additions (not the light paths) may differ between runs
    np.testing.assert_allclose(imgs[0], imgs[1], rtol=1e-5, atol=1e-7)


def _render_both(tmp_path, body):
    """Render ``body`` (a 12x10 camera added) with both renderers through the CLI, in
    subprocesses -> ({renderer: image}, {renderer: stderr})."""
    import subprocess
    import sys

    from links1.imaging.image import read_exr
    scene = tmp_path / "s.xml"
    scene.write_text(
        "<scene version='3.0.0'>\n<sensor type='perspective'><float name='fov' value='40'/><film type='hdrfilm'>"
        "<integer name='width' value='12'/><integer name='height' value='10'/><rfilter type='box'/></film></sensor>\n"
        + body + "</scene>\n")
    imgs, errs = {}, {}
    for r in ("core", "mitsuba"):
        out = tmp_path / f"{r}.exr"
        res = subprocess.run([sys.executable, "-m", "links1_app.cli", "render", str(scene), "--renderer", r,
                              "--workers", "0", "--no-progress", "-o", str(out), *cli_variant(r)],
                             capture_output=True, text=True, timeout=300)
        assert res.returncode == 0, res.stderr
        imgs[r], errs[r] = read_exr(str(out))[0], res.stderr
    return imgs, errs


@pytest.mark.slow
def test_blackbody_emitter_same_colour_in_both_renderers(tmp_path):
    """Mitsuba's RGB variants cannot evaluate a blackbody; both renderers use the colour its
    spectral variants integrate to (links1.shading.spectra), each saying so in one warning line."""
    imgs, errs = _render_both(tmp_path, (
        "<shape type='sphere'><point name='center' x='0' y='0' z='5'/></shape>\n"
        "<emitter type='point'><point name='position' x='0' y='1' z='0'/>\n"
        "<spectrum name='intensity' type='blackbody'><float name='temperature' value='3500'/></spectrum>"
        "</emitter>\n"))
    for err in errs.values():
        warns = [ln for ln in err.splitlines() if "blackbody (3500 K)" in ln]
        assert len(warns) == 1 and warns[0].startswith("links1: warning: "), err
    assert imgs["core"].max() > 0 and imgs["core"][..., 0].max() > imgs["core"][..., 2].max()
    np.testing.assert_allclose(imgs["mitsuba"], imgs["core"], rtol=1e-4, atol=1e-6)


@pytest.mark.slow
def test_spectra_on_links1_plugins_same_in_both_renderers(tmp_path):
    """links1_point, links1_spot and links1_phong read <spectrum> as Mitsuba's RGB variants
    (emitters unweighted, the Phong colours as reflectances) in the plugin as in the core."""
    imgs, _ = _render_both(tmp_path, (
        "<emitter type='links1_point'><point name='position' x='0' y='1' z='0'/>"
        "<spectrum name='L1' value='400:10, 700:20'/></emitter>\n"
        "<emitter type='links1_spot'><point name='origin' x='0' y='0' z='0'/><vector name='direction' x='0' "
        "y='0' z='1'/><float name='radius' value='0.3'/><spectrum name='intensity' value='0.5'/></emitter>\n"
        "<shape type='sphere'><point name='center' x='0' y='0' z='5'/><bsdf type='links1_phong'>"
        "<spectrum name='diffuse' value='400:0.2, 550:0.3, 700:0.8'/></bsdf></shape>\n"))
    assert imgs["core"].max() > 0 and imgs["core"][..., 0].max() > imgs["core"][..., 2].max()
    np.testing.assert_allclose(imgs["mitsuba"], imgs["core"], rtol=1e-4, atol=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize("integ", ["links1", "scene"])
def test_scene_parameter_named_integrator(tmp_path, integ):
    """Mitsuba's own scenes declare <default name="integrator">; -D integrator=... fills it
    (it once collided with load_file's integrator keyword: an internal error)."""
    from links1.imaging.image import read_exr
    head = "<default name='integrator' value='path'/><integrator type='$integrator'/>\n"
    scene = _no_integrator_scene(tmp_path, head)
    outs = {}
    for name in ("direct", "path"):
        out = tmp_path / f"{name}.exr"
        assert main(["render", str(scene), "--integrator", integ, "-D", f"integrator={name}", "--workers", "0",
                     "--no-progress", "-o", str(out)]) == 0
        outs[name] = read_exr(str(out))[0]
    assert outs["direct"].max() > 0
    if integ == "links1":  # links1_whitted whatever the file names: the parameter changes nothing
        np.testing.assert_array_equal(outs["direct"], outs["path"])
