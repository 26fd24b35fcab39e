"""Relighting a photo larger than a model's native size, as overlapping crops of the plane
(issue 16: resolution-free relighting).

A relighter that only accepts ``t x t`` images (the tiny diffusion model: its training
size) relights an ``S x S`` photo (S >= t) tile by tile. Each tile is a window of the
photographed plane, and a window is itself a scene: a plane of the model's side with the
camera and lights moved into the window's frame (``materials.capture_domain.crop_geometry``,
the same mapping the training crops use), so every tile is relit in its own, exact
l / v / h geometry and the specular prior is translated in the tile's own pixels.

Seams: tiles overlap by ``overlap`` pixels and are blended with a separable weight that
ramps linearly across each overlap (``blend_window``), so along any row the result moves
from one tile's prediction to the next one's over the whole overlap instead of jumping at
a border. Where two tiles agree (a local relighter, e.g. the Lambertian re-shading) the
blend returns exactly their common value (``tests/relight/test_tiling.py``).

Shapes: ``photo [3, S, S]`` linear radiance; ``light_pos [K, 3]`` and ``camera_pos [3]``
in the photo's scene units (plane of side ``plane_size`` at z = 0, SPEC section 2).
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from materials.capture_domain import crop_geometry

__all__ = ["tile_starts", "blend_window", "tiled_relight", "DEFAULT_OVERLAP"]

#: Overlap of neighbouring tiles in pixels, for 64 px tiles: a quarter of the tile, so the
#: blend ramp is wide against the few-pixel extent of the seam a tile border would leave,
#: at 1.8x the tiles of no overlap (a 256 px photo: 5 x 5 tiles instead of 4 x 4).
DEFAULT_OVERLAP = 16

#: ``relight_tile(photo [3, t, t], light_pos [K, 3], camera_pos [3]) -> [K, 3, t, t]``.
TileRelighter = Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]


def tile_starts(size: int, tile: int, overlap: int) -> list[int]:
    """First pixels of tiles of side ``tile`` that cover ``[0, size)`` with neighbours
    overlapping by at least ``overlap`` pixels; the last tile ends at ``size``.

    >>> tile_starts(256, 64, 16)
    [0, 48, 96, 144, 192]
    >>> tile_starts(64, 64, 16)
    [0]
    """
    if not 0 <= overlap < tile <= size:
        raise ValueError(f"need 0 <= overlap < tile <= size, got overlap={overlap}, tile={tile}, size={size}")
    stride = tile - overlap
    count = -(-(size - tile) // stride) + 1  # ceil: enough tiles to reach the far edge
    if count == 1:
        return [0]
    # Spread the tiles evenly: the overlap grows a little where the size asks for it.
    return [round(i * (size - tile) / (count - 1)) for i in range(count)]


def blend_window(tile: int, overlap: int, *, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """``[tile]`` blending weight of one tile along one axis: rising linearly over the
    first ``overlap`` pixels, 1 in the middle, falling over the last ``overlap``. It never
    reaches 0 (the smallest weight is ``1 / (overlap + 1)``), so the normalised blend is
    defined at the photo's own border too, where no neighbour overlaps."""
    i = torch.arange(tile, dtype=dtype)
    ramp = torch.minimum(i + 1, tile - i) / (overlap + 1)
    return ramp.clamp(max=1.0)


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
    """Relight ``photo [3, S, S]`` under ``light_pos [K, 3]`` tile by tile (module docstring).

    Args:
        relight_tile: relights one ``[3, tile, tile]`` window in its own frame (plane of
            side ``plane_size`` centred at the origin) to ``[K, 3, tile, tile]``.
        photo: ``[3, S, S]`` linear radiance, S >= ``tile`` (S == ``tile``: one call).
        light_pos, camera_pos: positions in the photo's frame (plane of side ``plane_size``).
        tile, overlap: tile side and the least overlap of neighbours, in pixels.
        plane_size: side of the photographed plane, which is also the side the relighter
            expects its window to have (the models' frame: 4).

    Returns:
        ``[K, 3, S, S]`` linear radiance, the weighted blend of the tiles' outputs.
    """
    _, h, w = photo.shape
    if h != w:
        raise ValueError(f"tiled relighting needs a square photo, got {h} x {w}")
    starts = tile_starts(h, tile, overlap)
    window = blend_window(tile, overlap, dtype=photo.dtype)
    weight2d = window[:, None] * window[None, :]
    out = photo.new_zeros((light_pos.shape[0], 3, h, w))
    total = photo.new_zeros((h, w))
    side = plane_size * tile / h  # the window's side on the plane
    for top in starts:
        for left in starts:
            # The window's centre on the plane (SPEC section 2: x right, y up, row 0 at +y).
            cx = ((left + tile / 2) / w - 0.5) * plane_size
            cy = -((top + tile / 2) / h - 0.5) * plane_size
            light, camera, _ = crop_geometry(light_pos, camera_pos, (cx, cy), side, plane_size=plane_size)
            crop = photo[:, top : top + tile, left : left + tile]
            relit = relight_tile(crop, light, camera)
            out[:, :, top : top + tile, left : left + tile] += relit * weight2d
            total[top : top + tile, left : left + tile] += weight2d
    return out / total
