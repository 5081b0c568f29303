"""links1_app.pytest_plugin: the links1_baseline fixture, run in throw-away test sessions."""
from __future__ import annotations

import re
from importlib.metadata import entry_points
from pathlib import Path

import numpy as np
import pytest

from links1_app.pytest_plugin import sidak_alpha, student_t_sf2, welch_t_test

pytest_plugins = ["pytester"]

# The plugin is normally loaded by its entry point; load it by name if the package's
# entry point is not installed (e.g. running from a plain checkout).
_ENTRY = any(e.value == "links1_app.pytest_plugin" for e in entry_points(group="pytest11"))
PLUGIN_ARGS = [] if _ENTRY else ["-p", "links1_app.pytest_plugin"]

TESTS = '''
import numpy as np

def image(scale=1.0):
    y, x = np.mgrid[0:16, 0:24]
    return scale * np.stack([x / 24, y / 16, (x + y) / 40], axis=-1)

def test_same(links1_baseline):
    links1_baseline.check("gradient", image())

def test_changed(links1_baseline):
    links1_baseline.check("gradient", lambda: image(1.2), metric="rmse", threshold=1e-3)

def test_noise(links1_baseline):
    rng = np.random.default_rng(SEED)
    samples = 0.5 + SHIFT + 0.1 * rng.standard_normal((16, 8, 10, 3))
    links1_baseline.check_statistical("noise", samples)
'''


def _write(pytester, seed=0, shift=0.0):
    pytester.makepyfile(test_images=TESTS.replace("SEED", str(seed)).replace("SHIFT", str(shift)))


def _run(pytester, *args):
    # (hypothesis's plugin is blocked only to keep these nested sessions fast; a nested session
    # in this process marks the plugin's distribution for assertion rewriting again, and pytest
    # warns that links1 and links1_app, imported by this session, cannot be rewritten: not the
    # plugin's warnings, which these tests count)
    return pytester.runpytest(*PLUGIN_ARGS, "-p", "no:cacheprovider", "-p", "no:hypothesispytest",
                              "-W", "ignore::pytest.PytestAssertRewriteWarning", *args)


def test_update_creates_baselines_then_passes(pytester):
    _write(pytester)
    res = _run(pytester, "--links1-update-baselines", "-k", "not changed")
    res.assert_outcomes(passed=2)
    base = pytester.path / "baselines"
    assert (base / "gradient.exr").exists() and (base / "noise.exr").exists()
    res.stdout.fnmatch_lines(["*links1 baselines written*"])
    res = _run(pytester, "-k", "same or noise")
    res.assert_outcomes(passed=2)


def test_missing_baseline_tells_how_to_create_it(pytester):
    _write(pytester)
    res = _run(pytester, "-k", "same")
    res.assert_outcomes(failed=1)
    res.stdout.fnmatch_lines(["*no baseline*gradient.exr*--links1-update-baselines*"])


@pytest.mark.slow
def test_failure_writes_and_names_four_report_files(pytester):
    _write(pytester)
    _run(pytester, "--links1-update-baselines", "-k", "same").assert_outcomes(passed=1)
    report = pytester.path / "rep"
    res = _run(pytester, "-k", "changed", "--links1-report-dir", str(report))
    res.assert_outcomes(failed=1)
    out = res.stdout.str()
    assert re.search(r"rmse = [0-9.e-]+ > threshold 0.001", out)
    files = sorted(p.name for p in report.rglob("*") if p.is_file())
    assert files == ["gradient.baseline.exr", "gradient.diff.exr", "gradient.exr",
                     "gradient.heatmap.png"]
    for f in report.rglob("*.*"):
        assert str(f) in out


def test_two_checks_writing_one_baseline_warn(pytester):
    _write(pytester)
    res = _run(pytester, "--links1-update-baselines", "-k", "same or changed")
    res.assert_outcomes(passed=2, warnings=1)
    res.stdout.fnmatch_lines(["*gradient.exr written twice*"])


