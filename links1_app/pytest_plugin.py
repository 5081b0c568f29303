"""Golden-image regression tests for pytest: the ``links1_baseline`` fixture.

Loaded automatically (entry point ``pytest11: links1``) wherever links1 is installed; no
conftest needed. See ``docs/regression-testing.md`` for a walk-through.

Fixture
-------
``links1_baseline.check(name_or_array, image=None, *, metric=None, threshold=None, channel_names=None)``
    Compare an image (array, or a callable returning one) with the EXR baseline
    ``<baseline dir>/<name>.exr`` under a metric of :mod:`links1.imaging.diff`.
``links1_baseline.check_statistical(name_or_samples, samples=None, *, mean=None, variance=None, count=None, alpha=None)``
    Per-pixel Welch t-test of a stochastic estimate (independent samples, or mean /
    per-sample variance / sample count) against a baseline that stores mean, variance and
    sample count; p-values corrected for the number of tests (Šidák).
``links1_baseline.check_scene(scene, *, renderer="core", spp=1, seed=0, ...)``
    Render a scene file (``links1.load_scene`` + ``links1.tracing.render.render``, or any callable
    renderer) and check it, exactly or statistically.

Options (command line / ini)
----------------------------
``--links1-update-baselines``
    Write the current images as the new baselines instead of comparing.
``--links1-baseline-dir DIR`` / ini ``links1_baseline_dir``
    Where baselines live (command line: relative to the invocation directory; ini: relative
    to the ini file's directory). Default: ``baselines/`` next to each test file.
``--links1-report-dir DIR`` / ini ``links1_report_dir``
    Where failures write image, baseline, difference and heatmap (default
    ``links1-report/`` in the rootdir), one sub-folder per test.
ini ``links1_metric`` (default ``relmse``), ``links1_threshold`` (``1e-3``),
``links1_alpha`` (significance level of the statistical test, ``0.01``).
"""
from __future__ import annotations

import math
import re
import warnings
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest

from links1.errors import UsageError
from links1.imaging.diff import METRICS, HIGHER_IS_BETTER, check_compatible, compare, exceeds, heatmap
from links1.imaging.image import read_exr, write_exr
from links1.scene.loader import load_scene
from links1.tracing.render import render

__all__ = ["Baseline", "welch_t_test", "student_t_sf2", "sidak_alpha"]

DEFAULT_METRIC = "relmse"
DEFAULT_THRESHOLD = 1e-3
DEFAULT_ALPHA = 0.01
SAMPLES_CHANNEL = "samples"
VARIANCE_PREFIX = "variance."

_UPDATED = pytest.StashKey[list]()
_REPORTS = pytest.StashKey[list]()


# ---------------------------------------------------------------------------------------
# Options and summary
# ---------------------------------------------------------------------------------------

def pytest_addoption(parser):
    group = parser.getgroup("links1", "links1 golden-image baselines")
    group.addoption("--links1-update-baselines", action="store_true", default=False,
                    help="write the current images as new baselines instead of comparing")
    group.addoption("--links1-baseline-dir", default=None, metavar="DIR",
                    help="baseline directory (default: baselines/ next to each test file)")
    group.addoption("--links1-report-dir", default=None, metavar="DIR",
                    help="where failing checks write image, baseline, diff and heatmap "
                         "(default: links1-report/ in the rootdir)")
    parser.addini("links1_baseline_dir", "baseline directory, relative to the ini file",
                  default="")
    parser.addini("links1_report_dir", "failure report directory, relative to the rootdir",
                  default="links1-report")
    parser.addini("links1_metric", "default metric of links1_baseline.check", default=DEFAULT_METRIC)
    parser.addini("links1_threshold", "default threshold of links1_baseline.check",
                  default=str(DEFAULT_THRESHOLD))
    parser.addini("links1_alpha", "significance level of links1_baseline.check_statistical",
                  default=str(DEFAULT_ALPHA))


def pytest_configure(config):
    config.stash[_UPDATED] = []
    config.stash[_REPORTS] = []


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    updated = list(dict.fromkeys(config.stash.get(_UPDATED, [])))
    reports = list(dict.fromkeys(config.stash.get(_REPORTS, [])))
    if updated:
        terminalreporter.section("links1 baselines written")
        for p in updated:
            terminalreporter.write_line(str(p))
    if reports:
        terminalreporter.section("links1 failure reports")
        for p in reports:
            terminalreporter.write_line(str(p))


