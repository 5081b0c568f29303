"""Image files: OpenEXR (linear float) and PNG (8-bit sRGB), read and written atomically.

Conventions
-----------
* Arrays are ``(H, W, C)``, row 0 at the top, values *linear* (scene-referred radiance).
* EXR files hold float32 channels. The default channel names are ``R, G, B`` (3 channels),
  ``R, G, B, A`` (4) or ``Y`` (1); anything else needs explicit ``channel_names``, e.g.
  ``["R", "G", "B", "depth", "normal.X", "normal.Y", "normal.Z"]``. OpenEXR stores channels
  sorted by name, so the writer also records the intended order in the header attribute
  ``links1_channels``; :func:`read_exr` restores that order (files from other tools come
  back with ``R, G, B, A`` first, then the rest in file order).
* PNG files are 8-bit sRGB: linear values go through the exact piecewise sRGB transfer
  function (IEC 61966-2-1), are clamped to [0, 1] and rounded to the nearest of 255 steps.
  An alpha channel is stored linearly. Writing needs only the standard library
  (``zlib`` + ``struct``); reading uses Pillow when it is installed and a small built-in
  decoder (8/16-bit, non-interlaced) otherwise.
* Every write is atomic: the file is written to a temporary file in the destination
  directory and moved over the destination with :func:`os.replace`, so a failed write
  leaves an earlier file untouched and no partial file behind.

Only numpy and the standard library are imported at module load; OpenEXR and Pillow are
imported when first needed.
"""
from __future__ import annotations

import os
import struct
import tempfile
import zlib
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..errors import UsageError

__all__ = [
    "read_exr", "write_exr", "read_png", "write_png", "read_image", "write_image",
    "linear_to_srgb", "srgb_to_linear", "atomic_write", "image_format",
]

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
EXR_MAGIC = b"\x76\x2f\x31\x01"
ORDER_ATTRIBUTE = "links1_channels"


# ---------------------------------------------------------------------------------------
# sRGB transfer function (IEC 61966-2-1)
# ---------------------------------------------------------------------------------------

def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """Exact sRGB encoding of linear values (no clamping; negative values map to 12.92 x)."""
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= 0.0031308, 12.92 * x,
                    1.055 * np.power(np.maximum(x, 0.0031308), 1.0 / 2.4) - 0.055)


def srgb_to_linear(s: np.ndarray) -> np.ndarray:
    """Exact sRGB decoding of encoded values in [0, 1] to linear values."""
    s = np.asarray(s, dtype=np.float64)
    return np.where(s <= 0.04045, s / 12.92,
                    np.power((np.maximum(s, 0.04045) + 0.055) / 1.055, 2.4))


# ---------------------------------------------------------------------------------------
# Atomic writes
# ---------------------------------------------------------------------------------------

def atomic_write(path: str | os.PathLike, writer: Callable[[str], None]) -> Path:
    """Call ``writer(tmp_path)`` on a fresh temporary file next to ``path``, then move it
    over ``path`` with :func:`os.replace`.

    If ``writer`` raises, the temporary file is removed, ``path`` is left as it was and the
    exception propagates. The temporary name keeps the destination's extension (some
    writers choose the format from it).
    """
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise UsageError(f"{path}: directory {directory} does not exist")
    fd, tmp = tempfile.mkstemp(dir=directory, prefix=f".{path.name}.", suffix=f".tmp{path.suffix}")
    os.close(fd)
    try:
        writer(tmp)
        # mkstemp creates the file 0600; give it the permissions a plain open() would.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    return path


# ---------------------------------------------------------------------------------------
# Helpers
# ---------------------------------------------------------------------------------------

def _as_hwc(array, what: str = "image") -> np.ndarray:
    a = np.asarray(array)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[0] == 0 or a.shape[1] == 0 or a.shape[2] == 0:
        raise UsageError(f"{what} must be an (H, W) or (H, W, C) array, got shape {a.shape}")
    if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)
            or a.dtype == np.bool_):
        raise UsageError(f"{what} must hold numbers, got dtype {a.dtype}")
    return a


def _default_channel_names(c: int) -> list[str]:
    if c == 1:
        return ["Y"]
    if c == 3:
        return ["R", "G", "B"]
    if c == 4:
        return ["R", "G", "B", "A"]
    raise UsageError(f"an image with {c} channels needs channel_names "
                     "(e.g. ['R', 'G', 'B', 'depth'])")


