"""INRIA / Deschaintre et al. 2018 material PNGs: five square panels side by side.

Layout (left to right), each panel ``S x S``, the whole image ``S x 5S``, 8-bit RGB::

    render | normal | diffuse | roughness | specular

Encodings (SPEC section 2: INRIA PNGs hold linear values), every panel included:

- render: **linear** radiance, clipped to [0, 1] by the 8-bit panel; no tone map.
  Re-rendering the ground-truth maps of 14 public files matches their render panel at
  27.4 dB read as linear and 14.0 dB read as tone-mapped (issue 15), so the files store
  linear values like the other panels. (Before that was measured, this reader undid a
  ``x ** (1/2.2)`` tone map and its writer applied one.)
- normal: ``(n + 1) / 2``; decoded and renormalised. Near-grazing normals can be stored
  a few 8-bit steps below z = 0; such pixels are lifted to z = ``NORMAL_Z_FLOOR``
  (renormalised) with a warning naming how many, as long as they are at most
  ``MAX_BELOW_HORIZON_FRACTION`` of the panel; more means a different convention or a
  broken file, and the file is refused.
- diffuse, specular: linear values, no sRGB curve.
- roughness: linear grey; channel 0 is taken.

The dataset's panels are 288 x 288; any ``S`` is accepted as long as the panels are square.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
import torch

from materials.io.encoding import chw_to_hwc, decode_normal, encode_normal, hwc_to_chw
from materials.io.errors import FormatError
from materials.io.png import read_png, write_png
from materials.types import MapError, Material

__all__ = ["read_inria", "write_inria", "INRIA_PANELS", "NORMAL_Z_FLOOR", "MAX_BELOW_HORIZON_FRACTION"]

#: Panel order, left to right.
INRIA_PANELS = ("render", "normal", "diffuse", "roughness", "specular")
#: z given to a decoded normal that points (slightly) into the surface: one 8-bit step of
#: the (n + 1) / 2 encoding, 2/255, the smallest z an 8-bit file can say is positive.
NORMAL_Z_FLOOR = 2.0 / 255.0
#: Most pixels of a normal panel that may point into the surface and still be clamped:
#: 1%. Quantisation of near-grazing normals touches a handful (6 of 65,536 in a public
#: file, 0.009%); a panel in another convention (e.g. signed values stored without the
#: (n + 1) / 2 offset, which puts every z < 0.5 below 0) touches far more than 1%.
MAX_BELOW_HORIZON_FRACTION = 1e-2


def _lift_below_horizon(path: Path, normal: torch.Tensor) -> torch.Tensor:
    """Normals ``[3, S, S]`` with z < 0 lifted to z = NORMAL_Z_FLOOR and renormalised
    (warning with the count); FormatError when there are too many (module docstring)."""
    below = normal[2] < 0
    count = int(below.sum())
    if count == 0:
        return normal
    total = below.numel()
    if count > MAX_BELOW_HORIZON_FRACTION * total:
        raise FormatError(
            path,
            f"{count} of {total} normal pixels ({100 * count / total:.2f}%) point into the surface (z < 0); "
            f"at most {100 * MAX_BELOW_HORIZON_FRACTION:g}% are taken as 8-bit quantisation and clamped "
            "(is the normal panel in another convention?)",
        )
    warnings.warn(
        f"{path}: {count} of {total} normal pixels had z < 0 (8-bit quantisation of near-grazing normals); "
        f"lifted to z = {NORMAL_Z_FLOOR:.4f} and renormalised",
        stacklevel=3,
    )
    lifted = normal.clone()
    lifted[2] = torch.where(below, torch.full_like(normal[2], NORMAL_Z_FLOOR), normal[2])
    return torch.nn.functional.normalize(lifted, dim=0)


def read_inria(path: str | os.PathLike) -> tuple[Material, torch.Tensor]:
    """Read an INRIA material PNG.

    Args:
        path: an 8-bit RGB PNG of width ``5 * height``.

    Returns:
        ``(material, render)``: an unbatched CPU float32 ``Material`` (``[C, S, S]``
        maps, linear, validated) and the render panel as linear radiance
        ``[3, S, S]`` in [0, 1], as stored.

    Warns:
        UserWarning: normal pixels below the surface were clamped (how many).

    Raises:
        FormatError: not an 8-bit PNG, alpha, not RGB, width != 5 * height, more than
            ``MAX_BELOW_HORIZON_FRACTION`` of the normals below the surface.
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
        normal=_lift_below_horizon(path, decode_normal(panels["normal"])),
        roughness=panels["roughness"][:1].contiguous(),
        specular=panels["specular"],
    ).validate(source=str(path))
    return material, panels["render"]


def write_inria(path: str | os.PathLike, material: Material, render: torch.Tensor) -> Path:
    """Write one material and its render as an INRIA PNG, atomically.

    Args:
        path: target ``.png``.
        material: unbatched square maps ``[C, S, S]`` (validated first).
        render: ``[3, S, S]`` linear radiance; stored linear, clipped to [0, 1] by the
            8-bit panel (module docstring).

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
        "render": render.detach().to("cpu", torch.float32).clamp(0.0, 1.0),
        "normal": encode_normal(m.normal),
        "diffuse": m.diffuse.clamp(0.0, 1.0),
        "roughness": m.roughness.clamp(0.0, 1.0).expand(3, -1, -1),
        "specular": m.specular.clamp(0.0, 1.0),
    }
    sheet = np.concatenate([chw_to_hwc(panels[name]) for name in INRIA_PANELS], axis=1)
    write_png(path, sheet)
    return path
