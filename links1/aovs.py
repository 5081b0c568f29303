"""The AOV table: which extra channels a render can carry, their names, and the one checker.

One table for every renderer (the core, ``links1_whitted`` in :mod:`links1_mitsuba`), back end
and worker count, in Mitsuba's ``name.X`` convention (what its ``aov`` integrator writes:
depth ``.T``, normals ``.X .Y .Z``, shape index ``.I``); ``cost`` (ray-primitive tests) and
``samples`` (camera samples of the pixel: spp, or the adaptive lattice points it used) are
counts, ``.N``. docs/architecture.md, "Render".
"""
from __future__ import annotations

from .errors import UsageError

#: AOV -> its channel names, in the order they follow R, G, B.
AOVS = {"depth": ("depth.T",), "normal": ("normal.X", "normal.Y", "normal.Z"), "id": ("id.I",),
        "cost": ("cost.N",), "samples": ("samples.N",)}


def check_aovs(aovs) -> tuple[str, ...]:
    """The AOV names of ``aovs``, checked: None, a sequence of names, or one string of names
    separated by commas or semicolons (the CLI's ``--aov``, ``links1_whitted``'s ``aovs``
    property). Blank names are dropped; an unknown one is a one-line :class:`UsageError` (a
    ``ValueError``) naming the choices."""
    if aovs is None:
        return ()
    items = aovs.replace(";", ",").split(",") if isinstance(aovs, str) else aovs
    names = tuple(s for s in (str(a).strip() for a in items if a is not None) if s)
    for a in names:
        if a not in AOVS:
            raise UsageError(f"unknown AOV {a!r}; choose from {', '.join(AOVS)}")
    return names


def channel_names(aovs=()) -> list[str]:
    """Channel names of a render with the given AOVs: R, G, B, then the AOV channels."""
    names = ["R", "G", "B"]
    for a in aovs:
        names.extend(AOVS[a])
    return names


def aov_channel(channels, aov: str) -> int | None:
    """Index of the first channel of ``aov`` in ``channels`` (a render's channel names), or
    None when the render has no such AOV."""
    first = AOVS[aov][0]
    return list(channels).index(first) if first in channels else None