def test_baseline_dir_from_ini_and_command_line(pytester):
    _write(pytester)
    pytester.makeini("[pytest]\nlinks1_baseline_dir = golden\n")
    _run(pytester, "-k", "same", "--links1-update-baselines").assert_outcomes(passed=1)
    _run(pytester, "-k", "same").assert_outcomes(passed=1)
    assert (pytester.path / "golden" / "gradient.exr").exists()
    _run(pytester, "-k", "same", "--links1-update-baselines",
         "--links1-baseline-dir", "other").assert_outcomes(passed=1)
    assert (pytester.path / "other" / "gradient.exr").exists()


def test_statistical_passes_for_independent_noise_with_same_mean(pytester):
    _write(pytester, seed=1)
    _run(pytester, "-k", "noise", "--links1-update-baselines").assert_outcomes(passed=1)
    _write(pytester, seed=2)
    _run(pytester, "-k", "noise").assert_outcomes(passed=1)


@pytest.mark.slow
def test_statistical_fails_for_shifted_mean_and_writes_pvalues(pytester):
    _write(pytester, seed=1)
    _run(pytester, "-k", "noise", "--links1-update-baselines").assert_outcomes(passed=1)
    _write(pytester, seed=2, shift=0.1)
    res = _run(pytester, "-k", "noise")
    res.assert_outcomes(failed=1)
    res.stdout.fnmatch_lines(["*Welch t-test*pixels have p <*"])
    assert list((pytester.path / "links1-report").rglob("noise.pvalue.exr"))


def test_check_scene_with_callable_renderer(pytester):
    pytester.makefile(".xml", scene="<scene version='3.0.0'/>")
    pytester.makepyfile(test_scene='''
import numpy as np
def fake(path, spp, seed):
    assert path.endswith("scene.xml")
    rng = np.random.default_rng(seed)
    return 0.3 + 0.05 * rng.standard_normal((6, 5, 3))

def test_exact(links1_baseline):
    links1_baseline.check_scene("scene.xml", renderer=fake, spp=4, threshold=1.0)

def test_stat(links1_baseline):
    links1_baseline.check_scene("scene.xml", renderer=fake, spp=4, statistical=True,
                                runs=6, name="scene_stat")
''')
    _run(pytester, "--links1-update-baselines").assert_outcomes(passed=2)
    assert (pytester.path / "baselines" / "scene_spp4.exr").exists()
    _run(pytester).assert_outcomes(passed=2)


# ------------------------------------------------------------------ statistics ---------

def test_student_t_two_sided_p_values():
    t = np.array([0.0, 0.5, 1.0, 3.0, 30.0])
    np.testing.assert_allclose(student_t_sf2(t, 2.0), 1 - t / np.sqrt(t * t + 2), atol=1e-12)
    assert student_t_sf2(1.0, 1.0) == pytest.approx(0.5)             # Cauchy
    assert student_t_sf2(2.228138851986, 10.0) == pytest.approx(0.05, rel=1e-9)


def test_welch_degenerate_variances():
    p = welch_t_test([1.0, 1.0], [0.0, 0.0], 4, [1.0, 2.0], [0.0, 0.0], 4)
    assert p.tolist() == [1.0, 0.0]


def test_sidak_level():
    assert sidak_alpha(0.01, 1) == pytest.approx(0.01)
    assert sidak_alpha(0.01, 1000) == pytest.approx(1 - 0.99 ** (1 / 1000))


# ------------------------------------------------ unchanged reruns pass -----------------

