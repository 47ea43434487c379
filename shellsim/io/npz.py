"""Files of named numpy arrays (``.npz``, no pickle), written atomically: the cage and the motion files."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from neural.errors import InputError
from neural.files import write_atomically


def save_npz(path: str | os.PathLike, **arrays) -> None:
    """Write ``arrays`` to ``path`` atomically (a temporary file, then a rename): readers see the old file or
    the new one, never a torn one (:mod:`neural.files`). Creates the parent directory."""
    write_atomically(path, lambda tmp: np.savez(tmp, **arrays))


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
        with path.open("rb") as f:
            head = f.read(4)
    except OSError as err:
        raise InputError(f"{path}: cannot read {what} file ({err.strerror})") from None
    if head not in _ZIP_MAGIC:
        raise refuse("not an .npz archive" if head else "the file is empty")
    return read_npz(path, keys, optional, refuse)


def read_npz(source, keys, optional, refuse, prefix: str | None = None) -> dict[str, np.ndarray]:
    """The arrays ``keys`` (and those of ``optional``, and any named ``prefix...``, present) of the npz
    archive ``source`` (a path or a binary file object), never unpickling; ``refuse(reason)`` makes the
    error for a missing key, an array of Python objects or a damaged archive."""
    try:
        with np.load(source, allow_pickle=False) as data:
            members = set(data.zip.namelist())
            missing = [k for k in keys if f"{k}.npy" not in members]
            if missing:
                raise refuse(f"missing the array{'s' * (len(missing) > 1)} {', '.join(missing)}")
            present = [k for k in optional if f"{k}.npy" in members]
            if prefix is not None:
                present += sorted(m[:-4] for m in members if m.startswith(prefix) and m.endswith(".npy"))
            for k in (*keys, *present):
                if _header_dtype(data, k).hasobject:
                    raise refuse(f"{k!r} holds Python objects, which are never loaded")
            return {k: data[k] for k in (*keys, *present)}
    except InputError:
        raise
    except Exception as err:  # zip, zlib and .npy format errors come in many types
        raise refuse(f"damaged archive: {err or type(err).__name__}") from None


_ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")  # a zip's first entry, or an empty zip


def _header_dtype(data, key: str) -> np.dtype:
    """The dtype in the ``.npy`` header of ``key`` in the open :class:`numpy.lib.npyio.NpzFile` ``data``."""
    with data.zip.open(f"{key}.npy") as f:
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            return np.lib.format.read_array_header_1_0(f)[2]
        if version == (2, 0):
            return np.lib.format.read_array_header_2_0(f)[2]
        raise ValueError(f"unsupported .npy format version {version}")
