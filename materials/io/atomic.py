"""Atomic writes: a file or a whole folder appears complete or not at all.

A writer fills a temporary sibling (same folder, so the final rename never crosses a
file system) and only a successful write is renamed onto the target with
``os.replace`` / ``os.rename``, which POSIX and Windows perform atomically for files.
An interrupted write leaves at most a hidden ``.<name>.<pid>-<token>.tmp`` sibling,
never a half-written target.

A killed process cannot clean up after itself, so the next write to the same target
does (``clean_stale``): it removes the ``.tmp`` siblings whose process (the ``<pid>`` in
the name) no longer runs on this machine, and siblings named before the pid was
recorded. A folder write killed between its two renames leaves the old folder as a
``.old`` sibling and no target; that folder is put back rather than deleted.
"""

from __future__ import annotations

import os
import re
import secrets
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from materials.io.errors import FormatError

__all__ = ["atomic_file", "atomic_folder", "clean_stale"]


def _sibling(path: Path, tag: str) -> Path:
    # Hidden, unique, owned by this process (the pid), and keeps the suffix so libraries
    # that look at it still work.
    return path.with_name(f".{path.name}.{os.getpid()}-{secrets.token_hex(6)}.{tag}{path.suffix}")


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs on this machine (a reused pid counts as alive)."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    except OSError:  # pids this platform cannot signal: assume alive, never delete
        return True
    return True


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def clean_stale(path: str | os.PathLike) -> list[Path]:
    """Remove the temporary siblings of ``path`` that killed writers left behind.

    A ``.tmp`` sibling is stale when the process named in it is gone (or it predates
    pid naming). A stale ``.old`` sibling (a folder replacement killed between its two
    renames) is moved back to ``path`` if ``path`` is missing, else removed.

    Returns:
        The siblings removed or restored (empty when there was nothing to clean).
    """
    path = Path(path)
    if not path.parent.is_dir():
        return []
    pattern = re.compile(rf"^\.{re.escape(path.name)}\.(?:(\d+)-)?[0-9a-f]{{12}}\.(tmp|old){re.escape(path.suffix)}$")
    stale: list[tuple[Path, str]] = []
    for sibling in path.parent.iterdir():
        match = pattern.match(sibling.name)
        if match and not (match.group(1) and _alive(int(match.group(1)))):
            stale.append((sibling, match.group(2)))
    olds = sorted((p for p, tag in stale if tag == "old"), key=lambda p: p.stat().st_mtime)
    if olds and not path.exists():
        os.rename(olds.pop(), path)  # the newest previous version comes back
    for sibling, tag in stale:
        if tag == "tmp" or sibling in olds:
            _remove(sibling)
    return [p for p, _ in stale]


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
    clean_stale(path)
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
            raise FileExistsError(f"{folder}: already exists (overwriting was not asked for)")
        if not folder.is_dir():
            raise FileExistsError(f"{folder}: exists and is not a folder; not replacing it")
        if any(folder.iterdir()) and (marker is None or not (folder / marker).is_file()):
            raise FileExistsError(
                f"{folder}: exists and does not look like a folder this writer made (no {marker}); not replacing it"
            )

    clean_stale(folder)
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