def image_format(path: str | os.PathLike) -> str:
    """``'exr'`` or ``'png'`` from the file's extension; :class:`UsageError` otherwise."""
    ext = Path(path).suffix.lower()
    if ext == ".exr":
        return "exr"
    if ext == ".png":
        return "png"
    raise UsageError(f"{path}: unsupported image format '{ext or '(no extension)'}' "
                     "(use .exr or .png)")


def _sniff(path: Path) -> str:
    """The format of an existing file from its first bytes (UsageError if unknown)."""
    if not path.exists():
        raise UsageError(f"{path}: no such file")
    if path.is_dir():
        raise UsageError(f"{path}: is a directory, not an image")
    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError as e:
        raise UsageError(f"{path}: cannot read ({e.strerror or e})") from None
    if head.startswith(PNG_SIGNATURE):
        return "png"
    if head.startswith(EXR_MAGIC):
        return "exr"
    ext = path.suffix.lower()
    if ext in (".exr", ".png"):
        raise UsageError(f"{path}: not a valid {ext[1:].upper()} file (bad signature)")
    raise UsageError(f"{path}: unsupported image format '{ext or '(no extension)'}' "
                     "(use .exr or .png)")


# ---------------------------------------------------------------------------------------
# OpenEXR
# ---------------------------------------------------------------------------------------

def _openexr():
    try:
        # a compiled library only EXR files need: imported at the first one (module doc)
        import OpenEXR  # noqa: PLC0415
    except ImportError as e:  # pragma: no cover - openexr is a hard dependency
        raise UsageError("reading/writing EXR files needs the 'openexr' package "
                         "(pip install openexr)") from e
    return OpenEXR


