"""Checks that the commands run on every output location before any heavy work starts.

A read-only directory, a path under a regular file or an output name taken by a directory must end a command
at once with one line (``shellsim: error: PATH: cannot write here (...)``), not with a traceback after minutes
of work. Writability is tested by creating and removing a temporary file, since permission bits alone say
nothing for root or on read-only mounts.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from neural.errors import InputError
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
