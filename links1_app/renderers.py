"""Choosing a renderer: the Renderer contract, the factory, Mitsuba's errors in one line.

This is the one module that knows both renderers, the core's
(:class:`links1.tracing.render.CoreRenderer`) and the Mitsuba plugin's
(:class:`links1_mitsuba.renderer.MitsubaRenderer`). It is a *front end*: the CLI, the
partitioning runtime and users (``from links1_app import make_renderer``) import it; the core
never does, and neither does the plugin, so the dependencies run one way, core <- plugin <-
front ends (docs/architecture.md, "Dependencies"). It lives here rather than in the plugin
because ``make_renderer("core", ...)`` and the message that says how to install Mitsuba must
work where Mitsuba is not installed: ``links1_mitsuba`` imports Mitsuba and Dr.Jit (an
optional dependency, and seconds of start-up), so it is imported only when a Mitsuba renderer
is asked for.
"""
from __future__ import annotations

import os
import re
import warnings
from typing import Protocol, Sequence, runtime_checkable

import numpy as np

from links1.errors import Links1Error, SceneError, UsageError, one_line_warnings
from links1.interrupts import held_interrupts
from links1.scene.loader import load_scene
from links1.tracing.render import CoreRenderer


@runtime_checkable
class Renderer(Protocol):
    """What a renderer offers the front ends (docs/architecture.md, "Renderers"): a scene
    file loaded once, any window of its film rendered many times (the partitioning layer keeps
    one per worker). :class:`links1.tracing.render.CoreRenderer` and
    :class:`links1_mitsuba.renderer.MitsubaRenderer` implement it; a ``module:callable``
    renderer of the partitioning layer (docs/partitioning.md) may leave ``render_batch`` out.
    """

    #: ``"core"``, ``"mitsuba"``, ... (what :func:`make_renderer` was asked for).
    kind: str
    #: The scene file.
    path: str
    #: Samples per pixel and the seed of the sample pattern (links1.maths.sampling).
    spp: int
    seed: int
    #: The AOVs of the render, in order (:data:`links1.tracing.aovs.AOVS`).
    aovs: Sequence[str]

    @property
    def film_size(self) -> tuple[int, int]:
        """``(width, height)`` of the full film in pixels."""

    @property
    def channels(self) -> list[str]:
        """Channel names: ``R, G, B``, then the AOV channels (:func:`links1.tracing.aovs.channel_names`)."""

    def render(self, window=None) -> np.ndarray:
        """``(h, w, C)`` float64 of ``window = (x0, y0, w, h)`` (row 0 at the top; None: the
        full film): the same bits as those pixels of the full frame, no recompilation per window."""

    def render_batch(self, windows) -> list:
        """One array per window, each exactly ``render(window)``."""

    def shapes_info(self) -> list[dict]:
        """Per shape, in index order: ``{index, name, type, bounds_lo, bounds_hi, reflective,
        transmissive, nbytes}`` (the partitioning layer's loads, 4-1, and data per node, 4-4)."""


def make_renderer(kind: str, path, **options) -> Renderer:
    """A :class:`Renderer` for ``kind`` = ``"core"`` (:class:`links1.tracing.render.CoreRenderer`) or
    ``"mitsuba"`` (:class:`links1_mitsuba.renderer.MitsubaRenderer`, imported only here);
    ``options`` are the renderer's keyword arguments. Errors are one-line
    :class:`links1.errors.Links1Error`: a missing Mitsuba, a bad scene (the core's reader
    checks it first, naming file, line and element), Mitsuba's own loading errors."""
    if kind == "core":
        return CoreRenderer(path, **options)
    if kind == "mitsuba":
        # Ctrl-C during Mitsuba's imports and loading is raised once they are done: inside a
        # native call it can be lost, or leave a native module half made (links1.interrupts)
        with held_interrupts():
            return _make_mitsuba_renderer(path, options)
    raise UsageError(f"unknown renderer {kind!r}; choose 'mitsuba' or 'core'")


