"""Branches: conv stacks shaped like ControlNet's conditioning embedding (SPEC section 4).

Channels 16, 16, 32, 32, 96, 96, C_out with three stride-2 steps (latent-space presets)
or none (pixel-space presets), so the features land at the resolution of the UNet's
``conv_in`` output. Every conv is of one kind: ``"ha"``, ``"md"`` or ``"plain"``.
"""

from __future__ import annotations

import torch
from torch import nn

from relight.modules.gated import HAConv, MDConv, PlainConv

__all__ = ["Branch", "BRANCH_CHANNELS", "CONV_KINDS"]

#: ControlNet conditioning-embedding widths (Zhang et al. 2023; diffusers' default
#: (16, 32, 96, 256) with each width used twice), before the final C_out layer.
BRANCH_CHANNELS = (16, 16, 32, 32, 96, 96)
CONV_KINDS = {"ha": HAConv, "md": MDConv, "plain": PlainConv}


class Branch(nn.Module):
    """``[N, c_in, H, W]`` -> ``[N, c_out, H / 8, W / 8]`` (``downsample``) or ``[N, c_out, H, W]``."""

    def __init__(self, kind: str, c_in: int, c_out: int, downsample: bool, widths=BRANCH_CHANNELS):
        super().__init__()
        if kind not in CONV_KINDS:
            raise ValueError(f"unknown conv kind {kind!r}; known: {sorted(CONV_KINDS)}")
        conv = CONV_KINDS[kind]
        s = 2 if downsample else 1
        # stride on the convs that widen the features (16->32, 32->96, 96->C_out), as in
        # ControlNet's embedding: three stride-2 steps in all.
        strides = [1, 1, s, 1, s, 1]
        chans = [c_in, *widths]
        layers = [conv(chans[i], chans[i + 1], strides[i]) for i in range(len(widths))]
        layers.append(conv(widths[-1], c_out, s))
        self.layers = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.layers(x)
