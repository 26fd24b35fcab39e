"""The condition encoder: background consistency encoder (BCE) + translated specular
prior, fused by attention-based feature selection (SPEC section 4).

- BCE: an HA branch and an MD branch on a photo of the material, in parallel, fused by
  AFS. In training the BCE features are shuffled within each group (8 renders of one
  material), so every target is conditioned on the background seen under *another*
  light: the encoder must keep what is stable (the material) and drop the highlight.
- Specular prior: an MD branch on the input (flash) photo, whose features are shifted by
  the Warp translation kernel so the input highlight lands where the target light puts
  it (``kernels.highlight_offsets``).
- Fusion: AFS over (BCE features, translated prior), then a zero-initialised conv, so a
  freshly built encoder adds exactly nothing to the ControlNet (ControlNet's habit).

Ablations (paper Table 3) are config switches: ``background`` = "bce" | "md" | "plain",
``conv`` = "gated" | "plain", ``prior`` on/off, ``shuffle`` on/off.
"""

from __future__ import annotations

import torch
from diffusers.configuration_utils import ConfigMixin, register_to_config
from diffusers.models.modeling_utils import ModelMixin
from torch import nn

import kernels
from relight.modules.afs import AttentionFeatureSelection
from relight.modules.branches import BRANCH_CHANNELS, Branch

__all__ = ["ConditionEncoder", "shuffle_within_groups"]


def shuffle_within_groups(n: int, group: int, generator: torch.Generator | None = None) -> torch.Tensor:
    """A permutation of ``range(n)`` that only moves items inside consecutive groups of
    ``group`` (one material's renders), as a ``[n]`` long tensor."""
    if n % group:
        raise ValueError(f"batch of {n} is not a whole number of groups of {group}")
    perms = [torch.randperm(group, generator=generator) + g * group for g in range(n // group)]
    return torch.cat(perms)


class ConditionEncoder(ModelMixin, ConfigMixin):
    """Photos -> ControlNet conditioning features ``[N, out_channels, h, w]``.

    Args (config):
        out_channels: C, the width of the UNet's first block (its ``conv_in`` output).
        downsample: three stride-2 steps (latent presets) or none (pixel presets).
        background: "bce" (HA + MD branches, AFS), "md" (one MD branch), "plain" (one
            plain branch: ControlNet's own conditioning embedding).
        conv: "gated" (HA/MD convs) or "plain" (ablation ``w/o HA&MD``).
        prior: use the translated specular prior (ablation ``w/o S. Prior`` when False).
        shuffle: shuffle BCE features within groups in training mode.
        widths: the six branch widths before C (ControlNet's 16, 16, 32, 32, 96, 96 by
            default; pixel-space presets run the branches at full resolution and use
            narrower ones to stay affordable on a CPU).
    """

    @register_to_config
    def __init__(
        self,
        out_channels: int = 32,
        downsample: bool = False,
        background: str = "bce",
        conv: str = "gated",
        prior: bool = True,
        shuffle: bool = True,
        widths: tuple[int, ...] = BRANCH_CHANNELS,
    ):
        super().__init__()
        widths = tuple(widths)
        if background not in ("bce", "md", "plain"):
            raise ValueError(f"background must be 'bce', 'md' or 'plain', got {background!r}")
        if conv not in ("gated", "plain"):
            raise ValueError(f"conv must be 'gated' or 'plain', got {conv!r}")
        ha, md = ("ha", "md") if conv == "gated" else ("plain", "plain")
        c = out_channels
        if background == "bce":
            self.ha_branch = Branch(ha, 3, c, downsample, widths)
            self.md_branch = Branch(md, 3, c, downsample, widths)
            self.bce_afs = AttentionFeatureSelection([c, c], c)
        else:
            self.background_branch = Branch(md if background == "md" else "plain", 3, c, downsample, widths)
        if prior:
            self.prior_branch = Branch(md, 3, c, downsample, widths)
            self.fuse_afs = AttentionFeatureSelection([c, c], c)
        self.zero_out = nn.Conv2d(c, c, 1)
        nn.init.zeros_(self.zero_out.weight)
        nn.init.zeros_(self.zero_out.bias)

    @staticmethod
    def normalise(photo: torch.Tensor) -> torch.Tensor:
        """Linear radiance -> tone-mapped [0, 1] -> [-1, 1] (the networks' input range)."""
        return kernels.tonemap(photo) * 2 - 1

    def background_features(self, photos: torch.Tensor) -> torch.Tensor:
        x = self.normalise(photos)
        if self.config.background == "bce":
            return self.bce_afs(self.ha_branch(x), self.md_branch(x))
        return self.background_branch(x)

    def forward(
        self,
        background: torch.Tensor,
        prior_photo: torch.Tensor | None = None,
        offsets: torch.Tensor | None = None,
        permutation: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """
        Args:
            background: ``[N, 3, H, W]`` linear photos for the background path (in
                training: the group's renders; at inference: the input photo per target).
            prior_photo: ``[N, 3, H, W]`` the input flash photo per target (prior on only).
            offsets: ``[N, 2]`` feature-pixel shifts (dx, dy) per target (prior on only).
            permutation: ``[N]`` indices shuffling background features across targets
                (used only in training mode with ``shuffle``; see ``shuffle_within_groups``).
        Returns:
            ``[N, C, h, w]`` conditioning features (zero at initialisation).
        """
        feats = self.background_features(background)
        if permutation is not None and self.training and self.config.shuffle:
            feats = feats[permutation]
        if self.config.prior:
            if prior_photo is None or offsets is None:
                raise ValueError("the specular prior needs prior_photo and offsets")
            prior = self.prior_branch(self.normalise(prior_photo))
            prior = kernels.translate(prior, offsets.to(prior.dtype))
            feats = self.fuse_afs(feats, prior)
        return self.zero_out(feats)
