"""Attention-based feature selection (AFS): channel attention over several sources.

After selective-kernel style channel attention (Li et al. 2019; used for fusion in the
style of Guo et al. 2021): the sources are projected to C channels, summed, globally
pooled, passed through a bottleneck MLP that outputs one logit per (source, channel);
a softmax over the sources gives per-channel weights, and the output is the weighted
sum of the sources. The authors' released AFS takes a softmax over a single element,
which is identically 1, so their "attention" is a plain sum; this one actually selects.
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["AttentionFeatureSelection"]


class AttentionFeatureSelection(nn.Module):
    """Fuse S feature maps ``[N, c_s, H, W]`` into ``[N, channels, H, W]`` by channel attention."""

    def __init__(self, in_channels: list[int], channels: int, reduction: int = 4):
        super().__init__()
        self.proj = nn.ModuleList([nn.Identity() if c == channels else nn.Conv2d(c, channels, 1) for c in in_channels])
        hidden = max(channels // reduction, 8)
        self.mlp = nn.Sequential(nn.Linear(channels, hidden), nn.SiLU(), nn.Linear(hidden, channels * len(in_channels)))
        self.num_sources = len(in_channels)
        self.channels = channels

    def weights(self, sources: list[torch.Tensor]) -> torch.Tensor:
        """Selection weights ``[N, S, C]`` (softmax over the S sources)."""
        pooled = torch.stack(sources).sum(0).mean(dim=(2, 3))
        logits = self.mlp(pooled).view(-1, self.num_sources, self.channels)
        return logits.softmax(dim=1)

    def forward(self, *features: torch.Tensor) -> torch.Tensor:
        if len(features) != self.num_sources:
            raise ValueError(f"AFS expects {self.num_sources} feature maps, got {len(features)}")
        sources = [p(f) for p, f in zip(self.proj, features)]
        w = self.weights(sources)
        return sum(w[:, s, :, None, None] * sources[s] for s in range(self.num_sources))
