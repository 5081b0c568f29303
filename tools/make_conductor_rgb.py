"""Write ``links1/data/conductors_rgb.json``: Mitsuba 3.9.1's RGB ``(eta, k)`` of each conductor
preset (the ``material`` parameter of ``conductor`` / ``roughconductor``), as its RGB variants
compute them from ``data/ior/<name>.{eta,k}.spd`` (``spectrum_list_to_srgb``), read back from
the BSDF Mitsuba builds.

Usage::

    python tools/make_conductor_rgb.py links1/data/conductors_rgb.json
"""
from __future__ import annotations

import json
import os
import sys

import mitsuba as mi


def main() -> int:
    mi.set_variant("scalar_rgb")
    mi.set_log_level(mi.LogLevel.Error)   # out-of-gamut clamping warnings: Mitsuba's own values
    folder = os.path.join(os.path.dirname(mi.__file__), "data", "ior")
    names = sorted(f[:-len(".eta.spd")] for f in os.listdir(folder)
                   if f.endswith(".eta.spd") and os.path.exists(os.path.join(folder, f[:-8] + ".k.spd")))
    table = {}
    for name in names:
        params = mi.traverse(mi.load_dict({"type": "conductor", "material": name}))
        table[name] = {"eta": [float(v) for v in params["eta.value"]],
                       "k": [float(v) for v in params["k.value"]]}
    with open(sys.argv[1], "w") as fh:
        json.dump(table, fh, indent=1)
        fh.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
