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
import re
import secrets
from collections.abc import Callable
from pathlib import Path

from .errors import write_failures


def _temporary_pattern(stem: str, suffix: str) -> re.Pattern:
    """The names :func:`temporary_name` gives for a target of this stem and suffix; group ``pid``."""
    return re.compile(rf"\.{re.escape(stem)}\.(?P<pid>\d+)-[0-9a-f]{{8}}\.partial{re.escape(suffix)}")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # another user's process
    return True


def remove_stale_temporaries(path) -> list[Path]:
    """Remove the temporary files that writers killed mid-write (their process gone) left for ``path``: beside
    a file, or inside a directory (its frames). Called by the one process that holds the output's lock
    (:func:`neural.lock.hold_output`), so no live writer's file is touched. Returns those removed."""
    path = Path(path)
    if path.is_dir():
        candidates = [
            (p, re.compile(r"\.(?:.+)\.(?P<pid>\d+)-[0-9a-f]{8}\.partial(?:\..*)?")) for p in path.iterdir()
        ]
    else:
        pattern = _temporary_pattern(path.stem, path.suffix)
        candidates = [(p, pattern) for p in path.parent.glob(f".{path.stem}.*.partial{path.suffix}")]
    removed = []
    for candidate, pattern in candidates:
        match = pattern.fullmatch(candidate.name)
        if match and int(match["pid"]) != os.getpid() and not _alive(int(match["pid"])):
            candidate.unlink(missing_ok=True)
            removed.append(candidate)
    return removed


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
