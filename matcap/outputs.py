"""Output folders and images: checking ``--out`` before the work, tone-mapped PNG +
linear EXR pairs, contact sheets (optionally labelled)."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from kernels.tonemap import tonemap
from matcap.errors import UsageError
from materials.io import write_exr, write_png
from materials.io.atomic import clean_stale
from materials.io.encoding import chw_to_hwc

__all__ = ["check_output_folder", "write_image_pair", "contact_sheet", "label_tiles", "EMPTY_TILE_GREY"]


def check_output_folder(folder: str | os.PathLike, *, overwrite: bool, marker: str) -> Path:
    """Check that ``--out`` can be written, before any compute (a bad ``--out`` costs a
    second, not the run). Also removes what a killed earlier run left next to it
    (``materials.io.atomic.clean_stale``).

    Args:
        folder: the ``--out`` folder.
        overwrite: ``--overwrite`` was given.
        marker: the file that marks a folder this command wrote (only such a folder, or
            an empty one, is replaced).

    Raises:
        UsageError: one line naming ``--out`` and, where it helps, ``--overwrite``.
    """
    folder = Path(folder)
    clean_stale(folder)
    if folder.exists() or folder.is_symlink():
        if not folder.is_dir():
            raise UsageError(f"--out {folder}: exists and is not a folder; choose another --out")
        if not overwrite:
            raise UsageError(f"--out {folder}: already exists; pass --overwrite to replace it, or choose another --out")
        if any(folder.iterdir()) and not (folder / marker).is_file():
            raise UsageError(
                f"--out {folder}: already exists and was not written by this command (no {marker}); "
                "not replacing it, even with --overwrite: choose another --out"
            )
    ancestor = folder.absolute().parent
    while not ancestor.exists():
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise UsageError(f"--out {folder}: {ancestor} is a file, not a folder")
    # Permission bits do not say it all (root, read-only mounts): try what the writer
    # will do, make a hidden folder there.
    try:
        probe = tempfile.mkdtemp(prefix=f".{folder.name}.probe-", dir=ancestor)
    except OSError as err:
        raise UsageError(f"--out {folder}: cannot write in {ancestor} ({err.strerror or err})") from None
    os.rmdir(probe)
    return folder


def write_image_pair(folder: Path, stem: str, image: torch.Tensor) -> list[Path]:
    """Write ``[3, H, W]`` linear radiance as ``stem.exr`` (linear) and ``stem.png``
    (tone-mapped: clamp then x^(1/2.2), SPEC section 2)."""
    exr, png = folder / f"{stem}.exr", folder / f"{stem}.png"
    write_exr(exr, chw_to_hwc(image))
    write_png(png, chw_to_hwc(tonemap(image)))
    return [exr, png]


#: Display value of a sheet's empty slots: a mid-dark grey, so an empty slot is not
#: mistaken for a black map (a dielectric's specular is nearly black).
EMPTY_TILE_GREY = 0.18
#: Label band: text height in pixels and the band's darkening (the text stays readable
#: on white maps, and the band covers only the top of the tile).
_LABEL_PX = 12
_LABEL_BAND_SCALE = 0.35


def label_tiles(tiles: torch.Tensor, labels: Sequence[str | None]) -> torch.Tensor:
    """Write one label into the top-left corner of each tile.

    Args:
        tiles: ``[N, 3, H, W]`` display values in [0, 1] (a copy is labelled).
        labels: N labels; None or "" leaves that tile untouched.
    Returns:
        ``[N, 3, H, W]``: each labelled tile's top band (``_LABEL_PX + 4`` rows, as wide
        as its text) darkened to ``_LABEL_BAND_SCALE`` with the text in white; every
        other pixel unchanged.
    """
    from PIL import Image, ImageDraw, ImageFont

    if len(labels) != tiles.shape[0]:
        raise ValueError(f"need one label per tile: {tiles.shape[0]} tiles, {len(labels)} labels")
    out = tiles.detach().float().clone()
    font = ImageFont.load_default(size=_LABEL_PX)
    band = _LABEL_PX + 4
    for k, label in enumerate(labels):
        if not label:
            continue
        width = min(out.shape[-1], int(font.getlength(label)) + 6)
        out[k, :, :band, :width] *= _LABEL_BAND_SCALE
        pixels = (out[k, :, :band, :width].clamp(0, 1) * 255).round().to(torch.uint8).permute(1, 2, 0)
        image = Image.fromarray(pixels.contiguous().numpy())
        ImageDraw.Draw(image).text((3, 1), label, fill=(255, 255, 255), font=font)
        # Write back only the band: the rest of the tile keeps its exact float values.
        out[k, :, :band, :width] = torch.from_numpy(np.array(image)).permute(2, 0, 1).float() / 255
    return out


def contact_sheet(images: torch.Tensor, columns: int | None = None) -> torch.Tensor:
    """Tile ``[N, 3, H, W]`` display values into one ``[3, rows*H, cols*W]`` image."""
    n, c, h, w = images.shape
    cols = columns or n
    rows = (n + cols - 1) // cols
    sheet = torch.zeros(c, rows * h, cols * w, dtype=images.dtype)
    for k in range(n):
        r, q = divmod(k, cols)
        sheet[:, r * h : (r + 1) * h, q * w : (q + 1) * w] = images[k]
    return sheet
