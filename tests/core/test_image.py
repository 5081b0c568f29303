"""links1.imaging.image: EXR / PNG round trips, sRGB, errors, atomic writes."""
from __future__ import annotations

import os
import sys

import numpy as np
import pytest

from links1.imaging import image
from links1.errors import UsageError


def codes(linear: np.ndarray) -> np.ndarray:
    """The 8-bit codes of an image :func:`links1.imaging.image.read_png` read: sRGB colour
    channels, linear alpha."""
    enc = image.linear_to_srgb(linear.astype(np.float64))
    if enc.shape[2] in (2, 4):
        enc[..., -1] = linear[..., -1]
    return np.rint(enc * 255).astype(np.uint8)


def test_srgb_transfer_known_values():
    lin = np.array([0.0, 0.0031308, 0.18, 0.5, 1.0])
    enc = image.linear_to_srgb(lin)
    expected = [0.0, 0.04044994, 0.46135612, 0.73535698, 1.0]
    np.testing.assert_allclose(enc, expected, atol=1e-7)
    np.testing.assert_allclose(image.srgb_to_linear(enc), lin, atol=1e-12)


def test_exr_round_trip_bit_exact_float32(tmp_path):
    rng = np.random.default_rng(1)
    a = (rng.standard_normal((7, 9, 3)) * 1e3).astype(np.float32)
    a[0, 0] = [np.inf, -0.0, 1e-38]
    image.write_exr(tmp_path / "a.exr", a)
    b, names = image.read_exr(tmp_path / "a.exr")
    assert names == ["R", "G", "B"]
    assert b.dtype == np.float32
    assert np.array_equal(b.view(np.uint32), a.view(np.uint32))


def test_exr_extra_channels_keep_names_and_order(tmp_path):
    rng = np.random.default_rng(2)
    names = ["R", "G", "B", "depth", "normal.X", "normal.Y", "normal.Z"]
    a = rng.random((5, 4, 7))  # float64 in, non-contiguous channel slices
    image.write_exr(tmp_path / "aov.exr", a, names)
    b, got = image.read_exr(tmp_path / "aov.exr")
    assert got == names
    assert np.array_equal(b, a.astype(np.float32))


def test_exr_needs_names_for_unusual_channel_counts(tmp_path):
    with pytest.raises(UsageError, match="channel_names"):
        image.write_exr(tmp_path / "x.exr", np.zeros((2, 2, 5)))
    with pytest.raises(UsageError, match="2 channel names"):
        image.write_exr(tmp_path / "x.exr", np.zeros((2, 2, 3)), ["R", "G"])


def test_png_srgb_round_trip_within_one_step(tmp_path):
    rng = np.random.default_rng(3)
    a = rng.random((16, 20, 3)) ** 2.2 * 1.2 - 0.05  # some values outside [0, 1]
    image.write_png(tmp_path / "a.png", a)
    b = image.read_image(tmp_path / "a.png")
    assert b.shape == a.shape and b.dtype == np.float32
    want = np.clip(image.linear_to_srgb(a), 0, 1)
    got = image.linear_to_srgb(b)
    assert np.abs(got - want).max() <= 0.5 / 255 + 1e-6  # rounding: half a step


def test_png_values_are_exact_srgb_codes(tmp_path):
    # linear 0.5 -> sRGB 0.7354 -> code 188; alpha stays linear: 0.5 -> 128
    image.write_png(tmp_path / "g.png", np.full((1, 1, 4), 0.5))
    assert codes(image.read_png(tmp_path / "g.png")).tolist() == [[[188, 188, 188, 128]]]


def test_builtin_png_decoder_matches_pillow_on_filtered_files(tmp_path, monkeypatch):
    PIL = pytest.importorskip("PIL.Image")
    rng = np.random.default_rng(4)
    smooth = np.cumsum(rng.integers(0, 3, (12, 17, 3)), axis=1).clip(0, 255).astype(np.uint8)
    PIL.fromarray(smooth).save(tmp_path / "f.png", optimize=True)  # adaptive filters
    monkeypatch.setitem(sys.modules, "PIL", None)  # read_png falls back to its own decoder
    assert np.array_equal(codes(image.read_png(tmp_path / "f.png")), smooth)


def test_read_image_errors_name_the_file(tmp_path):
    with pytest.raises(UsageError, match="missing.exr: no such file"):
        image.read_image(tmp_path / "missing.exr")
    (tmp_path / "junk.exr").write_bytes(b"not an exr")
    with pytest.raises(UsageError, match="junk.exr: not a valid EXR"):
        image.read_image(tmp_path / "junk.exr")
    (tmp_path / "pic.tif").write_bytes(b"II*\x00....")
    with pytest.raises(UsageError, match=r"pic.tif: unsupported image format '\.tif'"):
        image.read_image(tmp_path / "pic.tif")
    image.write_png(tmp_path / "ok.png", np.zeros((4, 4, 3)))
    bad = (tmp_path / "ok.png").read_bytes()[:40]
    (tmp_path / "cut.png").write_bytes(bad)
    with pytest.raises(UsageError, match="cut.png: cannot read PNG"):
        image.read_image(tmp_path / "cut.png")


def test_write_image_dispatches_by_extension(tmp_path):
    a = np.random.default_rng(5).random((3, 4, 5))
    image.write_image(tmp_path / "x.exr", a, ["R", "G", "B", "depth", "id"])
    assert image.read_exr(tmp_path / "x.exr")[1] == ["R", "G", "B", "depth", "id"]
    image.write_image(tmp_path / "x.png", a)  # colour channels only
    assert image.read_image(tmp_path / "x.png").shape == (3, 4, 3)
    with pytest.raises(UsageError, match="unsupported image format '.jpg'"):
        image.write_image(tmp_path / "x.jpg", a[:, :, :3])


@pytest.mark.parametrize("ext", ["exr", "png"])
def test_failed_write_leaves_old_file_and_no_temp(tmp_path, monkeypatch, ext):
    target = tmp_path / f"keep.{ext}"
    old = np.full((4, 4, 3), 0.25)
    image.write_image(target, old)
    before = target.read_bytes()

    def boom(src, dst):
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(image.os, "replace", boom)
    with pytest.raises(OSError, match="simulated"):
        image.write_image(target, np.ones((4, 4, 3)))
    assert target.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == [target.name]


def test_writer_exception_mid_write_cleans_up(tmp_path):
    target = tmp_path / "a.bin"
    target.write_bytes(b"old")

    def half_write(tmp):
        with open(tmp, "wb") as f:
            f.write(b"partial")
        raise RuntimeError("crash mid-write")

    with pytest.raises(RuntimeError):
        image.atomic_write(target, half_write)
    assert target.read_bytes() == b"old"
    assert os.listdir(tmp_path) == ["a.bin"]


def test_written_files_have_normal_permissions(tmp_path):
    image.write_png(tmp_path / "p.png", np.zeros((2, 2, 3)))
    umask = os.umask(0)
    os.umask(umask)
    assert (tmp_path / "p.png").stat().st_mode & 0o777 == 0o666 & ~umask