def _make_mitsuba_renderer(path, options):
    require_mitsuba()
    try:
        from links1_mitsuba import MitsubaRenderer   # lazy: Mitsuba is optional (module docstring)
    except ImportError as e:
        raise UsageError(f"the mitsuba renderer is unavailable: {e}") from None
    _validate_for_mitsuba(path, options.get("params") or {})
    try:
        return MitsubaRenderer(path, **options)
    except (RuntimeError, ValueError, OSError, IndexError) as e:
        if isinstance(e, Links1Error):
            raise
        if isinstance(e, IndexError):  # the plugin found no sensor to render from
            raise SceneError("the scene has no sensor (add a <sensor type='perspective'>)",
                             file=str(path)) from None
        raise SceneError(mitsuba_message(e, path)) from None


def require_mitsuba(variant: str | None = None) -> None:
    """Raise a one-line ``UsageError`` naming the extra to install when Mitsuba 3 / Dr.Jit
    cannot be imported (the core renderer needs neither), or naming the variants that work
    when ``variant`` is one the links1 plugins cannot run on (before any worker starts)."""
    with held_interrupts():   # Ctrl-C raised after the imports, not inside a native one
        try:
            import drjit  # noqa: F401  (lazy: whether the optional Mitsuba is there is the question)
            import mitsuba  # noqa: F401
        except ImportError as e:
            raise UsageError(f"the mitsuba renderer needs Mitsuba 3 and Dr.Jit ({e}): install them with "
                             "pip install 'links1[mitsuba]', or render with --renderer core") from None
        if variant is not None:
            from links1_mitsuba import unsupported_variant   # lazy: Mitsuba is optional
            why = unsupported_variant(variant)
            if why:
                raise UsageError(why)


def renderer_warnings(kind: str | None = None) -> None:
    """Every warning of this process (the CLI, a worker) in one line
    (:func:`links1.errors.one_line_warnings`), for ``kind="mitsuba"`` Mitsuba's own log
    warnings too (:func:`links1_mitsuba.log_to_warnings`)."""
    one_line_warnings()
    if kind == "mitsuba":
        from links1_mitsuba import log_to_warnings  # lazy: the core renderer never needs Mitsuba
        log_to_warnings()


def _validate_for_mitsuba(path, params) -> None:
    """Check a scene with the core's reader before Mitsuba sees it: the reader names file,
    line and element for bad values (NaN, negative sizes, bad links1 parameters) that
    Mitsuba would accept or crash on. Plugins the core lacks are left to Mitsuba."""
    if not os.path.exists(path):
        raise SceneError("scene file not found", file=str(path))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            load_scene(path, **params)
    except SceneError as e:
        if "not supported by the core" not in e.message:
            raise


def mitsuba_message(exc: BaseException, path) -> str:
    """One line from a Mitsuba loading error: the last line of a Python traceback, no
    ``[parser.cpp:NNN]`` source tags, and ``(offset N)`` turned into the file's line number."""
    text = str(exc)
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    msg = lines[-1] if lines else type(exc).__name__
    if len(lines) > 1 and "Traceback" in text:
        where = _SOURCE_TAG.sub("", lines[0]).split(": failed")[0]  # "At FILE (line L, col C)"
        msg = f"{where}: {msg}"
    elif len(lines) > 1:  # "While loading FILE (line L, col C): Found 1 unreferenced property ...:" + a list
        msg = " ".join(lines)
    msg = _SOURCE_TAG.sub("", msg)

    def line_of(m):
        try:
            with open(m.group(1), "rb") as f:
                line = f.read(int(m.group(2))).count(b"\n") + 1
            return f"{m.group(1)}:{line}"
        except OSError:
            return m.group(0)
    return _OFFSET.sub(line_of, msg)


_SOURCE_TAG = re.compile(r"\[[\w./]+:\d+\]\s*")
_OFFSET = re.compile(r"(\S+) \(offset (\d+)\)")