@pytest.fixture
def links1_baseline(request) -> "Baseline":
    """Golden-image checks against EXR baselines; see :class:`Baseline`."""
    return Baseline(request)


# ---------------------------------------------------------------------------------------
# Statistics: Welch's t-test without scipy
# ---------------------------------------------------------------------------------------

def _betainc(a: np.ndarray, b: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Regularised incomplete beta function I_x(a, b), vectorised (continued fraction,
    modified Lentz, as in Numerical Recipes' ``betai``/``betacf``)."""
    a, b, x = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (a, b, x)))
    out = np.where(x <= 0, 0.0, 1.0)
    inside = (x > 0) & (x < 1)
    if not inside.any():
        return out
    a, b, x = a[inside], b[inside], x[inside]
    swap = x > (a + 1.0) / (a + b + 2.0)
    a, b, x = np.where(swap, b, a), np.where(swap, a, b), np.where(swap, 1.0 - x, x)
    lgamma = np.vectorize(math.lgamma, otypes=[np.float64])
    front = np.exp(lgamma(a + b) - lgamma(a) - lgamma(b) + a * np.log(x) + b * np.log1p(-x)) / a
    tiny = 1e-300
    c = np.ones_like(x)
    d = 1.0 - (a + b) * x / (a + 1.0)
    d = 1.0 / np.where(np.abs(d) < tiny, tiny, d)
    f = d.copy()
    for m in range(1, 400):
        for numerator in (m * (b - m) * x / ((a + 2 * m - 1) * (a + 2 * m)),
                          -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1))):
            d = 1.0 + numerator * d
            d = 1.0 / np.where(np.abs(d) < tiny, tiny, d)
            c = 1.0 + numerator / c
            c = np.where(np.abs(c) < tiny, tiny, c)
            delta = c * d
            f *= delta
        if np.all(np.abs(delta - 1.0) < 1e-14):
            break
    val = front * f
    out[inside] = np.where(swap, 1.0 - val, val)
    return out


