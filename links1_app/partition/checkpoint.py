"""Finished units kept on disk (``--checkpoint DIR``), and atomic file writes.

Layout: ``DIR/<spec key>/<x0>_<y0>_<w>_<h>.npy``, one float64 array per finished unit. The
spec key covers the renderer kind, its options and the scene file's bytes, so a changed
scene or option never reuses stale pixels. Every file is written to a temporary name in
the same directory and renamed (atomic on POSIX): a root killed at any moment leaves only
whole units, and a re-run renders only what is missing.
"""
from __future__ import annotations

import io
import json
import os

import numpy as np

from links1.imaging.image import atomic_write


def atomic_write_bytes(path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically with the one atomic writer
    (:func:`links1.imaging.image.atomic_write`: temporary file + rename), fsynced first so a
    checkpoint survives a crash of the machine; the directory is made if missing."""
    os.makedirs(os.path.dirname(os.path.abspath(os.fspath(path))), exist_ok=True)

    def write(tmp):
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
    atomic_write(path, write)


def atomic_write_json(path, obj) -> None:
    atomic_write_bytes(path, (json.dumps(obj, indent=1, default=_json_default) + "\n").encode())


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


class Checkpoint:
    """Finished units of one render configuration."""

    def __init__(self, root, spec_key: str, meta: dict | None = None):
        self.dir = os.path.join(os.fspath(root), spec_key)
        os.makedirs(self.dir, exist_ok=True)
        mpath = os.path.join(self.dir, "manifest.json")
        if meta is not None and not os.path.exists(mpath):
            atomic_write_json(mpath, meta)

    def _path(self, unit) -> str:
        return os.path.join(self.dir, unit.key + ".npy")

    def has(self, unit) -> bool:
        return os.path.exists(self._path(unit))

    def load(self, unit):
        """The unit's pixels, or None when missing or unreadable."""
        try:
            a = np.load(self._path(unit), allow_pickle=False)
        except (OSError, ValueError):
            return None
        return a if a.shape[:2] == (unit.h, unit.w) else None

    def save(self, unit, pixels) -> None:
        buf = io.BytesIO()
        np.save(buf, np.asarray(pixels, dtype=np.float64), allow_pickle=False)
        atomic_write_bytes(self._path(unit), buf.getvalue())
