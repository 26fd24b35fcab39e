"""Typed architecture configuration of the multi-image SVBRDF estimator.

``EstimatorConfig`` is the one place the architecture's numbers live. ``SVBRDFEstimator``
registers the same fields with diffusers' ``ConfigMixin``, so a checkpoint's
``config.json`` carries the architecture and ``from_pretrained`` rebuilds it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

__all__ = ["EstimatorConfig", "TINY_TEST_CONFIG", "FIELDS_ADDED_SINCE"]


@dataclass(frozen=True)
class EstimatorConfig:
    """Architecture of ``SVBRDFEstimator`` (see ``estimator/DESIGN.md``).

    Attributes:
        base_channels: channels of the full-resolution encoder level; level ``i`` has
            ``base_channels * channel_mults[i]``.
        channel_mults: one multiplier per encoder level; level 0 is full resolution and
            each further level halves H and W with a stride-2 conv. The default, 16-32-64-
            128-192 over 5 levels (1.9 M parameters, 7.7 MB of safetensors), was measured
            on the 2-core CPU: a 32-64-128-256 encoder over 4 levels costs 2-3x more per
            step at 64 x 64 for V = 8, almost all of it in the full-resolution per-view
            convs, while the cheap deep levels are where the parameters are.
        blocks_per_level: 3x3 conv blocks (GroupNorm, SiLU) after each level's entry conv.
        adapter_width: hidden channels of each per-map adapter head.
        norm_groups: GroupNorm groups (reduced to a divisor of the channel count).
        plane_size: side of the material plane used for the l/v/h maps (``dgrsise``: 4).
        shading_channels: width of the full-resolution shading branch that feeds the normal
            map (``estimator/DESIGN.md``, "Shading branch"); 0 leaves it out (the
            architecture before 2026-12-02). Checkpoints saved without the field have none.
    """

    base_channels: int = 16
    channel_mults: tuple[int, ...] = (1, 2, 4, 8, 12)
    blocks_per_level: int = 1
    adapter_width: int = 32
    norm_groups: int = 8
    plane_size: float = 4.0
    shading_channels: int = 16

    def __post_init__(self) -> None:
        if self.base_channels < 1 or self.adapter_width < 1 or self.norm_groups < 1:
            raise ValueError(
                f"base_channels, adapter_width and norm_groups must be positive, got {self.base_channels}, "
                f"{self.adapter_width}, {self.norm_groups}"
            )
        if len(self.channel_mults) < 1 or any(int(m) < 1 for m in self.channel_mults):
            raise ValueError(f"channel_mults must be a non-empty tuple of positive ints, got {self.channel_mults}")
        if self.shading_channels < 0:
            raise ValueError(f"shading_channels must be >= 0, got {self.shading_channels}")
        if self.shading_channels and len(self.channel_mults) < 2:
            # The branch rides on the level-0 skip, which with one level is the latent.
            raise ValueError("shading_channels needs at least two levels (channel_mults)")
        if self.blocks_per_level < 0:
            raise ValueError(f"blocks_per_level must be >= 0, got {self.blocks_per_level}")
        if self.plane_size <= 0:
            raise ValueError(f"plane_size must be positive, got {self.plane_size}")
        object.__setattr__(self, "channel_mults", tuple(int(m) for m in self.channel_mults))

    @classmethod
    def from_saved(cls, saved: dict) -> EstimatorConfig:
        """From a saved config (a checkpoint's config.json or trainer state): a field the
        save predates takes the value that meant its absence (``FIELDS_ADDED_SINCE``)."""
        return cls(**{**FIELDS_ADDED_SINCE, **saved})

    @property
    def downsample_factor(self) -> int:
        """H and W must be multiples of this (2 ** (levels - 1))."""
        return 2 ** (len(self.channel_mults) - 1)

    def to_dict(self) -> dict:
        return asdict(self)


#: Fields added after checkpoints were shipped, with the value a checkpoint saved before
#: them means (the architecture it has): ``shading_channels`` 0, no shading branch.
FIELDS_ADDED_SINCE = {"shading_channels": 0}

#: The tiny architecture used by the fast tests (32 x 32 images, a few thousand params).
TINY_TEST_CONFIG = EstimatorConfig(
    base_channels=8, channel_mults=(1, 2, 4), adapter_width=8, norm_groups=4, shading_channels=4
)
