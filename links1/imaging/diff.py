"""Image metrics and difference heatmaps (the ``links1 diff`` command is :mod:`links1_app.diff`).

Every metric compares a *test* image ``a`` with a *reference* image ``b`` of the same
size and channel count, over all channels and pixels, in float64:

========  ====================================================================  ==========
metric    definition                                                            better
========  ====================================================================  ==========
rmse      ``sqrt(mean((a - b)**2))``                                            lower
relmse    ``mean((a - b)**2 / (b**2 + 1e-2))`` -- relative MSE as in Mitsuba's   lower
          and tev's error metrics; the 1e-2 keeps dark pixels from dominating
mae       ``mean(|a - b|)``                                                     lower
max       ``max(|a - b|)``                                                      lower
psnr      ``10 log10(peak**2 / mean((a - b)**2))`` dB; ``peak`` = 1 for LDR     higher
          inputs (PNG), the maximum of the reference for HDR inputs (EXR);
          ``inf`` for identical images
flip      mean NVIDIA FLIP error (``flip-evaluator`` package): LDR-FLIP on      lower
          colours clamped to [0, 1] for LDR inputs, HDR-FLIP (linear, negative
          values clamped to 0) otherwise; first 3 channels (1 channel is
          replicated to grey)
========  ====================================================================  ==========

Inputs are LDR when both come from PNG files (or ``ldr=True`` is passed).
NaN in either image makes every metric NaN, which fails any threshold.
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import UsageError
from .image import atomic_write, read_image, write_png

__all__ = [
    "METRICS", "HIGHER_IS_BETTER", "rmse", "relmse", "mae", "max_error", "psnr", "flip",
    "check_compatible", "compare", "all_metrics", "exceeds", "error_map", "heatmap",
]

METRICS = ("rmse", "relmse", "mae", "max", "psnr", "flip")
HIGHER_IS_BETTER = frozenset({"psnr"})
RELMSE_EPSILON = 1e-2


# ---------------------------------------------------------------------------------------
# Metrics
# ---------------------------------------------------------------------------------------

def _f64(a, b):
    return np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)


def rmse(a, b) -> float:
    """Root-mean-square error ``sqrt(mean((a - b)**2))``."""
    a, b = _f64(a, b)
    return float(np.sqrt(np.mean((a - b) ** 2)))


def relmse(a, b) -> float:
    """Relative MSE ``mean((a - b)**2 / (b**2 + 1e-2))``, ``b`` the reference."""
    a, b = _f64(a, b)
    return float(np.mean((a - b) ** 2 / (b * b + RELMSE_EPSILON)))


def mae(a, b) -> float:
    """Mean absolute error ``mean(|a - b|)``."""
    a, b = _f64(a, b)
    return float(np.mean(np.abs(a - b)))


def max_error(a, b) -> float:
    """Largest absolute difference ``max(|a - b|)`` (NaN if any value is NaN)."""
    a, b = _f64(a, b)
    d = np.abs(a - b)
    return float(np.nan if np.isnan(d).any() else d.max())


def psnr(a, b, peak: float | None = None) -> float:
    """Peak signal-to-noise ratio in dB, ``10 log10(peak**2 / mse)``.

    ``peak`` defaults to the maximum of the reference ``b`` (HDR convention); pass 1 for
    LDR images. ``inf`` when the images are equal; ``nan`` for a non-positive peak.
    """
    a, b = _f64(a, b)
    mse = float(np.mean((a - b) ** 2))
    if peak is None:
        peak = float(np.max(b))
    if math.isnan(mse) or not peak > 0:
        return math.nan
    if mse == 0.0:
        return math.inf
    return 10.0 * math.log10(peak * peak / mse)


def _flip_rgb(x: np.ndarray, ldr: bool) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == 2:
        x = x[:, :, None]
    x = np.repeat(x, 3, axis=2) if x.shape[2] < 3 else x[:, :, :3]
    x = np.nan_to_num(x, nan=0.0, posinf=0.0, neginf=0.0)
    x = np.clip(x, 0.0, 1.0) if ldr else np.maximum(x, 0.0)
    return np.ascontiguousarray(x, dtype=np.float32)


def flip(a, b, ldr: bool = False) -> float:
    """Mean FLIP error of test ``a`` against reference ``b`` (needs ``flip-evaluator``).

    Both images are linear. LDR-FLIP (``ldr=True``) clamps them to [0, 1] and tells FLIP
    they are linear (``inputsRGB=False``); HDR-FLIP clamps negatives to 0.
    """
    try:
        import flip_evaluator  # noqa: PLC0415 - optional (links1[diff]), imported lazily
    except ImportError:
        raise UsageError("metric 'flip' needs the flip-evaluator package "
                         "(pip install 'links1[diff]')") from None
    a64, b64 = _f64(a, b)
    if np.isnan(a64).any() or np.isnan(b64).any():
        return math.nan
    ref, test = _flip_rgb(b64, ldr), _flip_rgb(a64, ldr)
    if ldr:
        _, mean, _ = flip_evaluator.evaluate(ref, test, "LDR", inputsRGB=False,
                                             applyMagma=False, computeMeanError=True)
    else:
        _, mean, _ = flip_evaluator.evaluate(ref, test, "HDR", applyMagma=False,
                                             computeMeanError=True)
    return float(mean)


# ---------------------------------------------------------------------------------------
# Comparison
# ---------------------------------------------------------------------------------------

def _hwc(x) -> np.ndarray:
    x = np.asarray(x)
    return x[:, :, None] if x.ndim == 2 else x


def check_compatible(a, b, labels: Sequence[str] = ("a", "b")) -> None:
    """Raise :class:`UsageError` unless ``a`` and ``b`` have the same size and channels.

    Messages name both inputs, e.g. ``size mismatch: a.exr is 64x48, b.png is 32x32``
    (width x height).
    """
    a, b = _hwc(a), _hwc(b)
    la, lb = labels
    for x, lab in ((a, la), (b, lb)):
        if x.ndim != 3:
            raise UsageError(f"{lab}: expected an (H, W) or (H, W, C) image, got shape {x.shape}")
    if a.shape[:2] != b.shape[:2]:
        raise UsageError(f"size mismatch: {la} is {a.shape[1]}x{a.shape[0]}, "
                         f"{lb} is {b.shape[1]}x{b.shape[0]}")
    if a.shape[2] != b.shape[2]:
        raise UsageError(f"channel mismatch: {la} has {a.shape[2]} channels, "
                         f"{lb} has {b.shape[2]}")


def _load(x, label):
    """(array, label, is_ldr) from an array or an image path."""
    if isinstance(x, (str, os.PathLike)):
        return read_image(x), label or str(x), Path(x).suffix.lower() == ".png"
    return np.asarray(x), label, False


def _metric(name: str, a, b, ldr: bool) -> float:
    if name == "rmse":
        return rmse(a, b)
    if name == "relmse":
        return relmse(a, b)
    if name == "mae":
        return mae(a, b)
    if name == "max":
        return max_error(a, b)
    if name == "psnr":
        return psnr(a, b, 1.0 if ldr else None)
    if name == "flip":
        return flip(a, b, ldr)
    raise UsageError(f"unknown metric '{name}' (choose from {', '.join(METRICS)})")


def compare(a, b, metric: str = "relmse", *, ldr: bool | None = None,
            labels: Sequence[str] | None = None) -> float:
    """One metric of test image ``a`` against reference ``b``.

    Parameters
    ----------
    a, b : array_like (H, W[, C]) or path
        Linear images, or EXR/PNG files (read with :func:`links1.imaging.image.read_image`).
    metric : {'rmse', 'relmse', 'mae', 'max', 'psnr', 'flip'}
    ldr : bool, optional
        Treat the inputs as LDR (psnr peak 1, LDR-FLIP). Default: both inputs are PNG files.
    labels : (str, str), optional
        Names for error messages; default the file names, or ``a`` / ``b``.
    """
    if metric not in METRICS:
        raise UsageError(f"unknown metric '{metric}' (choose from {', '.join(METRICS)})")
    return all_metrics(a, b, ldr=ldr, labels=labels, metrics=(metric,))[metric]


def all_metrics(a, b, *, ldr: bool | None = None, labels: Sequence[str] | None = None,
                metrics: Sequence[str] = METRICS) -> dict[str, float]:
    """``{metric: value}`` for ``metrics`` (all by default; see :func:`compare`)."""
    la, lb = labels if labels is not None else (None, None)
    a, la, ldr_a = _load(a, la or ("a" if not isinstance(a, (str, os.PathLike)) else None))
    b, lb, ldr_b = _load(b, lb or ("b" if not isinstance(b, (str, os.PathLike)) else None))
    check_compatible(a, b, (la, lb))
    if ldr is None:
        ldr = ldr_a and ldr_b
    a, b = _hwc(a), _hwc(b)
    return {m: _metric(m, a, b, ldr) for m in metrics}


def exceeds(metric: str, value: float, threshold: float) -> bool:
    """True when ``value`` fails ``threshold``: above it, or below it for psnr; NaN fails."""
    if math.isnan(value):
        return True
    return value < threshold if metric in HIGHER_IS_BETTER else value > threshold


# ---------------------------------------------------------------------------------------
# Heatmaps
# ---------------------------------------------------------------------------------------

ERROR_MAPS = ("abs", "sq", "rel")


def error_map(a, b, error: str = "abs") -> np.ndarray:
    """Per-pixel error (H, W), averaged over channels: ``abs`` |a-b|, ``sq`` (a-b)^2,
    ``rel`` (a-b)^2 / (b^2 + 1e-2)."""
    a, b = _f64(_hwc(a), _hwc(b))
    check_compatible(a, b)
    d = a - b
    if error == "abs":
        e = np.abs(d)
    elif error == "sq":
        e = d * d
    elif error == "rel":
        e = d * d / (b * b + RELMSE_EPSILON)
    else:
        raise UsageError(f"unknown error map '{error}' (choose from {', '.join(ERROR_MAPS)})")
    return e.mean(axis=2)


def _fallback_colours(t: np.ndarray) -> np.ndarray:
    """A black-red-yellow-white ramp (linear RGB) for when matplotlib is missing."""
    t = np.clip(t, 0.0, 1.0)
    return np.stack([np.clip(3 * t, 0, 1), np.clip(3 * t - 1, 0, 1), np.clip(3 * t - 2, 0, 1)],
                    axis=-1) ** 2.2


def heatmap(a, b, out_png: str | os.PathLike, *, error: str = "abs", vmax: float | None = None,
            cmap: str = "inferno", colorbar: bool = True, title: str | None = None) -> np.ndarray:
    """Write a false-colour PNG of the per-pixel error of ``a`` against ``b``.

    The error map (see :func:`error_map`) is scaled from 0 to ``vmax`` (default: its 99th
    percentile, or its maximum when that is 0) through a matplotlib colormap, with a colour
    bar. Without matplotlib a plain black-red-yellow-white ramp is written at image size.
    The write is atomic. Returns the error map.
    """
    e = error_map(a, b, error)
    finite = e[np.isfinite(e)]
    if vmax is None:
        vmax = float(np.percentile(finite, 99)) if finite.size else 1.0
        if not vmax > 0:
            vmax = float(finite.max()) if finite.size and finite.max() > 0 else 1.0
    shown = np.where(np.isfinite(e), e, vmax)
    try:
        # optional (links1[plot]) and slow to import: only a heatmap needs it
        from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: PLC0415
        from matplotlib.figure import Figure  # noqa: PLC0415
    except ImportError:
        write_png(out_png, _fallback_colours(shown / vmax))
        return e

    h, w = e.shape
    dpi = 100
    width_in = max(w / dpi, 2.0) + (1.2 if colorbar else 0.0)
    height_in = max(h / dpi, 2.0) + (0.4 if title else 0.0)
    fig = Figure(figsize=(width_in, height_in), dpi=dpi)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    im = ax.imshow(shown, cmap=cmap, vmin=0.0, vmax=vmax, interpolation="nearest")
    ax.set_axis_off()
    if title:
        ax.set_title(title, fontsize=8)
    if colorbar:
        cb = fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
        cb.set_label({"abs": "|a - b|", "sq": "(a - b)^2", "rel": "(a-b)^2/(b^2+0.01)"}[error],
                     fontsize=8)
        cb.ax.tick_params(labelsize=7)
    atomic_write(out_png, lambda tmp: fig.savefig(tmp, format="png", bbox_inches="tight"))
    return e
