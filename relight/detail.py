"""Relighting a photo larger than a model's native size from the whole plane at that size,
the photo's detail carried by the analytic re-shading at full size (issue 16: relighting
at real resolution; ``large="global"`` of the network relighters).

A model trained on whole planes of ``t x t`` pixels learns how a highlight moves across
the whole plane at that scale. Relit window by window (``relight.tiling``) it sees each
window as if it were a whole plane, so it draws no highlight of the size a quarter of
the plane has (measured: ``results/relight_detail/``). Here it sees the whole plane,
area-averaged to ``t x t``, as in training, and only the part of its output the flat
Lambertian re-shading does not explain is upsampled:

    tm(out_S) = tm(lambertian_S) + up(tm(out_t) - tm(lambertian_t))

with ``tm`` the display tone map (``kernels.tonemap``; the models predict their residual
to the re-shading in that space, and the residual added there scored 1.4 dB higher than
in linear radiance), ``lambertian_S`` the re-shading of the full-size photo (it carries
the texture at full resolution, exactly for a flat diffuse material) and ``up`` bilinear.
What the model changes (the flash highlight removed, the new one drawn) comes at its own
resolution; high-frequency detail inside a moved highlight is lost, as it is at ``t``.

Shapes: ``photo [B, 3, S, S]`` linear radiance, S >= ``size``; ``light_pos [B, K, 3]`` and
``camera_pos [B, 3]`` in the photo's scene units (plane of side ``preset.plane_size``).
"""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F

import kernels
from kernels.presets import RenderPreset
from relight.shading import lambertian_relight

__all__ = ["LARGE_MODES", "detail_relight"]

#: How a network relighter treats a photo larger than its native size: ``"global"`` (this
#: module), ``"tiles"`` (``relight.tiling``: windows in their own geometry) or ``"whole"``
#: (the network run fully convolutionally on the full-size photo).
LARGE_MODES = ("global", "tiles", "whole")

#: ``relight_native(photo [B, 3, t, t], light_pos [B, K, 3], camera_pos [B, 3]) -> [B, K, 3, t, t]``.
NativeRelighter = Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]


def detail_relight(
    relight_native: NativeRelighter,
    photo: torch.Tensor,
    light_pos: torch.Tensor,
    camera_pos: torch.Tensor,
    *,
    size: int,
    preset: RenderPreset,
) -> torch.Tensor:
    """Relight ``photo [B, 3, S, S]`` (linear) to ``light_pos [B, K, 3]`` through a model of
    native side ``size`` (module docstring).

    Args:
        relight_native: the model on ``[B, 3, size, size]`` photos of the whole plane.
        photo: ``[B, 3, S, S]`` linear radiance, S >= ``size`` (S == ``size``: one call).
        light_pos, camera_pos: in the scene units of ``preset`` (its plane spans the photo).
        size: the model's native side in pixels.
        preset: scene conventions of the analytic re-shading (the models': ``dgrsise``).

    Returns:
        ``[B, K, 3, S, S]`` linear radiance in [0, 1] (the tone map saturates at 1, as the
        networks' outputs do).
    """
    b, _, h, w = photo.shape
    if h != w or h < size:
        raise ValueError(f"photo must be square with a side of at least {size}, got {h} x {w}")
    if h == size:
        return relight_native(photo, light_pos, camera_pos)
    # Area averaging is what a camera of 1/factor the resolution would record (the photo
    # is linear radiance); adaptive pooling also covers sides that are not multiples.
    small = F.adaptive_avg_pool2d(photo, size)
    out = relight_native(small, light_pos, camera_pos)
    k = out.shape[1]
    residual = kernels.tonemap(out) - kernels.tonemap(lambertian_relight(small, light_pos, camera_pos, preset))
    up = F.interpolate(residual.flatten(0, 1), size=(h, w), mode="bilinear", align_corners=False)
    full = kernels.tonemap(lambertian_relight(photo, light_pos, camera_pos, preset))
    return kernels.inverse_tonemap(full + up.unflatten(0, (b, k)))
