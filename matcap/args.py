"""Parsing helpers shared by the subcommands."""

from __future__ import annotations

import math
import re
from collections.abc import Sequence

import torch

from matcap.errors import UsageError

__all__ = [
    "parse_position",
    "positions_or_default",
    "check_at_least_one",
    "set_sampling",
    "join_negative_values",
    "parse_map_names",
]

_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
# A comma-separated list of numbers whose first one is negative: "-1,0,5", "-.5, 2, 4e0".
_NEGATIVE_LIST = re.compile(rf"^-(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?(?:\s*,\s*{_NUMBER})+$")


def join_negative_values(argv: Sequence[str]) -> list[str]:
    """Let a value that starts with a minus follow its option: ``--light -1,0,5``.

    argparse takes any token starting with ``-`` that is not a plain negative number for
    an option, so ``--light -1,0,5`` fails with "expected one argument" and only
    ``--light=-1,0,5`` works. This joins such a value to the long option before it into
    the ``=`` form, which argparse reads the same way. Only comma-separated number
    lists are joined (plain negative numbers already work), and nothing after ``--``.

    Example:
        >>> join_negative_values(["render", "--light", "-1,0,5", "--out", "o"])
        ['render', '--light=-1,0,5', '--out', 'o']
    """
    out: list[str] = []
    for token in argv:
        prev = out[-1] if out else ""
        if "--" not in out and _NEGATIVE_LIST.match(token) and prev.startswith("--") and "=" not in prev:
            out[-1] = f"{prev}={token}"
        else:
            out.append(token)
    return out


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


def parse_map_names(text: str | None, flag: str, allow_none: bool = True) -> tuple[str, ...] | None:
    """``"roughness,specular"`` -> ``("roughness", "specular")``; ``"none"`` -> ``()`` (if
    ``allow_none``); None passes. A name that is not a map, a repeated or an empty list is
    a UsageError naming ``flag``."""
    from materials.types import MAP_CHANNELS

    if text is None:
        return None
    names = tuple(v.strip() for v in text.split(",") if v.strip())
    if names == ("none",) and allow_none:
        return ()
    unknown = [n for n in names if n not in MAP_CHANNELS]
    if not names or unknown or len(set(names)) != len(names):
        alternative = " (or none)" if allow_none else ""
        raise UsageError(f"{flag} takes distinct names of {', '.join(MAP_CHANNELS)}{alternative}, got {text!r}")
    return names


def check_at_least_one(flag: str, value: int | None) -> None:
    """UsageError naming ``flag`` when an optional count is given below 1 (None passes)."""
    if value is not None and value < 1:
        raise UsageError(f"{flag} must be at least 1, got {value}")


def set_sampling(relighter, name: str, steps: int | None, samples: int | None = None) -> None:
    """Apply ``--steps`` / ``--samples`` to a sampling relighter (diffusion).

    Args:
        relighter: a ``relight.interface.Relighter``; a sampling one has ``steps`` and
            ``num_samples`` attributes (``relight.diffusion.DiffusionRelighter``).
        name: its method name, for the error message.
        steps, samples: None leaves the relighter's default.
    Raises:
        UsageError: a value below 1, or an option given for a method that does not sample.
    """
    for flag, value, attr in (("--steps", steps, "steps"), ("--samples", samples, "num_samples")):
        check_at_least_one(flag, value)
        if value is None:
            continue
        if not hasattr(relighter, attr):
            raise UsageError(f"{flag} applies to sampling methods (diffusion), not to {name!r}")
        setattr(relighter, attr, value)
