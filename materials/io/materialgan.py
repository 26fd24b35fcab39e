"""MaterialGAN (Guo et al. 2020) / Luo et al. 2024 capture folders.

Layout::

    0.png ... N-1.png   photos, 8-bit RGB, square crops of the material plane, viewed
                        through the SPEC tone map clamp(x, 0, 1) ** (1/2.2) (undone here);
                        zero-padded names (00.png, 01.png, ...) and .jpg are accepted
    camera_pos.txt      one "x, y, z" per line, cm, one line per photo (required)
    light_pos.txt       one "x, y, z" per line, cm (optional: when absent the light is
                        the camera's flash, i.e. collocated with the camera, which is how
                        the MaterialGAN captures are made and shipped)
    image_size.txt      side of the photographed plane, cm, one number (optional:
                        the preset's fallback plane size is used when absent)
    light_power.txt     light power, one number or three (R, G, B), on one line or one
                        line per photo (optional: the preset's 1500 when absent)

Numbers may be separated by commas and/or spaces; blank lines and lines starting with
``#`` are skipped. The result is a ``Capture`` in preset ``materialgan`` (cm, 1/d^2).
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

import torch

from kernels.tonemap import inverse_tonemap
from materials.io.encoding import hwc_to_chw
from materials.io.errors import FormatError, require_same_size
from materials.io.png import read_ldr
from materials.types import Capture, MapError

__all__ = ["read_materialgan", "find_numbered_images", "read_number_rows"]

_IMAGE_NAME = re.compile(r"^(\d+)\.(png|jpe?g)$", re.IGNORECASE)
_SEPARATORS = re.compile(r"[,\s]+")


def find_numbered_images(folder: str | os.PathLike) -> list[Path]:
    """The photos ``0.png ... N-1.png`` of ``folder`` in index order (maybe empty).

    Raises:
        FormatError: two files share an index (``1.png`` and ``01.png``) or the indices
            are not 0 .. N-1 without gaps.
    """
    folder = Path(folder)
    by_index: dict[int, list[Path]] = {}
    for path in folder.iterdir():
        match = _IMAGE_NAME.match(path.name)
        if match and path.is_file():
            by_index.setdefault(int(match.group(1)), []).append(path)
    for index, paths in sorted(by_index.items()):
        if len(paths) > 1:
            names = ", ".join(sorted(p.name for p in paths))
            raise FormatError(folder, f"several photos have index {index}: {names}")
    indices = sorted(by_index)
    if indices and indices != list(range(len(indices))):
        gaps = sorted(set(range(max(indices) + 1)) - set(indices))
        raise FormatError(folder, f"photos must be numbered 0 .. N-1 without gaps; missing index(es) {gaps[:10]}")
    return [by_index[i][0] for i in indices]


def read_number_rows(path: Path, widths: tuple[int, ...]) -> list[list[float]]:
    """Parse a text file of numbers, one row per line; each row must have a width in ``widths``.

    Raises:
        FormatError: naming the file and the 1-based line of a malformed or non-finite
            number, a row of the wrong width, or a file with no rows.
    """
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as err:
        raise FormatError(path, f"not a text file: {err}") from err
    rows = []
    for line_no, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        tokens = [t for t in _SEPARATORS.split(stripped) if t]
        values = []
        for token in tokens:
            try:
                value = float(token)
            except ValueError:
                raise FormatError(path, f"line {line_no}: {token!r} is not a number ({line!r})") from None
            if not math.isfinite(value):
                raise FormatError(path, f"line {line_no}: {token!r} is not a finite number")
            values.append(value)
        if len(values) not in widths:
            expected = " or ".join(str(w) for w in widths)
            raise FormatError(path, f"line {line_no}: expected {expected} numbers, found {len(values)} ({line!r})")
        rows.append(values)
    if not rows:
        raise FormatError(path, "file holds no numbers")
    return rows


def _positions(path: Path, count: int) -> torch.Tensor:
    rows = read_number_rows(path, (3,))
    if len(rows) != count:
        raise FormatError(path, f"mismatched counts: {count} photos but {len(rows)} positions (one x, y, z per photo)")
    return torch.tensor(rows, dtype=torch.float32)


def _light_power(path: Path, count: int) -> tuple[float, float, float]:
    rows = read_number_rows(path, (1, 3))
    if len(rows) not in (1, count):
        raise FormatError(path, f"expected 1 line or one per photo ({count}), found {len(rows)}")
    powers = {tuple(r * 3 if len(r) == 1 else r) for r in rows}
    if len(powers) != 1:
        raise FormatError(path, "light power differs between photos; one power for all photos is supported")
    power = next(iter(powers))
    if min(power) <= 0:
        raise FormatError(path, f"light power must be positive, found {list(power)}")
    return power  # type: ignore[return-value]


def read_materialgan(folder: str | os.PathLike) -> Capture:
    """Read a MaterialGAN-style capture folder (layout in the module docstring).

    Returns:
        A CPU float32 ``Capture`` with ``images [N, 3, S, S]`` linear radiance in [0, 1]
        (tone map undone), ``light_pos`` / ``camera_pos [N, 3]`` in cm, preset
        ``"materialgan"``, ``plane_size`` from ``image_size.txt`` and ``intensity``
        from ``light_power.txt`` (None when a file is absent: the preset's value), and
        ``meta = {"format": "materialgan", "source", "images", "light_pos_source"}``.

    Raises:
        FormatError: no photos, missing ``camera_pos.txt``, mismatched counts, malformed
            numbers (file and line named), photos of different sizes, non-square photos,
            photos that are not RGB. MapError: positions below the plane.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FormatError(folder, "capture folder does not exist" if not folder.exists() else "not a folder")
    photos = find_numbered_images(folder)
    if not photos:
        raise FormatError(folder, "no photos found (expected 0.png ... N-1.png)")
    count = len(photos)

    camera_path, light_path = folder / "camera_pos.txt", folder / "light_pos.txt"
    if not camera_path.is_file():
        raise FormatError(camera_path, "missing positions file: camera_pos.txt (one x, y, z per photo, cm) is required")
    camera_pos = _positions(camera_path, count)
    if light_path.is_file():
        light_pos, light_source = _positions(light_path, count), light_path.name
    else:
        light_pos, light_source = camera_pos.clone(), "camera_pos.txt (flash collocated with the camera)"

    size_path = folder / "image_size.txt"
    plane_size = None
    if size_path.is_file():
        rows = read_number_rows(size_path, (1,))
        if len(rows) != 1 or rows[0][0] <= 0:
            raise FormatError(size_path, f"expected one positive number (plane size, cm), found {rows}")
        plane_size = rows[0][0]
    power_path = folder / "light_power.txt"
    intensity = _light_power(power_path, count) if power_path.is_file() else None

    images, sizes = [], {}
    for path in photos:
        image = read_ldr(path)
        height, width, channels = image.shape
        if channels != 3:
            raise FormatError(path, f"photo has {channels} channel(s); expected 3 (RGB)")
        if height != width:
            raise FormatError(path, f"photo is {height}x{width} (H x W), not square; MaterialGAN photos are square")
        sizes[path.name] = (height, width)
        images.append(hwc_to_chw(image))
    require_same_size(folder, sizes)

    try:
        return Capture(
            images=inverse_tonemap(torch.stack(images)),
            light_pos=light_pos,
            camera_pos=camera_pos,
            preset="materialgan",
            plane_size=plane_size,
            intensity=intensity,
            meta={
                "format": "materialgan",
                "source": str(folder),
                "images": [p.name for p in photos],
                "light_pos_source": light_source,
            },
        )
    except MapError as err:
        raise MapError(f"{folder}: {err}") from err
