"""links1.imaging.diff (metrics against hand-computed values, shape checks, heatmap) and its
command line, links1_app.diff."""
from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from links1.imaging import diff
from links1.errors import UsageError
from links1.imaging.image import write_exr, write_png
from links1_app import diff as diff_cli

# a = test, b = reference; differences d = a - b = [0.1, -0.2, 0, 0.3]
A = np.array([[[1.1], [0.3]], [[0.0], [0.8]]])
B = np.array([[[1.0], [0.5]], [[0.0], [0.5]]])


def test_rmse():
    assert diff.rmse(A, B) == pytest.approx(math.sqrt((0.01 + 0.04 + 0 + 0.09) / 4))


def test_relmse():
    expected = (0.01 / 1.01 + 0.04 / 0.26 + 0.0 / 0.01 + 0.09 / 0.26) / 4
    assert diff.relmse(A, B) == pytest.approx(expected)


def test_mae_and_max():
    assert diff.mae(A, B) == pytest.approx(0.6 / 4)
    assert diff.max_error(A, B) == pytest.approx(0.3)


def test_psnr_peak_conventions():
    mse = 0.14 / 4
    assert diff.psnr(A, B) == pytest.approx(10 * math.log10(1.0 / mse))  # max(B) = 1
    assert diff.psnr(2 * A, 2 * B) == pytest.approx(10 * math.log10(4.0 / (4 * mse)))
    assert diff.psnr(A, B, peak=1.0) == pytest.approx(10 * math.log10(1.0 / mse))
    assert diff.psnr(B, B) == math.inf


def test_identical_images_score_zero():
    for m in ("rmse", "relmse", "mae", "max"):
        assert diff.compare(B, B, m) == 0.0


def test_nan_fails_every_threshold():
    a = A.copy()
    a[0, 0, 0] = np.nan
    assert math.isnan(diff.rmse(a, B)) and math.isnan(diff.max_error(a, B))
    assert diff.exceeds("rmse", math.nan, 1.0) and diff.exceeds("psnr", math.nan, 1.0)
    assert diff.exceeds("psnr", 20.0, 30.0) and not diff.exceeds("psnr", 40.0, 30.0)


@pytest.mark.slow
def test_flip_zero_for_equal_and_positive_for_different():
    pytest.importorskip("flip_evaluator")
    rng = np.random.default_rng(0)
    ref = rng.random((24, 24, 3))
    assert diff.flip(ref, ref, ldr=True) == pytest.approx(0.0, abs=1e-6)
    assert diff.flip(np.clip(ref + 0.2, 0, 1), ref, ldr=True) > 0.05
    assert diff.flip(ref * 4 + 0.5, ref * 4, ldr=False) > 0.0
    assert diff.flip(ref[:, :, :1], ref[:, :, :1]) == pytest.approx(0.0, abs=1e-6)  # grey


def test_size_and_channel_mismatch_messages(tmp_path):
    write_exr(tmp_path / "a.exr", np.zeros((48, 64, 3)))
    write_png(tmp_path / "b.png", np.zeros((32, 32, 3)))
    with pytest.raises(UsageError, match=r"size mismatch: .*a\.exr is 64x48, .*b\.png is 32x32"):
        diff.compare(tmp_path / "a.exr", tmp_path / "b.png", "rmse")
    with pytest.raises(UsageError, match="channel mismatch: a has 3 channels, b has 1"):
        diff.compare(np.zeros((2, 2, 3)), np.zeros((2, 2)), "rmse")
    with pytest.raises(UsageError, match="unknown metric"):
        diff.compare(B, B, "ssim")


def test_png_inputs_use_ldr_peak(tmp_path):
    # both PNG -> peak 1 even though the reference's maximum is 0.5
    write_png(tmp_path / "a.png", np.full((4, 4, 3), 0.25))
    write_png(tmp_path / "b.png", np.full((4, 4, 3), 0.5))
    v = diff.compare(tmp_path / "a.png", tmp_path / "b.png", "psnr")
    from links1.imaging.image import read_image
    a, b = read_image(tmp_path / "a.png"), read_image(tmp_path / "b.png")
    assert v == pytest.approx(diff.psnr(a, b, peak=1.0))


