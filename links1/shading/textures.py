"""Mitsuba 3.9.1's ``bitmap`` and ``checkerboard`` textures, evaluated as its ``*_rgb`` variants do.

A texture maps surface coordinates ``uv (N, 2)`` to RGB ``(N, 3)``. Each shape gives its hits'
``uv`` (``shape.uv``: mesh texcoords interpolated by barycentrics, or the analytic
parameterisation of Mitsuba's sphere / cylinder / disk, see :mod:`links1.geometry.shapes`); a material
parameter that is a :class:`Texture` is evaluated there (``Material.at``).

Mitsuba semantics kept here (``src/textures/bitmap.cpp``, ``checkerboard.cpp``, drjit's
``texture_impl.h``):

* ``to_uv``: a 3x3 affine transform of ``uv``; a 4x4 ``<transform>`` keeps its rows and
  columns 0, 1 and 3 (Mitsuba's ``Transform4f::extract``).
* ``checkerboard``: with ``(s, t) = to_uv(uv)``, ``color0`` (default 0.4) where
  ``frac(s) > 1/2`` equals ``frac(t) > 1/2``, else ``color1`` (default 0.2); both may be
  textures themselves.
* ``bitmap``: the image's row 0 (its top row) is ``v = 0``, column 0 is ``u = 0``; pixel
  ``(i, j)`` covers ``[j, j+1)/W x [i, i+1)/H``, its centre at ``+0.5``.
  ``filter_type = bilinear`` (default) interpolates the four pixels around
  ``(u W - 1/2, v H - 1/2)``; ``nearest`` takes pixel ``floor(u W), floor(v H)``.
  ``wrap_mode`` applies to integer pixel indices: ``repeat`` (default, index mod size),
  ``mirror`` (period ``2 size``, the second half reversed: ``-1 -> 0``, ``size -> size-1``)
  and ``clamp`` (to the edge pixel).
* Stored values: 8- and 16-bit images (PNG, JPEG, ...) are sRGB-decoded to linear unless
  ``raw = true`` (Mitsuba's ``format = auto`` keeps 8-bit data as bytes and decodes each
  texel before interpolating, and stores 16-bit data as half floats); float EXR is linear
  and kept as float32 (half EXR as half).
  Values are not clamped (Mitsuba only warns when a non-raw texture leaves [0, 1]). RGB(A)
  and XYZ(A) become RGB, Y(A) one grey channel (alpha is dropped). A side of one pixel is
  widened to two by repeating it (Mitsuba's ``Bitmap::pad_to``).
"""
from __future__ import annotations

import os

import numpy as np

from ..errors import UsageError
from ..imaging.image import read_exr, srgb_to_linear

__all__ = ["Texture", "Checkerboard", "Bitmap", "read_bitmap", "is_texture", "upper_bound",
           "uv_transform", "FILTER_TYPES", "WRAP_MODES"]

FILTER_TYPES = ("bilinear", "nearest")
WRAP_MODES = ("repeat", "mirror", "clamp")


def uv_transform(m) -> np.ndarray:
    """A ``to_uv`` transform as a 3x3 affine matrix (4x4: rows/columns 0, 1, 3; None: identity)."""
    if m is None:
        return np.eye(3)
    m = np.asarray(m, dtype=np.float64)
    if m.shape == (4, 4):
        m = m[np.ix_([0, 1, 3], [0, 1, 3])]
    if m.shape != (3, 3) or not np.all(np.isfinite(m)):
        raise ValueError(f"to_uv must be a finite 3x3 or 4x4 transform, got shape {m.shape}")
    return m


#: Mitsuba's luminance weights (linear sRGB primaries), as its ``luminance()``
LUMINANCE = np.array([0.212671, 0.715160, 0.072169])


