"""A fake renderer following the Renderer contract, for the partitioning tests.

Every pixel is a deterministic function of (x, y, channel), so bit equality of assembled
frames is testable without a real scene. Hooks make failures happen at chosen units:
``kill_window`` SIGKILLs the rendering process the first time that window is rendered
(``marker`` records that it happened), ``hold_window`` blocks on a ``distributed.Event``
after writing the worker's pid to ``marker``, ``count_file`` gets one line per rendered
window (to count work across processes), ``kill_in_send=(window, delay_s)`` SIGKILLs the
process ``delay_s`` after it returns that window's pixels (the first time): with a large window,
while the result is on its way to the root.
"""
from __future__ import annotations

import os
import signal
import time

import numpy as np

from links1.sensor.camera import Camera

FAKE = "tests.dist.fake_renderer:FakeRenderer"


def _mark(path):
    """Write this process's pid to ``path`` atomically (a test that waits for the file reads
    it as soon as it exists: written in place, it could read it empty)."""
    tmp = f"{path}.{os.getpid()}.tmp"
    with open(tmp, "w") as f:
        f.write(str(os.getpid()))
    os.replace(tmp, path)


def pixel_values(x0, y0, w, h, nc):
    y, x = np.mgrid[y0:y0 + h, x0:x0 + w].astype(np.int64)
    out = np.empty((h, w, nc))
    for c in range(nc):
        v = (x * 73856093) ^ (y * 19349663) ^ ((c + 1) * 83492791)
        out[..., c] = (v % 1000003) / 1000003.0 + np.sin(0.1 * x + 0.07 * y + c)
    return out


class FakeRenderer:
    kind = "fake"

    def __init__(self, path="fake", *, width=48, height=32, nc=4, sleep_per_row=0.0, kill_window=None,
                 hold_window=None, event=None, marker=None, count_file=None, max_depth=1, kill_in_send=None):
        self.path = path
        self.width, self.height, self.nc = int(width), int(height), int(nc)
        self.sleep_per_row = float(sleep_per_row)
        self.kill_window = tuple(kill_window) if kill_window else None
        self.hold_window = tuple(hold_window) if hold_window else None
        self.event, self.marker, self.count_file = event, marker, count_file
        self.max_depth = max_depth
        self.kill_in_send = (tuple(kill_in_send[0]), float(kill_in_send[1])) if kill_in_send else None
        # camera at the origin looking down +z (+x to the left), 60 degrees across
        self.camera = Camera(fov_x=60.0, width=self.width, height=self.height)

    @property
    def film_size(self):
        return self.width, self.height

    @property
    def channels(self):
        return ["R", "G", "B", "cost"][: self.nc] + [f"c{i}" for i in range(4, self.nc)]

    def render(self, window=None, progress=False):
        x0, y0, w, h = window if window is not None else (0, 0, self.width, self.height)
        win = (int(x0), int(y0), int(w), int(h))
        if self.count_file:
            with open(self.count_file, "a") as f:
                f.write(f"{win}\n")
        if self.kill_window == win and self.marker and not os.path.exists(self.marker):
            _mark(self.marker)
            os.kill(os.getpid(), signal.SIGKILL)
        if self.kill_in_send and self.kill_in_send[0] == win and self.marker and not os.path.exists(self.marker):
            import threading
            _mark(self.marker)
            delay = self.kill_in_send[1]
            threading.Thread(target=lambda: (time.sleep(delay), os.kill(os.getpid(), signal.SIGKILL)),
                             daemon=True).start()
        if self.hold_window == win and self.marker:
            if not os.path.exists(self.marker):
                _mark(self.marker)
            from distributed import Event
            Event(self.event).wait(timeout=60)
        if self.sleep_per_row:
            time.sleep(self.sleep_per_row * h)
        return pixel_values(*win, self.nc)

    def shapes_info(self):
        # three boxes in front of the camera; the middle one reflective
        boxes = [((-3, -1, 8), (-1, 1, 10)), ((-0.5, -0.5, 5), (0.5, 0.5, 6)), ((1, -2, 9), (4, 0, 12))]
        return [{"index": i, "name": f"b{i}", "type": "quadric", "bounds_lo": list(lo), "bounds_hi": list(hi),
                 "reflective": i == 1, "transmissive": False, "nbytes": 1000 * (i + 1)}
                for i, (lo, hi) in enumerate(boxes)]
