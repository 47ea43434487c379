"""One writer per output: an exclusive ``flock`` on a lock file beside each output a command writes.

The lock of ``OUT`` (a file or a directory) is ``OUT.lock``, holding the owner's pid and command line as
JSON. A second process that asks for it is refused at once (:class:`OutputBusy`, naming the owner); it never
waits. The kernel drops a ``flock`` when its process dies, however it dies, so the lock file a killed
process leaves behind is simply locked again and its owner rewritten. Releasing removes the lock file while
still holding it; a taker checks after locking that the file it locked is still the one at the path (else
it locked a removed file and tries again), so two processes never both hold one output. Within a process
the lock is re-entrant (a job that locks its output may call one that locks it again). The lock file is
not a published file: it is written in place, never through :mod:`neural.files`.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import time
from collections.abc import Iterator
from pathlib import Path

from .asset import command_line
from .errors import ShellsimError
from .files import remove_stale_temporaries

#: Seconds a refused taker waits for the owner to write its pid and command line into a fresh lock file.
OWNER_WAIT = 1.0

#: Outputs this process holds: resolved path -> (file descriptor, depth).
_held: dict[Path, tuple[int, int]] = {}


class OutputBusy(ShellsimError):
    """``path`` is being written by another process: ``pid`` and ``command`` (None where unknown)."""

    def __init__(self, path: Path, pid: int | None, command: str | None):
        self.path, self.pid, self.command = path, pid, command
        super().__init__(f"{path}: being written by {self.owner}; wait for it or choose another output")

    @property
    def owner(self) -> str:
        """``another shellsim (pid 4242: shellsim simulate ...)``."""
        if self.pid is None:
            return "another shellsim"
        return f"another shellsim (pid {self.pid}" + (f": {self.command})" if self.command else ")")


def lock_path(path) -> Path:
    """The lock file of the output ``path``: ``path.lock`` beside it."""
    path = Path(path)
    return path.with_name(path.name + ".lock")


def _owner(lock: Path) -> tuple[int | None, str | None]:
    """(pid, command) recorded in ``lock``, awaited up to :data:`OWNER_WAIT` for a new owner to write them."""
    deadline = time.monotonic() + OWNER_WAIT
    while True:
        try:
            record = json.loads(lock.read_text(encoding="utf-8"))
            return int(record["pid"]), str(record["command"])
        except (OSError, ValueError, KeyError, TypeError):
            if time.monotonic() > deadline:
                return None, None
            time.sleep(0.02)


def _acquire(path: Path, lock: Path) -> int:
    """A descriptor of ``lock`` holding its exclusive flock, owner recorded; :class:`OutputBusy` if held."""
    lock.parent.mkdir(parents=True, exist_ok=True)
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as err:
            os.close(fd)
            if err.errno not in (errno.EWOULDBLOCK, errno.EACCES):
                raise
            raise OutputBusy(path, *_owner(lock)) from None
        try:
            same = os.stat(lock).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)  # locked a lock file its owner removed on release: take the one now at the path
    record = json.dumps({"pid": os.getpid(), "command": command_line()}).encode()
    os.ftruncate(fd, 0)
    os.pwrite(fd, record, 0)
    return fd


def _release(lock: Path, fd: int) -> None:
    """Remove ``lock`` while holding it, then drop the flock."""
    try:
        lock.unlink(missing_ok=True)
    finally:
        os.close(fd)


@contextlib.contextmanager
def hold_output(path) -> Iterator[Path]:
    """Hold the lock of the output ``path`` (a file or a directory) for the ``with`` block; yields the Path.
    :class:`OutputBusy` when another process holds it."""
    path = Path(path)
    key = path.resolve()
    lock = lock_path(key)
    if key in _held:
        fd, depth = _held[key]
        _held[key] = (fd, depth + 1)
    else:
        _held[key] = (_acquire(path, lock), 1)
    try:
        if _held[key][1] == 1:
            with contextlib.suppress(OSError):  # best effort: a folder that cannot be listed keeps them
                remove_stale_temporaries(path)  # of writers killed mid-write: only the lock's holder may
        yield path
    finally:
        fd, depth = _held[key]
        if depth > 1:
            _held[key] = (fd, depth - 1)
        else:
            del _held[key]
            _release(lock, fd)
