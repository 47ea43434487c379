"""The one atomic writer of the project: every file a command publishes goes through :func:`write_atomically`.

A file is written under a temporary name beside its target, unique to the writing process and call
(``.NAME.<pid>-<random>.partial.SUFFIX``: two writers never share one), flushed to disk (``fsync``), renamed
onto the target (``os.replace``: readers see the old complete file or the new complete one, never a torn
one) and the directory is flushed too, so that the rename survives a power loss. The temporary file of a
failed write is removed (one left by a killed process has a name no reader opens), and a disk full or I/O
error is a :class:`neural.errors.WriteError` naming the file. It lives in :mod:`neural` because both
packages write files and :mod:`neural` never imports :mod:`shellsim`.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Callable
from pathlib import Path

from .errors import write_failures


def temporary_name(path: Path) -> Path:
    """A fresh temporary path beside ``path`` with the same suffix (writers that go by the suffix work)."""
    return path.with_name(f".{path.stem}.{os.getpid()}-{secrets.token_hex(4)}.partial{path.suffix}")


def fsync_directory(directory: Path) -> None:
    """Flush ``directory``'s entries (a rename into it) to disk (a no-op where they cannot be opened)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass  # some file systems refuse fsync on a directory; the rename itself is still atomic
    finally:
        os.close(fd)


def fsync_file(path: Path) -> None:
    """Flush the file ``path``'s data to disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_atomically(path, write: Callable[[Path], object]) -> Path:
    """Call ``write(tmp)`` for a temporary file beside ``path`` (module docstring), then publish it as
    ``path``; creates the parent directory. Returns the Path. A disk full, I/O error or refused write is a
    :class:`neural.errors.WriteError` naming ``path``; ``path`` then holds what it held before."""
    path = Path(path)
    tmp = temporary_name(path)
    with write_failures(path, kept="the previous file is kept" if path.is_file() else ""):
        path.parent.mkdir(parents=True, exist_ok=True)
        try:
            write(tmp)
            fsync_file(tmp)
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
    fsync_directory(path.parent)
    return path


def write_bytes_atomically(path, data: bytes) -> Path:
    """:func:`write_atomically` of ``data``."""
    return write_atomically(path, lambda tmp: tmp.write_bytes(data))


def write_text_atomically(path, text: str) -> Path:
    """:func:`write_atomically` of ``text`` as UTF-8."""
    return write_atomically(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))
