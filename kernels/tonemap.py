"""Tone mapping and sRGB transfer functions: explicit steps, never inside a renderer.

SPEC section 2: the renderer returns linear radiance; the 8-bit display/storage tone
map is ``clamp(x, 0, 1) ** (1 / 2.2)``. sRGB encode/decode (IEC 61966-2-1, piecewise)
is separate and used only for colour maps stored as sRGB (e.g. MatSynth basecolor,
our diffuse/specular PNG twins).

All functions are elementwise on tensors of any shape; they keep dtype and device.
"""

from __future__ import annotations

import torch

__all__ = ["tonemap", "inverse_tonemap", "srgb_encode", "srgb_decode", "GAMMA"]

#: Display gamma of the tone map (SPEC section 2).
GAMMA = 2.2

# IEC 61966-2-1 sRGB constants: linear segment slope 12.92 below 0.0031308, and
# 1.055 * x^(1/2.4) - 0.055 above it.
_SRGB_LINEAR_CUTOFF = 0.0031308
_SRGB_ENCODED_CUTOFF = 0.04045


#: Lower clamp of the tone map: x^(1/2.2) has an infinite slope at 0, so a loss taken
#: through the tone map would get inf/NaN gradients on black pixels. 1e-10 maps to
#: 2.8e-5, far below one 8-bit step (1/255), so displayed values do not change.
TONEMAP_FLOOR = 1e-10


def tonemap(x: torch.Tensor) -> torch.Tensor:
    """Linear radiance -> display value in [0, 1]: ``clamp(x, 0, 1) ** (1/2.2)``
    (clamped below at ``TONEMAP_FLOOR`` so the gradient stays finite)."""
    return x.clamp(TONEMAP_FLOOR, 1.0) ** (1.0 / GAMMA)


def inverse_tonemap(y: torch.Tensor) -> torch.Tensor:
    """Display value in [0, 1] -> linear radiance in [0, 1] (saturated pixels stay 1)."""
    return y.clamp(0.0, 1.0) ** GAMMA


def srgb_encode(x: torch.Tensor) -> torch.Tensor:
    """Linear [0, 1] -> sRGB-encoded [0, 1] (exact piecewise curve; input clamped)."""
    x = x.clamp(0.0, 1.0)
    return torch.where(
        x <= _SRGB_LINEAR_CUTOFF, 12.92 * x, 1.055 * x.clamp_min(_SRGB_LINEAR_CUTOFF) ** (1 / 2.4) - 0.055
    )


def srgb_decode(y: torch.Tensor) -> torch.Tensor:
    """sRGB-encoded [0, 1] -> linear [0, 1] (exact piecewise curve; input clamped)."""
    y = y.clamp(0.0, 1.0)
    return torch.where(
        y <= _SRGB_ENCODED_CUTOFF, y / 12.92, ((y.clamp_min(_SRGB_ENCODED_CUTOFF) + 0.055) / 1.055) ** 2.4
    )
