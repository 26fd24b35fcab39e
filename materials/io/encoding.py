"""Encodings applied at the file boundary that are not tone maps.

- Normal maps: files store ``(n + 1) / 2`` in [0, 1]; memory holds unit vectors
  (tangent space, OpenGL / green-up, SPEC section 2). Decoding renormalises, because
  8-bit quantisation moves each component by up to half a step.
- Layout: files are channels-last numpy ``[H, W, C]``; memory is channels-first torch
  ``[C, H, W]`` float32.

The tone map (``clamp(x, 0, 1) ** (1/2.2)``) and the sRGB curve live in
``kernels.tonemap`` (``tonemap``, ``inverse_tonemap``, ``srgb_encode``, ``srgb_decode``).
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["encode_normal", "decode_normal", "hwc_to_chw", "chw_to_hwc"]

# Smallest length a decoded normal is divided by: a stored (0.5, 0.5, 0.5) pixel decodes
# to the zero vector and stays zero (validation then reports it) instead of NaN.
_NORMAL_EPS = 1e-12


def encode_normal(n: torch.Tensor) -> torch.Tensor:
    """Unit normals -> stored values: ``(n + 1) / 2``, elementwise.

    Args:
        n: ``[..., 3, H, W]`` unit vectors, components in [-1, 1].

    Returns:
        Same shape, values in [0, 1] (clamped, so tiny overshoots do not wrap in 8 bits).

    Example:
        >>> encode_normal(torch.tensor([0.0, 0.0, 1.0]).view(3, 1, 1)).flatten().tolist()
        [0.5, 0.5, 1.0]
    """
    return ((n + 1.0) * 0.5).clamp(0.0, 1.0)


def decode_normal(e: torch.Tensor, dim: int = -3) -> torch.Tensor:
    """Stored values -> unit normals: ``normalize(2 e - 1)`` along ``dim``.

    Args:
        e: ``[..., 3, H, W]`` stored values in [0, 1].
        dim: the channel dim (default -3, the ``[..., C, H, W]`` layout).

    Returns:
        Same shape, unit vectors (a stored mid-grey pixel decodes to the zero vector).
    """
    return torch.nn.functional.normalize(e * 2.0 - 1.0, dim=dim, eps=_NORMAL_EPS)


def hwc_to_chw(array: np.ndarray) -> torch.Tensor:
    """Channels-last numpy ``[H, W, C]`` -> channels-first float32 torch ``[C, H, W]``."""
    return torch.from_numpy(np.ascontiguousarray(array, dtype=np.float32)).permute(2, 0, 1).contiguous()


def chw_to_hwc(tensor: torch.Tensor) -> np.ndarray:
    """Channels-first torch ``[C, H, W]`` -> channels-last float32 numpy ``[H, W, C]`` (on the CPU)."""
    return tensor.detach().to("cpu", torch.float32).permute(1, 2, 0).contiguous().numpy()
