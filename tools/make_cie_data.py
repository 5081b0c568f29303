"""Write ``links1/data/cie1931_d65.csv``: the colour tables Mitsuba 3.9.1 converts spectra with.

Run once (``python tools/make_cie_data.py``); the CSV is committed and read by
:mod:`links1.shading.spectra` (nothing is fetched at run time). The source is the installed Mitsuba
itself (``scalar_rgb``), so the core uses exactly its float32 tables:

* CIE 1931 2-degree colour matching functions x, y, z at 360, 365, ..., 830 nm (95 samples):
  ``mi.cie1931_xyz`` evaluated at the table's own wavelengths, where its linear
  interpolation weight is exactly 0 or 1, returns the stored float32 values unchanged;
* the CIE D65 illuminant at the same wavelengths (relative power, 100 at 560 nm):
  ``mi.cie_d65`` returns ``float32(d65 * float32(MI_CIE_D65_NORMALIZATION))``; the table's
  values have 6 significant digits, so dividing the normalisation out and rounding to 6
  digits recovers them; every value is checked by recomputing Mitsuba's result from it.
"""
from __future__ import annotations

import os
import sys

import numpy as np


def main() -> int:
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    lo, hi, n = float(mi.MI_CIE_MIN), float(mi.MI_CIE_MAX), 95
    wl = np.linspace(lo, hi, n)
    xyz = np.array([[float(c) for c in mi.cie1931_xyz(float(w))] for w in wl], dtype=np.float32)
    norm32 = np.float32(mi.MI_CIE_D65_NORMALIZATION)
    d65 = []
    for w in wl:
        got = np.float32(mi.cie_d65(float(w)))
        v = np.float32(float(f"{float(got) / float(norm32):.6g}"))
        if np.float32(v * norm32) != got:
            raise SystemExit(f"D65 at {w} nm: no 6-digit value reproduces Mitsuba's {got!r}")
        d65.append(v)
    out = os.path.join(os.path.dirname(__file__), "..", "links1", "data", "cie1931_d65.csv")
    with open(out, "w") as f:
        f.write(f"# CIE 1931 2-degree observer and CIE D65, as tabulated in Mitsuba {mi.__version__} "
                "(float32 values); written by tools/make_cie_data.py\n")
        f.write("wavelength_nm,x,y,z,d65\n")
        for w, (x, y, z), d in zip(wl, xyz, d65):
            f.write(f"{w:g},{x!r},{y!r},{z!r},{d!r}\n".replace("np.float32(", "").replace(")", ""))
    print(f"wrote {os.path.normpath(out)} ({n} rows)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
