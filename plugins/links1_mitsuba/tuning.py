"""The switches of ``links1_whitted`` (its one home): one frozen :class:`Tuning` value, part of
the frozen launches' key and of the prepared tables' identity.

Each switch turns one acceleration on or off (for before/after runs and for tests
that compare it with the plain code); none changes what is rendered beyond float32 rounding
(the tests of each acceleration say how much).

The switches belong to each integrator: its engine takes them once per frame
(``Engine.current_tuning``: its own ``Tuning``, set with ``integrator.tuning = ...``, or
without one this module's default) and hands that value to its parts (``Tables.prepare``,
the frame's ``raytree.Tracer``, the gradients), which read no global. This module holds the
default, for every integrator without its own, whenever made::

    from links1_mitsuba import tuning
    with tuning.tuned(split=False):          # the default for a block
        img = mi.render(scene)
    tuning.set_tuning(light_buffer=False)    # the default from now on (returns the previous one)
    scene.integrator().tuning = tuning.Tuning(split=False)   # that integrator's alone

A change takes effect at the next frame: the launches recorded by
:func:`drjit.freeze` are keyed on the whole value (``launch.Launches._key``), and
the tables that depend on it (:meth:`Tuning.tables_key`: the light buffers, the BVH) are
rebuilt by ``prepare`` when their part differs from the one they were built with.
"""
from __future__ import annotations

import contextlib
import dataclasses


@dataclasses.dataclass(frozen=True)
class Tuning:
    """The switches of ``links1_whitted``; the defaults are what it renders with."""

    #: transparent shadow rays: Embree's preliminary hit, the full surface record (for the next
    #: crossing's origin) only at transparent hits (False: ``scene.ray_intersect``)
    preliminary: bool = True
    #: shadow rays first tested against the boxes of the few Mitsuba shapes that can occlude
    #: their light (``shadow_plan.occluder_boxes``); Embree only where one is met
    box_cull: bool = True
    #: camera rays of a pinhole camera find their nearest BVH quadric through the eye's buffer
    #: (``lightbuffer.plan_eye``) where there is one (False: the BVH walk)
    eye_buffer: bool = True
    #: transparent shadows through few transparent Mitsuba shapes as any-hit queries on
    #: sub-scenes (``shadow_plan.shadow_split``) instead of the walk over the crossings
    split: bool = True
    #: the camera rays' hits' shadow rays, in scenes without delta lobes (``raytree.Tracer.level``):
    #: their any-hit queries on Mitsuba's shapes in Embree's coherent mode (``scene.ray_test``'s
    #: ``coherent``; the same answers), the rays of a packet coming from neighbouring hits toward
    #: one light (False: the incoherent mode, as Mitsuba's ``direct``; other shadow rays always)
    coherent_shadows: bool = True
    #: direct light under a symbolic ``dr.if_stmt`` on the hit: a packet of escaped rays skips
    #: it instead of computing it masked (False: the straight-line code)
    skip_misses: bool = True
    #: light buffers (``lightbuffer.plan``, ``plan_eye``) built with the tables (False: none;
    #: shadow and camera rays walk the BVH)
    light_buffer: bool = True
    #: an explicit choice: a frame rendered while parameters have gradients enabled that does
    #: not depend on the seed (spp 1, no sampled light) and is one block is the derivative
    #: pass's, its graph kept for ``dr.backward`` instead of rendering the frame twice
    #: (``gradients.Gradients.render_keeping_graph``); its values are the primal's to float32
    #: rounding. False (default): the primal frame, bit for bit, then the pass again
    keep_graph: bool = False
    #: the camera rays' hits send no shadow ray toward a light at a pinhole camera's eye (their
    #: shadow rays would retrace the camera rays: ``shadow_plan.eye_lights``; False: tested, and
    #: at a grazing hit the test may find the hit's neighbour: 9 of 262,144 pixels of
    #: ``data_instancing`` at spp 16 lose one sample in 16)
    eye_lights: bool = True
    #: custom quadrics with finite bounds go under a BVH (bvh.py) from this many on
    bvh_min: int = 8

    def __post_init__(self):
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            want = int if f.type in ("int", int) else bool
            if not isinstance(v, want) or (want is int and isinstance(v, bool)):
                raise TypeError(f"links1_whitted tuning: {f.name} must be {want.__name__}, got {v!r}")
        if self.bvh_min < 1:
            raise ValueError(f"links1_whitted tuning: bvh_min must be >= 1, got {self.bvh_min}")

    def key(self) -> int:
        """The whole value as one Python int, part of a frozen launch's key (``launch.py``):
        bit k the k-th switch, ``bvh_min`` above them, and bit 62 set. One number rather than a
        tuple of bools: :func:`drjit.freeze` (Dr.Jit 1.5) does not tell apart keys that differ
        only in where repeated ``True``/``False`` objects sit (``f(x, (False, (True, False)))``
        replays the recording of ``f(x, (False, (True, True)))``: box_cull=False replayed the
        default's launch, ``tests/plugins/test_tuning.py``); bit 62 keeps the number off
        CPython's shared small ints (a repeated object). Made once a value (it is frozen): a
        frame asks for it."""
        key = self.__dict__.get("_key")
        if key is None:
            flags = [getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "bvh_min"]
            bits = sum(int(b) << k for k, b in enumerate(flags))
            key = (1 << 62) | (min(self.bvh_min, (1 << 40) - 1) << len(flags)) | bits
            object.__setattr__(self, "_key", key)
        return key

    def tables_key(self) -> tuple:
        """The part that the prepared tables are built from (``tables.py``: the light buffers,
        which quadrics go under the BVH); a change rebuilds them."""
        return (self.light_buffer, self.bvh_min)


_current = Tuning()


def current() -> Tuning:
    """The default tuning: what every ``links1_whitted`` without its own renders with now."""
    return _current


def set_tuning(value: Tuning | None = None, **changes) -> Tuning:
    """Make ``value`` (default: the current one) with ``changes`` (field names of
    :class:`Tuning`) the current tuning; returns the previous one."""
    global _current
    prev = _current
    base = prev if value is None else value
    if not isinstance(base, Tuning):
        raise TypeError(f"links1_whitted tuning: expected a Tuning, got {type(base).__name__}")
    _current = dataclasses.replace(base, **changes) if changes else base
    return prev


@contextlib.contextmanager
def tuned(value: Tuning | None = None, **changes):
    """``with tuned(split=False): ...``: :func:`set_tuning` for the block, restored after it."""
    prev = set_tuning(value, **changes)
    try:
        yield _current
    finally:
        set_tuning(prev)
