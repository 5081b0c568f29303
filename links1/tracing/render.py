"""Rendering a scene (or windows of its film) with the core, and the core's renderer.

``render`` is the core's public entry point; :class:`CoreRenderer` is the core's side of the
Renderer contract (:class:`links1_app.renderers.Renderer`: load a scene file once, render any
window of it), which the front ends get from :func:`links1_app.renderers.make_renderer`. Nothing
here names the Mitsuba plugin (docs/architecture.md, "Dependencies").
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from .adaptive import DEFAULT_ADAPTIVE_DEPTH, check_options, render_adaptive_window
from .aovs import channel_names, check_aovs
from ..errors import UsageError
from ..sensor.filters import FilterGather
from .integrator import DEFAULT_MIN_WEIGHT, WhittedIntegrator
from ..scene.params import check_resources
from ..scene.scenefile import SceneFile
from ..maths.sampling import pixel_keys, ray_keys, sample_offsets
from ..scene.scene import check_sensor_index

#: Sample rays traced per numpy batch (bounds memory: ~40 arrays of 3 doubles per ray).
BATCH = 1 << 16


def _check_window(window, width, height):
    if window is None:
        return 0, 0, width, height
    try:
        x0, y0, w, h = (int(v) for v in window)
    except (TypeError, ValueError):
        raise UsageError(f"window must be (x0, y0, width, height), got {window!r}") from None
    if w <= 0 or h <= 0 or x0 < 0 or y0 < 0 or x0 + w > width or y0 + h > height:
        raise UsageError(f"window {(x0, y0, w, h)} is outside the {width}x{height} film")
    return x0, y0, w, h


def render(scene, *, spp: int | None = None, max_depth: int | None = None, seed: int = 0,
           window=None, aovs=(), min_weight: float | None = None, progress: bool | None = False,
           width: int | None = None, height: int | None = None, light_samples: int | None = None,
           adaptive: float | None = None, adaptive_depth: int = DEFAULT_ADAPTIVE_DEPTH,
           sensor: int | None = None) -> np.ndarray:
    """Render ``scene`` with the float64 core.

    Parameters
    ----------
    scene : Scene
        From :func:`links1.load_scene`.
    spp : int, optional
        Samples per pixel (default: the scene's sampler ``sample_count``).
    max_depth : int, optional
        Surface interactions per branch of the ray tree (default: the scene's, else 5).
    seed : int
        Seed of the stratified sample pattern (ignored at spp 1: pixel centres).
    window : (x0, y0, w, h), optional
        A window of the film, in full-film pixels with row 0 at the top. Its pixels equal
        the same pixels of a full render, bit for bit. Default: the film's crop window.
    aovs : sequence of {"depth", "normal", "id", "cost"}
    min_weight : float, optional
        Stop a branch of the ray tree when its weight drops to this or below (default: the
        scene's ``links1_whitted`` ``min_weight``, else 1/255, POV-Ray's adc_bailout; 0: never).
    width, height : int, optional
        Override the film resolution (the field of view is kept).
    light_samples : int, optional
        Shadow rays per area light / environment per hit (default: the scene's
        ``links1_whitted`` ``light_samples``, else 1); the points lie on one lattice over the
        pixel's samples (:func:`links1.maths.sampling.light_samples_uv`).
    adaptive : float, optional
        Adaptive anti-aliasing instead of ``spp`` samples per pixel (:mod:`links1.tracing.adaptive`):
        a pixel's square of lattice points is split while its corners differ by more than
        this (tone-mapped ``v/(1+v)``, max over channels), down to ``adaptive_depth`` levels.
        Pixels are reconstructed with the film's filter from the bilinear interpolant of the
        refined squares (:class:`links1.tracing.adaptive.FilteredLeaves`).
    adaptive_depth : int
        Most levels of refinement (default 2; 0..8).
    sensor : int, optional
        Render from the file's sensor ``k`` (0-based, file order; as ``mi.render(scene,
        sensor=k)``): its camera, film (size, crop window, filter) and sample count. Default:
        ``scene.camera`` and ``scene.spp`` (the first sensor unless ``scene.use_sensor``).
    progress : bool or None
        A tqdm bar on stderr for renders longer than a second: True always, None only when
        stderr is a terminal (tqdm's ``disable=None``), False (default) never.

    Returns
    -------
    ndarray (h, w, 3 + AOV channels), float64, linear radiance; see :func:`channel_names`.
    """
    cam, scene_spp = scene.camera, scene.spp
    if sensor is not None:
        k = check_sensor_index(scene.path, sensor, scene.sensor_count())
        sensors = scene.sensors or [(scene.camera, scene.spp)]
        if isinstance(sensors[k], Exception):
            raise sensors[k]
        cam, scene_spp = sensors[k]
    if width is not None or height is not None:
        cam = _resized(cam, width, height)
    spp = scene_spp if spp is None else int(spp)
    if spp < 1:
        raise UsageError(f"spp must be >= 1, got {spp}")
    aovs = check_aovs(aovs)
    if window is None:
        window = (*cam.crop_offset, *cam.crop_size)
    x0, y0, w, h = _check_window(window, cam.width, cam.height)
    return render_windows(scene, [(x0, y0, w, h)], spp=spp, max_depth=max_depth, seed=seed, aovs=aovs,
                          min_weight=min_weight, light_samples=light_samples, progress=progress, cam=cam,
                          adaptive=adaptive, adaptive_depth=adaptive_depth)[0]


def render_windows(scene, windows, *, spp: int | None = None, max_depth: int | None = None, seed: int = 0,
                   aovs=(), min_weight: float | None = None, light_samples: int | None = None,
                   progress: bool = False, cam=None, adaptive: float | None = None,
                   adaptive_depth: int = DEFAULT_ADAPTIVE_DEPTH) -> list:
    """Render several windows of the film in one pass -> one array per window, each bit for bit
    what :func:`render` returns for it (pixels are traced independently, in batches of
    ``BATCH``: a batch of small windows pays the per-call numpy overhead once). Each window
    traces the samples of its filter border too (links1/sensor/filters.py) and gathers them alone."""
    cam = scene.camera if cam is None else cam
    spp = scene.spp if spp is None else int(spp)
    if spp < 1:
        raise UsageError(f"spp must be >= 1, got {spp}")
    min_weight, light_samples = ray_tree_options(scene, min_weight, light_samples)
    check_resources(cam.width, cam.height, spp, light_samples)
    aovs = check_aovs(aovs)
    wins = [_check_window(win, cam.width, cam.height) for win in windows]
    if adaptive is not None:
        return [_render_adaptive(scene, cam, win, threshold=adaptive, depth=adaptive_depth, max_depth=max_depth,
                                 seed=seed, aovs=aovs, min_weight=min_weight, light_samples=light_samples,
                                 progress=progress) for win in wins]
    gathers = [FilterGather(cam.rfilter, win, (cam.width, cam.height)) for win in wins]
    pxs, pys = zip(*(_window_pixels(*g.sample_window) for g in gathers))
    starts = np.cumsum([0] + [len(p) for p in pxs])

    def add_layer(rgb, ox, oy):
        for g, a, b in zip(gathers, starts[:-1], starts[1:]):
            sh, sw = g.sample_window[3], g.sample_window[2]
            g.add(rgb[a:b].reshape(sh, sw, 3), ox[a:b].reshape(sh, sw), oy[a:b].reshape(sh, sw))

    flat = _render_pixels(scene, cam, np.concatenate(pxs), np.concatenate(pys), add_layer, spp=spp,
                          max_depth=max_depth, seed=seed, aovs=aovs, min_weight=min_weight, progress=progress,
                          light_samples=light_samples)
    out = []
    for g, a, b in zip(gathers, starts[:-1], starts[1:]):
        sh, sw = g.sample_window[3], g.sample_window[2]
        out.append(np.concatenate([g.result(), g.inner(flat[a:b].reshape(sh, sw, -1))], axis=2))
    return out


def ray_tree_options(scene, min_weight=None, light_samples=None) -> tuple[float, int]:
    """``(min_weight, light_samples)``: the given values, else the scene's (its
    ``links1_whitted`` element's, else the defaults), checked."""
    mw = float(getattr(scene, "min_weight", DEFAULT_MIN_WEIGHT) if min_weight is None else min_weight)
    ls = int(getattr(scene, "light_samples", 1) if light_samples is None else light_samples)
    if not mw >= 0:
        raise UsageError(f"min_weight must be >= 0, got {min_weight}")
    if ls < 1:
        raise UsageError(f"light_samples must be >= 1, got {light_samples}")
    return mw, ls


def _window_pixels(x0, y0, w, h):
    """Pixel coordinates of a window, row by row."""
    ys, xs = np.divmod(np.arange(w * h, dtype=np.int64), w)
    return xs + x0, ys + y0


def _render_pixels(scene, cam, px, py, add_layer, *, spp, max_depth, seed, aovs, min_weight, progress,
                   light_samples=1):
    """Trace the ``spp`` samples of the pixels ``(px, py)`` of the film (row 0 at the top):
    ``add_layer(rgb (n, 3), offx (n,), offy (n,))`` receives sample 0, 1, ... of every pixel in
    turn; returns the per-pixel AOV channels ``(n, number of AOV channels)``."""
    integ = WhittedIntegrator(scene, max_depth=max_depth, min_weight=min_weight, light_samples=light_samples,
                              camera=cam)
    npix = len(px)
    layer, offs = np.zeros((npix, 3)), np.zeros((2, npix))  # one sample of every pixel
    cost = np.zeros(npix, dtype=np.int64)
    depth_aov = np.zeros(npix)
    normal_aov = np.zeros((npix, 3))
    id_aov = np.full(npix, -1.0)

    chunks = [(i, s, min(s + BATCH, npix)) for i in range(spp) for s in range(0, npix, BATCH)]
    bar = _progress(len(chunks), progress)
    for i, a, b in chunks:
        ox, oy = sample_offsets(px[a:b], py[a:b], i, spp, seed, cam.width)
        keys = ray_keys(px[a:b], py[a:b], i, spp, seed, cam.width)
        o, d, tmin, tmax = cam.generate_rays((px[a:b] + ox) / cam.width, (py[a:b] + oy) / cam.height, keys)
        c = np.zeros(b - a, dtype=np.int64)
        L, hits, rec = integ.trace(o, d, tmin, tmax, c, keys=keys,
                                   sample=(pixel_keys(px[a:b], py[a:b], seed, cam.width), i, spp))
        integ.stats.rays["camera"] += b - a
        layer[a:b], offs[0, a:b], offs[1, a:b] = L, ox, oy
        cost[a:b] += c
        if i == 0 and aovs:
            valid = hits.valid
            depth_aov[a:b] = np.where(valid, hits.t, 0.0)
            id_aov[a:b] = np.where(valid, hits.shape, -1)
            if rec is not None:
                normal_aov[a:b] = rec.ns
        if b == npix:
            add_layer(layer, offs[0], offs[1])
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    channels = [np.zeros((npix, 0))]
    for a in aovs:
        channels.append({"depth": depth_aov[:, None], "normal": normal_aov, "id": id_aov[:, None],
                         "cost": cost[:, None].astype(np.float64), "samples": np.full((npix, 1), float(spp))}[a])
    return np.concatenate(channels, axis=1)


def _render_adaptive(scene, cam, win, *, threshold, depth, max_depth, seed, aovs, min_weight, light_samples,
                     progress):
    """The core's adaptive render of window ``win``: :func:`render_adaptive_window` with the
    core's integrator tracing the lattice points and an spp-1 pass for the centre AOVs."""
    integ = WhittedIntegrator(scene, max_depth=max_depth, min_weight=min_weight, light_samples=light_samples,
                              camera=cam)

    def trace_points(xf, yf, keys):
        L, cost = np.empty((len(xf), 3)), np.empty(len(xf))
        for a in range(0, len(xf), BATCH):
            b = min(a + BATCH, len(xf))
            o, d, tmin, tmax = cam.generate_rays(xf[a:b], yf[a:b], keys[a:b])
            c = np.zeros(b - a, dtype=np.int64)
            L[a:b], _, _ = integ.trace(o, d, tmin, tmax, c, keys=keys[a:b])
            integ.stats.rays["camera"] += b - a
            cost[a:b] = c
        return L, cost

    def centre_aovs(window, names):
        x0, y0, w, h = window
        px, py = _window_pixels(x0, y0, w, h)
        return _render_pixels(scene, cam, px, py, lambda *_: None, spp=1, max_depth=max_depth, seed=seed,
                              aovs=tuple(names), min_weight=min_weight, progress=False,
                              light_samples=light_samples).reshape(h, w, -1)

    return render_adaptive_window(trace_points, centre_aovs, win, (cam.width, cam.height), threshold, depth,
                                  seed, aovs, bar=_progress(None, progress), rfilter=cam.rfilter)


def _resized(cam, width, height):
    w = cam.width if width is None else int(width)
    h = cam.height if height is None else int(height)
    if w <= 0 or h <= 0:
        raise UsageError(f"resolution must be positive, got {w}x{h}")
    # Keep the vertical extent consistent with Mitsuba: fov_x is the stored quantity.
    return replace(cam, width=w, height=h, crop_offset=(0, 0), crop_size=(w, h))


def _progress(total, enabled):
    """A tqdm bar on stderr: ``enabled`` True always, None only on a terminal, False never."""
    if enabled is False:
        return None
    try:
        # here, not at the top: tqdm takes about a quarter of `import links1`'s own time to
        # import, and only a render that may show a bar needs it
        from tqdm import tqdm  # noqa: PLC0415
    except ImportError:  # pragma: no cover - tqdm is a declared dependency
        return None
    # delay: the bar appears only for renders that last more than a second
    return tqdm(total=total, desc="render", unit="batch", delay=1.0, leave=False,
                disable=None if enabled is None else False)


# ---------------------------------------------------------------------- renderers
class CoreRenderer:
    """Loads a scene file once with the core and renders windows of it (Renderer contract)."""

    kind = "core"

    def __init__(self, path, *, params=None, spp=None, max_depth=None, seed=0, aovs=(),
                 min_weight=None, width=None, height=None, variant=None, light_samples=None,
                 adaptive=None, adaptive_depth=DEFAULT_ADAPTIVE_DEPTH, sensor=None):
        self.path = str(path)
        self.source = SceneFile(self.path, **(params or {}))
        self.scene = self.source.scene
        self.sensor_index = check_sensor_index(self.path, sensor, self.scene.sensor_count())
        self.given = dict(spp=spp, width=width, height=height, min_weight=min_weight, light_samples=light_samples)
        self.max_depth = max_depth
        self.seed = int(seed)
        self.aovs = check_aovs(aovs)
        self._adopt()
        self.adaptive, self.adaptive_depth = adaptive, adaptive_depth
        if adaptive is not None:
            self.adaptive, self.adaptive_depth = check_options(adaptive, adaptive_depth)

    def _adopt(self):
        """The loaded scene's sensor, film size, sample count and ray-tree values, as given."""
        g = self.given
        self.scene.use_sensor(self.sensor_index)
        if g["width"] is not None or g["height"] is not None:
            self.scene.camera = _resized(self.scene.camera, g["width"], g["height"])
        # this renderer owns its scene and changes it only in set_params: hash it once, not per window
        self.scene.pin_content()
        self.spp = self.scene.spp if g["spp"] is None else int(g["spp"])
        # the scene's own (links1_whitted) values unless given
        self.min_weight, self.light_samples = ray_tree_options(self.scene, g["min_weight"], g["light_samples"])
        if self.spp < 1:
            raise UsageError(f"spp must be >= 1, got {self.spp}")
        check_resources(*self.film_size, self.spp, self.light_samples)

    def set_params(self, params) -> set:
        """Give the loaded scene other ``$name`` values (all of them, as ``params=`` at load) in
        place, without reading its file again: only the elements whose parameters changed are
        built again, and the BVH and the integrator's plan are kept when the shapes and lights
        did not change (:class:`links1.scene.scenefile.SceneFile`). Renders then equal those of
        a renderer loaded with ``params``, bit for bit. Returns the names that changed."""
        self.scene.unpin_content()      # _adopt pins the new content
        changed = self.source.update(**(params or {}))
        if changed:
            self._adopt()
        return changed

    @property
    def film_size(self) -> tuple[int, int]:
        return self.scene.camera.width, self.scene.camera.height

    @property
    def channels(self) -> list[str]:
        return channel_names(self.aovs)

    def render(self, window=None, progress=False) -> np.ndarray:
        if window is None:
            window = (0, 0, *self.film_size)
        return render(self.scene, spp=self.spp, max_depth=self.max_depth, seed=self.seed,
                      window=window, aovs=self.aovs, min_weight=self.min_weight, progress=progress,
                      light_samples=self.light_samples, adaptive=self.adaptive, adaptive_depth=self.adaptive_depth)

    def render_batch(self, windows) -> list:
        """One array per window, each exactly ``render(window)`` (one pass over their pixels)."""
        return render_windows(self.scene, windows, spp=self.spp, max_depth=self.max_depth, seed=self.seed,
                              aovs=self.aovs, min_weight=self.min_weight, light_samples=self.light_samples,
                              adaptive=self.adaptive, adaptive_depth=self.adaptive_depth)

    def shapes_info(self) -> list[dict]:
        return shapes_info(self.scene)


def shapes_info(scene) -> list[dict]:
    """Per-shape facts the partitioning layer needs (4-1 loads, 4-4 data per node)."""
    out = []
    for s in scene.shapes:
        lo, hi = s.bounds()
        m = s.material
        out.append({
            "index": s.index, "name": s.name, "type": type(s).__name__.lower(),
            "bounds_lo": [float(v) for v in lo], "bounds_hi": [float(v) for v in hi],
            "reflective": bool(m.has_reflection), "transmissive": bool(m.has_transmission or np.any(m.shadow_t > 0)),
            "nbytes": int(getattr(s, "nbytes", 0) or 0),
        })
    return out
