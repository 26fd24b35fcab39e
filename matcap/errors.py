"""User-facing errors of the command line: printed as one line, exit code 2."""

from __future__ import annotations

__all__ = ["UsageError"]


class UsageError(ValueError):
    """A bad command-line value (parsed positions, missing inputs, ...)."""
