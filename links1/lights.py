"""Light sources (digest §4.1, paper 3-3-1). Every intensity is an RGB triple.

Each light answers one question for a batch of shading points ``p`` (N, 3)::

    wi, dist, L = light.illuminate(p)

``wi`` is the unit direction from ``p`` toward the light, ``dist`` the length of the shadow
ray (``inf`` for a parallel light; the base plane for the cylinder spotlight) and ``L`` the
strength ``L_s`` arriving at ``p`` (zero where the light does not reach).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .vec import dot, length

FALLOFFS = ("none", "inverse_square")


def _rgb(v) -> np.ndarray:
    return np.broadcast_to(np.asarray(v, dtype=np.float64), (3,)).copy()


def _unit(v, what: str) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v)
    if not (np.isfinite(n) and n > 0):
        raise ValueError(f"{what} must be a finite non-zero vector, got {v.tolist()}")
    return v / n


class Light:
    """Interface: ``illuminate(p) -> (wi, dist, L)``."""

    name: str = ""

    def illuminate(self, p: np.ndarray):  # pragma: no cover - interface
        raise NotImplementedError


@dataclass
class ParallelLight(Light):
    """The paper's parallel light; Mitsuba's ``directional`` emitter.

    ``direction`` is the direction the light travels; ``irradiance`` its strength (RGB).
    """

    direction: np.ndarray
    irradiance: np.ndarray
    name: str = ""

    def __post_init__(self):
        self.direction = _unit(self.direction, "directional: direction")
        self.irradiance = _rgb(self.irradiance)

    def illuminate(self, p):
        n = p.shape[0]
        wi = np.broadcast_to(-self.direction, (n, 3))
        return wi, np.full(n, np.inf), np.broadcast_to(self.irradiance, (n, 3))


@dataclass
class PointLight(Light):
    """The paper's point light with a cosine lobe, eq. (3.10).

    ``L_s = L1 + L2 cos θ`` for ``|θ| ≤ 90°`` and ``L1`` beyond, θ measured from
    ``direction`` (the direction of maximum strength). With ``L2 = 0`` and
    ``falloff='inverse_square'`` this is Mitsuba's isotropic ``point`` emitter (``L1`` = intensity).
    """

    position: np.ndarray
    direction: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    L1: np.ndarray = field(default_factory=lambda: np.ones(3))
    L2: np.ndarray = field(default_factory=lambda: np.zeros(3))
    falloff: str = "none"
    name: str = ""

    def __post_init__(self):
        self.position = np.asarray(self.position, dtype=np.float64).reshape(3)
        self.direction = _unit(self.direction, "links1_point: direction")
        self.L1 = _rgb(self.L1)
        self.L2 = _rgb(self.L2)
        if self.falloff not in FALLOFFS:
            raise ValueError(f"falloff must be one of {FALLOFFS}, got {self.falloff!r}")

    def illuminate(self, p):
        to_light = self.position - p
        dist = length(to_light)
        with np.errstate(invalid="ignore", divide="ignore"):
            wi = to_light / np.where(dist > 0, dist, 1.0)[:, None]
        cos_theta = -dot(wi, self.direction)  # angle from the lobe axis to the shaded point
        lobe = np.where(cos_theta[:, None] >= 0.0, cos_theta[:, None], 0.0)
        L = self.L1 + self.L2 * lobe  # eq. (3.10)
        if self.falloff == "inverse_square":
            with np.errstate(divide="ignore"):
                L = L / np.where(dist > 0, dist * dist, np.inf)[:, None]
        return wi, dist, L


@dataclass
class CylinderSpotLight(Light):
    """The paper's spotlight: parallel light inside a semi-infinite cylinder (3-3-1 iii).

    ``origin`` is the centre of the base disc, ``direction`` the direction the light travels,
    ``radius`` the cylinder's radius. Points behind the base plane or farther than ``radius``
    from the axis are unlit; shadow rays end at the base plane.
    """

    origin: np.ndarray
    direction: np.ndarray
    radius: float
    intensity: np.ndarray
    name: str = ""

    def __post_init__(self):
        self.origin = np.asarray(self.origin, dtype=np.float64).reshape(3)
        self.direction = _unit(self.direction, "links1_spot: direction")
        self.radius = float(self.radius)
        if not (np.isfinite(self.radius) and self.radius > 0):
            raise ValueError(f"links1_spot: radius must be > 0, got {self.radius}")
        self.intensity = _rgb(self.intensity)

    def illuminate(self, p):
        rel = p - self.origin
        s = dot(rel, self.direction)  # distance in front of the base plane
        radial = rel - s[:, None] * self.direction
        rho2 = dot(radial, radial)
        inside = (s > 0.0) & (rho2 <= self.radius * self.radius)
        n = p.shape[0]
        wi = np.broadcast_to(-self.direction, (n, 3))
        L = np.where(inside[:, None], self.intensity, 0.0)
        return wi, np.where(inside, s, 0.0), L


@dataclass
class ConeSpotLight(Light):
    """Mitsuba's ``spot`` emitter: a cone with a linear fall-off between ``beam_width`` and
    ``cutoff_angle`` (degrees), inverse-square distance fall-off."""

    to_world: np.ndarray
    intensity: np.ndarray
    cutoff_angle: float = 20.0
    beam_width: float | None = None
    name: str = ""

    def __post_init__(self):
        self.intensity = _rgb(self.intensity)
        if self.beam_width is None:
            self.beam_width = self.cutoff_angle * 3.0 / 4.0
        self.position = self.to_world[:3, 3].copy()
        self.axis = _unit(self.to_world[:3, 2], "spot: to_world z axis")
        self.cutoff = np.deg2rad(self.cutoff_angle)
        self.beam = np.deg2rad(self.beam_width)

    def illuminate(self, p):
        to_light = self.position - p
        dist = length(to_light)
        with np.errstate(invalid="ignore", divide="ignore"):
            wi = to_light / np.where(dist > 0, dist, 1.0)[:, None]
        cos_theta = -dot(wi, self.axis)
        theta = np.arccos(np.clip(cos_theta, -1.0, 1.0))
        ramp = np.where(cos_theta >= np.cos(self.beam), 1.0,
                        (self.cutoff - theta) / max(self.cutoff - self.beam, 1e-300))
        ramp = np.where(cos_theta > np.cos(self.cutoff), ramp, 0.0)
        with np.errstate(divide="ignore"):
            L = self.intensity * (ramp / np.where(dist > 0, dist * dist, np.inf))[:, None]
        return wi, dist, L
