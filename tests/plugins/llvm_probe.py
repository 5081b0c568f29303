"""Probe Mitsuba's LLVM backend in a subprocess (a bad libLLVM aborts the whole process)."""
from __future__ import annotations

import functools
import subprocess
import sys

import pytest

PROBE = """
import mitsuba as mi, drjit as dr
mi.set_variant('llvm_ad_rgb')
x = dr.arange(mi.Float, 8)
print(float(dr.sum(dr.minimum(x, 3.0))[0] if hasattr(dr.sum(x), '__len__') else dr.sum(dr.minimum(x, 3.0))))
"""


@functools.lru_cache(maxsize=None)
def llvm_status() -> tuple[bool, str]:
    try:
        res = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=300)
    except subprocess.TimeoutExpired:
        return False, "the LLVM probe timed out"
    if res.returncode != 0:
        tail = (res.stderr or res.stdout).strip().splitlines()[-1:] or ["(no output)"]
        return False, f"mitsuba's llvm_ad_rgb variant cannot run here: {tail[0]} (install libllvm19)"
    return True, ""


def require_llvm_variant(variant: str = "llvm_ad_rgb") -> str:
    ok, why = llvm_status()
    if not ok:
        pytest.skip(why)
    import mitsuba as mi
    mi.set_variant(variant)
    return variant
