"""Writing rendered images for people and renderers: tone-mapped PNG + linear EXR."""

from __future__ import annotations

from pathlib import Path

import torch

from kernels.tonemap import tonemap
from materials.io import write_exr, write_png
from materials.io.encoding import chw_to_hwc

__all__ = ["write_image_pair", "contact_sheet"]


def write_image_pair(folder: Path, stem: str, image: torch.Tensor) -> list[Path]:
    """Write ``[3, H, W]`` linear radiance as ``stem.exr`` (linear) and ``stem.png``
    (tone-mapped: clamp then x^(1/2.2), SPEC section 2)."""
    exr, png = folder / f"{stem}.exr", folder / f"{stem}.png"
    write_exr(exr, chw_to_hwc(image))
    write_png(png, chw_to_hwc(tonemap(image)))
    return [exr, png]


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
