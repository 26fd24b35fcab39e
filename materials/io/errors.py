"""The one exception for unreadable or malformed files.

``FormatError`` is about *files* (missing, truncated, wrong layout, wrong channel set);
``materials.types.MapError`` is about *values* (NaN, out of range, non-unit normals).
Both are ``ValueError`` subclasses, so ``except ValueError`` catches either.
``require_same_size`` is the one shared check that several readers raise it from.
"""

from __future__ import annotations

import os
from collections.abc import Mapping

__all__ = ["FormatError", "require_same_size"]


class FormatError(ValueError):
    """A file or folder cannot be read (or written) as the format it should be.

    The message always starts with the path, then says what is wrong:
    ``"/data/wood/normal.png: expected 3 channels (RGB), found 4 (RGBA); alpha is not supported"``.

    Attributes:
        path: the file or folder concerned, as given.
        problem: what is wrong with it, without the path.

    Example:
        >>> try:
        ...     raise FormatError("maps/normal.png", "file is empty")
        ... except FormatError as e:
        ...     print(e)
        maps/normal.png: file is empty
    """

    def __init__(self, path: str | os.PathLike, problem: str) -> None:
        self.path = os.fspath(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")

    def __reduce__(self):  # keep pickling working (multiprocess data loaders)
        return (type(self), (self.path, self.problem))


def require_same_size(path: str | os.PathLike, sizes: Mapping[str, tuple[int, ...]]) -> tuple[int, int]:
    """Check that every named map or image has the same (H, W); return it.

    Args:
        path: the folder or file the maps came from (named in the error).
        sizes: ``{name: (H, W)}`` for each map or image read (at least one).

    Raises:
        FormatError: listing every name with its size when they differ.
    """
    distinct = set(sizes.values())
    if len(distinct) != 1:
        listing = ", ".join(f"{name} {h}x{w}" for name, (h, w) in sizes.items())
        raise FormatError(path, f"sizes differ (H x W): {listing}; all must match")
    height, width = next(iter(distinct))
    return height, width
