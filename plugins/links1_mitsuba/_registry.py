"""Variant selection and the one place where the links1 plugins are registered with Mitsuba."""
from __future__ import annotations

import os
import subprocess
import sys
import threading

from .registered import REGISTERED as _REGISTERED
from .registered import SUPPORTED_VARIANTS, unsupported_variant  # noqa: F401 - the public names

_LOCK = threading.Lock()
_LOGGING: dict[str, bool] = {}   # log_to_warnings done
_PROBED: dict[str, str | None] = {}  # backend -> None (works) or the reason it does not

_PROBE = r"""
import drjit as dr, mitsuba as mi
mi.set_variant({variant!r})
x = dr.arange(mi.Float, 16)
y = dr.minimum(dr.sqrt(x), 2.0) + dr.fma(x, x, 1.0)
dr.eval(y)
print(float(dr.sum(y)[0]) if hasattr(dr.sum(y), '__getitem__') else float(dr.sum(y)))
"""


def probe_variant(variant: str) -> str | None:
    """Run a tiny kernel of ``variant`` in a subprocess: ``None`` if it works, else why not.

    A bad libLLVM aborts the whole process inside drjit, so it is never tried in this one.
    """
    if variant in _PROBED:
        return _PROBED[variant]
    if variant.startswith("scalar"):
        _PROBED[variant] = None
        return None
    try:
        out = subprocess.run([sys.executable, "-c", _PROBE.format(variant=variant)],
                             capture_output=True, text=True, timeout=300)
        reason = None if out.returncode == 0 else (
            f"variant {variant} cannot run kernels (exit {out.returncode}): "
            + (out.stderr.strip().splitlines() or ["no message"])[-1][:300])
    except Exception as exc:  # pragma: no cover - environment dependent
        reason = f"variant {variant} probe failed: {exc}"
    if reason and variant.startswith("llvm"):
        reason += (" (drjit 1.5 needs libLLVM >= 16: apt-get install libllvm19, or set "
                   "DRJIT_LIBLLVM_PATH)")
    _PROBED[variant] = reason
    return reason


def default_variant() -> str:
    """``cuda_ad_rgb`` when a CUDA GPU works, else ``llvm_ad_rgb`` (``LINKS1_VARIANT`` overrides)."""
    env = os.environ.get("LINKS1_VARIANT")
    if env:
        return env
    import mitsuba as mi
    if "cuda_ad_rgb" in mi.variants() and _has_cuda():
        return "cuda_ad_rgb"
    return "llvm_ad_rgb"


def _has_cuda() -> bool:
    if not (os.path.exists("/dev/nvidiactl") or os.environ.get("CUDA_VISIBLE_DEVICES")):
        return False
    return probe_variant("cuda_ad_rgb") is None


def register(variant: str | None = None) -> str:
    """Select ``variant`` (default: the active one, else :func:`default_variant`) and register
    the links1 plugins for it: integrator ``links1_whitted``, emitters ``links1_point`` and
    ``links1_spot``, BSDF ``links1_phong`` and shape ``links1_bicubic`` (a tessellated
    :class:`mitsuba.Mesh`). Idempotent; returns the variant name.

    Raises ``UsageError`` (a ``ValueError``) naming the variants that work for one the plugins
    cannot render on (:data:`SUPPORTED_VARIANTS`: scalar, spectral and mono variants are
    refused), and ``RuntimeError`` with the reason when the variant cannot run here (e.g. a
    libLLVM that is too old): that check runs in a subprocess so that a crash there cannot
    kill the caller.
    """
    import mitsuba as mi

    from links1.errors import UsageError
    if variant is None:
        variant = mi.variant() or default_variant()
    why = unsupported_variant(variant)
    if why:
        raise UsageError(why)
    with _LOCK:
        if variant not in _REGISTERED:
            reason = probe_variant(variant)
            if reason:
                raise RuntimeError(reason)
        if mi.variant() != variant:
            mi.set_variant(variant)
        if variant in _REGISTERED:
            return variant
        from .bsdfs import define_phong
        from .emitters import define_emitters
        from .integrator import define_integrator
        from .bicubic import define_bicubic
        classes = {"links1_phong": define_phong()}
        classes.update(define_emitters())
        classes["links1_whitted"] = define_integrator()
        classes["links1_bicubic"] = define_bicubic()
        mi.register_bsdf("links1_phong", lambda props, c=classes["links1_phong"]: c(props))
        mi.register_emitter("links1_point", lambda props, c=classes["links1_point"]: c(props))
        mi.register_emitter("links1_spot", lambda props, c=classes["links1_spot"]: c(props))
        mi.register_integrator("links1_whitted",
                               lambda props, c=classes["links1_whitted"]: c(props))
        mi.register_shape("links1_bicubic", lambda props, c=classes["links1_bicubic"]: c(props))
        from .proxies import define_proxies
        for name, c in define_proxies().items():   # for scenes loaded by Mitsuba itself
            classes[name] = c
            mi.register_shape(name, lambda props, c=c: c(props))
        _REGISTERED[variant] = classes
        return variant


class MitsubaLogWarning(UserWarning):
    """A warning Mitsuba logged (``Log(Warn, ...)``), re-issued through :mod:`warnings`."""


def log_to_warnings() -> None:
    """Route Mitsuba's log (warnings and above) through :func:`warnings.warn`, so that it
    prints as the caller formats warnings (the CLI: one ``links1: warning: mitsuba: ...``
    line) instead of Mitsuba's own coloured lines. Idempotent."""
    import warnings

    import mitsuba as mi

    class _Message(mi.Formatter):
        def format(self, level, cname, fname, line, msg):
            return msg

    class _ToWarnings(mi.Appender):
        def append(self, level, text):
            if level >= mi.LogLevel.Warn:
                try:
                    warnings.warn(f"mitsuba: {text}", MitsubaLogWarning, stacklevel=2)
                except Exception:  # warnings turned into errors: never raise into Mitsuba
                    sys.stderr.write(f"links1: warning: mitsuba: {text}\n")

        def log_progress(self, progress, name, formatted, eta, ptr=None):
            pass

    with _LOCK:
        if _LOGGING.get("to_warnings"):
            return
        logger = mi.logger()
        logger.clear_appenders()
        logger.add_appender(_ToWarnings())
        logger.set_formatter(_Message())
        _LOGGING["to_warnings"] = True