CONSTANTS = '''
import numpy as np
import pytest

DTYPE = np.__DTYPE__
LARGE = {np.float16: 65504.0, np.float32: float(np.finfo(np.float32).max), np.float64: 3e38}

@pytest.mark.parametrize("value", [0.06, 0.5, 0.0, 1e-30, "large"])
def test_constant(links1_baseline, value):
    value = LARGE[DTYPE] if value == "large" else value
    links1_baseline.check_statistical(f"const_{value}", np.full((8, 4, 4, 3), value, dtype=DTYPE))

def test_spread_of_one_ulp(links1_baseline):
    # float64 samples a rounding apart (a deterministic pixel under jitter): a variance
    # of ~1e-35, far below what the float32 baseline can hold of the mean
    x = np.array(0.06, dtype=DTYPE)
    stack = np.stack([np.full((4, 4, 3), x), np.full((4, 4, 3), np.nextafter(x, DTYPE(1)))] * 4)
    links1_baseline.check_statistical("spread", stack)

def test_moments(links1_baseline):
    links1_baseline.check_statistical("moments", mean=np.full((4, 4, 3), 0.06, dtype=DTYPE),
                                      variance=np.zeros((4, 4, 3), dtype=DTYPE), count=8)

def test_exact(links1_baseline):
    links1_baseline.check("exact", np.full((4, 4, 3), 0.06, dtype=DTYPE), metric="max", threshold=0)
'''


@pytest.mark.parametrize("dtype", ["float16", "float32", "float64"])
def test_unchanged_rerun_of_constants_passes(pytester, dtype):
    pytester.makepyfile(test_const=CONSTANTS.replace("__DTYPE__", dtype))
    _run(pytester, "--links1-update-baselines").assert_outcomes(passed=8)
    _run(pytester).assert_outcomes(passed=8)


@pytest.mark.slow
def test_a_changed_constant_still_fails(pytester):
    pytester.makepyfile(test_const='''
import numpy as np
VALUE = np.float32(0.06)

def test_const(links1_baseline):
    links1_baseline.check_statistical("const", np.full((8, 4, 4, 3), VALUE))
''')
    _run(pytester, "--links1-update-baselines").assert_outcomes(passed=1)
    _run(pytester).assert_outcomes(passed=1)
    # three float32 steps up: beyond the baseline's rounding, and no variance to hide it
    pytester.makepyfile(test_const=f'''
import numpy as np
VALUE = np.float32({float(np.float32(0.06) + 3 * np.spacing(np.float32(0.06)))!r})

def test_const(links1_baseline):
    links1_baseline.check_statistical("const", np.full((8, 4, 4, 3), VALUE))
''')
    res = _run(pytester)
    res.assert_outcomes(failed=1)
    res.stdout.fnmatch_lines(["*16 of 16 pixels have p <*smallest p = 0*"])


def test_a_value_a_baseline_cannot_hold_is_an_error(pytester):
    pytester.makepyfile(test_big='''
import numpy as np

def test_big(links1_baseline):
    links1_baseline.check_statistical("big", np.full((8, 2, 3, 3), 1e300))
''')
    res = _run(pytester, "--links1-update-baselines")
    res.assert_outcomes(failed=1)
    res.stdout.fnmatch_lines(["*ValueError: mean 1e+300 at pixel (x=0, y=0), channel 0, does not "
                              "fit a float32 baseline*"])
    assert not (pytester.path / "baselines" / "big.exr").exists()


@pytest.mark.slow
def test_unchanged_statistical_scene_rerun_passes(pytester):
    fig4 = Path(__file__).resolve().parents[2] / "scenes" / "fig4.xml"
    pytester.makepyfile(test_scene=f'''
def test_fig4(links1_baseline):
    links1_baseline.check_scene({str(fig4)!r}, spp=2, statistical=True, runs=8,
                                params={{"res": 16}})
''')
    _run(pytester, "--links1-update-baselines").assert_outcomes(passed=1)
    _run(pytester).assert_outcomes(passed=1)


def test_welch_means_within_the_tolerance_are_equal():
    p = welch_t_test([1.0, 1.0, np.inf], [0.0, 0.0, np.nan], 4, [1.5, 2.0, np.inf],
                     [0.0, 0.0, np.nan], 4, tolerance=0.5)
    assert p.tolist() == [1.0, 0.0, 1.0]
    # with noise, only the part of the difference beyond the tolerance counts
    shifted = welch_t_test(0.0, 1.0, 8, 1.5, 1.0, 8, tolerance=0.5)
    assert shifted == pytest.approx(welch_t_test(0.0, 1.0, 8, 1.0, 1.0, 8))
