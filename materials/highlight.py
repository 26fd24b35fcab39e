"""Where a flash photo has its highlight: a disc on the plane around the point under the
flash, and the saturated pixels.

One place for the two tests that the estimator's evaluation (diffuse error inside the
highlight, ``estimator.evaluate``), the capture evaluation and the capture pipeline's
``relit_highlight`` option (``matcap.capture``) all make. Pixel centres follow SPEC
section 2 (``kernels.reference.plane_points``: pixel (i, j) of an H x W image at
x = ((j + 0.5)/W - 0.5) * plane_size, y = -((i + 0.5)/H - 0.5) * plane_size).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

import kernels
from kernels.reference import plane_points

__all__ = ["SATURATION", "HIGHLIGHT_RADIUS", "plane_disc", "saturated", "highlight_mask"]

#: Tone-mapped value above which a flash pixel counts as saturated (the 8-bit photo
#: clips at 1; 0.98 catches the clipped core and its immediate rim).
SATURATION = 0.98
#: Radius, in plane units (plane side 4), of the disc around the flash's mirror point that
#: counts as highlight whatever its value: 0.5 = 1/8 of the plane side, the extent of a
#: GGX lobe at roughness ~0.3 seen from height 4 (tan of the ~7 degree half-width x 4).
HIGHLIGHT_RADIUS = 0.5


def plane_disc(centre: Sequence[float], radius: float, size: tuple[int, int], plane_size: float) -> torch.Tensor:
    """``[H, W]`` bool: the pixels whose centre lies within ``radius`` (scene units) of the
    plane point ``centre = (x, y)``. Computed in float64, so a pixel centre on the
    boundary does not flip between CPUs."""
    h, w = size
    p = plane_points(h, w, plane_size, dtype=torch.float64)
    x0, y0 = (float(v) for v in centre[:2])
    return (p[0] - x0) ** 2 + (p[1] - y0) ** 2 <= float(radius) ** 2


def saturated(images: torch.Tensor) -> torch.Tensor:
    """``[B, 1, H, W]`` bool: pixels of linear images ``[B, 3, H, W]`` whose tone-mapped
    brightest channel reaches ``SATURATION`` (clipped in an 8-bit photo, or nearly)."""
    return kernels.tonemap(images).amax(1, keepdim=True) >= SATURATION


def highlight_mask(
    flash: torch.Tensor,
    camera_pos: Sequence[float],
    plane_size: float = 4.0,
    radius: float = HIGHLIGHT_RADIUS,
) -> torch.Tensor:
    """Highlight region of flash photos ``[B, 3, H, W]`` (linear) taken with the flash at
    the camera ``camera_pos``: saturated (``saturated``), or within ``radius`` of the point
    under the flash (the mirror point of a collocated light on a flat sample). Returns
    ``[B, 1, H, W]`` bool on ``flash``'s device."""
    disc = plane_disc(camera_pos, radius, (flash.shape[-2], flash.shape[-1]), plane_size).to(flash.device)
    return saturated(flash) | disc[None, None]
