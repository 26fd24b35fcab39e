"""Parsing helpers shared by the subcommands."""

from __future__ import annotations

import math

import torch

from matcap.errors import UsageError

__all__ = ["parse_position", "positions_or_default"]


def parse_position(text: str, what: str = "position") -> tuple[float, float, float]:
    """'x,y,z' -> (x, y, z); z must be above the plane."""
    parts = text.replace(" ", "").split(",")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        raise UsageError(f"{what} {text!r} is not x,y,z numbers") from None
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise UsageError(f"{what} {text!r} must be three finite numbers x,y,z")
    if values[2] <= 0:
        raise UsageError(f"{what} {text!r} lies on or below the material plane (z must be > 0)")
    return values  # type: ignore[return-value]


def positions_or_default(texts: list[str] | None, default: torch.Tensor, what: str) -> torch.Tensor:
    """Parsed ``[K, 3]`` positions, or ``default`` when none were given."""
    if not texts:
        return default
    return torch.tensor([parse_position(t, what) for t in texts], dtype=torch.float32)
