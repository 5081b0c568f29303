"""Dr.Jit helpers shared by the parts of ``links1_whitted``: the sample pattern's hash
(``mix32``, ``u24``), colour / vector literals, gathers, the next float up.

:func:`define_util` makes them for the Mitsuba variant in use.
"""
from __future__ import annotations

from types import SimpleNamespace

INF = float("inf")
_M1 = 0x7FEB352D
_M2 = 0x846CA68B


def define_util(mi, dr):
    """The helpers for the variant in use: ``mix32``, ``u24``, ``c3``, ``v3``, ``gather3``, ``next_up``,
    as attributes of one namespace."""

    def mix32(x):
        """lowbias32 on UInt32 (wrapping), as links1.sampling.mix32."""
        x = x ^ (x >> 16)
        x = x * _M1
        x = x ^ (x >> 15)
        x = x * _M2
        x = x ^ (x >> 16)
        return x

    def u24(x):
        return mi.Float(x >> 8) * (2.0 ** -24)

    def c3(v):
        return mi.Color3f(float(v[0]), float(v[1]), float(v[2]))

    def v3(v):
        return mi.Vector3f(float(v[0]), float(v[1]), float(v[2]))

    def gather3(table, idx, active=True):
        return dr.gather(mi.Color3f, table, idx, active)

    def next_up(x):
        """The next float32 above positive ``x`` (infinity stays): a strict ``t < limit`` test
        against ``next_up(t)`` accepts a tie at ``t``."""
        return dr.select(dr.isfinite(x) & (x >= 0), dr.reinterpret_array(
            mi.Float, dr.reinterpret_array(mi.UInt32, x) + 1), x)

    return SimpleNamespace(mix32=mix32, u24=u24, c3=c3, v3=v3, gather3=gather3, next_up=next_up)
