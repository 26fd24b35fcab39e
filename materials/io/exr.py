"""OpenEXR read/write for float maps and images (OpenEXR 3.x ``OpenEXR.File`` API).

Arrays are channels-last numpy ``[H, W, C]`` float32, values exactly as stored (EXR
holds linear floats; what they *mean* -- colour, signed normal, roughness -- is up to
the caller). Channel sets: ``("R", "G", "B")`` -> C = 3, ``("Y",)`` -> C = 1.

Reads reject, with a ``FormatError`` naming the file: missing, empty, truncated or
non-EXR files, multi-part / deep / subsampled images, integer channels, an unexpected
channel set, and NaN or inf values. Writes are float32, uncompressed or ZIP, and atomic.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import OpenEXR

from materials.io.atomic import atomic_file
from materials.io.errors import FormatError
from materials.types import MapError

__all__ = ["read_exr", "write_exr", "RGB", "GREY", "EXR_MAGIC"]

RGB: tuple[str, ...] = ("R", "G", "B")
GREY: tuple[str, ...] = ("Y",)
#: The four bytes every OpenEXR file starts with (OpenEXR file layout, "magic number").
EXR_MAGIC = b"\x76\x2f\x31\x01"

_COMPRESSION = {"none": OpenEXR.NO_COMPRESSION, "zip": OpenEXR.ZIP_COMPRESSION}
_FLOAT_TYPES = (OpenEXR.HALF, OpenEXR.FLOAT)


def _check_file(path: Path, what: str) -> None:
    """Raise FormatError for a missing or empty file (before any decoder sees it)."""
    if not path.exists():
        raise FormatError(path, f"{what} file does not exist")
    if not path.is_file():
        raise FormatError(path, f"expected a {what} file, found a folder or special file")
    if path.stat().st_size == 0:
        raise FormatError(path, f"{what} file is empty (0 bytes)")


def read_exr(path: str | os.PathLike, channels: Sequence[str] | None = None) -> np.ndarray:
    """Read a single-part scanline or tiled EXR into ``[H, W, C]`` float32.

    Args:
        path: the ``.exr`` file.
        channels: the exact channel set expected, in output order (e.g. ``("R", "G", "B")``).
            None accepts either R,G,B (-> C = 3, in that order) or Y (-> C = 1).

    Returns:
        ``[H, W, C]`` float32, finite; half channels are widened to float32 exactly.

    Raises:
        FormatError: naming ``path`` and the problem (see module docstring).
    """
    path = Path(path)
    _check_file(path, "EXR")
    with open(path, "rb") as fh:
        magic = fh.read(len(EXR_MAGIC))
    if magic != EXR_MAGIC:
        raise FormatError(path, "not an OpenEXR file (it does not start with the EXR magic number)")

    try:
        with OpenEXR.File(str(path), separate_channels=True) as exr:
            # The header dict is emptied when the file closes: copy what is needed now.
            n_parts = len(exr.parts)
            storage = exr.header().get("type")
            raw = {
                name: (np.array(ch.pixels, copy=True), ch.type(), ch.xSampling, ch.ySampling)
                for name, ch in exr.channels().items()
            }
    except Exception as err:  # the binding raises RuntimeError / ValueError on bad data
        raise FormatError(path, f"cannot decode the EXR data (truncated or corrupt file?): {err}") from err

    if n_parts != 1:
        raise FormatError(path, f"multi-part EXR with {n_parts} parts is not supported; expected 1")
    if storage not in (OpenEXR.scanlineimage, OpenEXR.tiledimage):
        raise FormatError(path, f"EXR image type {storage} is not supported (deep images are not)")

    names = set(raw)
    if channels is None:
        if names == set(RGB):
            order: Sequence[str] = RGB
        elif names == set(GREY):
            order = GREY
        else:
            raise FormatError(path, f"unexpected EXR channels {sorted(names)}; expected R,G,B or Y")
    else:
        order = tuple(channels)
        if names != set(order):
            raise FormatError(path, f"unexpected EXR channels {sorted(names)}; expected {','.join(order)}")

    planes = []
    for name in order:
        pixels, ptype, xs, ys = raw[name]
        if ptype not in _FLOAT_TYPES:
            raise FormatError(path, f"channel {name} holds {ptype.name} values; expected HALF or FLOAT")
        if xs != 1 or ys != 1:
            raise FormatError(path, f"channel {name} is subsampled ({xs}x{ys}); expected full resolution")
        planes.append(pixels.astype(np.float32, copy=False))
    shapes = {p.shape for p in planes}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise FormatError(path, f"channels have inconsistent shapes {sorted(shapes)}")
    image = np.stack(planes, axis=-1)

    finite = np.isfinite(image)
    if not finite.all():
        n_nan = int(np.isnan(image).sum())
        n_inf = int(image.size - finite.sum()) - n_nan
        raise FormatError(path, f"EXR holds {n_nan} NaN and {n_inf} inf values; all values must be finite")
    return image


def write_exr(
    path: str | os.PathLike,
    array: np.ndarray,
    channels: Sequence[str] | None = None,
    *,
    compression: str = "zip",
) -> None:
    """Write ``[H, W, C]`` (or ``[H, W]``) values to a float32 EXR, atomically.

    Args:
        path: target ``.exr`` file; its folder must exist.
        array: ``[H, W, C]`` or ``[H, W]`` real values, any range, finite; stored as float32.
        channels: channel names, one per C; None picks ``("R", "G", "B")`` for C = 3 and
            ``("Y",)`` for C = 1.
        compression: ``"zip"`` (lossless, default) or ``"none"``.

    Raises:
        MapError: the array holds NaN or inf (also after float32 conversion), or has
            a shape that does not match ``channels``.
        FormatError: the target folder does not exist.
    """
    path = Path(path)
    data = np.asarray(array)
    if data.ndim == 2:
        data = data[..., None]
    if data.ndim != 3 or data.shape[0] < 1 or data.shape[1] < 1:
        raise MapError(f"{path}: write_exr needs an [H, W, C] array, got shape {data.shape}")
    if not np.issubdtype(data.dtype, np.number) or np.iscomplexobj(data):
        raise MapError(f"{path}: write_exr needs real numbers, got dtype {data.dtype}")
    data = data.astype(np.float32, copy=False)
    if channels is None:
        if data.shape[-1] == 3:
            channels = RGB
        elif data.shape[-1] == 1:
            channels = GREY
        else:
            raise MapError(f"{path}: cannot pick EXR channel names for C = {data.shape[-1]}; pass channels")
    channels = tuple(channels)
    if len(channels) != data.shape[-1] or len(set(channels)) != len(channels):
        raise MapError(f"{path}: {data.shape[-1]} channels in the array, but names {channels}")
    if not np.isfinite(data).all():
        raise MapError(f"{path}: refusing to write NaN or inf values to an EXR (after float32 conversion)")
    if compression not in _COMPRESSION:
        raise ValueError(f"compression must be one of {sorted(_COMPRESSION)}, got {compression!r}")

    # The binding reads the buffer as C-contiguous whatever its strides: copy each plane.
    planes = {name: np.ascontiguousarray(data[..., i]) for i, name in enumerate(channels)}
    header = {"compression": _COMPRESSION[compression], "type": OpenEXR.scanlineimage}
    with atomic_file(path) as tmp, OpenEXR.File(header, planes) as exr:
        exr.write(str(tmp))
