"""8-bit PNG (and JPEG) read/write for maps and photos, no colour transform.

Arrays are channels-last numpy ``[H, W, C]`` float32 in [0, 1] (the 8-bit code
divided by 255), C = 1 (grey) or 3 (RGB). What the values *mean* -- sRGB colour,
(n+1)/2 normals, tone-mapped radiance, linear roughness -- is the caller's business:
decode with ``kernels.tonemap`` / ``materials.io.encoding`` right after reading.

Rejected with a ``FormatError`` naming the file: missing, empty, truncated or
non-PNG files, 16-bit PNGs (the header's bit depth is read directly: Pillow would
silently drop 16-bit RGB to 8 bits), alpha channels (RGBA, grey+alpha, or a
transparency chunk), and CMYK JPEGs.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np
from PIL import Image

from materials.io.atomic import atomic_file
from materials.io.errors import FormatError
from materials.types import RANGE_SLACK, MapError

__all__ = ["read_png", "read_ldr", "write_png", "PNG_STEP", "PNG_SIGNATURE", "JPEG_MAGIC"]

#: One 8-bit quantisation step in the stored (encoded) domain. A write-then-read round
#: trip moves a value by at most half of it (rounding to the nearest code).
PNG_STEP = 1.0 / 255.0
#: PNG file signature (PNG spec, section 5.2).
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: JPEG files start with an SOI marker followed by another marker's 0xFF.
JPEG_MAGIC = b"\xff\xd8\xff"

# PNG IHDR colour types (PNG spec, section 11.2.2) -> (name, channels).
_PNG_COLOUR_TYPES = {0: ("grey", 1), 2: ("RGB", 3), 3: ("palette", 3), 4: ("grey+alpha", 2), 6: ("RGBA", 4)}


def _check_file(path: Path, what: str) -> bytes:
    """Raise FormatError for a missing or empty file; return its first 33 bytes."""
    if not path.exists():
        raise FormatError(path, f"{what} file does not exist")
    if not path.is_file():
        raise FormatError(path, f"expected a {what} file, found a folder or special file")
    if path.stat().st_size == 0:
        raise FormatError(path, f"{what} file is empty (0 bytes)")
    with open(path, "rb") as fh:
        return fh.read(33)  # signature (8) + IHDR length/type (8) + IHDR data (13) + CRC (4)


def _check_png_header(path: Path, head: bytes) -> None:
    """Bit depth and colour type straight from IHDR: reject 16-bit and alpha early."""
    if len(head) < 29 or head[12:16] != b"IHDR":
        raise FormatError(path, "PNG file is truncated or corrupt (no complete IHDR header)")
    _, _, bit_depth, colour_type = struct.unpack(">IIBB", head[16:26])
    if colour_type not in _PNG_COLOUR_TYPES:
        raise FormatError(path, f"PNG header has an invalid colour type {colour_type}")
    name, n_channels = _PNG_COLOUR_TYPES[colour_type]
    if bit_depth == 16:
        raise FormatError(
            path,
            f"16-bit PNG ({name}, {n_channels} channels) is not supported; only 8-bit PNGs are "
            "(store high-precision maps as EXR instead)",
        )
    if colour_type in (4, 6):
        raise FormatError(
            path, f"PNG has an alpha channel ({name}, {n_channels} channels); expected 1 (grey) or 3 (RGB)"
        )


def read_ldr(path: str | os.PathLike) -> np.ndarray:
    """Read an 8-bit PNG or a JPEG as ``[H, W, C]`` float32 in [0, 1], C = 1 or 3.

    Values are the stored 8-bit codes / 255, in whatever encoding the file uses (no
    colour transform). Palette PNGs become RGB; 1-bit images become grey.

    Raises:
        FormatError: naming ``path`` and the problem (see module docstring).
    """
    path = Path(path)
    head = _check_file(path, "image")
    if head.startswith(PNG_SIGNATURE):
        kind = "PNG"
        _check_png_header(path, head)
    elif head.startswith(JPEG_MAGIC):
        kind = "JPEG"
    else:
        raise FormatError(path, "not a PNG or JPEG file (unrecognised signature)")

    try:
        with Image.open(path) as img:
            img.load()
            mode = img.mode
            transparency = "transparency" in img.info
            # Palette and 1-bit images are expanded first (``convert`` returns a new image).
            decoded = img.convert("RGB" if mode == "P" else "L") if mode in ("P", "1") else img
            pixels = np.asarray(decoded)
    except (OSError, SyntaxError, ValueError) as err:  # Pillow's errors for bad data
        raise FormatError(path, f"cannot decode the {kind} data (truncated or corrupt file?): {err}") from err

    if transparency:
        raise FormatError(path, f"{kind} has transparency (an alpha channel, mode {mode}); expected grey or RGB")
    if pixels.dtype != np.uint8:
        raise FormatError(path, f"{kind} holds {pixels.dtype} pixels (mode {mode}); only 8-bit is supported")
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    channels = pixels.shape[-1]
    if channels not in (1, 3):
        raise FormatError(path, f"{kind} has {channels} channels (mode {mode}); expected 1 (grey) or 3 (RGB), no alpha")
    return pixels.astype(np.float32) / 255.0


def read_png(path: str | os.PathLike) -> np.ndarray:
    """Read an 8-bit PNG as ``[H, W, C]`` float32 in [0, 1], C = 1 (grey) or 3 (RGB).

    Like :func:`read_ldr`, but the file must be a PNG.

    Example:
        >>> img = read_png("diffuse.png")  # doctest: +SKIP
        >>> img.shape, img.dtype           # doctest: +SKIP
        ((256, 256, 3), dtype('float32'))
    """
    path = Path(path)
    head = _check_file(path, "PNG")
    if not head.startswith(PNG_SIGNATURE):
        raise FormatError(path, "not a PNG file (it does not start with the PNG signature)")
    return read_ldr(path)


def write_png(path: str | os.PathLike, array: np.ndarray) -> None:
    """Write ``[H, W, C]`` (C = 1 or 3) or ``[H, W]`` values in [0, 1] as an 8-bit PNG, atomically.

    Values are rounded to the nearest code ``round(x * 255)``; no colour transform is
    applied (encode first). Values up to ``RANGE_SLACK`` outside [0, 1] are clamped,
    anything further out is an error, so a forgotten tone map does not pass silently.

    Raises:
        MapError: wrong shape, NaN/inf, or values outside [0, 1] beyond the slack.
        FormatError: the target folder does not exist.
    """
    path = Path(path)
    data = np.asarray(array, dtype=np.float32)
    if data.ndim == 2:
        data = data[..., None]
    if data.ndim != 3 or data.shape[-1] not in (1, 3) or data.shape[0] < 1 or data.shape[1] < 1:
        raise MapError(f"{path}: write_png needs [H, W, 1] or [H, W, 3] values, got shape {data.shape}")
    if not np.isfinite(data).all():
        raise MapError(f"{path}: refusing to write NaN or inf values to a PNG")
    lo, hi = float(data.min()), float(data.max())
    if lo < -RANGE_SLACK or hi > 1.0 + RANGE_SLACK:
        raise MapError(f"{path}: PNG values must lie in [0, 1] (encode or tone-map first), found [{lo:.4g}, {hi:.4g}]")
    codes = np.round(np.clip(data, 0.0, 1.0) * 255.0).astype(np.uint8)
    image = Image.fromarray(codes[..., 0] if codes.shape[-1] == 1 else codes)
    with atomic_file(path) as tmp:
        image.save(tmp, format="PNG")
