"""Feature translation for the specular prior (SPEC section 3).

``translate`` shifts feature maps by a per-sample sub-pixel offset (bilinear, edges
clamped), differentiable with respect to the features and the offsets;
``highlight_offsets`` (pure torch, ``kernels.geometry``) turns light and camera
positions into those offsets.
"""

from __future__ import annotations

import torch
import warp as wp

from kernels._image_kernels import build_image_kernels
from kernels._warp import chunk_bounds, ensure_init, parallel_chunks, preload, warp_device, warp_scalar, wp_array
from kernels.checks import check_finite, check_same, check_shape
from kernels.geometry import highlight_offsets, mirror_point  # re-exported

__all__ = ["translate", "highlight_offsets", "mirror_point"]


def _launch(features, offsets, out, *, adjoint=False, adj_features=None, adj_offsets=None, adj_out=None):
    F = warp_scalar(features.dtype)
    kern = build_image_kernels(F).translate
    b, _, h, w = features.shape
    dev = warp_device(features.device)
    stream = wp.stream_from_torch() if features.device.type == "cuda" else None
    wf, wo, wout = wp_array(features), wp_array(offsets), wp_array(out)

    def launch(_index: int, start: int, count: int) -> None:
        if not adjoint:
            wp.launch(kern, dim=(count, h, w), inputs=[wf, wo, start], outputs=[wout], device=dev, stream=stream)
            return
        wp.launch(
            kern,
            dim=(count, h, w),
            inputs=[wf, wo, start],
            outputs=[wout],
            adj_inputs=[wp_array(adj_features), wp_array(adj_offsets), 0],
            adj_outputs=[wp_array(adj_out)],
            adjoint=True,
            device=dev,
            stream=stream,
        )

    # Batch chunks touch disjoint samples (features, offsets and outputs alike).
    preload(kern, dev)
    parallel_chunks(chunk_bounds(b, features.device), launch)


class _TranslateFunction(torch.autograd.Function):
    @staticmethod
    def forward(ctx, features, offsets):
        features, offsets = features.contiguous(), offsets.contiguous()
        out = torch.empty_like(features)
        _launch(features, offsets, out)
        ctx.save_for_backward(features, offsets, out)
        return out

    @staticmethod
    def backward(ctx, grad_out):
        features, offsets, out = ctx.saved_tensors
        grad_features, grad_offsets = torch.zeros_like(features), torch.zeros_like(offsets)
        _launch(
            features,
            offsets,
            out,
            adjoint=True,
            adj_features=grad_features,
            adj_offsets=grad_offsets,
            adj_out=grad_out.contiguous().clone(),
        )
        return grad_features, grad_offsets


def translate(features: torch.Tensor, offsets: torch.Tensor) -> torch.Tensor:
    """Shift feature maps by sub-pixel offsets, bilinear, with edge-clamped borders.

    Args:
        features: ``[B, C, h, w]`` float32/float64 feature maps (any content).
        offsets: ``[B, 2]`` shift (dx, dy) in feature pixels: content moves dx columns
            right and dy rows down, i.e. ``out(i, j) = features(i - dy, j - dx)``.
    Returns:
        ``[B, C, h, w]`` shifted features; uncovered borders repeat the edge value.
        Differentiable with respect to ``features`` and ``offsets``.
    """
    ensure_init()
    dims = check_shape(features, "B C h w", name="features")
    check_shape(offsets, "B 2", name="offsets", dims=dims)
    check_same("features", features, offsets=offsets)
    if features.numel() == 0:
        raise ValueError(f"features must be non-empty, got shape {tuple(features.shape)}")
    check_finite(features=features, offsets=offsets)
    return _TranslateFunction.apply(features, offsets)
