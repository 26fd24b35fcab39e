"""Flat-plane Lambertian shading and the analytic relighting built on it.

Shared by the ``lambertian`` baseline (``relight.interface.LambertianRelighter``) and by
the tiny diffusion preset's ``base="lambertian"`` switch, which diffuses the difference
between the target and this relighting (``relight.diffusion.config``).

With the SPEC BRDF's diffuse term only and the normal (0, 0, 1), a pixel at x lit by a
light at p has radiance ``rho / pi * cos(theta) * I * falloff``, with ``cos(theta) =
(p - x)_z / |p - x|`` and falloff ``1`` (``dgrsise``) or ``1 / |p - x|^2``. Dividing the
photo by its own collocated shading (light at the camera c) and multiplying by the
target's gives ``relit = photo * shade(p) / shade(c)``; ``rho / pi`` and ``I`` cancel.
Exact for a flat, purely diffuse material with F0 = 0 (up to the small Schlick-Fresnel
remainder the specular term keeps at F0 = 0); any other material keeps its flash
highlight, scaled, in the relit images.
"""

from __future__ import annotations

import torch

from kernels.presets import RenderPreset
from kernels.reference import plane_points

__all__ = ["plane_shading", "lambertian_relight"]


def plane_shading(pos: torch.Tensor, h: int, w: int, preset: RenderPreset) -> torch.Tensor:
    """``cos(theta) * falloff`` per pixel for positions ``[B, K, 3]``: ``[B, K, 1, H, W]``."""
    # Pixel centres on the plane (SPEC section 2), as the renderer's twin defines them.
    x = plane_points(h, w, preset.plane_size, dtype=pos.dtype, device=pos.device)  # [3, H, W]
    dx = pos[..., 0, None, None] - x[0]
    dy = pos[..., 1, None, None] - x[1]
    dz = pos[..., 2, None, None].expand(-1, -1, h, w)
    d2 = dx * dx + dy * dy + dz * dz
    shade = dz / d2.sqrt()
    if preset.inverse_square:
        shade = shade / d2
    return shade[:, :, None]


def lambertian_relight(
    photo: torch.Tensor, light_pos: torch.Tensor, camera_pos: torch.Tensor, preset: RenderPreset
) -> torch.Tensor:
    """Relight flash photos as if they were Lambertian.

    Args:
        photo: ``[B, 3, H, W]`` linear radiance, lit by a flash at ``camera_pos``.
        light_pos: ``[B, K, 3]`` target light positions (camera unchanged).
        camera_pos: ``[B, 3]`` camera (= flash) positions.
        preset: scene conventions (plane size, falloff).
    Returns:
        ``[B, K, 3, H, W]`` linear radiance.
    """
    h, w = photo.shape[-2:]
    ratio = plane_shading(light_pos, h, w, preset) / plane_shading(camera_pos[:, None], h, w, preset)
    return photo[:, None] * ratio