class Texture:
    """A spatially varying RGB parameter: ``eval(uv (N, 2)) -> (N, 3)`` float64."""

    def __init__(self, to_uv=None, name: str = ""):
        self.to_uv = uv_transform(to_uv)
        self.name = name

    def _uv(self, uv) -> tuple[np.ndarray, np.ndarray]:
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        m = self.to_uv
        return (m[0, 0] * uv[:, 0] + m[0, 1] * uv[:, 1] + m[0, 2],
                m[1, 0] * uv[:, 0] + m[1, 1] * uv[:, 1] + m[1, 2])

    def eval_1(self, uv) -> np.ndarray:
        """One value per point (N,), as Mitsuba's ``Texture::eval_1``: the luminance of ``eval``."""
        return self.eval(uv) @ LUMINANCE

    def eval(self, uv) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    def max(self) -> np.ndarray:
        """Per-channel upper bound of the values (3,): what a material may at most reflect."""
        raise NotImplementedError  # pragma: no cover - interface

    def mean(self) -> np.ndarray:
        """Per-channel mean (3,) (Mitsuba's ``Texture::mean`` per channel)."""
        raise NotImplementedError  # pragma: no cover - interface


class MeshAttribute(Texture):
    """Mitsuba's ``mesh_attribute`` texture: a mesh's ``vertex_*`` / ``face_*`` attribute at the
    hit, times ``scale``. It needs the hit, not its uv: the integrator evaluates it per shape
    (:meth:`links1.geometry.shapes.TriangleMesh.attribute`) and hands the values to
    :meth:`links1.shading.materials.Material.at`."""

    def __init__(self, name: str, scale: float = 1.0, to_uv=None, texname: str = ""):
        super().__init__(to_uv, texname)
        if not (name.startswith("vertex_") or name.startswith("face_")):
            raise ValueError(f"mesh_attribute: 'name' must start with 'vertex_' or 'face_', got {name!r}")
        self.attribute, self.scale = name, float(scale)

    def values(self, a: np.ndarray) -> np.ndarray:
        """RGB from the attribute's columns at the hits (1 column: grey, 3: RGB)."""
        a = np.asarray(a, dtype=np.float64)
        rgb = np.repeat(a[:, :1], 3, axis=1) if a.shape[1] == 1 else a[:, :3]
        return rgb * self.scale

    def eval(self, uv) -> np.ndarray:
        raise TypeError("a mesh_attribute texture is evaluated at hits, not at uv")

    def max(self) -> np.ndarray:
        return np.full(3, np.inf)    # unknown before the mesh is seen: no bound

    def mean(self) -> np.ndarray:
        return np.full(3, 0.5 * self.scale)


def is_texture(v) -> bool:
    return isinstance(v, Texture)


def upper_bound(v) -> np.ndarray:
    """Per-channel upper bound of a constant (3,) or a texture."""
    return v.max() if isinstance(v, Texture) else np.asarray(v, dtype=np.float64)


def _value(c, uv, sel) -> np.ndarray:
    if isinstance(c, Texture):
        return c.eval(uv[sel])
    return np.broadcast_to(np.asarray(c, dtype=np.float64), (int(np.count_nonzero(sel)), 3))


class Checkerboard(Texture):
    """Mitsuba ``checkerboard``: ``color0`` / ``color1`` (constants (3,) or textures), ``to_uv``."""

    def __init__(self, color0=0.4, color1=0.2, to_uv=None, name: str = ""):
        super().__init__(to_uv, name)
        self.color0 = color0 if isinstance(color0, Texture) else _rgb3(color0)
        self.color1 = color1 if isinstance(color1, Texture) else _rgb3(color1)

    def eval(self, uv) -> np.ndarray:
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        s, t = self._uv(uv)
        first = (s - np.floor(s) > 0.5) == (t - np.floor(t) > 0.5)
        out = np.empty((uv.shape[0], 3))
        out[first] = _value(self.color0, uv, first)
        out[~first] = _value(self.color1, uv, ~first)
        return out

    def eval_1(self, uv) -> np.ndarray:
        """Mitsuba 3.9.1's scalar lookup (``Checkerboard::eval_1``): it tests ``!=`` where
        ``eval`` tests ``==``, so it returns ``color1`` where ``eval`` returns ``color0`` and the
        reverse. A mask's opacity reads it; followed so both renderers agree with it."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        s, t = self._uv(uv)
        first = (s - np.floor(s) > 0.5) != (t - np.floor(t) > 0.5)
        out = np.empty(uv.shape[0])
        for sel, c in ((first, self.color0), (~first, self.color1)):
            out[sel] = (c.eval_1(uv[sel]) if isinstance(c, Texture)
                        else np.full(int(sel.sum()), float(np.asarray(c) @ LUMINANCE)))
        return out

    def max(self) -> np.ndarray:
        return np.maximum(upper_bound(self.color0), upper_bound(self.color1))

    def mean(self) -> np.ndarray:
        m = [c.mean() if isinstance(c, Texture) else c for c in (self.color0, self.color1)]
        return 0.5 * (m[0] + m[1])


def _rgb3(v) -> np.ndarray:
    return np.broadcast_to(np.asarray(v, dtype=np.float64), (3,)).copy()


def _wrap(i: np.ndarray, size: int, mode: str) -> np.ndarray:
    """drjit's wrap of integer pixel indices (``tex_wrap``)."""
    if mode == "clamp":
        return np.clip(i, 0, size - 1)
    if mode == "repeat":
        return np.mod(i, size)
    q = np.mod(i, 2 * size)  # mirror: period 2 size, second half reversed
    return np.where(q < size, q, 2 * size - 1 - q)


