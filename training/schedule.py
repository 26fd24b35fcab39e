"""Learning-rate schedules: functions of the step alone (no wall clock, no object state),
so a resumed run continues the same curve and a checkpoint needs no scheduler state.

Each returns the factor on the base rate for the update that takes the model from
``step`` to ``step + 1`` (``step`` counts from 0); ``set_lr`` applies it.

Example:
    >>> [round(warmup_cosine(s, total=10, warmup=2, floor=0.1), 3) for s in (0, 1, 2, 6, 10)]
    [0.5, 1.0, 1.0, 0.55, 0.1]
    >>> [warmup_cosine(s, total=300, decay_from=100) for s in (0, 100, 200, 300)][1:3]
    [1.0, 0.5]
"""

from __future__ import annotations

import math

import torch

__all__ = ["SCHEDULES", "constant", "warmup_cosine", "lr_factor", "set_lr"]

#: The names a trainer's ``--schedule`` / ``--lr-schedule`` flag accepts.
SCHEDULES = ("constant", "cosine")


def constant(step: int, *, warmup: int = 0) -> float:
    """1, after a linear warm-up ``(step + 1) / warmup`` over the first ``warmup`` steps."""
    return (step + 1) / warmup if step < warmup else 1.0


def warmup_cosine(step: int, *, total: int, warmup: int = 0, decay_from: int = 0, floor: float = 0.0) -> float:
    """Linear warm-up, a constant stretch, then a half cosine from 1 down to ``floor`` at ``total``.

    Args:
        step: the update's index (0-based); past ``total`` the factor stays at ``floor``.
        total: the run's last step (the cosine reaches ``floor`` there).
        warmup: steps of linear warm-up ``(step + 1) / warmup``.
        decay_from: the cosine starts at ``max(warmup, decay_from)``; before it (after
            the warm-up) the factor is 1. 0: right after the warm-up.
        floor: the final factor (e.g. 0.1: the rate ends at a tenth of the base rate).

    Warm-up then cosine to a floor (``decay_from`` 0) and constant then cosine to zero
    (``warmup`` 0, ``floor`` 0) are the two uses.
    """
    if step < warmup:
        return (step + 1) / warmup
    start = max(warmup, decay_from)
    if step < start:
        return 1.0
    t = min(1.0, (step - start) / max(1, total - start))
    return floor + (1 - floor) * 0.5 * (1 + math.cos(math.pi * t))


def lr_factor(kind: str, step: int, *, total: int, warmup: int = 0, decay_from: int = 0, floor: float = 0.0) -> float:
    """``constant`` or ``warmup_cosine`` by name (``SCHEDULES``)."""
    if kind == "constant":
        return constant(step, warmup=warmup)
    if kind == "cosine":
        return warmup_cosine(step, total=total, warmup=warmup, decay_from=decay_from, floor=floor)
    raise ValueError(f"schedule must be one of {SCHEDULES}, got {kind!r}")


def set_lr(optimizer: torch.optim.Optimizer, lr: float) -> None:
    """Set every parameter group's learning rate to ``lr``."""
    for group in optimizer.param_groups:
        group["lr"] = lr