def write_exr(path: str | os.PathLike, array, channel_names: Sequence[str] | None = None) -> Path:
    """Write a linear float image as a ZIP-compressed float32 scanline EXR, atomically.

    Parameters
    ----------
    path : str or path-like
        Destination file.
    array : array_like, shape (H, W) or (H, W, C)
        Linear values; converted to float32.
    channel_names : sequence of str, optional
        One name per channel. Defaults to ``Y`` / ``R, G, B`` / ``R, G, B, A`` for 1 / 3 / 4
        channels; required otherwise.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    a = _as_hwc(array)
    c = a.shape[2]
    names = list(channel_names) if channel_names is not None else _default_channel_names(c)
    if len(names) != c:
        raise UsageError(f"{path}: {len(names)} channel names {names} for an image with {c} channels")
    if len(set(names)) != len(names) or any(not isinstance(n, str) or not n for n in names):
        raise UsageError(f"{path}: channel names must be distinct non-empty strings, got {names}")
    if any("," in n for n in names):
        raise UsageError(f"{path}: channel names must not contain ',' (got {names})")
    OpenEXR = _openexr()
    # The bindings read the array buffer as if it were C-contiguous: copy every channel.
    channels = {n: np.ascontiguousarray(a[:, :, i], dtype=np.float32) for i, n in enumerate(names)}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              ORDER_ATTRIBUTE: ",".join(names)}

    def _write(tmp: str) -> None:
        try:
            OpenEXR.File(header, channels).write(tmp)
        except RuntimeError as e:
            raise UsageError(f"{path}: cannot write EXR ({e})") from None

    return atomic_write(path, _write)


def read_exr(path: str | os.PathLike) -> tuple[np.ndarray, list[str]]:
    """Read an EXR file (first part).

    Returns
    -------
    array : ndarray, shape (H, W, C)
        float32 for half/float channels; float64 if any channel is uint32.
    names : list of str
        Channel names in the order written by :func:`write_exr` (``links1_channels``
        header attribute) or, for other files, ``R, G, B, A`` first then the others.
    """
    path = Path(path)
    if _sniff(path) != "exr":
        raise UsageError(f"{path}: not an EXR file")
    OpenEXR = _openexr()
    try:
        f = OpenEXR.File(str(path), separate_channels=True)
        header = f.header()
        chans = {name: ch.pixels for name, ch in f.channels().items()}
    except (RuntimeError, ValueError) as e:
        raise UsageError(f"{path}: cannot read EXR ({e})") from None
    if not chans:
        raise UsageError(f"{path}: EXR file has no channels")
    stored = header.get(ORDER_ATTRIBUTE)
    if isinstance(stored, str) and sorted(stored.split(",")) == sorted(chans):
        names = stored.split(",")
    else:
        first = [n for n in ("R", "G", "B", "A") if n in chans]
        names = first + [n for n in chans if n not in first]
    shapes = {chans[n].shape for n in names}
    if len(shapes) != 1:
        raise UsageError(f"{path}: channels are sub-sampled differently {sorted(shapes)}; "
                         "only full-resolution channels are supported")
    dtype = np.float64 if any(chans[n].dtype == np.uint32 for n in names) else np.float32
    array = np.stack([chans[n].astype(dtype, copy=False) for n in names], axis=-1)
    return array, names


# ---------------------------------------------------------------------------------------
# PNG
# ---------------------------------------------------------------------------------------

def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return (struct.pack(">I", len(data)) + kind + data
            + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))


def encode_png(rgb) -> bytes:
    """Bytes of an 8-bit sRGB PNG of a linear image (1 = grey, 3 = RGB, 4 = RGBA channels).

    Colour channels are sRGB-encoded, alpha is stored linearly; all are clamped to [0, 1]
    and rounded to the nearest 8-bit value. NaN becomes 0.
    """
    a = _as_hwc(rgb).astype(np.float64)
    h, w, c = a.shape
    if c not in (1, 3, 4):
        raise UsageError(f"PNG needs 1, 3 or 4 channels, got {c}")
    enc = linear_to_srgb(a)
    if c == 4:
        enc[:, :, 3] = a[:, :, 3]
    enc = np.nan_to_num(enc, nan=0.0, posinf=1.0, neginf=0.0)
    q = np.rint(np.clip(enc, 0.0, 1.0) * 255.0).astype(np.uint8)
    colour_type = {1: 0, 3: 2, 4: 6}[c]
    raw = np.concatenate([np.zeros((h, 1), np.uint8), q.reshape(h, w * c)], axis=1)  # filter 0
    ihdr = struct.pack(">IIBBBBB", w, h, 8, colour_type, 0, 0, 0)
    srgb = struct.pack(">B", 0)  # sRGB chunk, rendering intent 'perceptual'
    return (PNG_SIGNATURE + _png_chunk(b"IHDR", ihdr) + _png_chunk(b"sRGB", srgb)
            + _png_chunk(b"IDAT", zlib.compress(raw.tobytes(), 6)) + _png_chunk(b"IEND", b""))


def write_png(path: str | os.PathLike, rgb) -> Path:
    """Write a linear image as an 8-bit sRGB PNG (see :func:`encode_png`), atomically."""
    data = encode_png(rgb)

    def _write(tmp: str) -> None:
        with open(tmp, "wb") as f:
            f.write(data)

    return atomic_write(path, _write)


def _unfilter(data: bytes, h: int, stride: int, bpp: int) -> np.ndarray:
    """Undo PNG scanline filters (filter method 0) -> (h, stride) uint8."""
    rows = np.frombuffer(data, np.uint8)
    if rows.size != h * (stride + 1):
        raise ValueError("truncated image data")
    rows = rows.reshape(h, stride + 1)
    out = np.zeros((h, stride), np.uint8)
    prev = np.zeros(stride, np.int32)
    for y in range(h):
        ftype = rows[y, 0]
        line = rows[y, 1:].astype(np.int32)
        if ftype == 0:
            cur = line
        elif ftype == 1:  # Sub: running sum per byte lane
            cur = np.cumsum(line.reshape(-1, bpp), axis=0).reshape(-1) & 0xFF
        elif ftype == 2:  # Up
            cur = (line + prev) & 0xFF
        elif ftype in (3, 4):  # Average, Paeth: sequential along the row
            cur = np.zeros(stride, np.int32)
            for i in range(0, stride, bpp):
                left = cur[i - bpp:i] if i else np.zeros(bpp, np.int32)
                up = prev[i:i + bpp]
                if ftype == 3:
                    pred = (left + up) >> 1
                else:
                    ul = prev[i - bpp:i] if i else np.zeros(bpp, np.int32)
                    p = left + up - ul
                    pa, pb, pc = np.abs(p - left), np.abs(p - up), np.abs(p - ul)
                    pred = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, up, ul))
                cur[i:i + bpp] = (line[i:i + bpp] + pred) & 0xFF
        else:
            raise ValueError(f"unknown filter type {ftype}")
        out[y] = cur
        prev = cur
    return out


def _decode_png_builtin(path: Path) -> np.ndarray:
    """Minimal decoder: bit depth 8/16, colour types 0/2/4/6, no interlace -> float in [0,1]."""
    data = path.read_bytes()
    pos, idat, ihdr = 8, [], None
    while pos + 8 <= len(data):
        (length,) = struct.unpack(">I", data[pos:pos + 4])
        kind = data[pos + 4:pos + 8]
        body = data[pos + 8:pos + 8 + length]
        pos += 12 + length
        if kind == b"IHDR":
            ihdr = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
    if ihdr is None or not idat:
        raise ValueError("missing IHDR or IDAT chunk")
    w, h, depth, ctype, _, _, interlace = ihdr
    channels = {0: 1, 2: 3, 4: 2, 6: 4}.get(ctype)
    if channels is None or depth not in (8, 16) or interlace:
        raise NotImplementedError(f"colour type {ctype}, bit depth {depth}, interlace {interlace}")
    nbytes = depth // 8
    raw = _unfilter(zlib.decompress(b"".join(idat)), h, w * channels * nbytes, channels * nbytes)
    if depth == 16:
        vals = raw.reshape(h, w * channels, 2).astype(np.uint32)
        vals = ((vals[:, :, 0] << 8) | vals[:, :, 1]).astype(np.float64) / 65535.0
    else:
        vals = raw.astype(np.float64) / 255.0
    return vals.reshape(h, w, channels)


def _decode_png_pillow(path: Path) -> np.ndarray:
    from PIL import Image  # noqa: PLC0415 - optional here (module doc: a built-in decoder otherwise)

    with Image.open(path) as im:
        im.load()
        mode = im.mode
        if mode in ("I;16", "I;16B", "I"):
            return np.asarray(im, dtype=np.float64)[:, :, None] / 65535.0
        if mode not in ("L", "LA", "RGB", "RGBA"):
            im = im.convert("RGBA" if ("A" in mode or "transparency" in im.info) else "RGB")
        a = np.asarray(im, dtype=np.float64) / 255.0
    return a[:, :, None] if a.ndim == 2 else a


def read_png(path: str | os.PathLike) -> np.ndarray:
    """Read a PNG as a linear float32 ``(H, W, C)`` array (C = 1, 2, 3 or 4).

    Colour channels are decoded with the inverse sRGB transfer function; alpha is linear.
    """
    path = Path(path)
    if _sniff(path) != "png":
        raise UsageError(f"{path}: not a PNG file")
    try:
        try:
            enc = _decode_png_pillow(path)
        except ImportError:
            enc = _decode_png_builtin(path)
    except NotImplementedError as e:
        raise UsageError(f"{path}: unsupported PNG variant ({e}); install Pillow to read it") from None
    except Exception as e:  # noqa: BLE001 - any decoder failure is a bad file to the user
        raise UsageError(f"{path}: cannot read PNG ({e})") from None
    lin = srgb_to_linear(enc)
    if enc.shape[2] in (2, 4):  # alpha stays linear
        lin[:, :, -1] = enc[:, :, -1]
    return lin.astype(np.float32)


# ---------------------------------------------------------------------------------------
# Dispatch
# ---------------------------------------------------------------------------------------

def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read an EXR (values as stored) or PNG (decoded to linear) as a float ``(H, W, C)`` array.

    The format is recognised from the file's signature. Missing, unreadable or
    unsupported files raise :class:`links1.errors.UsageError` naming the file.
    """
    path = Path(path)
    fmt = _sniff(path)
    if fmt == "exr":
        return read_exr(path)[0]
    return read_png(path)


def write_image(path: str | os.PathLike, array, channel_names: Sequence[str] | None = None) -> Path:
    """Write ``array`` to ``path``, choosing the format from the extension (atomic).

    ``.exr`` keeps every channel (see :func:`write_exr`). ``.png`` keeps 1, 3 or 4 channels
    as they are; an image with more channels (e.g. a render with AOVs) is written as its
    first three (colour) channels. Other extensions raise :class:`UsageError`.
    """
    fmt = image_format(path)
    if fmt == "exr":
        return write_exr(path, array, channel_names)
    a = _as_hwc(array)
    if a.shape[2] not in (1, 3, 4):
        if a.shape[2] < 3:
            raise UsageError(f"{path}: PNG needs 1, 3 or 4 channels, got {a.shape[2]}")
        a = a[:, :, :3]
    return write_png(path, a)