class Bitmap(Texture):
    """Mitsuba ``bitmap`` over stored linear values ``data (H, W, C)``, C = 1 (grey) or 3.

    ``data`` is used as given (see :func:`read_bitmap` for what Mitsuba stores for a file).
    """

    def __init__(self, data, filter_type: str = "bilinear", wrap_mode: str = "repeat",
                 to_uv=None, name: str = ""):
        super().__init__(to_uv, name)
        a = np.asarray(data, dtype=np.float64)
        if a.ndim == 2:
            a = a[:, :, None]
        if a.ndim != 3 or a.shape[2] not in (1, 3) or a.shape[0] < 1 or a.shape[1] < 1:
            raise ValueError(f"bitmap data must be (H, W, 1 or 3), got shape {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError("bitmap data must be finite")
        if filter_type not in FILTER_TYPES:
            raise ValueError(f"filter_type must be one of {', '.join(FILTER_TYPES)}, got '{filter_type}'")
        if wrap_mode not in WRAP_MODES:
            raise ValueError(f"wrap_mode must be one of {', '.join(WRAP_MODES)}, got '{wrap_mode}'")
        # Mitsuba pads a side of one pixel to two by repeating the last row / column.
        a = np.repeat(a, 2 if a.shape[0] == 1 else 1, axis=0)
        a = np.repeat(a, 2 if a.shape[1] == 1 else 1, axis=1)
        self.data = np.repeat(a, 3, axis=2) if a.shape[2] == 1 else a
        self.filter_type = filter_type
        self.wrap_mode = wrap_mode

    @property
    def resolution(self) -> tuple[int, int]:
        """``(width, height)`` in pixels."""
        return self.data.shape[1], self.data.shape[0]

    def eval(self, uv) -> np.ndarray:
        s, t = self._uv(uv)
        h, w = self.data.shape[:2]
        mode = self.wrap_mode
        if self.filter_type == "nearest":
            j = _wrap(np.floor(s * w).astype(np.int64), w, mode)
            i = _wrap(np.floor(t * h).astype(np.int64), h, mode)
            return self.data[i, j]
        x = s * w - 0.5
        y = t * h - 0.5
        x0, y0 = np.floor(x), np.floor(y)
        ax, ay = (x - x0)[:, None], (y - y0)[:, None]
        x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
        j0, j1 = _wrap(x0, w, mode), _wrap(x0 + 1, w, mode)
        i0, i1 = _wrap(y0, h, mode), _wrap(y0 + 1, h, mode)
        d = self.data
        top = (1.0 - ax) * d[i0, j0] + ax * d[i0, j1]
        bottom = (1.0 - ax) * d[i1, j0] + ax * d[i1, j1]
        return (1.0 - ay) * top + ay * bottom

    def eval_1_grad(self, uv) -> np.ndarray:
        """Mitsuba's ``Bitmap::eval_1_grad``: the gradient (N, 2) of the bilinear lookup of the
        texels' luminance in pixel units, taken through ``to_uv``'s transpose and scaled by the
        resolution ``(W, H)`` as Mitsuba does; zero for ``nearest`` (piecewise constant)."""
        s, t = self._uv(uv)
        if self.filter_type == "nearest":
            return np.zeros((s.shape[0], 2))
        h, w = self.data.shape[:2]
        mode = self.wrap_mode
        x, y = s * w - 0.5, t * h - 0.5
        x0, y0 = np.floor(x), np.floor(y)
        ax, ay = x - x0, y - y0
        x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
        j0, j1 = _wrap(x0, w, mode), _wrap(x0 + 1, w, mode)
        i0, i1 = _wrap(y0, h, mode), _wrap(y0 + 1, h, mode)
        lum = self.data @ LUMINANCE
        f00, f10, f01, f11 = lum[i0, j0], lum[i0, j1], lum[i1, j0], lum[i1, j1]
        dfx = (1.0 - ay) * (f10 - f00) + ay * (f11 - f01)
        dfy = (1.0 - ax) * (f01 - f00) + ax * (f11 - f10)
        m = self.to_uv
        return np.stack([w * (m[0, 0] * dfx + m[1, 0] * dfy),
                         h * (m[0, 1] * dfx + m[1, 1] * dfy)], axis=1)

    def max(self) -> np.ndarray:
        return self.data.reshape(-1, 3).max(axis=0)

    def mean(self) -> np.ndarray:
        return self.data.reshape(-1, 3).mean(axis=0)


# ---------------------------------------------------------------------------------------------
# reading the stored values Mitsuba's bitmap plugin keeps for a file
# ---------------------------------------------------------------------------------------------

def read_bitmap(path, raw: bool = False) -> np.ndarray:
    """The linear values Mitsuba stores for the image file ``path`` → ``(H, W, 1 or 3)`` float64.

    PNG, JPEG and the other formats Pillow reads: 8/16-bit integers scaled to [0, 1],
    sRGB-decoded unless ``raw`` (16-bit data rounded to half precision). EXR: values as stored (float32;
    half channels are exact in it), never sRGB-decoded. Raises ``ValueError`` naming the file.
    """
    path = os.fspath(path)
    try:
        with open(path, "rb") as fh:
            head = fh.read(4)
    except OSError as exc:
        raise ValueError(f"{path}: cannot read: {exc.strerror}") from None
    if head == b"\x76\x2f\x31\x01":
        return _read_exr(path)
    return _read_pillow(path, raw)


def _read_exr(path: str) -> np.ndarray:
    try:
        a, names = read_exr(path)
    except UsageError as exc:
        raise ValueError(str(exc)) from None
    if all(c in names for c in "RGB"):
        a = a[:, :, [names.index(c) for c in "RGB"]]
    elif "Y" in names:
        a = a[:, :, [names.index("Y")]]
    else:
        raise ValueError(f"{path}: a bitmap texture needs R, G, B or Y channels, got {names}")
    return a.astype(np.float64)


def _read_pillow(path: str, raw: bool) -> np.ndarray:
    # Pillow when first needed, as links1.imaging.image: importing links1 loads numpy and the
    # standard library only
    from PIL import Image, UnidentifiedImageError  # noqa: PLC0415
    try:
        with Image.open(path) as im:
            im.load()
            mode = im.mode
            wide = mode.startswith("I;16") or mode == "I"
            if wide:
                a = np.asarray(im, dtype=np.float64)[:, :, None] / 65535.0
            else:
                if mode not in ("L", "LA", "RGB", "RGBA"):
                    im = im.convert("RGBA" if ("A" in mode or "transparency" in im.info) else "RGB")
                a = np.asarray(im, dtype=np.float64) / 255.0
    except (UnidentifiedImageError, OSError, ValueError) as exc:
        raise ValueError(f"{path}: cannot read image ({exc})") from None
    if a.ndim == 2:
        a = a[:, :, None]
    a = a[:, :, :1] if a.shape[2] in (1, 2) else a[:, :, :3]  # alpha is dropped
    if not raw:
        a = srgb_to_linear(a)
    # 8-bit data is kept as bytes and decoded per lookup (float32: exact enough here);
    # 16-bit data is decoded once and stored as half floats.
    return a.astype(np.float16).astype(np.float64) if wide else a
