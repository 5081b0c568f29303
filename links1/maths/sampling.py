"""The deterministic sample pattern shared by the core and the Mitsuba plugins.

Exact definition (the plugins reproduce it with Dr.Jit ``UInt32`` arithmetic):

* ``spp == 1``: one sample at the pixel centre, offset ``(0.5, 0.5)``.
* ``spp > 1``: ``k = ceil(sqrt(spp))`` strata per axis; sample ``i`` (0-based) lies in stratum
  ``(i mod k, (i div k))`` and is jittered inside it by two 24-bit hashes::

      key  = mix(mix(mix(seed) ^ (py * film_width + px)) ^ (2 * i + axis))   # uint32, wraps
      u    = (key >> 8) * 2**-24                                              # in [0, 1)
      off  = (stratum + u) / k

  where ``mix`` is Chris Wellons' ``lowbias32``, ``(px, py)`` the pixel in the *full film*
  (so a crop window renders the same samples as the full frame) and ``axis`` 0 for x, 1 for y.
* Film coordinates: ``x_film = (px + off_x) / film_width``, ``y_film = (py + off_y) / film_height``,
  row 0 at the top (Mitsuba's convention). Samples are weighted by the film's reconstruction
  filter (:mod:`links1.sensor.filters`).
"""
from __future__ import annotations

import math

import numpy as np

_M1 = np.uint32(0x7FEB352D)
_M2 = np.uint32(0x846CA68B)


def mix32(x: np.ndarray) -> np.ndarray:
    """lowbias32 integer hash on uint32 (wrapping arithmetic)."""
    x = np.asarray(x, dtype=np.uint32)
    with np.errstate(over="ignore"):
        x = x ^ (x >> np.uint32(16))
        x = x * _M1
        x = x ^ (x >> np.uint32(15))
        x = x * _M2
        x = x ^ (x >> np.uint32(16))
    return x


def strata(spp: int) -> int:
    return max(1, math.ceil(math.sqrt(spp)))


def sample_offsets(px: np.ndarray, py: np.ndarray, i: int, spp: int, seed: int,
                   film_width: int) -> tuple[np.ndarray, np.ndarray]:
    """Offsets in [0, 1)² inside pixel ``(px, py)`` of sample ``i`` out of ``spp``."""
    px = np.asarray(px)
    if spp == 1:
        h = np.full(px.shape, 0.5)
        return h, h.copy()
    k = strata(spp)
    sx, sy = i % k, i // k
    base = mix32(np.uint32(seed & 0xFFFFFFFF)) ^ (np.asarray(py, dtype=np.uint32) * np.uint32(film_width)
                                                  + np.asarray(px, dtype=np.uint32))
    base = mix32(base)
    ux = (mix32(base ^ np.uint32(2 * i)) >> np.uint32(8)).astype(np.float64) * 2.0 ** -24
    uy = (mix32(base ^ np.uint32(2 * i + 1)) >> np.uint32(8)).astype(np.float64) * 2.0 ** -24
    return (sx + ux) / k, (sy + uy) / k


# ----------------------------------------------------------------------------- light samples
#: Tags that derive a child ray's key from its parent's (mirror, refraction): as the plugin.
KEY_REFLECT = 0x63D83595
KEY_REFRACT = 0xA511E9B3


#: Salts of the keys below (one home: the plugin imports them): the pixel key's
#: (:func:`pixel_keys`) and the adaptive lattice point's (:func:`lattice_keys`).
KEY_PIXEL = 0x5BD1E995
KEY_LATTICE = 0x68E31DA4


def key_seed(seed: int) -> int:
    """The seed of the per-ray keys (a second stream, independent of the pixel pattern's)."""
    return (int(seed) * 0x27D4EB2F + 0x165667B1) & 0xFFFFFFFF


def ray_keys(px, py, i: int, spp: int, seed: int, film_width: int) -> np.ndarray:
    """Key of camera sample ``i`` of pixel ``(px, py)``::

        key = mix(mix(key_seed(seed)) ^ ((py * film_width + px) * spp + i))   # uint32, wraps

    A mirror / refraction child's key is ``mix(key ^ KEY_REFLECT)`` / ``mix(key ^ KEY_REFRACT)``.
    """
    pix = np.asarray(py, dtype=np.uint32) * np.uint32(film_width) + np.asarray(px, dtype=np.uint32)
    with np.errstate(over="ignore"):
        idx = pix * np.uint32(spp) + np.uint32(i)
    return mix32(mix32(np.uint32(key_seed(seed))) ^ idx)


