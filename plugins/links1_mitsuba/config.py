"""The parameters of ``links1_whitted`` (their one home): :class:`Config`, read from the
integrator's properties with the rules the core's reader applies (links1.scene.params), read
and set through the integrator (``Links1Whitted.max_depth``, ...) and read by the engine's parts
when they render (``Tracer``: depth, weight threshold, light samples; ``Launches``: seed, AOVs,
freezing; ``Tables``: verify_scene; ``Gradients``: adaptive, projective).
"""
from __future__ import annotations

import dataclasses

from links1.scene.params import default as l1_default
from links1.scene.params import read as l1_read
from links1.tracing.adaptive import DEFAULT_ADAPTIVE_DEPTH, check_options
from links1.tracing.aovs import check_aovs as parse_aovs  # the one AOV table and checker (links1/tracing/aovs.py)


@dataclasses.dataclass
class Config:
    """The integrator's parameters (``links1_whitted``'s properties, docs/guide.md)."""

    #: surface interactions along one branch of the ray tree (primary hit = 1)
    max_depth: int
    #: seed of the sample pattern (links1.maths.sampling)
    seed: int
    #: a secondary ray is traced only if its weight in the pixel exceeds this
    min_weight: float
    #: shadow rays per sampled light per hit
    light_samples: int
    #: the extra channels (links1.tracing.aovs)
    aovs: list
    #: adaptive anti-aliasing threshold (links1.tracing.adaptive) instead of the sampler's count
    adaptive: float | None = None
    adaptive_depth: int = DEFAULT_ADAPTIVE_DEPTH
    #: check the scene's parameters (mi.traverse) before reusing the prepared tables;
    #: MitsubaRenderer, whose scene is its own, turns it off for its launches
    verify_scene: bool = True
    #: render windows through a frozen function (launch.Launches._frozen_fn): no re-tracing
    use_freeze: bool = True
    #: add the visibility (boundary) term to the derivatives (boundary.py)
    projective: bool = False

    @classmethod
    def from_props(cls, props) -> "Config":
        """The parameters of ``props`` checked by the rules the core's reader applies too
        (links1.scene.params)."""
        def param(name, conv):
            return l1_read("links1_whitted", name, conv(props[name]) if name in props else None)
        md = param("max_depth", int)
        if md == -1:
            md = l1_default("links1_whitted", "max_depth")
        if md < 1:
            raise ValueError(f"links1_whitted: max_depth must be >= 1 (or -1), got {md}")
        cfg = cls(max_depth=md, seed=param("seed", int), min_weight=param("min_weight", float),
                  light_samples=param("light_samples", int), aovs=parse_aovs(props.get("aovs", "")),
                  projective=param("projective", bool))
        if "adaptive" in props:
            try:
                cfg.adaptive, cfg.adaptive_depth = check_options(
                    props.get("adaptive"), props.get("adaptive_depth", DEFAULT_ADAPTIVE_DEPTH))
            except Exception as e:
                raise ValueError(f"links1_whitted: {e}") from None
        elif "adaptive_depth" in props:
            raise ValueError("links1_whitted: adaptive_depth needs adaptive")
        return cfg
