"""The core's in-memory scene: what the XML loader builds and the integrator renders."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .camera import Camera


@dataclass
class Scene:
    """A loaded scene.

    Attributes
    ----------
    camera : Camera
    shapes : list of links1.shapes.Shape (``shape.index`` is its position here: the ``id`` AOV)
    lights : list of links1.lights.Light
    spp : int            sample count from the scene's sampler (default 1)
    max_depth : int      surface interactions along one branch of the ray tree (default 5)
    background : (3,)    radiance of rays that escape (Mitsuba ``constant`` emitters)
    environments : list  ``EnvironmentMap`` lights (also in ``lights``): escaping rays add them
    integrator : str     the integrator the file names (the core always traces LINKS-1 Whitted)
    path : str | None    the scene file
    """

    camera: Camera
    shapes: list = field(default_factory=list)
    lights: list = field(default_factory=list)
    spp: int = 1
    max_depth: int = 5
    background: np.ndarray = field(default_factory=lambda: np.zeros(3))
    integrator: str = "links1_whitted"
    environments: list = field(default_factory=list)  # envmap lights: escaping rays add their eval
    path: str | None = None
    _accel: object = field(default=None, repr=False)
    _plan: object = field(default=None, repr=False)  # links1.integrator.ScenePlan, built on first use

    def __post_init__(self):
        for i, s in enumerate(self.shapes):
            s.index = i

    @property
    def accel(self):
        """The hierarchical bounding boxes over all shapes (paper 3-2-4), built on first use."""
        if self._accel is None:
            from .accel import Accel
            self._accel = Accel(self.shapes)
        return self._accel

    def __repr__(self) -> str:
        c = self.camera
        return (f"Scene(path={self.path!r}, film={c.width}x{c.height}, shapes={len(self.shapes)}, "
                f"lights={len(self.lights)}, spp={self.spp}, max_depth={self.max_depth})")
