"""Adaptive anti-aliasing wired into the core renderer, the CLI and the partitioning.

The refinement logic itself is tested on analytic images in test_adaptive.py; here a rendered
silhouette must be refined exactly where the corner rays of a pixel disagree (computed
independently, from the camera model of tests/core/oracle.py and a closed-form ray-sphere
test), a flat image not at all, and tiles, batches and worker processes must assemble the same
image bit for bit."""
from __future__ import annotations

import numpy as np
import pytest

from links1_app.cli import main
from links1.imaging.image import read_exr
from links1.tracing.render import render
from links1_app.renderers import make_renderer

from tests.scenes import perspective, scene

from . import oracle

W, H = 40, 30
SCENE = scene(perspective("0.3, 0.2, 5", "0, 0, 0", fov=40, width="{w}", height="{h}", spp=None), """
  <shape type="sphere"><float name="radius" value="{r}"/>
    <bsdf type="links1_phong"><rgb name="ambient" value="0.6, 0.4, 0.2"/><rgb name="diffuse" value="0"/></bsdf></shape>""")


@pytest.fixture
def disk(tmp_path):
    p = tmp_path / "disk.xml"
    p.write_text(SCENE.format(w=W, h=H, r=1.0))
    return str(p)


def corner_hits(path):
    """(H+1, W+1) bool: whether the camera ray through each pixel corner hits the unit sphere."""
    sc = oracle.Scene(path, {})
    X, Y = np.meshgrid(np.arange(W + 1.0), np.arange(H + 1.0))
    d = sc.rays_through(X, Y)
    b = d @ sc.eye
    return b * b - (sc.eye @ sc.eye - 1.0) > 0


def test_a_silhouette_is_refined_exactly_where_pixel_corners_disagree(disk):
    img = render(make_renderer("core", disk).scene, adaptive=0.01, adaptive_depth=2, aovs=("samples",))
    refined = img[..., 3] > 4
    c = corner_hits(disk)
    corners = np.stack([c[:-1, :-1], c[:-1, 1:], c[1:, :-1], c[1:, 1:]])
    expect = corners.any(0) & ~corners.all(0)
    assert expect.sum() > 40
    assert np.array_equal(refined, expect)
    # inside and outside the disk the colour is flat: 4 samples (the pixel's corners) only
    assert np.all(img[~expect, 3] == 4)
    # refined pixels carry the disk's coverage better than the pixel centre: values between
    # the two flat colours, and the sum over the image is close to the disk's area (eq. of a
    # projected sphere's area is not needed: compare with a 16x16-sample box render)
    ref = render(make_renderer("core", disk).scene, spp=256)[..., 0]
    adaptive_err = np.abs(img[..., 0] - ref)[expect].mean()
    centre_err = np.abs(render(make_renderer("core", disk).scene, spp=1)[..., 0] - ref)[expect].mean()
    assert adaptive_err < 0.5 * centre_err, (adaptive_err, centre_err)


def test_a_flat_image_is_not_refined(tmp_path):
    p = tmp_path / "flat.xml"
    p.write_text(SCENE.format(w=W, h=H, r=100.0).replace('origin="0.3, 0.2, 5"', 'origin="0.3, 0.2, 0"'))
    img = render(make_renderer("core", str(p)).scene, adaptive=0.0, adaptive_depth=3, aovs=("samples",))
    # the eye is inside a large sphere: every corner sees its flat ambient colour
    assert np.all(img[..., 3] == 4)
    np.testing.assert_array_equal(img[..., :3], np.broadcast_to([0.6, 0.4, 0.2], img[..., :3].shape))


@pytest.mark.slow
def test_windows_batches_and_workers_assemble_the_same_image(disk, tmp_path):
    r = make_renderer("core", disk, adaptive=0.02, adaptive_depth=3, aovs=("samples", "cost", "depth"))
    full = r.render()
    wins = [(0, 0, 17, 11), (17, 0, 23, 11), (0, 11, 40, 19), (13, 7, 5, 9)]
    for win, part in zip(wins, r.render_batch(wins)):
        x0, y0, w, h = win
        assert np.array_equal(part, full[y0:y0 + h, x0:x0 + w]), win
        assert np.array_equal(r.render(win), part)
    one, two = tmp_path / "one.exr", tmp_path / "two.exr"
    assert main(["render", disk, "--renderer", "core", "--adaptive", "0.02", "--adaptive-depth", "3",
                 "-o", str(one), "--no-progress", "--aov", "samples"]) == 0
    assert main(["render", disk, "--renderer", "core", "--adaptive", "0.02", "--adaptive-depth", "3",
                 "-o", str(two), "--no-progress", "--aov", "samples", "--workers", "2"]) == 0
    a, ca = read_exr(str(one))
    b, cb = read_exr(str(two))
    assert ca == cb == ["R", "G", "B", "samples.N"]
    assert np.array_equal(a, b)
    assert np.array_equal(a, full[..., :4].astype(np.float32))


@pytest.mark.parametrize("args,message", [
    (["--adaptive", "0.1", "--integrator", "scene"], "links1 integrator"),
    (["--renderer", "core", "--adaptive", "0.1", "--spp", "4"], "replaces --spp"),
    (["--renderer", "core", "--adaptive-depth", "2"], "needs --adaptive"),
    (["--renderer", "core", "--adaptive", "-1"], "threshold"),
    (["--renderer", "core", "--adaptive", "0.1", "--adaptive-depth", "9"], "depth"),
])
def test_bad_adaptive_options_are_one_line_errors(disk, tmp_path, capsys, args, message):
    out = tmp_path / "x.exr"
    assert main(["render", disk, "-o", str(out), "--no-progress", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("links1:") and message in err[0], err
    assert not out.exists()


@pytest.mark.slow
def test_the_films_filter_is_applied(tmp_path):
    """With a Gaussian film the adaptive image is the filtered one: close to a 256-spp render
    through the same filter, and much closer to it than to the box-filtered adaptive image;
    tiles and worker processes still assemble it bit for bit."""
    p = tmp_path / "g.xml"
    p.write_text(SCENE.format(w=W, h=H, r=1.0).replace('<rfilter type="box"/>', '<rfilter type="gaussian"/>'))
    box = tmp_path / "b.xml"
    box.write_text(SCENE.format(w=W, h=H, r=1.0))
    r = make_renderer("core", str(p), adaptive=0.01, adaptive_depth=3, aovs=("samples",))
    img = r.render()
    ref = render(make_renderer("core", str(p)).scene, spp=256)[..., :3]
    boxed = make_renderer("core", str(box), adaptive=0.01, adaptive_depth=3).render()[..., :3]

    def relmse(a, b):
        return float(np.mean((a - b) ** 2 / (b * b + 1e-2)))
    err, err_box = relmse(img[..., :3], ref), relmse(boxed, ref)
    assert err < 0.1 * err_box, (err, err_box)
    assert err < 1e-4, err
    for win, part in zip([(0, 0, 17, 11), (17, 0, 23, 11), (0, 11, 40, 19), (13, 7, 5, 9)],
                         r.render_batch([(0, 0, 17, 11), (17, 0, 23, 11), (0, 11, 40, 19), (13, 7, 5, 9)])):
        x0, y0, w, h = win
        assert np.array_equal(part, img[y0:y0 + h, x0:x0 + w]), win
    out = tmp_path / "two.exr"
    assert main(["render", str(p), "--renderer", "core", "--adaptive", "0.01", "--adaptive-depth", "3",
                 "-o", str(out), "--no-progress", "--aov", "samples", "--workers", "2"]) == 0
    assert np.array_equal(read_exr(str(out))[0], img.astype(np.float32))