def lattice_keys(keys, seed: int) -> np.ndarray:
    """Key of the adaptive lattice points with global keys ``keys`` (int64, links1.tracing.adaptive):
    ``mix(mix(mix(key_seed(seed) ^ 0x68E31DA4) ^ low 32 bits) ^ high 32 bits)``, a function of
    the point alone, so every window that samples it traces the same ray tree."""
    k = np.asarray(keys, dtype=np.int64).astype(np.uint64)
    lo = (k & np.uint64(0xFFFFFFFF)).astype(np.uint32)
    hi = (k >> np.uint64(32)).astype(np.uint32)
    return mix32(mix32(mix32(np.uint32(key_seed(seed) ^ KEY_LATTICE)) ^ lo) ^ hi)


def pixel_keys(px, py, seed: int, film_width: int) -> np.ndarray:
    """Key shared by all samples of pixel ``(px, py)``:
    ``mix(mix(key_seed(seed) ^ 0x5BD1E995) ^ (py * film_width + px))``."""
    pix = np.asarray(py, dtype=np.uint32) * np.uint32(film_width) + np.asarray(px, dtype=np.uint32)
    return mix32(mix32(np.uint32(key_seed(seed) ^ KEY_PIXEL)) ^ pix)


def child_keys(keys: np.ndarray, tag: int) -> np.ndarray:
    return mix32(np.asarray(keys, dtype=np.uint32) ^ np.uint32(tag))


# ----------------------------------------------------------------------------- lens samples
#: Tags of a camera ray's lens sample (a thin lens's aperture point), drawn from the ray's key.
KEY_LENS_U = 0x2C1B3C6D
KEY_LENS_V = 0x297A2D39


def lens_samples(keys) -> tuple[np.ndarray, np.ndarray]:
    """The aperture sample ``(u, v)`` in [0, 1)² of camera rays with keys ``keys``
    (:func:`ray_keys`; an adaptive lattice point's key likewise)::

        u = (mix(key ^ KEY_LENS_U) >> 8) * 2**-24,   v = (mix(key ^ KEY_LENS_V) >> 8) * 2**-24

    independent of the film position (a per-pixel stratification of both would correlate them).
    The plugin computes the same in float32."""
    k = np.asarray(keys, dtype=np.uint32)
    u = (mix32(k ^ np.uint32(KEY_LENS_U)) >> np.uint32(8)).astype(np.float64) * 2.0 ** -24
    v = (mix32(k ^ np.uint32(KEY_LENS_V)) >> np.uint32(8)).astype(np.float64) * 2.0 ** -24
    return u, v


def square_to_uniform_disk_concentric(u, v) -> tuple[np.ndarray, np.ndarray]:
    """Shirley and Chiu's concentric map of [0, 1)² onto the unit disk, as Mitsuba's
    ``warp::square_to_uniform_disk_concentric`` (Dave Cline's form): ``x = 2u - 1``,
    ``y = 2v - 1``; ``r = x``, ``φ = π/4 · y/x`` where ``|x| >= |y|``, else ``r = y``,
    ``φ = π/2 - π/4 · x/y``; ``(r cos φ, r sin φ)``, the centre for ``x = y = 0``."""
    x = 2.0 * np.asarray(u, dtype=np.float64) - 1.0
    y = 2.0 * np.asarray(v, dtype=np.float64) - 1.0
    steep = np.abs(x) < np.abs(y)
    r = np.where(steep, y, x)
    rp = np.where(steep, x, y)
    with np.errstate(invalid="ignore", divide="ignore"):
        phi = 0.25 * np.pi * rp / r
    phi = np.where(steep, 0.5 * np.pi - phi, phi)
    phi = np.where((x == 0.0) & (y == 0.0), 0.0, phi)
    return r * np.cos(phi), r * np.sin(phi)


