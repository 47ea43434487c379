"""Files of named numpy arrays (``.npz``, no pickle): written atomically, read whole or member by member.

:func:`save_npz` / :func:`load_npz` write and read a whole file (the cage). :func:`write_npz` writes numpy's
``np.savez`` layout (uncompressed ``NAME.npy`` members, zip64) with members that may arrive in blocks, and
:class:`NpzReader` reads an open archive's members from their headers alone, whole, or a few rows along
their first axis (by offset for an uncompressed member: only those rows' bytes are read). Nothing is ever
unpickled: an array of Python objects is refused from its header, before its data is read.
"""

from __future__ import annotations

import contextlib
import math
import os
import struct
import zipfile
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from neural.errors import InputError
from neural.files import write_atomically


def save_npz(path: str | os.PathLike, **arrays) -> None:
    """Write ``arrays`` to ``path`` atomically (a temporary file, then a rename): readers see the old file or
    the new one, never a torn one (:mod:`neural.files`). Creates the parent directory."""
    write_atomically(path, lambda tmp: np.savez(tmp, **arrays))


@dataclass(frozen=True)
class Blocks:
    """An array of ``shape`` and ``dtype`` given as ``blocks`` along its first axis: arrays (n_i, *shape[1:])
    whose n_i sum to shape[0], written one after the other by :func:`write_npz`."""

    shape: tuple[int, ...]
    dtype: np.dtype
    blocks: Iterable[np.ndarray]


def write_npz(file, arrays: dict[str, np.ndarray | Blocks]) -> None:
    """Write ``arrays`` (name -> array, or :class:`Blocks` streamed without holding the whole array) to
    ``file`` (a path or a binary file object) in the layout of ``np.savez``: a zip of uncompressed members
    ``NAME.npy``, each an ``.npy`` file, so :func:`numpy.load` reads it and :class:`NpzReader` reads rows
    by offset. A :class:`Blocks` whose blocks do not add up to its shape is a ``ValueError``."""
    with zipfile.ZipFile(file, "w", zipfile.ZIP_STORED, allowZip64=True) as archive:
        for name, value in arrays.items():
            with archive.open(f"{name}.npy", "w", force_zip64=True) as f:
                if not isinstance(value, Blocks):
                    np.lib.format.write_array(f, np.asanyarray(value), allow_pickle=False)
                    continue
                dtype, shape = np.dtype(value.dtype), tuple(value.shape)
                header = {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False}
                np.lib.format.write_array_header_1_0(f, {**header, "shape": shape})
                rows = 0
                for block in value.blocks:
                    block = np.ascontiguousarray(block, dtype)
                    if block.shape[1:] != shape[1:]:
                        raise ValueError(f"{name}: expected blocks (n, {shape[1:]}), got {block.shape}")
                    f.write(block.data)
                    rows += len(block)
                if rows != shape[0]:
                    raise ValueError(f"{name}: blocks of {rows} rows in all, expected {shape[0]}")


def load_npz(path: str | os.PathLike, keys, what: str, optional=()) -> dict[str, np.ndarray]:
    """The arrays ``keys`` of the ``what`` file (e.g. "cage") at ``path``, and those of ``optional`` it has.

    Never unpickles: an array of Python objects is refused from its header, before it is read. Any problem is
    one :class:`InputError` naming the file: not found, a directory, unreadable, or ``not a shellsim WHAT
    file (...)`` for anything that is not an ``.npz`` archive holding ``keys`` as plain arrays (another
    kind of file, a truncated or damaged archive, missing keys).
    """
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: is a directory, not a {what} file")
    if not path.is_file():
        raise InputError(f"{path}: {what} file not found")

    def refuse(reason: str) -> InputError:
        return InputError(f"{path}: not a shellsim {what} file ({reason})")

    try:
        with open(path, "rb") as f:
            head = f.read(4)
            if head not in ZIP_MAGIC:
                raise refuse("not an .npz archive" if head else "the file is empty")
            with damaged_as(refuse):
                reader = NpzReader(f, refuse)
                reader.require(keys)
                return {k: reader.read(k) for k in (*keys, *(k for k in optional if k in reader.keys))}
    except OSError as err:
        raise InputError(f"{path}: cannot read {what} file ({err.strerror})") from None


#: The first bytes of a zip archive: its first entry, or the end record of an empty one.
ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")


@contextlib.contextmanager
def damaged_as(refuse: Callable[[str], InputError]):
    """Turn any error but an :class:`InputError` raised inside the block (zip, zlib and ``.npy`` format
    errors come in many types) into ``refuse("damaged archive: ...")``."""
    try:
        yield
    except InputError:
        raise
    except Exception as err:
        raise refuse(f"damaged archive: {err or type(err).__name__}") from None


