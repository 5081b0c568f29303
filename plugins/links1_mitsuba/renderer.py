"""``MitsubaRenderer``: the Renderer contract of docs/architecture.md on Mitsuba 3."""
from __future__ import annotations

import numpy as np

from ._registry import register
from links1.tracing.aovs import channel_names
from links1.tracing.aovs import check_aovs as parse_aovs  # the one AOV table and checker (links1/tracing/aovs.py)
from links1.scene.scene import check_sensor_index

from .integrator import DEFAULT_MIN_WEIGHT
from .util import kind_of


def resize_film(sensor, width, height):
    """Give ``sensor``'s film a new resolution keeping ``x_fov`` (crop = whole film)."""
    import mitsuba as mi
    size = sensor.film().size()
    w = int(size[0]) if width is None else int(width)
    h = int(size[1]) if height is None else int(height)
    if w <= 0 or h <= 0:
        raise ValueError(f"resolution must be positive, got {w}x{h}")
    prm = mi.traverse(sensor)
    keys = set(prm.keys())
    x_fov = prm["x_fov"] if "x_fov" in keys else None
    prm["film.size"] = [w, h]
    prm["film.crop_size"] = [w, h]
    prm["film.crop_offset"] = [0, 0]
    if x_fov is not None:
        prm["x_fov"] = x_fov  # the sensor derives its projection from the new size and this
    prm.update()


