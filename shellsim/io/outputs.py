"""Checks that the commands run on every output location before any heavy work starts.

A read-only directory, a path under a regular file or an output name taken by a directory must end a command
at once with one line (``shellsim: error: PATH: cannot write here (...)``), not with a traceback after minutes
of work. Writability is tested by creating and removing a temporary file, since permission bits alone say
nothing for root or on read-only mounts. Each output is then locked (:mod:`neural.lock`) for as long as the
job that writes it runs (a job decorated with :func:`holds_outputs` calls :func:`lock_output`): a second
command that asks for the same output is refused in one line naming the process that holds it.
"""

from __future__ import annotations

import contextlib
import functools
import os
import tempfile
from collections.abc import Iterator
from contextvars import ContextVar
from pathlib import Path

from neural.errors import InputError
from neural.lock import OutputBusy, hold_output
from shellsim.errors import SettingError


def _existing_ancestor(directory: Path) -> Path:
    """The deepest existing path among ``directory`` and its parents (a file, if a parent is a file)."""
    for candidate in (directory, *directory.parents):
        if candidate.exists():
            return candidate
    return Path.cwd()  # a relative path's parents end at "."; never reached for absolute ones


def _check(target: Path, directory: Path, flag: str | None) -> None:
    """Raise an InputError naming ``target`` unless ``directory`` takes new files or can be created."""
    base = _existing_ancestor(directory)
    reason = None
    if not base.is_dir():
        reason = f"{base} is a file, not a directory"
    elif not os.access(base, os.W_OK | os.X_OK):
        reason = f"{base} is not writable"
    else:
        try:
            fd, probe = tempfile.mkstemp(prefix=".shellsim-write-test-", dir=base)
        except OSError as err:
            reason = f"{base}: {err.strerror or err}"
        else:
            os.close(fd)
            os.unlink(probe)
    if reason:
        _refuse(target, flag, f"cannot write here ({reason})")


def _refuse(target: Path, setting: str | None, message: str) -> None:
    """An InputError about ``target``, a :class:`SettingError` of ``setting`` (field or option) if given."""
    if setting:
        raise SettingError(setting, message, value=target)
    raise InputError(f"{target}: {message}")


def check_writable_dir(path, flag: str | None = None) -> Path:
    """Raise an InputError (of setting ``flag``) unless directory ``path`` exists, takes new files or can be
    created: its nearest existing parent is a writable directory. Nothing is left behind; returns the Path."""
    path = Path(path)
    _check(path, path, flag)
    return path


def check_writable_file(path, flag: str | None = None) -> Path:
    """Raise an InputError (of setting ``flag``) unless file ``path`` can be written (replaced atomically): no
    directory has its name and its directory takes new files or can be created. Returns the Path."""
    path = Path(path)
    if path.is_dir():
        _refuse(path, flag, "cannot write here (a directory has this name)")
    _check(path, path.parent, flag)
    return path


#: The locks of the job running in this context (:func:`holds_outputs`), released when it ends.
_job_locks: ContextVar[contextlib.ExitStack | None] = ContextVar("job_locks", default=None)


@contextlib.contextmanager
def output_lock(path, setting: str | None = None) -> Iterator[Path]:
    """Hold the lock of output ``path`` for the ``with`` block; yields the Path. When another process holds
    it, an error naming ``path``, that process and (as a placeholder) the ``setting`` to change."""
    with contextlib.ExitStack() as stack:
        try:
            path = stack.enter_context(hold_output(path))
        except OutputBusy as err:
            other = f"{{{setting}}}" if setting else "output"
            raise SettingError(
                None, f"{err.path}: being written by {err.owner}; wait for it or choose another {other}"
            ) from None
        yield path


def holds_outputs(job):
    """Decorate a job: what it locks with :func:`lock_output` stays locked until it returns or raises."""

    @functools.wraps(job)
    def run(*args, **kwargs):
        with contextlib.ExitStack() as stack:
            token = _job_locks.set(stack)
            try:
                return job(*args, **kwargs)
            finally:
                _job_locks.reset(token)

    return run


def lock_output(path, setting: str | None = None) -> Path:
    """Lock output ``path`` (:func:`output_lock`) until the running job (:func:`holds_outputs`) ends."""
    stack = _job_locks.get()
    if stack is None:
        raise RuntimeError("lock_output is for jobs decorated with holds_outputs")
    return stack.enter_context(output_lock(path, setting))
