"""Gated convolutions of the paper (SPEC section 4).

- MD conv (mask-driven): ``M = sigmoid(conv_g(x)); out = M * LeakyReLU(conv_f(IN(x)))``,
  a gated convolution whose gate learns to mark highlight regions.
- HA conv (highlight-aware): the same gated path plus an Inception path (3x3 conv to
  C/2, and 3x3 then 1x1 to C/2, concatenated) added to it; the Inception path keeps
  global context so the HA branch can localise highlights.
- Plain conv: conv + LeakyReLU, for the ``w/o HA&MD`` ablation (paper Table 3).

All take ``[N, C_in, H, W]`` features and return ``[N, C_out, H/stride, W/stride]``.
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["MDConv", "HAConv", "PlainConv", "InceptionPath", "LEAKY_SLOPE"]

#: LeakyReLU slope of the gated feature path (the common gated-conv choice, 0.2).
LEAKY_SLOPE = 0.2


class MDConv(nn.Module):
    """Mask-driven gated convolution: gate * LeakyReLU(conv(InstanceNorm(x)))."""

    def __init__(self, c_in: int, c_out: int, stride: int = 1):
        super().__init__()
        self.norm = nn.InstanceNorm2d(c_in, affine=True)
        self.feature = nn.Conv2d(c_in, c_out, 3, stride=stride, padding=1)
        self.gate = nn.Conv2d(c_in, c_out, 3, stride=stride, padding=1)
        self.act = nn.LeakyReLU(LEAKY_SLOPE)

    def gated(self, x: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.gate(x)) * self.act(self.feature(self.norm(x)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.gated(x)


class InceptionPath(nn.Module):
    """Two parallel paths to C/2 channels each: 3x3, and 3x3 followed by 1x1."""

    def __init__(self, c_in: int, c_out: int, stride: int = 1):
        super().__init__()
        half = c_out // 2
        self.a = nn.Conv2d(c_in, half, 3, stride=stride, padding=1)
        self.b = nn.Sequential(
            nn.Conv2d(c_in, c_out - half, 3, stride=stride, padding=1),
            nn.LeakyReLU(LEAKY_SLOPE),
            nn.Conv2d(c_out - half, c_out - half, 1),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.cat([self.a(x), self.b(x)], dim=1)


class HAConv(MDConv):
    """Highlight-aware convolution: the MD gated path plus an Inception path."""

    def __init__(self, c_in: int, c_out: int, stride: int = 1):
        super().__init__(c_in, c_out, stride)
        self.inception = InceptionPath(c_in, c_out, stride)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.gated(x) + self.inception(x)


class PlainConv(nn.Module):
    """Ungated conv + LeakyReLU (ablation ``w/o HA&MD``)."""

    def __init__(self, c_in: int, c_out: int, stride: int = 1):
        super().__init__()
        self.conv = nn.Conv2d(c_in, c_out, 3, stride=stride, padding=1)
        self.act = nn.LeakyReLU(LEAKY_SLOPE)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.act(self.conv(x))
