"""A node's renderer threads never leave Mitsuba unable to read an EXR file.

Mitsuba 3.9.1 reads EXR files (bitmap textures, environment maps) with tasks on Dr.Jit's
thread pool; with the pool set to one thread (``dr.set_thread_count(1)``) that read waits
forever. ``set_threads`` gives a Mitsuba node at least two, so a node of a 2-core machine split
between two workers still loads such a scene. Run in a child process: a hang must not take the
test session with it.
"""
from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

pytest.importorskip("mitsuba")

SCRIPT = textwrap.dedent("""
    import numpy as np, drjit as dr, mitsuba as mi
    from links1_app.partition.runtime import set_threads
    mi.set_variant("llvm_ad_rgb")
    path = {path!r}
    mi.Bitmap(np.full((4, 4, 3), 0.5, dtype=np.float32)).write(path)
    set_threads(1, "mitsuba")
    bitmap = mi.Bitmap(path)
    print("read", dr.thread_count(), float(np.array(bitmap).mean()))
""")


def test_one_thread_per_node_still_reads_exr_files(tmp_path):
    code = SCRIPT.format(path=str(tmp_path / "half.exr"))
    try:
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        pytest.fail("reading an EXR file after set_threads(1, 'mitsuba') hangs")
    assert out.returncode == 0, out.stderr[-2000:]
    words = out.stdout.split()
    assert words[0] == "read" and int(words[1]) >= 2 and float(words[2]) == pytest.approx(0.5)