@dataclass(frozen=True)
class Member:
    """An array of an archive known from its headers: ``shape``, ``dtype``, whether it is laid out in
    ``fortran`` order (as ``np.save`` writes an F-contiguous array), and where its data starts: ``offset`` in
    the archive's file when ``stored`` (uncompressed), else in the member's own bytes."""

    key: str
    shape: tuple[int, ...]
    dtype: np.dtype
    fortran: bool
    offset: int
    stored: bool


class NpzReader:
    """An ``.npz`` archive on the open binary file ``fp`` (seekable; unbuffered, each read takes only the
    bytes it asks for), read member by member. ``refuse(reason)`` makes the error for a missing member or an
    array of Python objects; a damaged archive raises what zipfile or numpy raise (see :func:`damaged_as`).
    """

    def __init__(self, fp, refuse: Callable[[str], InputError]):
        self.fp, self.refuse = fp, refuse
        self.archive = zipfile.ZipFile(fp)
        self.keys = [name[: -len(".npy")] for name in self.archive.namelist() if name.endswith(".npy")]

    def require(self, keys) -> None:
        """``refuse`` naming the ``keys`` the archive lacks, if any."""
        missing = [k for k in keys if k not in self.keys]
        if missing:
            raise self.refuse(f"missing the array{'s' * (len(missing) > 1)} {', '.join(missing)}")

    def member(self, key: str) -> Member:
        """The headers of ``key`` (its zip entry and ``.npy`` header), without its data."""
        self.require([key])
        info = self.archive.getinfo(f"{key}.npy")
        if info.compress_type == zipfile.ZIP_STORED:
            self.fp.seek(info.header_offset)
            local = read_exactly(self.fp, 30)
            if local[:4] != b"PK\x03\x04":
                raise zipfile.BadZipFile(f"no local header for {key}.npy")
            self.fp.seek(info.header_offset + 30 + sum(struct.unpack("<2H", local[26:30])))
            shape, fortran, dtype = self._npy_header(self.fp, key)
            return Member(key, shape, dtype, fortran, self.fp.tell(), True)
        with self.archive.open(info) as f:
            shape, fortran, dtype = self._npy_header(f, key)
            return Member(key, shape, dtype, fortran, f.tell(), False)

    def read(self, key: str) -> np.ndarray:
        """The whole array ``key``, its CRC checked."""
        self.member(key)  # refuses Python objects before their data is read
        with self.archive.open(f"{key}.npy") as f:
            return np.lib.format.read_array(f, allow_pickle=False)

    def rows(self, member: Member, rows: np.ndarray) -> np.ndarray:
        """(len(rows), *member.shape[1:]): the rows ``rows`` (ascending, distinct, in 0..shape[0]-1) of
        ``member``, reading only their bytes when it is stored (so without a CRC check); a ``ValueError`` for
        an array in Fortran order, whose rows are not contiguous."""
        if member.fortran and len(member.shape) > 1:
            raise ValueError(f"{member.key}: stored in Fortran order, so its rows cannot be read alone")
        size = member.dtype.itemsize * math.prod(member.shape[1:])
        out = bytearray(len(rows) * size)
        view = memoryview(out)
        runs = np.split(np.arange(len(rows)), np.flatnonzero(np.diff(rows) != 1) + 1)
        source = contextlib.nullcontext(self.fp) if member.stored else self.archive.open(f"{member.key}.npy")
        with source as f:
            for run in (r for r in runs if len(r)):
                f.seek(member.offset + int(rows[run[0]]) * size)
                view[run[0] * size : (run[-1] + 1) * size] = read_exactly(f, len(run) * size)
        return np.frombuffer(out, member.dtype).reshape(len(rows), *member.shape[1:])

    def _npy_header(self, f, key: str) -> tuple[tuple[int, ...], bool, np.dtype]:
        version = np.lib.format.read_magic(f)
        read_header = {
            (1, 0): np.lib.format.read_array_header_1_0,
            (2, 0): np.lib.format.read_array_header_2_0,
        }
        if version not in read_header:
            raise ValueError(f"{key}: unsupported .npy format version {version}")
        shape, fortran, dtype = read_header[version](f)
        if dtype.hasobject:
            raise self.refuse(f"{key!r} holds Python objects, which are never loaded")
        return shape, bool(fortran), dtype


def read_exactly(f, n: int) -> bytes:
    """``n`` bytes from the binary file ``f`` (in several reads if need be); ``EOFError`` if it ends first."""
    parts, left = [], n
    while left:
        part = f.read(left)
        if not part:
            raise EOFError(f"the file ends {left} bytes short")
        parts.append(part)
        left -= len(part)
    return b"".join(parts)
