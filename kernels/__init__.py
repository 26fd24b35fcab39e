"""Warp kernels for differentiable SVBRDF rendering, feature translation and losses.

Public functions take and return torch tensors (CPU or CUDA; the device follows the
tensors), share memory with Warp without copies, and are differentiable through torch
autograd. ``kernels.reference`` holds a pure-torch twin of each, with the same name.
This package imports nothing else of the project (see DESIGN.md).
"""

from kernels.geometry import highlight_offsets, mirror_point
from kernels.loss import LOG_EPS, log_l1_loss, map_rendering_loss, mse_loss, rendering_loss, sample_loss_lights
from kernels.presets import PRESETS, RenderPreset, get_preset
from kernels.render import lvh_maps, render
from kernels.tonemap import inverse_tonemap, srgb_decode, srgb_encode, tonemap
from kernels.translate import translate

__all__ = [
    "render",
    "lvh_maps",
    "translate",
    "highlight_offsets",
    "mirror_point",
    "rendering_loss",
    "map_rendering_loss",
    "sample_loss_lights",
    "log_l1_loss",
    "mse_loss",
    "LOG_EPS",
    "tonemap",
    "inverse_tonemap",
    "srgb_encode",
    "srgb_decode",
    "RenderPreset",
    "PRESETS",
    "get_preset",
]
