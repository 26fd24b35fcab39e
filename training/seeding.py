"""Seeds derived from (run seed, step, stream), so the random draws of step ``t`` do not
depend on what ran before it: a resumed run draws exactly what an uninterrupted one would.

A stream is one independent use within a step (the batch, the view subset, the loss
lights; or one per process). ``streams`` fixes how many a trainer reserves per step: the
mixing ``(seed * SEED_STRIDE + step) * streams + stream`` is one-to-one for
``step < SEED_STRIDE`` and ``stream < streams``, so no two (seed, step, stream) share a seed.

Example:
    >>> step_seed(0, 5, stream=2)
    42
    >>> step_seed(1, 0, stream=0, streams=64) == 1_000_003 * 64
    True
"""

from __future__ import annotations

import torch

__all__ = ["SEED_STRIDE", "step_seed", "step_generator"]

#: A prime above any step count a run reaches, so consecutive run seeds' step ranges do
#: not overlap.
SEED_STRIDE = 1_000_003


def step_seed(seed: int, step: int, stream: int = 0, *, streams: int = 8) -> int:
    """The seed of ``stream`` (``0 <= stream < streams``) at ``step`` of a run seeded ``seed``."""
    if not 0 <= stream < streams:
        raise ValueError(f"stream must lie in [0, {streams}), got {stream}")
    if not 0 <= step < SEED_STRIDE:
        raise ValueError(f"step must lie in [0, {SEED_STRIDE}), got {step}")
    return (seed * SEED_STRIDE + step) * streams + stream


def step_generator(seed: int, step: int, stream: int = 0, *, streams: int = 8) -> torch.Generator:
    """A CPU ``torch.Generator`` seeded with ``step_seed(seed, step, stream, streams=streams)``."""
    return torch.Generator().manual_seed(step_seed(seed, step, stream, streams=streams))
