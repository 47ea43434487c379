"""Files of named numpy arrays (``.npz``, no pickle), written atomically: the cage and the motion files."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from neural.errors import InputError


def save_npz(path: str | os.PathLike, **arrays) -> None:
    """Write ``arrays`` to ``path`` atomically (a temporary file, then a rename): readers see the old file or
    the new one, never a torn one. Creates the parent directory."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)


def load_npz(path: str | os.PathLike, keys, what: str, optional=()) -> dict[str, np.ndarray]:
    """The arrays ``keys`` of the ``what`` file (e.g. "cage") at ``path``, and those of ``optional`` that it
    holds; a missing file, a missing key or an unreadable file is an :class:`InputError` naming the file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: {what} file not found")
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [k for k in keys if k not in data.files]
            if missing:
                raise InputError(f"{path}: not a {what} file, missing {', '.join(missing)}")
            return {k: data[k] for k in (*keys, *optional) if k in data.files}
    except InputError:
        raise
    except Exception as err:  # zip/npy format errors come in many types
        raise InputError(f"{path}: cannot read {what} file ({err})") from None
