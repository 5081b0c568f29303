"""Mitsuba's ``perspective`` and ``orthographic`` sensors: the same pixel gives the same ray.

Camera space: +z forward, +y up, +x to the *left* (Mitsuba's ``look_at`` columns are
left, up, dir). Perspective: a film point ``(x, y)`` in [0, 1]² (row 0 at the top) maps to
the camera direction ``((1 − 2x)·tan(fov_x/2), (1 − 2y)·tan(fov_x/2)/aspect, 1)`` (Mitsuba's
``perspective_projection``), normalised and turned by ``to_world``; the ray starts on the
near plane and ends on the far plane, as in Mitsuba. Orthographic: the film covers
``[-1, 1] x [-1/aspect, 1/aspect]`` of the camera's near plane (Mitsuba's
``orthographic_projection``): the ray starts at ``to_world · (1 − 2x, (1 − 2y)/aspect,
near)``, runs along ``to_world · (0, 0, 1)`` (normalised) and is ``far − near`` long;
``to_world`` may scale (it sizes the sensor plane).

A thin lens (Mitsuba's ``thinlens``: ``aperture_radius``, ``focus_distance``) changes the
perspective ray only: the ray starts at the aperture point ``a = aperture_radius ·
concentric_disk(u, v)`` (camera space, z = 0; ``(u, v)`` the ray's lens sample,
:func:`links1.maths.sampling.lens_samples`) and passes through the point of the focus plane
(``z = focus_distance``) that the pinhole ray of the same film point meets, as Mitsuba's
``ThinLensCamera::sample_ray``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .filters import Filter
from ..maths.sampling import lens_samples, square_to_uniform_disk_concentric
from ..maths.vec import matvec, normalize

FOV_AXES = ("x", "y", "diagonal", "smaller", "larger")
PROJECTIONS = ("perspective", "orthographic")


def fov_x_from(fov: float, axis: str, width: int, height: int) -> float:
    """Convert a field of view given along ``axis`` to the horizontal one (degrees)."""
    aspect = width / height
    t = math.tan(math.radians(fov) / 2.0)
    if axis == "smaller":
        axis = "y" if aspect > 1 else "x"
    elif axis == "larger":
        axis = "x" if aspect > 1 else "y"
    if axis == "x":
        return fov
    if axis == "y":
        return math.degrees(2.0 * math.atan(t * aspect))
    if axis == "diagonal":
        diag = math.hypot(width, height)
        return math.degrees(2.0 * math.atan(t * width / diag))
    raise ValueError(f"fov_axis must be one of {FOV_AXES}, got {axis!r}")


@dataclass
class Camera:
    """A perspective or orthographic camera with an ``hdrfilm`` (full size, crop window,
    reconstruction filter). ``fov_x`` applies to the perspective projection only."""

    to_world: np.ndarray = field(default_factory=lambda: np.eye(4))
    fov_x: float = 39.3077
    near_clip: float = 1e-2
    far_clip: float = 1e4
    width: int = 768
    height: int = 576
    crop_offset: tuple[int, int] = (0, 0)
    crop_size: tuple[int, int] | None = None
    #: the film's reconstruction filter (Mitsuba's default: gaussian)
    rfilter: Filter = field(default_factory=Filter)
    #: ``"perspective"`` or ``"orthographic"``
    projection: str = "perspective"
    #: a thin lens's aperture radius (perspective only), or None: a pinhole
    aperture_radius: float | None = None
    #: a thin lens's distance to the plane in focus (Mitsuba's default: ``far_clip``)
    focus_distance: float | None = None

    def __post_init__(self):
        if self.crop_size is None:
            self.crop_size = (self.width, self.height)
        if self.projection not in PROJECTIONS:
            raise ValueError(f"projection must be one of {PROJECTIONS}, got {self.projection!r}")
        if self.aperture_radius is not None and self.focus_distance is None:
            self.focus_distance = self.far_clip

    @property
    def thin_lens(self) -> bool:
        return self.aperture_radius is not None and self.projection == "perspective"

    @property
    def origin(self) -> np.ndarray:
        return self.to_world[:3, 3].copy()

    def generate_rays(self, x_film: np.ndarray, y_film: np.ndarray, keys=None):
        """Rays through film points in [0,1]² → ``(o, d, tmin, tmax)`` (d unit, world space);
        ``keys``: the rays' keys (their lens samples), needed by a thin lens only."""
        aspect = self.width / self.height
        if self.projection == "orthographic":
            n = np.shape(x_film)[0]
            p_cam = np.stack([1.0 - 2.0 * x_film, (1.0 - 2.0 * y_film) / aspect,
                              np.full(n, self.near_clip)], axis=-1)
            o = matvec(self.to_world[:3, :3], p_cam) + self.to_world[:3, 3]
            d = normalize(np.broadcast_to(self.to_world[:3, 2], (n, 3)).copy())
            return o, d, np.zeros(n), np.full(n, self.far_clip - self.near_clip)
        t = math.tan(math.radians(self.fov_x) / 2.0)
        d_cam = np.stack([(1.0 - 2.0 * x_film) * t, (1.0 - 2.0 * y_film) * t / aspect,
                          np.ones_like(x_film)], axis=-1)
        if self.thin_lens:
            if keys is None:
                raise ValueError("a thin-lens camera's rays need their keys (lens samples)")
            ax, ay = square_to_uniform_disk_concentric(*lens_samples(keys))
            a_cam = np.stack([self.aperture_radius * ax, self.aperture_radius * ay, np.zeros_like(ax)], axis=-1)
            # the pinhole ray's point on the focus plane (d_cam.z = 1), seen from the aperture point
            d_cam = normalize(d_cam * self.focus_distance - a_cam)
            inv_z = 1.0 / d_cam[:, 2]
            o = matvec(self.to_world[:3, :3], a_cam) + self.to_world[:3, 3]
            return o, normalize(matvec(self.to_world, d_cam)), self.near_clip * inv_z, self.far_clip * inv_z
        d_cam = normalize(d_cam)
        inv_z = 1.0 / d_cam[:, 2]
        d = normalize(matvec(self.to_world, d_cam))
        n = d.shape[0]
        o = np.broadcast_to(self.origin, (n, 3)).copy()
        return o, d, self.near_clip * inv_z, self.far_clip * inv_z
