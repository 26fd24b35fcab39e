"""Overlapping windows of a photographed plane, and the seam-free blend of what a model
predicts in each (issue 16: models run at any resolution in their native window size).

A model that sees ``t x t`` images runs on an ``S x S`` photo (S >= t) window by window.
Each window is itself a scene: a plane of the model's side with the camera and lights
moved into the window's frame (``materials.capture_domain.crop_geometry``, the mapping
the training crops use), so every window is seen in its exact l / v / h geometry.

Seams: windows overlap by at least ``overlap`` pixels and are blended with a separable
weight that ramps linearly across each overlap (``blend_window``), so along any row the
result moves from one window's prediction to the next one's over the whole overlap
instead of jumping at a border. Where two windows agree (a pixel-local model) the blend
returns exactly their common value.

Used by ``relight.tiling`` (relit images) and ``estimator.tiling`` (SVBRDF maps).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

__all__ = ["DEFAULT_OVERLAP", "PlaneWindow", "TileBlend", "blend_window", "plane_windows", "tile_starts"]

#: Overlap of neighbouring windows in pixels, for 64 px windows: a quarter of the window,
#: so the blend ramp is wide against the few-pixel extent of the seam a border would
#: leave, at 1.8x the windows of no overlap (a 256 px photo: 5 x 5 instead of 4 x 4).
DEFAULT_OVERLAP = 16


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


@dataclass(frozen=True)
class PlaneWindow:
    """One ``tile x tile`` window of an ``S x S`` photo of a plane.

    Attributes:
        top, left: its first pixel row and column.
        center: (cx, cy) of the window on the plane, scene units (SPEC section 2: x right,
            y up, row 0 at +y).
        side: the window's side on the plane, scene units.
    """

    top: int
    left: int
    center: tuple[float, float]
    side: float


def plane_windows(size: int, tile: int, overlap: int, plane_size: float) -> list[PlaneWindow]:
    """The windows (row-major) that cover an ``size x size`` photo of a plane of side
    ``plane_size`` with neighbours overlapping by at least ``overlap`` pixels."""
    starts = tile_starts(size, tile, overlap)
    side = plane_size * tile / size

    def coord(start: int) -> float:
        return ((start + tile / 2) / size - 0.5) * plane_size

    return [PlaneWindow(top, left, (coord(left), -coord(top)), side) for top in starts for left in starts]


class TileBlend:
    """Accumulates per-window predictions ``[..., tile, tile]`` into the blended
    ``[..., size, size]`` result (module docstring)."""

    def __init__(self, size: int, tile: int, overlap: int, *, dtype: torch.dtype = torch.float32):
        self.size, self.tile = size, tile
        window = blend_window(tile, overlap, dtype=dtype)
        self.weight = window[:, None] * window[None, :]
        self.total = torch.zeros(size, size, dtype=dtype)
        self.sum: torch.Tensor | None = None

    def add(self, window: PlaneWindow, values: torch.Tensor) -> None:
        """Add one window's prediction ``[..., tile, tile]``."""
        t = self.tile
        if values.shape[-2:] != (t, t):
            raise ValueError(f"a window's prediction must be [..., {t}, {t}], got {tuple(values.shape)}")
        if self.sum is None:
            self.sum = values.new_zeros((*values.shape[:-2], self.size, self.size))
        rows, cols = slice(window.top, window.top + t), slice(window.left, window.left + t)
        self.sum[..., rows, cols] += values * self.weight.to(values)
        self.total[rows, cols] += self.weight

    def result(self) -> torch.Tensor:
        """``[..., size, size]``: the weighted mean of the windows over each pixel."""
        if self.sum is None:
            raise ValueError("no window was added")
        return self.sum / self.total.to(self.sum)
