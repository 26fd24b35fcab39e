"""Light/view tokens: the 9-channel l/v/h map -> N tokens of the cross-attention width.

A small strided CNN reads the per-pixel unit light, view and half vectors
(``kernels.lvh_maps``), pools them, and an MLP emits ``num_tokens`` tokens, injected by
decoupled cross-attention (``relight.modules.ip_attention``) (SPEC section 4).
"""

from __future__ import annotations

import torch
from diffusers.configuration_utils import ConfigMixin, register_to_config
from diffusers.models.modeling_utils import ModelMixin
from torch import nn

__all__ = ["LightTokenEncoder"]


class LightTokenEncoder(ModelMixin, ConfigMixin):
    """``[N, 9, H, W]`` l/v/h maps -> ``[N, num_tokens, token_dim]`` tokens."""

    @register_to_config
    def __init__(self, token_dim: int = 64, num_tokens: int = 4, width: int = 32, pool: int = 4):
        super().__init__()
        self.cnn = nn.Sequential(
            nn.Conv2d(9, width, 3, stride=2, padding=1),
            nn.SiLU(),
            nn.Conv2d(width, width * 2, 3, stride=2, padding=1),
            nn.SiLU(),
            nn.Conv2d(width * 2, width * 2, 3, stride=2, padding=1),
            nn.SiLU(),
            nn.AdaptiveAvgPool2d(pool),
        )
        self.mlp = nn.Sequential(
            nn.Linear(width * 2 * pool * pool, 256), nn.SiLU(), nn.Linear(256, num_tokens * token_dim)
        )
        self.norm = nn.LayerNorm(token_dim)

    def forward(self, lvh: torch.Tensor) -> torch.Tensor:
        if lvh.dim() != 4 or lvh.shape[1] != 9:
            raise ValueError(f"lvh must have shape [N, 9, H, W], got {tuple(lvh.shape)}")
        x = self.cnn(lvh).flatten(1)
        cfg = self.config
        return self.norm(self.mlp(x).view(-1, cfg.num_tokens, cfg.token_dim))
