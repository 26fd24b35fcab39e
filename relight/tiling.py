"""Relighting a photo larger than a model's native size, as overlapping windows of the
plane (issue 16: resolution-free relighting).

A relighter that only accepts ``t x t`` images (the tiny diffusion model: its training
size) relights an ``S x S`` photo (S >= t) window by window (``materials.windows``): each
window is relit in its own, exact l / v / h geometry, so the specular prior is translated
in the window's own pixels, and the windows are blended across their overlaps.

Shapes: ``photo [3, S, S]`` linear radiance; ``light_pos [K, 3]`` and ``camera_pos [3]``
in the photo's scene units (plane of side ``plane_size`` at z = 0, SPEC section 2).
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from materials.capture_domain import crop_geometry
from materials.windows import DEFAULT_OVERLAP, TileBlend, plane_windows

__all__ = ["tiled_relight", "DEFAULT_OVERLAP"]

#: ``relight_tile(photo [3, t, t], light_pos [K, 3], camera_pos [3]) -> [K, 3, t, t]``.
TileRelighter = Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]


def tiled_relight(
    relight_tile: TileRelighter,
    photo: torch.Tensor,
    light_pos: torch.Tensor,
    camera_pos: torch.Tensor,
    *,
    tile: int,
    overlap: int = DEFAULT_OVERLAP,
    plane_size: float = 4.0,
) -> torch.Tensor:
    """Relight ``photo [3, S, S]`` under ``light_pos [K, 3]`` window by window (module docstring).

    Args:
        relight_tile: relights one ``[3, tile, tile]`` window in its own frame (plane of
            side ``plane_size`` centred at the origin) to ``[K, 3, tile, tile]``.
        photo: ``[3, S, S]`` linear radiance, S >= ``tile`` (S == ``tile``: one call).
        light_pos, camera_pos: positions in the photo's frame (plane of side ``plane_size``).
        tile, overlap: window side and the least overlap of neighbours, in pixels.
        plane_size: side of the photographed plane, which is also the side the relighter
            expects its window to have (the models' frame: 4).

    Returns:
        ``[K, 3, S, S]`` linear radiance, the weighted blend of the windows' outputs.
    """
    _, h, w = photo.shape
    if h != w:
        raise ValueError(f"tiled relighting needs a square photo, got {h} x {w}")
    blend = TileBlend(h, tile, overlap, dtype=photo.dtype)
    for window in plane_windows(h, tile, overlap, plane_size):
        light, camera, _ = crop_geometry(light_pos, camera_pos, window.center, window.side, plane_size=plane_size)
        crop = photo[:, window.top : window.top + tile, window.left : window.left + tile]
        blend.add(window, relight_tile(crop, light, camera))
    return blend.result()
