"""Scene geometry in plain torch (tiny tensors; no kernel needed): where highlights sit.

Shared by the Warp-backed functions and their references.
"""

from __future__ import annotations

import torch

__all__ = ["mirror_point", "highlight_offsets"]


def mirror_point(light_pos: torch.Tensor, camera_pos: torch.Tensor) -> torch.Tensor:
    """Plane point ``[..., 2]`` where the mirror highlight of light p seen from camera c sits:
    m = (c_xy p_z + p_xy c_z) / (p_z + c_z) (SPEC section 3). Shapes broadcast."""
    c_xy, c_z = camera_pos[..., :2], camera_pos[..., 2:3]
    p_xy, p_z = light_pos[..., :2], light_pos[..., 2:3]
    return (c_xy * p_z + p_xy * c_z) / (p_z + c_z)


def highlight_offsets(
    light_pos: torch.Tensor, camera_pos: torch.Tensor, plane_size: float, size: tuple[int, int]
) -> torch.Tensor:
    """Feature-pixel offsets ``[..., 2]`` (dx, dy) that move the input's highlight to the
    target light's.

    The input photo is lit from the camera, so its highlight sits under the camera at
    c_xy; the target's sits at the mirror point m. The shift (m - c_xy) in plane units
    becomes (dx, dy) pixels of an ``(h, w)`` feature map: +x is right (+columns), +y is
    up (-rows).

    Args:
        light_pos: ``[..., 3]`` target lights; camera_pos: ``[..., 3]`` camera positions.
        plane_size: side of the plane in scene units; size: (h, w) of the feature map.
    """
    if not plane_size > 0:
        raise ValueError(f"plane_size must be positive, got {plane_size}")
    if (light_pos[..., 2] <= 0).any() or (camera_pos[..., 2] <= 0).any():
        raise ValueError("light_pos and camera_pos must lie above the plane (z > 0)")
    shift = mirror_point(light_pos, camera_pos) - camera_pos[..., :2]
    h, w = size
    return torch.stack([shift[..., 0] * (w / plane_size), -shift[..., 1] * (h / plane_size)], dim=-1)