@pytest.mark.slow
def test_heatmap_writes_png(tmp_path):
    rng = np.random.default_rng(1)
    a, b = rng.random((20, 30, 3)), rng.random((20, 30, 3))
    e = diff.heatmap(a, b, tmp_path / "h.png")
    assert e.shape == (20, 30)
    np.testing.assert_allclose(e, np.abs(a - b).mean(axis=2))
    assert (tmp_path / "h.png").read_bytes()[:4] == b"\x89PNG"


# --------------------------------------------------------------------------- CLI -------

def _run(argv, capsys):
    parser = argparse.ArgumentParser(prog="links1")
    diff_cli.add_cli(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["diff", *map(str, argv)])
    assert args.func is diff_cli.run_cli
    rc = diff_cli.run_cli(args)
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.fixture
def pair(tmp_path):
    rng = np.random.default_rng(2)
    a = rng.random((12, 16, 3))
    write_exr(tmp_path / "ref.exr", a)
    write_exr(tmp_path / "test.exr", a * 1.01)
    return tmp_path / "test.exr", tmp_path / "ref.exr"


def test_cli_exit_0_below_threshold_and_table(pair, capsys):
    rc, out, _ = _run([*pair, "--metric", "rmse", "--threshold", "0.1", "--no-flip"], capsys)
    assert rc == 0
    for m in ("rmse", "relmse", "mae", "max", "psnr"):
        assert m in out
    assert "ok: rmse" in out


def test_cli_exit_1_above_threshold_with_heatmap(pair, capsys, tmp_path):
    rc, out, _ = _run([*pair, "--threshold", "1e-9", "--heatmap", tmp_path / "h.png",
                       "--no-flip"], capsys)
    assert rc == 1 and "FAIL: relmse" in out
    assert (tmp_path / "h.png").exists()


def test_cli_psnr_fails_below_threshold(pair, capsys):
    assert _run([*pair, "--metric", "psnr", "--threshold", "80", "--no-flip"], capsys)[0] == 1
    assert _run([*pair, "--metric", "psnr", "--threshold", "20", "--no-flip"], capsys)[0] == 0


def test_cli_exit_2_bad_input_one_line(pair, capsys, tmp_path):
    rc, out, err = _run([pair[0], tmp_path / "nope.exr"], capsys)
    assert rc == 2 and out == ""
    assert err.count("\n") == 1 and "nope.exr: no such file" in err
    write_png(tmp_path / "small.png", np.zeros((2, 2, 3)))
    rc, _, err = _run([pair[0], tmp_path / "small.png"], capsys)
    assert rc == 2 and "size mismatch" in err


def test_cli_json(pair, capsys):
    rc, out, _ = _run([*pair, "--json", "--metric", "max", "--threshold", "1"], capsys)
    assert rc == 0
    doc = json.loads(out)
    assert doc["metric"] == "max" and doc["passed"] is True
    assert doc["width"] == 16 and doc["height"] == 12 and doc["channels"] == 3
    assert set(doc["metrics"]) >= {"rmse", "relmse", "mae", "max", "psnr"}
    assert doc["value"] == pytest.approx(doc["metrics"]["max"])


def test_cli_json_infinite_psnr_is_a_string(tmp_path, capsys):
    write_exr(tmp_path / "a.exr", np.ones((2, 2, 3)))
    rc, out, _ = _run([tmp_path / "a.exr", tmp_path / "a.exr", "--json", "--no-flip"], capsys)
    assert rc == 0 and json.loads(out)["metrics"]["psnr"] == "inf"


def test_cli_subprocess(pair):
    cmd = [sys.executable, "-m", "links1_app.diff", *map(str, pair), "--threshold", "1e-9",
           "--no-flip"]
    root = Path(__file__).resolve().parents[2]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=root, timeout=60)
    assert proc.returncode == 1, proc.stderr
    assert "FAIL" in proc.stdout