def radical_inverse2(s) -> np.ndarray:
    """Van der Corput radical inverse in base 2 of ``s`` (uint32), as 24-bit integers:
    ``bit_reverse32(s) >> 8``."""
    x = np.asarray(s, dtype=np.uint32)
    x = ((x >> np.uint32(1)) & np.uint32(0x55555555)) | ((x & np.uint32(0x55555555)) << np.uint32(1))
    x = ((x >> np.uint32(2)) & np.uint32(0x33333333)) | ((x & np.uint32(0x33333333)) << np.uint32(2))
    x = ((x >> np.uint32(4)) & np.uint32(0x0F0F0F0F)) | ((x & np.uint32(0x0F0F0F0F)) << np.uint32(4))
    x = ((x >> np.uint32(8)) & np.uint32(0x00FF00FF)) | ((x & np.uint32(0x00FF00FF)) << np.uint32(8))
    x = (x >> np.uint32(16)) | (x << np.uint32(16))
    return x >> np.uint32(8)


def light_tag(light_id: int) -> int:
    """Per-light stream tag: ``0x9E3779B9 + 2 * light_id`` (uint32). ``light_id`` is an area light's
    rank by place (:func:`links1.shading.lights.number_area_lights`: the same whichever order a
    loader gives the shapes), ``0x40000000 + k`` for the k-th environment."""
    return (0x9E3779B9 + 2 * int(light_id)) & 0xFFFFFFFF


def light_samples_uv(shift_keys, light_id: int, s, n) -> tuple[np.ndarray, np.ndarray]:
    """Point ``s`` (0 <= s < n) of a randomly shifted Hammersley set in [0, 1)² (Cranley-
    Patterson rotation: unbiased; ``u`` stratified over the ``n`` points, ``v`` low-discrepancy)::

        h     = mix(shift_key ^ light_tag(light_id))
        (a,b) = ((h' >> 8) * 2**-24 for h' in (mix(h ^ 1), mix(h ^ 2)))
        u     = frac(s / n + a)
        v     = frac(radical_inverse2(s) * 2**-24 + b)

    At a primary hit (depth 1) the shift key is the pixel's key (:func:`pixel_keys`), ``n =
    spp * light_samples`` and ``s = i * light_samples + j`` for light sample ``j`` of camera
    sample ``i``: the set spans the pixel's samples. Deeper hits use their ray's key,
    ``n = light_samples`` and ``s = j``. The plugin computes the same in float32.
    """
    h = mix32(np.asarray(shift_keys, dtype=np.uint32) ^ np.uint32(light_tag(light_id)))
    a = (mix32(h ^ np.uint32(1)) >> np.uint32(8)).astype(np.float64) * 2.0 ** -24
    b = (mix32(h ^ np.uint32(2)) >> np.uint32(8)).astype(np.float64) * 2.0 ** -24
    s = np.asarray(s)
    u = s.astype(np.float64) / n + a
    v = radical_inverse2(s.astype(np.uint32)).astype(np.float64) * 2.0 ** -24 + b
    return u - np.floor(u), v - np.floor(v)


#: The stream id of the BSDF samples (beside the lights' ids of :func:`light_tag`).
BSDF_SAMPLE_ID = 0x60000000


def bsdf_samples_uv(shift_keys, s, n) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The BSDF sample ``(u1, u, v)`` of a hit (the direction BSDF sampling draws, combined with
    the light samples by multiple importance sampling): ``(u, v)`` is point ``s`` of ``n`` of
    :func:`light_samples_uv` with the id ``BSDF_SAMPLE_ID`` (the same shift keys, ``s`` and ``n``
    as one light sample per hit), and ``u1`` (the lobe choice) a hash of the point::

        u1 = (mix(mix(h ^ 3) ^ s) >> 8) * 2**-24,   h = mix(shift_key ^ light_tag(BSDF_SAMPLE_ID))

    The plugin computes the same in float32."""
    u, v = light_samples_uv(shift_keys, BSDF_SAMPLE_ID, s, n)
    h = mix32(np.asarray(shift_keys, dtype=np.uint32) ^ np.uint32(light_tag(BSDF_SAMPLE_ID)))
    u1 = (mix32(mix32(h ^ np.uint32(3)) ^ np.asarray(s, dtype=np.uint32)) >> np.uint32(8))
    return u1.astype(np.float64) * 2.0 ** -24, u, v


def power_heuristic(pdf_a, pdf_b) -> np.ndarray:
    """Veach's power heuristic (β = 2; Veach's thesis eq. 9.13) of strategy a against b, each
    pdf times its sample count: ``a² / (a² + b²)``, 0 where that is not finite (Mitsuba's
    ``direct``: ``mis_weight``)."""
    a, b = np.square(pdf_a), np.square(pdf_b)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        w = a / (a + b)
    return np.where(np.isfinite(w), w, 0.0)
