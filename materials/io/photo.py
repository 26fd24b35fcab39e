"""Reading a user's photo: PNG (8/16-bit), JPEG or EXR -> linear radiance + metadata.

A photo is the one input of a capture. Whatever the file, the result is the same:
``Photo.image``, ``[3, H, W]`` float32 linear radiance (SPEC section 2), upright (the
EXIF orientation applied), with the facts the pipeline needs about where it came from.

Decoding (the project's photo convention, README "Photos"):

- 8- and 16-bit PNG, JPEG: the stored values are display values; they are decoded with
  the inverse of the project's tone map, ``clamp(v, 0, 1) ** 2.2``
  (``kernels.tonemap.inverse_tonemap``). A phone's JPEG is sRGB-ish, and 2.2 is the
  project's convention for it, not an exact sRGB decode (the two differ by at most 0.009
  in linear value, and by a large factor in relative terms in the deep shadows, where
  sRGB is linear). 16-bit files keep their 65,536 levels.
- EXR: linear radiance as stored (R, G, B or Y). Negative values (possible after
  processing) are clamped to 0 with a note.
- Grey files are copied to three channels; alpha (RGBA, grey+alpha, palette
  transparency, EXR ``A``) is dropped, with a note: the material is assumed opaque.
- CMYK JPEGs are refused: CMYK is a print separation, and without its ICC profile and
  the printer's ink model any conversion to RGB radiance is a guess (Pillow's naive
  inversion shifts colours by tens of percent). Convert such a file to sRGB first.

Refused, with a ``FormatError`` naming the file and saying what to do: missing, empty,
a folder, not a PNG/JPEG/EXR, truncated or corrupt data, a side below
``MIN_PHOTO_SIDE``, more than ``MAX_PHOTO_SIDE`` pixels on a side or ``MAX_PHOTO_PIXELS``
pixels in all (downscale it first), NaN or inf in an EXR, unsupported channel sets.
The size is checked from the header, before the pixels are decoded.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import OpenEXR
import torch
from PIL import ExifTags, Image

from kernels.tonemap import inverse_tonemap
from materials.io.encoding import hwc_to_chw
from materials.io.errors import FormatError
from materials.io.exr import EXR_MAGIC, read_exr
from materials.io.png import JPEG_MAGIC, PNG_SIGNATURE

__all__ = [
    "Photo",
    "read_photo",
    "PHOTO_FORMATS",
    "MIN_PHOTO_SIDE",
    "MAX_PHOTO_SIDE",
    "MAX_PHOTO_PIXELS",
]

#: Formats ``read_photo`` reads (file signatures are checked, not the file name).
PHOTO_FORMATS = ("png", "jpeg", "exr")
#: Smallest accepted side, pixels: the models' coarsest feature maps are 1/8 of the input
#: and the paper's smallest images are 256 px; below 64 px a photo holds too little of
#: the material for the estimator to see its structure.
MIN_PHOTO_SIDE = 64
#: Largest accepted side, pixels, and pixel count. A 40 MP RGB image is 480 MB as float32
#: linear radiance, before any model runs; a 12 MP phone photo (4032 x 3024) fits, a
#: 48 MP one (8000 x 6000) is refused with a message to downscale it.
MAX_PHOTO_SIDE = 8192
MAX_PHOTO_PIXELS = 40_000_000

# EXIF tags (EXIF 2.3, CIPA DC-008): the orientation of the stored pixels and the lens's
# focal length in 35 mm film equivalent (mm, an integer; 0 means unknown).
_ORIENTATION = ExifTags.Base.Orientation
_FOCAL_35MM = ExifTags.Base.FocalLengthIn35mmFilm
_EXIF_WIDTH = ExifTags.Base.ExifImageWidth
_EXIF_HEIGHT = ExifTags.Base.ExifImageHeight


@dataclass(frozen=True)
class Photo:
    """One photo, decoded to linear radiance, and what the file said about it.

    Attributes:
        image: ``[3, H, W]`` float32 linear radiance (not tone-mapped), upright, >= 0.
        path: the file read.
        format: ``"png"``, ``"jpeg"`` or ``"exr"``.
        bit_depth: bits per stored sample: 8 or 16 for PNG / JPEG; None for EXR (floats).
        file_size: ``(H, W)`` of the pixels as stored, before the EXIF orientation
            (equal to ``size`` unless the orientation swaps the axes).
        channels: channels stored in the file (1 grey, 2 grey+alpha, 3 RGB, 4 RGBA).
        orientation: the EXIF orientation applied (1: none; 1-8 as in EXIF 2.3).
        focal_35mm: EXIF ``FocalLengthIn35mmFilm`` in mm, or None when absent / zero.
        exif_size: ``(H, W)`` the camera recorded (EXIF ``ExifImageHeight/Width``), or
            None. When it differs from ``size`` the photo was cropped or resized after
            capture, and a field of view from ``focal_35mm`` refers to the full frame.
        icc_profile: the file embeds an ICC colour profile (it is not applied: the
            project's 2.2 decode is used whatever the profile says).
        notes: what was done to the data on the way (alpha dropped, grey expanded, ...).
    """

    image: torch.Tensor
    path: str
    format: str
    bit_depth: int | None
    file_size: tuple[int, int]
    channels: int
    orientation: int = 1
    focal_35mm: float | None = None
    exif_size: tuple[int, int] | None = None
    icc_profile: bool = False
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def size(self) -> tuple[int, int]:
        """``(H, W)`` of ``image`` (upright)."""
        return tuple(self.image.shape[-2:])  # type: ignore[return-value]

    def metadata(self) -> dict:
        """Everything but the pixels, JSON-serialisable (for provenance files)."""
        return {
            "path": self.path,
            "format": self.format,
            "bit_depth": self.bit_depth,
            "size": list(self.size),
            "file_size": list(self.file_size),
            "channels": self.channels,
            "orientation": self.orientation,
            "focal_35mm": self.focal_35mm,
            "exif_size": None if self.exif_size is None else list(self.exif_size),
            "icc_profile": self.icc_profile,
            "notes": list(self.notes),
        }


# ---------------------------------------------------------------------- checks
def _sniff(path: Path) -> str:
    """The format from the file's first bytes; FormatError for missing/empty/unknown."""
    if not path.exists():
        raise FormatError(path, "photo file does not exist")
    if not path.is_file():
        raise FormatError(path, "expected a photo file, found a folder or special file")
    if path.stat().st_size == 0:
        raise FormatError(path, "photo file is empty (0 bytes)")
    with open(path, "rb") as fh:
        head = fh.read(8)
    if head.startswith(PNG_SIGNATURE):
        return "png"
    if head.startswith(JPEG_MAGIC):
        return "jpeg"
    if head.startswith(EXR_MAGIC):
        return "exr"
    raise FormatError(path, "not a PNG, JPEG or EXR file (unrecognised signature); convert the photo to one of those")


def _check_size(path: Path, height: int, width: int, min_side: int, max_side: int, max_pixels: int) -> None:
    if min(height, width) < min_side:
        raise FormatError(path, f"photo is {width}x{height} (W x H); each side must be at least {min_side} pixels")
    if max(height, width) > max_side or height * width > max_pixels:
        raise FormatError(
            path,
            f"photo is {width}x{height} (W x H, {height * width / 1e6:.1f} MP); the limit is {max_side} pixels "
            f"on a side and {max_pixels / 1e6:.0f} MP: downscale it first (e.g. to 2048 pixels on the long side)",
        )


# ---------------------------------------------------------------------- PNG / JPEG
def _decode_pil(path: Path, kind: str, img: Image.Image, rawmode) -> tuple[np.ndarray, int, int, list[str]]:
    """Pixels of an opened Pillow image as ``[H, W, C]`` float32 display values in [0, 1]
    (before orientation), with the bit depth, the stored channel count and notes.
    ``rawmode`` is the file's raw pixel layout (``img.tile[0].args``, read before
    anything loads the image, which empties ``img.tile``)."""
    notes: list[str] = []
    mode = img.mode
    if mode == "CMYK":
        raise FormatError(
            path,
            "CMYK JPEG (a print colour space) is not supported: its colours cannot be turned into "
            "radiance without the printer's profile; convert it to RGB (sRGB) first",
        )
    # Pillow decodes 16-bit RGB(A) PNGs to 8 bits. Both bytes of every sample are kept by
    # decoding twice with the same PNG unfiltering (it works on bytes, 6 or 8 per pixel
    # for either raw mode): once keeping the high byte ("...;16B"), once the low byte
    # (the same data read as little-endian, "...;16L").
    if kind == "png" and rawmode in ("RGB;16B", "RGBA;16B"):
        planes = []
        for raw in (rawmode, rawmode.replace("16B", "16L")):
            with Image.open(path) as part:
                t = part.tile[0]
                # Pillow's tile entries are a private type (a namedtuple in new versions).
                part.tile = [t._replace(args=raw) if hasattr(t, "_replace") else (*t[:3], raw)]  # type: ignore[list-item]
                part.load()
                planes.append(np.asarray(part).astype(np.uint32))
        pixels = ((planes[0] << 8) | planes[1]).astype(np.float32) / 65535.0
        channels, bit_depth = pixels.shape[-1], 16
    elif kind == "png" and rawmode == "LA;16B":
        # 16-bit grey + alpha: no raw mode keeps both bytes; 8-bit precision, said so.
        img.load()
        pixels = np.asarray(img.convert("RGBA"), dtype=np.float32) / 255.0
        channels, bit_depth = 2, 16
        notes.append("16-bit grey+alpha PNG read at 8-bit precision (Pillow has no 16-bit grey+alpha mode)")
    else:
        img.load()
        transparency = "transparency" in img.info
        if mode == "P":
            img = img.convert("RGBA" if transparency else "RGB")
        elif mode == "1":
            img = img.convert("L")
        elif mode == "I" or mode.startswith("I;16"):
            pass
        elif mode not in ("L", "LA", "RGB", "RGBA"):
            img = img.convert("RGB")
            notes.append(f"{kind.upper()} mode {mode} converted to RGB")
        pixels = np.asarray(img)
        if pixels.ndim == 2:
            pixels = pixels[..., None]
        channels = pixels.shape[-1] + (1 if transparency and mode in ("L", "RGB") else 0)
        if pixels.dtype == np.uint8:
            bit_depth, scale = 8, 255.0
        elif pixels.dtype in (np.uint16, np.int32) and mode.startswith("I"):
            bit_depth, scale = 16, 65535.0
        else:
            raise FormatError(path, f"{kind.upper()} holds {pixels.dtype} pixels (mode {mode}); expected 8 or 16 bits")
        pixels = pixels.astype(np.float32) / scale
        if transparency and mode in ("L", "RGB"):
            notes.append("transparency chunk ignored: the material is assumed opaque")
    return pixels, bit_depth, channels, notes


def _exif_facts(img: Image.Image) -> tuple[int, float | None, tuple[int, int] | None]:
    """(orientation, focal length in 35 mm equivalent, recorded (H, W)) from EXIF."""
    exif = img.getexif()
    orientation = exif.get(_ORIENTATION, 1)
    if not isinstance(orientation, int) or not 1 <= orientation <= 8:
        orientation = 1
    sub = exif.get_ifd(ExifTags.IFD.Exif)
    focal = sub.get(_FOCAL_35MM)
    focal_35mm = float(focal) if isinstance(focal, (int, float)) and focal > 0 else None
    w, h = sub.get(_EXIF_WIDTH), sub.get(_EXIF_HEIGHT)
    exif_size = (int(h), int(w)) if isinstance(w, int) and isinstance(h, int) and w > 0 and h > 0 else None
    return orientation, focal_35mm, exif_size


def _orient(pixels: np.ndarray, orientation: int) -> np.ndarray:
    """Apply an EXIF orientation to ``[H, W, C]`` pixels (the same transposes as
    ``PIL.ImageOps.exif_transpose``, on arrays of any dtype)."""
    ops = {
        1: lambda a: a,
        2: lambda a: a[:, ::-1],  # mirrored left-right
        3: lambda a: a[::-1, ::-1],  # rotated 180
        4: lambda a: a[::-1],  # mirrored top-bottom
        5: lambda a: a.transpose(1, 0, 2),  # transposed
        6: lambda a: np.rot90(a, k=-1),  # stored rotated 90 CCW: turn 90 CW
        7: lambda a: a[::-1, ::-1].transpose(1, 0, 2),  # transversed
        8: lambda a: np.rot90(a, k=1),  # stored rotated 90 CW: turn 90 CCW
    }
    return np.ascontiguousarray(ops[orientation](pixels))


def _read_raster(path: Path, kind: str, limits: tuple[int, int, int]) -> Photo:
    try:
        with Image.open(path) as img:
            width, height = img.size
            _check_size(path, height, width, *limits)
            rawmode = img.tile[0][3] if img.tile else None
            orientation, focal_35mm, exif_size = _exif_facts(img)  # may load the image
            icc = bool(img.info.get("icc_profile"))
            pixels, bit_depth, channels, notes = _decode_pil(path, kind, img, rawmode)
    except FormatError:
        raise
    except Image.DecompressionBombError as err:  # Pillow's own size guard, past ours
        raise FormatError(path, f"photo is far too large ({err}); downscale it first") from err
    except (OSError, SyntaxError, ValueError) as err:
        raise FormatError(path, f"cannot decode the {kind.upper()} data (truncated or corrupt file?): {err}") from err
    pixels = _orient(pixels, orientation)
    if orientation != 1:
        notes.append(f"EXIF orientation {orientation} applied")
    pixels, more = _to_rgb(pixels)
    image = inverse_tonemap(hwc_to_chw(pixels))
    return Photo(
        image=image,
        path=str(path),
        format=kind,
        bit_depth=bit_depth,
        file_size=(height, width),
        channels=channels,
        orientation=orientation,
        focal_35mm=focal_35mm,
        exif_size=exif_size,
        icc_profile=icc,
        notes=tuple(notes + more),
    )


def _to_rgb(pixels: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """``[H, W, C]`` with C in 1..4 -> ``[H, W, 3]``: grey copied, alpha dropped."""
    c = pixels.shape[-1]
    if c == 1:
        return np.repeat(pixels, 3, axis=-1), ["grey photo copied to R, G, B"]
    if c == 2:
        return np.repeat(pixels[..., :1], 3, axis=-1), ["grey photo copied to R, G, B; alpha dropped"]
    if c == 4:
        return np.ascontiguousarray(pixels[..., :3]), ["alpha channel dropped (the material is assumed opaque)"]
    return pixels, []


# ---------------------------------------------------------------------- EXR
def _read_exr_photo(path: Path, limits: tuple[int, int, int]) -> Photo:
    try:
        with OpenEXR.File(str(path), header_only=True) as exr:
            header = exr.header()
            names = {c.name for c in header["channels"]}
            (x0, y0), (x1, y1) = header["dataWindow"]
    except Exception as err:  # the binding raises RuntimeError / ValueError on bad data
        raise FormatError(path, f"cannot decode the EXR header (truncated or corrupt file?): {err}") from err
    height, width = int(y1 - y0 + 1), int(x1 - x0 + 1)
    _check_size(path, height, width, *limits)
    order: tuple[str, ...]
    if names == {"R", "G", "B"}:
        order, channels = ("R", "G", "B"), 3
    elif names == {"R", "G", "B", "A"}:
        order, channels = ("R", "G", "B", "A"), 4
    elif names == {"Y"}:
        order, channels = ("Y",), 1
    elif names == {"Y", "A"}:
        order, channels = ("Y", "A"), 2
    else:
        raise FormatError(path, f"EXR channels {sorted(names)}; expected R,G,B or Y (with or without A)")
    pixels = read_exr(path, order)  # NaN / inf and corrupt data are refused there
    pixels, notes = _to_rgb(pixels)
    negative = int((pixels < 0).sum())
    if negative:
        notes.append(f"{negative} negative values clamped to 0 (radiance cannot be negative)")
        pixels = np.maximum(pixels, 0.0)
    return Photo(
        image=hwc_to_chw(pixels),
        path=str(path),
        format="exr",
        bit_depth=None,
        file_size=(height, width),
        channels=channels,
        notes=tuple(notes),
    )


# ---------------------------------------------------------------------- public
def read_photo(
    path: str | os.PathLike,
    *,
    min_side: int = MIN_PHOTO_SIDE,
    max_side: int = MAX_PHOTO_SIDE,
    max_pixels: int = MAX_PHOTO_PIXELS,
) -> Photo:
    """Read a photo (PNG 8/16-bit, JPEG, EXR) as linear radiance, upright.

    Args:
        path: the file; its format is taken from its first bytes, not its name.
        min_side, max_side, max_pixels: size limits (defaults: the module constants).

    Returns:
        A ``Photo``: ``image [3, H, W]`` float32 linear radiance (8/16-bit files decoded
        with ``clamp(v, 0, 1) ** 2.2``, EXR as stored), plus the file's metadata.

    Raises:
        FormatError: naming ``path`` and the problem (module docstring).

    Example:
        >>> photo = read_photo("wood.jpg")  # doctest: +SKIP
        >>> photo.image.shape, photo.focal_35mm  # doctest: +SKIP
        (torch.Size([3, 3024, 4032]), 26.0)
    """
    path = Path(path)
    kind = _sniff(path)
    limits = (min_side, max_side, max_pixels)
    if kind == "exr":
        return _read_exr_photo(path, limits)
    return _read_raster(path, kind, limits)
