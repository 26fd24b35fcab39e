"""Atomic writes: a file or a whole folder appears complete or not at all.

A writer fills a temporary sibling (same folder, so the final rename never crosses a
file system) and only a successful write is renamed onto the target with
``os.replace`` / ``os.rename``, which POSIX and Windows perform atomically for files.
An interrupted write leaves at most a hidden ``.<name>.<token>.tmp`` sibling, never a
half-written target.
"""

from __future__ import annotations

import os
import secrets
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from materials.io.errors import FormatError

__all__ = ["atomic_file", "atomic_folder"]


def _sibling(path: Path, tag: str) -> Path:
    # Hidden, unique, and keeps the suffix so libraries that look at it still work.
    return path.with_name(f".{path.name}.{secrets.token_hex(6)}.{tag}{path.suffix}")


@contextmanager
def atomic_file(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success move it onto ``path``.

    The body writes the temporary file (by name, with any library). If the body raises,
    the temporary file is removed and ``path`` is left untouched.

    Example:
        >>> with atomic_file(tmp_dir / "x.txt") as tmp:  # doctest: +SKIP
        ...     tmp.write_text("hello")
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise FormatError(path, f"cannot write: folder {path.parent} does not exist")
    tmp = _sibling(path, "tmp")
    try:
        yield tmp
        if not tmp.is_file():
            raise FormatError(path, "writer produced no file")
        with open(tmp, "rb+") as fh:  # flush to disk before the rename makes it visible
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


@contextmanager
def atomic_folder(folder: str | os.PathLike, *, overwrite: bool = False, marker: str | None = None) -> Iterator[Path]:
    """Yield an empty temporary sibling folder; on success rename it to ``folder``.

    Args:
        folder: target folder. Its parent is created if missing.
        overwrite: if False and ``folder`` exists, raise ``FileExistsError`` (before and
            after the body runs). If True, an existing folder is replaced, but only if it
            is empty or holds ``marker`` (e.g. ``material.json``), so a typo can never
            delete an unrelated folder.
        marker: file name that identifies a folder this writer may replace.

    Replacing an existing folder takes two renames (old folder aside, new folder in),
    so a reader may briefly see no folder, but never a half-written one.
    """
    folder = Path(folder)

    def check_target() -> None:
        if not folder.exists():
            return
        if not overwrite:
            raise FileExistsError(f"{folder}: already exists (pass overwrite=True to replace it)")
        if not folder.is_dir():
            raise FileExistsError(f"{folder}: exists and is not a folder; not replacing it")
        if any(folder.iterdir()) and (marker is None or not (folder / marker).is_file()):
            raise FileExistsError(
                f"{folder}: exists and does not look like a folder this writer made (no {marker}); not replacing it"
            )

    check_target()
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = _sibling(folder, "tmp")
    tmp.mkdir()
    try:
        yield tmp
        check_target()
        if folder.exists():
            old = _sibling(folder, "old")
            os.rename(folder, old)
            try:
                os.rename(tmp, folder)
            except BaseException:
                os.rename(old, folder)
                raise
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.rename(tmp, folder)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