class MitsubaRenderer:
    """Load a scene file once; render windows of its film many times.

    Parameters
    ----------
    path : str
        Scene file (Mitsuba 3 XML with links1 plugins).
    params : dict, optional
        ``$name`` substitutions.
    spp, max_depth : int, optional
        Override the file's sampler count / integrator depth.
    seed : int
        Seed of the sample pattern (links1.maths.sampling).
    aovs : sequence of str
        Extra channels: ``depth``, ``normal``, ``id``, ``cost``.
    variant : str, optional
        Mitsuba variant (default ``llvm_ad_rgb``, ``cuda_ad_rgb`` with a GPU).
    integrator : {"links1", "scene"}
        ``"scene"`` renders with the integrator the file names (Mitsuba's ``path``/``direct``
        ...) through ``mi.render`` with a crop window (kernels then recompile per window).
    width, height : int, optional
        Override the film resolution, keeping the horizontal field of view (as the core's
        ``links1.tracing.render._resized``); the crop window becomes the whole new film.
    min_weight : float
        A secondary ray is traced only if its weight in the pixel (largest RGB component of the
        product of the r / t factors down the ray tree) exceeds this; default: the scene's
        ``links1_whitted`` ``min_weight``, else 1/255 (POV-Ray's adc_bailout, as the core); 0
        traces every branch. links1 integrator only.
    light_samples : int, optional
        Shadow rays per sampled light and hit; default: the scene's ``links1_whitted``
        ``light_samples``, else 1. links1 integrator only.
    adaptive, adaptive_depth : float, int, optional
        Adaptive anti-aliasing instead of ``spp`` (:mod:`links1.tracing.adaptive`, as the core's
        ``links1.tracing.render``): one launch per refinement level over the new lattice points
        (:meth:`Links1Whitted.trace_points`). links1 integrator only.
    sensor : int, optional
        Which of the file's sensors renders (index in file order, default 0): its camera,
        film and sample count (as ``mi.render(scene, sensor=k)``).

    ``render(window)`` passes the window to the kernels as run-time values: no recompilation
    per window; a window renders the same bits as the same pixels of the full frame.
    """

    kind = "mitsuba"

    def __init__(self, path, *, params=None, spp=None, max_depth=None, seed=0, aovs=(),
                 variant=None, integrator="links1", width=None, height=None,
                 min_weight=None, light_samples=None, adaptive=None, adaptive_depth=None, sensor=None):
        self.variant = register(variant)
        import mitsuba as mi
        from .loader import load_file
        self.path = str(path)
        self.scene = load_file(self.path, links1_integrator=integrator, params=params)
        self.mode = integrator
        self.seed = int(seed)
        self.aovs = parse_aovs(aovs)
        self.sensor_index = check_sensor_index(self.path, sensor, len(self.scene.sensors()))
        self.sensor = sensor = self.scene.sensors()[self.sensor_index]
        if width is not None or height is not None:
            resize_film(sensor, width, height)
        self.min_weight = DEFAULT_MIN_WEIGHT if min_weight is None else float(min_weight)
        if not self.min_weight >= 0:
            raise ValueError(f"min_weight must be >= 0, got {min_weight}")
        self.light_samples = 1 if light_samples is None else int(light_samples)
        self.spp = int(spp) if spp else int(sensor.sampler().sample_count())
        if self.spp < 1:
            raise ValueError(f"spp must be >= 1, got {self.spp}")
        size = sensor.film().size()
        self._film = (int(size[0]), int(size[1]))
        self.adaptive = None
        if adaptive is not None:
            from links1.tracing.adaptive import check_options
            from links1.tracing.adaptive import DEFAULT_ADAPTIVE_DEPTH
            self.adaptive, self.adaptive_depth = check_options(
                adaptive, DEFAULT_ADAPTIVE_DEPTH if adaptive_depth is None else adaptive_depth)
        if integrator == "links1":
            self.integrator = self.scene.integrator()
            if max_depth is not None:
                if int(max_depth) < 1:
                    raise ValueError(f"max_depth must be >= 1, got {max_depth}")
                self.integrator.max_depth = int(max_depth)
            # the scene's own links1_whitted values (the integrator read them) unless given
            if min_weight is not None:
                self.integrator.min_weight = self.min_weight
            self.min_weight = float(self.integrator.min_weight)
            if light_samples is not None:
                if int(light_samples) < 1:
                    raise ValueError(f"light_samples must be >= 1, got {light_samples}")
                self.integrator.light_samples = int(light_samples)
            self.light_samples = int(self.integrator.light_samples)
            from links1.scene.params import check_resources   # before any film-sized allocation
            check_resources(*self._film, self.spp, self.light_samples)
            self.integrator.engine.forget()
            # the renderer's scene is its own (loaded here, changed by no one): launches skip the
            # parameter digest (mi.traverse) that mi.render() and render_window() check
            self.integrator.verify_scene = False
            self.integrator.prepare(self.scene, self.sensor)
        else:
            if adaptive is not None:
                raise ValueError("adaptive anti-aliasing needs the links1_whitted integrator (integrator='links1')")
            if self.aovs:
                raise ValueError("AOVs need the links1_whitted integrator (integrator='links1')")
            if max_depth is not None:
                mi.traverse(self.scene)  # Mitsuba's integrators keep their own max_depth
            from links1.scene.params import check_resources
            check_resources(*self._film, self.spp)
            self.integrator = self.scene.integrator()

    @property
    def film_size(self):
        return self._film

    @property
    def channels(self):
        return channel_names(self.aovs)

    def render(self, window=None) -> np.ndarray:
        """``(h, w, C)`` float64 of ``window = (x0, y0, w, h)`` (full film when None)."""
        if self.adaptive is not None:
            return self.integrator.render_adaptive(self.scene, window, seed=self.seed, aovs=self.aovs,
                                                   threshold=self.adaptive, depth=self.adaptive_depth,
                                                   sensor=self.sensor)
        if self.mode == "links1":
            return self.integrator.render_window(self.scene, window, spp=self.spp, seed=self.seed,
                                                 aovs=self.aovs, sensor=self.sensor)
        import mitsuba as mi
        W, H = self._film
        x0, y0, w, h = (0, 0, W, H) if window is None else (int(v) for v in window)
        prm = mi.traverse(self.sensor)  # keys do not depend on the sensor's id
        prm["film.crop_offset"] = [x0, y0]
        prm["film.crop_size"] = [w, h]
        prm.update()
        img = mi.render(self.scene, sensor=self.sensor, spp=self.spp, seed=self.seed)
        return np.array(img, dtype=np.float64)[:, :, :3]

    def render_batch(self, windows) -> list:
        """One array per window, each exactly ``render(window)``: with the links1 integrator all
        their pixels in one launch (:meth:`Links1Whitted.render_windows`)."""
        if self.mode == "links1" and self.adaptive is None:
            return self.integrator.render_windows(self.scene, list(windows), spp=self.spp, seed=self.seed,
                                                  aovs=self.aovs, sensor=self.sensor)
        return [self.render(w) for w in windows]

    def shapes_info(self) -> list:
        """One dict per shape, in file order (``index`` = the ``id`` AOV)."""
        import mitsuba as mi
        from .registered import plugin_class
        info = []
        names = getattr(self.integrator, "shape_names", None) or []
        by_slot = {s: (nm, tp) for s, nm, tp in names}
        if self.mode != "links1":
            return [dict(index=i, name=s.id(), type=kind_of(s),
                         bounds_lo=np.array(s.bbox().min, dtype=np.float64),
                         bounds_hi=np.array(s.bbox().max, dtype=np.float64),
                         reflective=False, transmissive=False, nbytes=0)
                    for i, s in enumerate(self.scene.shapes())]
        P = self.integrator.prepare(self.scene, self.sensor)
        Phong = plugin_class("links1_phong")
        slot_list, _ = self.integrator.engine.shape_slots(list(self.scene.shapes()))
        for s, sl in zip(self.scene.shapes(), slot_list):
            b = s.bbox()
            bsdf = s.bsdf()
            if isinstance(bsdf, Phong):
                refl = max(bsdf.params["reflectance"]) > 0
                trans = max(bsdf.params["transmittance"]) > 0
            else:
                fl = int(bsdf.flags())
                refl = bool(fl & int(mi.BSDFFlags.DeltaReflection))
                trans = bool(fl & int(mi.BSDFFlags.DeltaTransmission))
            if s.is_mesh():
                nb = int(s.vertex_count()) * 12 * (2 if s.has_vertex_normals() else 1) + int(s.face_count()) * 12
            else:
                nb = 64
            name, tp = by_slot.get(sl, (s.id(), kind_of(s)))
            info.append(dict(index=sl, name=name, type=tp,
                             bounds_lo=np.array([b.min[0], b.min[1], b.min[2]], dtype=np.float64),
                             bounds_hi=np.array([b.max[0], b.max[1], b.max[2]], dtype=np.float64),
                             reflective=refl, transmissive=trans, nbytes=nb))
        for spec in P.custom:
            lo, hi = spec.bounds()
            r = max(P.refl.numpy()[3 * spec.slot:3 * spec.slot + 3]) > 0 if P.is_phong_np[spec.slot] else False
            t = P.shadow_t_np[spec.slot].max() > 0
            name, tp = by_slot.get(spec.slot, (spec.name, type(spec).__name__))
            info.append(dict(index=spec.slot, name=name, type=tp, bounds_lo=lo, bounds_hi=hi,
                             reflective=bool(r), transmissive=bool(t), nbytes=spec.nbytes()))
        info.sort(key=lambda d: d["index"])
        return info

    def __repr__(self):
        return (f"MitsubaRenderer(path={self.path!r}, variant={self.variant}, film={self._film}, "
                f"spp={self.spp}, aovs={self.aovs})")
