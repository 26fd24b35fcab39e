"""INRIA / Deschaintre et al. 2018 material PNGs: five square panels side by side.

Layout (left to right), each panel ``S x S``, the whole image ``S x 5S``, 8-bit RGB::

    render | normal | diffuse | roughness | specular

Encodings (SPEC section 2: INRIA PNGs hold linear values):

- normal: ``(n + 1) / 2``; decoded and renormalised.
- diffuse, specular: linear values, no sRGB curve.
- roughness: linear grey; channel 0 is taken.
- render: **our choice** -- the render panel is stored tone-mapped,
  ``clamp(x, 0, 1) ** (1/2.2)`` (SPEC tone map), which is how INRIA renders are
  usually viewed; reading undoes it with ``inverse_tonemap``. Radiance above 1 is
  clipped by the 8-bit panel.

The dataset's panels are 288 x 288; any ``S`` is accepted as long as the panels are square.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from kernels.tonemap import inverse_tonemap, tonemap
from materials.io.encoding import chw_to_hwc, decode_normal, encode_normal, hwc_to_chw
from materials.io.errors import FormatError
from materials.io.png import read_png, write_png
from materials.types import MapError, Material

__all__ = ["read_inria", "write_inria", "INRIA_PANELS"]

#: Panel order, left to right.
INRIA_PANELS = ("render", "normal", "diffuse", "roughness", "specular")


def read_inria(path: str | os.PathLike) -> tuple[Material, torch.Tensor]:
    """Read an INRIA material PNG.

    Args:
        path: an 8-bit RGB PNG of width ``5 * height``.

    Returns:
        ``(material, render)``: an unbatched CPU float32 ``Material`` (``[C, S, S]``
        maps, linear, validated) and the render panel as linear radiance
        ``[3, S, S]`` in [0, 1] (tone map undone).

    Raises:
        FormatError: not an 8-bit PNG, alpha, not RGB, width != 5 * height.
        MapError: invalid map values (the file is named).
    """
    path = Path(path)
    image = read_png(path)
    height, width, channels = image.shape
    if channels != 3:
        raise FormatError(path, f"INRIA image has {channels} channel(s); expected 3 (RGB panels)")
    if width % len(INRIA_PANELS) != 0:
        raise FormatError(
            path,
            f"width {width} is not 5 x height {height}: expected five square panels "
            f"side by side ({' | '.join(INRIA_PANELS)})",
        )
    side = width // len(INRIA_PANELS)
    if side != height:
        raise FormatError(
            path,
            f"panels are {height}x{side} (H x W), not square: width {width} must be 5 x height {height} "
            f"({' | '.join(INRIA_PANELS)})",
        )
    panels = {name: hwc_to_chw(image[:, i * side : (i + 1) * side]) for i, name in enumerate(INRIA_PANELS)}
    material = Material(
        diffuse=panels["diffuse"],
        normal=decode_normal(panels["normal"]),
        roughness=panels["roughness"][:1].contiguous(),
        specular=panels["specular"],
    ).validate(source=str(path))
    return material, inverse_tonemap(panels["render"])


def write_inria(path: str | os.PathLike, material: Material, render: torch.Tensor) -> Path:
    """Write one material and its render as an INRIA PNG, atomically.

    Args:
        path: target ``.png``.
        material: unbatched square maps ``[C, S, S]`` (validated first).
        render: ``[3, S, S]`` linear radiance; stored tone-mapped (module docstring).

    Returns:
        The path written.
    """
    path = Path(path)
    if material.batch_shape:
        raise MapError(f"{path}: write_inria takes one material [C, S, S], got batch {material.batch_shape}")
    height, width = material.shape
    if height != width:
        raise MapError(f"{path}: INRIA panels are square; the maps are {height}x{width}")
    if not isinstance(render, torch.Tensor) or tuple(render.shape) != (3, height, width):
        shape = tuple(render.shape) if isinstance(render, torch.Tensor) else type(render).__name__
        raise MapError(f"{path}: render must be [3, {height}, {width}] like the maps, got {shape}")
    if not torch.isfinite(render).all():
        raise MapError(f"{path}: render holds NaN or inf values")
    material.validate(source=f"write_inria({path})")
    m = material.to("cpu", torch.float32)
    panels = {
        "render": tonemap(render.detach().to("cpu", torch.float32)),
        "normal": encode_normal(m.normal),
        "diffuse": m.diffuse.clamp(0.0, 1.0),
        "roughness": m.roughness.clamp(0.0, 1.0).expand(3, -1, -1),
        "specular": m.specular.clamp(0.0, 1.0),
    }
    sheet = np.concatenate([chw_to_hwc(panels[name]) for name in INRIA_PANELS], axis=1)
    write_png(path, sheet)
    return path
