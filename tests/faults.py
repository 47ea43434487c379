"""Fault injection for the writers: the k-th file-system call of a write fails with an I/O error, with a
full disk, or "kills" the process (:class:`Killed`, which nothing catches, and every later call raises it
again: the files stay as the crash left them, no cleanup runs).

:func:`injected` patches ``open`` (``builtins`` and ``io``), ``os.open``, ``os.write``, ``os.fsync``,
``os.replace``, ``os.rename``, ``os.truncate``, ``os.ftruncate`` and the ``write``, ``flush`` and
``truncate`` of the files opened for writing by name; those calls are counted. ``os.unlink`` is not
counted (a full or failing disk does not stop a removal) but raises :class:`Killed` after a kill. The
writers are then checked by :func:`sweep`, which runs a scenario with the fault at every call index until
one run makes fewer calls (the whole write succeeded) or ``bound`` is reached.
"""

from __future__ import annotations

import builtins
import contextlib
import errno
import io
import os
from collections.abc import Callable
from dataclasses import dataclass, field

FAULTS = ("eio", "enospc", "kill")


class Killed(BaseException):
    """A simulated crash: not an ``Exception``, so no writer handles it."""


class Counter:
    """Counts the patched calls and fails the ``k``-th with ``fault`` (one of :data:`FAULTS`)."""

    def __init__(self, fault: str, k: int):
        if fault not in FAULTS:
            raise ValueError(f"fault: expected one of {FAULTS}, got {fault!r}")
        self.fault, self.k, self.calls, self.killed = fault, k, 0, False

    def hit(self, what: str) -> None:
        if self.killed:
            raise Killed(what)
        self.calls += 1
        if self.calls != self.k:
            return
        if self.fault == "kill":
            self.killed = True
            raise Killed(what)
        code = errno.EIO if self.fault == "eio" else errno.ENOSPC
        raise OSError(code, os.strerror(code), what)

    def dead(self, what: str) -> None:
        if self.killed:
            raise Killed(what)


class _File:
    """A file open for writing whose ``write``, ``flush`` and ``truncate`` go through ``counter``."""

    def __init__(self, file, counter: Counter):
        self._file, self._counter = file, counter

    def write(self, data):
        self._counter.hit("write")
        return self._file.write(data)

    def flush(self):
        self._counter.hit("flush")
        return self._file.flush()

    def truncate(self, *size):
        self._counter.hit("truncate")
        return self._file.truncate(*size)

    def __getattr__(self, name):
        return getattr(self._file, name)

    def __iter__(self):
        return iter(self._file)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._file.close()


def _writes(mode: str) -> bool:
    return any(c in mode for c in "wax+")


@contextlib.contextmanager
def injected(fault: str, k: int):
    """Patch the calls of the module docstring for the ``with`` block; yields the :class:`Counter`."""
    counter = Counter(fault, k)
    real_open = io.open
    real = {name: getattr(os, name) for name in ("open", "write", "fsync", "replace", "rename", "unlink")}
    real |= {name: getattr(os, name) for name in ("truncate", "ftruncate", "remove")}

    def open_(file, mode="r", *args, **kwargs):
        if not _writes(mode) or isinstance(file, int):  # an fd: a pipe to a child process, not a file
            counter.dead("open")
            return real_open(file, mode, *args, **kwargs)
        counter.hit("open")
        return _File(real_open(file, mode, *args, **kwargs), counter)

    def counted(name):
        def call(*args, **kwargs):
            counter.hit(name)
            return real[name](*args, **kwargs)

        return call

    def after_kill(name):
        def call(*args, **kwargs):
            counter.dead(name)
            return real[name](*args, **kwargs)

        return call

    patched = {name: counted(name) for name in ("open", "write", "fsync", "replace", "rename")}
    patched |= {name: counted(name) for name in ("truncate", "ftruncate")}
    patched |= {name: after_kill(name) for name in ("unlink", "remove")}
    saved_builtin = builtins.open
    builtins.open = io.open = open_
    for name, function in patched.items():
        setattr(os, name, function)
    try:
        yield counter
    finally:
        builtins.open, io.open = saved_builtin, real_open
        for name, function in real.items():
            setattr(os, name, function)


@dataclass
class Tally:
    """Cases run and cases left inconsistent (with what was wrong) of one writer and fault."""

    runs: int = 0
    inconsistent: list[str] = field(default_factory=list)


def sweep(scenario: Callable[[str, int], None], fault: str, bound: int) -> Tally:
    """Run ``scenario(fault, k)`` for k = 1, 2, ... until a run's write completes before its k-th call
    (``scenario`` returns True then) or k passes ``bound``; an ``AssertionError`` is an inconsistent case."""
    tally = Tally()
    for k in range(1, bound + 1):
        tally.runs += 1
        try:
            finished = scenario(fault, k)
        except AssertionError as err:
            tally.inconsistent.append(f"k={k}: {err}")
            continue
        if finished:
            break
    return tally