def student_t_sf2(t, dof) -> np.ndarray:
    """Two-sided p-value P(|T| >= |t|) of Student's t with ``dof`` degrees of freedom
    (``I_{dof/(dof+t^2)}(dof/2, 1/2)``)."""
    t = np.asarray(t, dtype=np.float64)
    dof = np.asarray(dof, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        x = dof / (dof + t * t)
    x = np.where(np.isinf(t), 0.0, x)
    return np.clip(_betainc(dof / 2.0, np.full_like(x, 0.5), x), 0.0, 1.0)


def welch_t_test(mean_a, var_a, n_a, mean_b, var_b, n_b, tolerance=0.0) -> np.ndarray:
    """Per-element two-sided p-values of Welch's t-test for equal means.

    ``var_*`` are sample variances of single samples (ddof=1) and ``n_*`` sample counts
    (>= 2), so ``var/n`` is the variance of each mean. ``tolerance`` (per element, >= 0)
    is how far apart the means may be for want of precision (e.g. the resolution they
    are stored at): the test sees ``max(|mean_a - mean_b| - tolerance, 0)``. Where both
    variances are zero the p-value is 1 for means within ``tolerance`` and 0 otherwise.
    """
    ma, va, na, mb, vb, nb = (np.asarray(v, dtype=np.float64)
                              for v in (mean_a, var_a, n_a, mean_b, var_b, n_b))
    sa, sb = np.maximum(va, 0.0) / na, np.maximum(vb, 0.0) / nb
    se2 = sa + sb
    with np.errstate(invalid="ignore"):
        diff = np.where(ma == mb, 0.0, np.abs(ma - mb))     # inf == inf: no difference
        diff = np.maximum(diff - np.asarray(tolerance, dtype=np.float64), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = diff / np.sqrt(se2)
        dof = se2 * se2 / (sa * sa / np.maximum(na - 1, 1) + sb * sb / np.maximum(nb - 1, 1))
    degenerate = ~(se2 > 0)
    t = np.where(degenerate, 0.0, t)
    dof = np.where(degenerate | ~np.isfinite(dof), 1.0, np.maximum(dof, 1e-12))
    p = student_t_sf2(t, dof)
    p = np.where(degenerate, np.where(diff == 0.0, 1.0, 0.0), p)
    return np.where(np.isnan(ma) | np.isnan(mb), 0.0, p)


def sidak_alpha(alpha: float, tests: int) -> float:
    """Per-test significance level so that ``tests`` independent tests have a family-wise
    error rate ``alpha`` (Šidák: ``1 - (1 - alpha)**(1/tests)``, about ``alpha/tests``)."""
    return -math.expm1(math.log1p(-alpha) / max(int(tests), 1))


# ---------------------------------------------------------------------------------------
# The fixture object
# ---------------------------------------------------------------------------------------

def _safe(s: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", s).strip("_.") or "image"


def _hwc(x) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == 2:
        x = x[:, :, None]
    if x.ndim != 3:
        raise ValueError(f"expected an (H, W) or (H, W, C) image, got shape {x.shape}")
    return x


STORED_DTYPE = np.float32   # what links1.imaging.image.write_exr stores


def _as_stored(x: np.ndarray, what: str) -> np.ndarray:
    """``x`` (float64) rounded as a baseline EXR stores it, so that an image is compared
    at the precision its baseline was kept at; a finite value beyond that range is an
    error rather than a baseline holding inf."""
    stored = x.astype(STORED_DTYPE)
    overflow = np.isfinite(x) & ~np.isfinite(stored)
    if overflow.any():
        row, col, ch = (int(i[0]) for i in np.nonzero(overflow))
        raise ValueError(f"{what} {x[row, col, ch]:g} at pixel (x={col}, y={row}), channel {ch}, "
                         f"does not fit a {np.dtype(STORED_DTYPE).name} baseline (largest "
                         f"{float(np.finfo(STORED_DTYPE).max):.4g})")
    return stored.astype(np.float64)


def _stored_resolution(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """One stored-precision ulp at the larger magnitude: two values each rounded to the
    nearest stored number from the same true value lie at most this far apart."""
    big = np.maximum(np.abs(a), np.abs(b))
    finite = np.where(np.isfinite(big), big, 0.0).astype(STORED_DTYPE)
    return np.spacing(finite).astype(np.float64)


def _default_names(c: int) -> list[str]:
    return {1: ["Y"], 3: ["R", "G", "B"], 4: ["R", "G", "B", "A"]}.get(
        c, ["R", "G", "B"] + [f"C{i}" for i in range(3, c)] if c > 3 else [f"C{i}" for i in range(c)])


class Baseline:
    """Checks images against EXR baselines; obtained from the ``links1_baseline`` fixture.

    Every check returns the measured value (metric, or smallest p-value) and calls
    ``pytest.fail`` with a message naming the report files when the check fails.
    """

    def __init__(self, request):
        self._request = request
        self._config = request.config
        self._counter = 0

    def __repr__(self) -> str:
        return f"Baseline(dir={str(self.baseline_dir)!r}, update={self.update})"

    # -- configuration -------------------------------------------------------------------

    @property
    def update(self) -> bool:
        """True under ``--links1-update-baselines``."""
        return bool(self._config.getoption("links1_update_baselines"))

    @property
    def baseline_dir(self) -> Path:
        """The directory holding this test's baselines."""
        opt = self._config.getoption("links1_baseline_dir")
        if opt:
            return (Path(self._config.invocation_params.dir) / opt).resolve()
        ini = self._config.getini("links1_baseline_dir")
        if ini:
            base = Path(self._config.inipath).parent if self._config.inipath else self._config.rootpath
            return (base / ini).resolve()
        return Path(self._request.path).parent / "baselines"

    @property
    def report_dir(self) -> Path:
        """This test's failure report folder (created on first failure)."""
        opt = self._config.getoption("links1_report_dir")
        root = (Path(self._config.invocation_params.dir) / opt) if opt else (
            self._config.rootpath / self._config.getini("links1_report_dir"))
        return (root / _safe(self._request.node.nodeid)).resolve()

    def path(self, name: str) -> Path:
        """The baseline file of ``name``."""
        if Path(name).is_absolute() or ".." in Path(name).parts:
            raise ValueError(f"baseline name must be a relative path without '..', got {name!r}")
        return self.baseline_dir / f"{name}.exr"

    def _ini_float(self, key: str, default: float) -> float:
        raw = self._config.getini(key)
        try:
            return float(raw) if raw not in ("", None) else default
        except ValueError:
            raise pytest.UsageError(f"ini option {key} must be a number, got {raw!r}") from None

    def _name(self, name: str | None) -> str:
        if name:
            return name
        self._counter += 1
        base = _safe(self._request.node.name)
        return base if self._counter == 1 else f"{base}_{self._counter}"

    @staticmethod
    def _split(first, second, what: str):
        """(name, payload) from check(name, payload) or check(payload)."""
        if isinstance(first, str):
            if second is None:
                raise TypeError(f"check({first!r}) needs {what}")
            return first, second
        if second is not None:
            raise TypeError(f"pass the baseline name as a string, got {type(first).__name__}")
        return None, first

    # -- reporting -----------------------------------------------------------------------

    def _write_report(self, name: str, image, baseline=None, names=None, pvalue=None) -> list[Path]:

        out = self.report_dir / name
        out.parent.mkdir(parents=True, exist_ok=True)
        stem = out.name
        files = []
        img = _hwc(image)
        img_names = names if names and len(names) == img.shape[2] else _default_names(img.shape[2])
        files.append(write_exr(out.with_name(f"{stem}.exr"), img, img_names))
        if baseline is not None:
            base = _hwc(baseline)
            base_names = names if names and len(names) == base.shape[2] else _default_names(base.shape[2])
            files.append(write_exr(out.with_name(f"{stem}.baseline.exr"), base, base_names))
            if base.shape == img.shape:
                files.append(write_exr(out.with_name(f"{stem}.diff.exr"), img - base, img_names))
                heatmap(img, base, out.with_name(f"{stem}.heatmap.png"),
                        title=f"{name}: |image - baseline|")
                files.append(out.with_name(f"{stem}.heatmap.png"))
        if pvalue is not None:
            p = _hwc(pvalue)
            files.append(write_exr(out.with_name(f"{stem}.pvalue.exr"), p,
                                   img_names if p.shape[2] == len(img_names) else None))
        self._config.stash[_REPORTS].append(self.report_dir)
        return files

    def _fail(self, message: str, files) -> None:
        listing = "".join(f"\n  {f}" for f in files)
        pytest.fail(f"{message}{listing and chr(10) + 'report files:' + listing}", pytrace=False)

    def _missing(self, name: str, path: Path, image, names) -> None:
        files = self._write_report(name, image, names=names)
        self._fail(f"no baseline {path} for '{name}'; run pytest with "
                   f"--links1-update-baselines to create it", files)

    def _stored(self, name, path: Path, array, names, shown, shown_names):
        """The baseline at ``path`` as ``(float64 array, channel names)``; with
        ``--links1-update-baselines``, ``array`` (channels ``names``) is written there instead and
        None returned. A missing baseline fails the test (:meth:`_missing`, showing ``shown``)."""
        if self.update:
            path.parent.mkdir(parents=True, exist_ok=True)
            write_exr(path, array, names)
            self._updated(path)
            return None
        if not path.exists():
            self._missing(name, path, shown, shown_names)
        data, stored = read_exr(path)
        return data.astype(np.float64), stored

    def _updated(self, path: Path) -> None:
        updated = self._config.stash[_UPDATED]
        if path in updated:
            warnings.warn(f"links1 baseline {path} written twice in this session; the last "
                          "check wins (give the checks different names)", stacklevel=3)
        updated.append(path)

    # -- checks --------------------------------------------------------------------------

    def check(self, name_or_array, image=None, *, metric: str | None = None,
              threshold: float | None = None, channel_names=None) -> float:
        """Compare an image with the baseline ``name`` under ``metric``.

        Parameters
        ----------
        name_or_array : str or array_like
            The baseline name (``image`` then holds the image), or the image itself (the
            baseline is then named after the test, with a counter for further checks).
        image : array_like (H, W[, C]) or callable returning one
        metric : str, optional
            One of :data:`links1.imaging.diff.METRICS`; default ini ``links1_metric`` (relmse).
        threshold : float, optional
            Fails when the metric exceeds it (falls below it for psnr); default ini
            ``links1_threshold`` (1e-3).
        channel_names : list of str, optional
            EXR channel names for the baseline (default R, G, B ...).

        Returns
        -------
        float
            The metric's value (NaN in update mode).
        """

        name, image = self._split(name_or_array, image, "an image")
        name = self._name(name)
        metric = metric or self._config.getini("links1_metric") or DEFAULT_METRIC
        if metric not in METRICS:
            raise ValueError(f"unknown metric {metric!r}; choose from {', '.join(METRICS)}")
        threshold = self._ini_float("links1_threshold", DEFAULT_THRESHOLD) if threshold is None \
            else float(threshold)
        img = _as_stored(_hwc(image() if callable(image) else image), "image value")
        names = list(channel_names) if channel_names else _default_names(img.shape[2])
        path = self.path(name)

        stored = self._stored(name, path, img, names, img, names)
        if stored is None:
            return math.nan
        base, base_names = stored
        try:
            check_compatible(img, base, ("image", str(path)))
        except UsageError as e:
            files = self._write_report(name, img, base, base_names)
            self._fail(f"'{name}': {e}", files)
        value = compare(img, base, metric)
        if exceeds(metric, value, threshold):
            files = self._write_report(name, img, base, names)
            rel = "<" if metric in HIGHER_IS_BETTER else ">"
            self._fail(f"'{name}' differs from baseline {path}: {metric} = {value:.6g} "
                       f"{rel} threshold {threshold:g}", files)
        return value

    def check_statistical(self, name_or_samples, samples=None, *, mean=None, variance=None,
                          count=None, alpha: float | None = None, channel_names=None) -> float:
        """Per-pixel Welch t-test of a stochastic estimate against the baseline ``name``.

        Give either ``samples``, a stack ``(K, H, W[, C])`` of K >= 2 independent images
        (e.g. renders with different seeds), or ``mean``, ``variance`` (sample variance of
        one sample, per pixel) and ``count`` (samples per pixel). The baseline stores the
        mean channels, ``variance.<channel>`` channels and a ``samples`` channel.

        The test fails when any pixel-channel's two-sided p-value is below the Šidák-
        corrected level ``1 - (1 - alpha)**(1/N)`` (N = number of pixel-channel values),
        so ``alpha`` (ini ``links1_alpha``, default 0.01) is the chance that a correct
        renderer fails the whole image. On failure a ``.pvalue.exr`` is written too.

        Returns
        -------
        float
            The smallest p-value (NaN in update mode).
        """

        if isinstance(name_or_samples, str) or name_or_samples is None:
            name = name_or_samples
        else:
            if samples is not None:
                raise TypeError("pass the baseline name as a string")
            name, samples = None, name_or_samples
        name = self._name(name)
        alpha = self._ini_float("links1_alpha", DEFAULT_ALPHA) if alpha is None else float(alpha)
        if not 0.0 < alpha < 1.0:
            raise ValueError(f"alpha must be in (0, 1), got {alpha}")
        if samples is not None:
            stack = np.asarray(samples() if callable(samples) else samples, dtype=np.float64)
            if stack.ndim == 3:
                stack = stack[..., None]
            if stack.ndim != 4 or stack.shape[0] < 2:
                raise ValueError(f"samples must be (K, H, W[, C]) with K >= 2, got {stack.shape}")
            m, v = stack.mean(axis=0), stack.var(axis=0, ddof=1)
            # Identical samples: their value and no spread, not a mean and a variance
            # carrying the sum's rounding.
            constant = (stack == stack[0]).all(axis=0)
            m, v = np.where(constant, stack[0], m), np.where(constant, 0.0, v)
            n = np.full(m.shape[:2] + (1,), float(stack.shape[0]))
        else:
            if mean is None or variance is None or count is None:
                raise TypeError("check_statistical needs samples=, or mean=, variance= and count=")
            m, v = _hwc(mean), _hwc(variance)
            if m.shape != v.shape:
                raise ValueError(f"mean {m.shape} and variance {v.shape} differ in shape")
            n = np.broadcast_to(np.asarray(count, dtype=np.float64), m.shape[:2]).reshape(m.shape[:2] + (1,))
            if np.any(n < 2):
                raise ValueError("count must be >= 2 samples per pixel")
        m, v = _as_stored(m, "mean"), _as_stored(v, "variance")
        c = m.shape[2]
        names = list(channel_names) if channel_names else _default_names(c)
        path = self.path(name)
        all_names = names + [VARIANCE_PREFIX + x for x in names] + [SAMPLES_CHANNEL]

        got = self._stored(name, path, np.concatenate([m, v, n], axis=2), all_names, m, names)
        if got is None:
            return math.nan
        data, stored = got
        if SAMPLES_CHANNEL not in stored or (len(stored) - 1) % 2:
            files = self._write_report(name, m, names=names)
            self._fail(f"baseline {path} has no mean/variance/samples channels "
                       f"(channels {stored}); regenerate it with --links1-update-baselines "
                       "from check_statistical", files)
        bc = (len(stored) - 1) // 2
        bm, bv = data[:, :, :bc], data[:, :, bc:2 * bc]
        bn = data[:, :, stored.index(SAMPLES_CHANNEL)][:, :, None]
        if bm.shape != m.shape:
            files = self._write_report(name, m, bm, names)
            self._fail(f"'{name}': image is {m.shape[1]}x{m.shape[0]}x{m.shape[2]}, baseline "
                       f"{path} is {bm.shape[1]}x{bm.shape[0]}x{bm.shape[2]}", files)
        p = welch_t_test(m, v, n, bm, bv, bn, tolerance=_stored_resolution(m, bm))
        level = sidak_alpha(alpha, p.size)
        failing = p < level
        pmin = float(p.min())
        if failing.any():
            files = self._write_report(name, m, bm, names, pvalue=p)
            bad_pixels = int(failing.any(axis=2).sum())
            self._fail(f"'{name}' differs from baseline {path} (Welch t-test): {bad_pixels} of "
                       f"{p.shape[0] * p.shape[1]} pixels have p < {level:.3g} (alpha {alpha:g}, "
                       f"Šidák-corrected for {p.size} tests); smallest p = {pmin:.3g}", files)
        return pmin

    def check_scene(self, scene, *, renderer: str | Callable = "core", spp: int = 1,
                    seed: int = 0, name: str | None = None, metric: str | None = None,
                    threshold: float | None = None, statistical: bool = False, runs: int = 8,
                    alpha: float | None = None, params: dict | None = None,
                    **render_kwargs: Any) -> float:
        """Render a scene file and check the image against the baseline.

        Parameters
        ----------
        scene : str or path
            Scene XML; a relative path is looked up next to the test file, then in the
            rootdir.
        renderer : "core" or callable
            ``"core"``: ``links1.load_scene(scene, **params)`` then
            ``links1.tracing.render.render(scene, spp=spp, seed=seed, **render_kwargs)``.
            A callable is called as ``renderer(path, spp=spp, seed=seed, **render_kwargs)``
            and returns an (H, W, C) array.
        name : str, optional
            Baseline name; default the scene file's stem plus ``_spp<N>``.
        statistical : bool
            Render ``runs`` times with seeds ``seed, seed+1, ...`` and use
            :meth:`check_statistical` (for stochastic renders, e.g. spp > 1 with area lights).
        """
        path = Path(scene)
        if not path.is_absolute():
            here = Path(self._request.path).parent / path
            path = here if here.exists() else self._config.rootpath / path
        if not path.exists():
            raise FileNotFoundError(f"scene file {scene} not found (looked next to the test "
                                    f"file and in {self._config.rootpath})")
        if renderer == "core":
            def render_once(s):
                return render(load_scene(str(path), **(params or {})), spp=spp, seed=s,
                              **render_kwargs)
        elif callable(renderer):
            def render_once(s):
                return renderer(str(path), spp=spp, seed=s, **render_kwargs)
        else:
            raise ValueError(f"renderer must be 'core' or a callable, got {renderer!r}")
        name = name or f"{_safe(path.stem)}_spp{spp}"
        if statistical:
            if runs < 2:
                raise ValueError(f"statistical checks need runs >= 2, got {runs}")
            stack = np.stack([_hwc(render_once(seed + i)) for i in range(runs)])
            return self.check_statistical(name, stack, alpha=alpha)
        return self.check(name, render_once(seed), metric=metric, threshold=threshold)
