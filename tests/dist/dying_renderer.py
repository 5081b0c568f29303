"""A real renderer whose worker process SIGKILLs itself at a chosen moment (death tests).

``DyingRenderer(path, inner=KIND, die=..., marker=FILE, **options)`` builds the renderer
``KIND`` (``core``, ``mitsuba`` or a ``module:callable``) and forwards everything to it,
so the pixels are that renderer's. The first process to claim ``marker`` (an exclusive
create; ``always=True``: every process) SIGKILLs itself:

- ``die="start"``: right after loading the scene, inside the worker's first task;
- ``die="unit"``: inside ``render`` (or ``render_batch``) of ``die_window``, after rendering it,
  before returning.

A death "while idle" needs no hook: the test kills a ready worker from outside.
"""
from __future__ import annotations

import os
import signal

DYING = "tests.dist.dying_renderer:DyingRenderer"


def _claim(marker, always):
    if always:
        return True
    try:
        fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        return False
    os.write(fd, str(os.getpid()).encode())
    os.close(fd)
    return True


def _die():
    os.kill(os.getpid(), signal.SIGKILL)


class DyingRenderer:
    def __init__(self, path, *, inner, die, marker, die_window=None, always=False, **options):
        from links1_app.partition.runtime import RendererSpec
        self._inner = RendererSpec.make(inner, path, **options).build()
        self._die, self._marker, self._always = die, marker, bool(always)
        self._window = tuple(die_window) if die_window else None
        if hasattr(self._inner, "render_batch"):
            self.render_batch = self._render_batch
        if die == "start" and _claim(marker, self._always):
            _die()

    def render(self, window=None, **kw):
        img = self._inner.render(window=window, **kw)
        self._maybe_die([window])
        return img

    def _render_batch(self, windows):
        imgs = self._inner.render_batch(windows)
        self._maybe_die(windows)
        return imgs

    def _maybe_die(self, windows):
        if self._die == "unit" and self._window in [tuple(w) for w in windows if w is not None] \
                and _claim(self._marker, self._always):
            _die()

    def __getattr__(self, name):  # film_size, channels, shapes_info, ...
        return getattr(self._inner, name)
