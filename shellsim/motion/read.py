"""Reading motion files, whatever their format (:mod:`shellsim.motion.format`): whole (:func:`load_motion`),
all but the frames (:func:`read_motion_info`), or some frames (:func:`read_frames`, :func:`iter_frames`,
:func:`frame_bounds`), reading only the bytes those frames take in a format-3 file and only the chunks
that hold them in a log.

A path whose file does not exist but whose log does (``OUT.partial``,
:func:`shellsim.motion.log.partial_path`: a run in progress, or killed) is read from its log. Nothing is
ever unpickled; every problem is one :class:`InputError` naming the file.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from neural.errors import InputError
from shellsim.io.npz import ZIP_MAGIC, NpzReader, damaged_as
from shellsim.motion.format import Motion, MotionInfo, npz_frames, npz_info, npz_positions, refuser
from shellsim.motion.log import MAGIC, chunk_frames, open_chunks, partial_path, read_log

log = logging.getLogger(__name__)


@contextlib.contextmanager
def open_motion(path: str | os.PathLike, say: bool = False):
    """Open the motion file ``path`` (else its log, saying so in the log with ``say``) unbuffered; yields
    ``(fp, source, kind)``: the file, its path and ``"log"`` (a log or a format-2 file) or ``"npz"``."""
    path = Path(path)
    source = path
    if not path.exists() and partial_path(path).is_file():
        source = partial_path(path)
        if say:
            log.info("%s: reading %s, the log of a run in progress or interrupted", path, source.name)
    if source.is_dir():
        raise InputError(f"{source}: is a directory, not a motion file")
    if not source.is_file():
        raise InputError(f"{source}: motion file not found")
    try:
        fp = open(source, "rb", buffering=0)
    except OSError as err:
        raise InputError(f"{source}: cannot read motion file ({err.strerror})") from None
    with fp:
        head = fp.read(len(MAGIC))
        if head == MAGIC:
            yield fp, source, "log"
        elif head[:4] in ZIP_MAGIC:
            yield fp, source, "npz"
        else:
            raise refuser(source)("not an .npz archive" if head else "the file is empty")


def load_motion(path: str | os.PathLike) -> Motion:
    """Read and check the whole motion file ``path`` (format 3, 2 or 1, or the log of a run in progress)."""
    with open_motion(path, say=True) as (fp, source, kind):
        if kind == "log":
            contents = read_log(fp, source, full=True)
            return contents.info.with_positions(contents.positions)
        refuse = refuser(source)
        with damaged_as(refuse):
            reader = NpzReader(fp, refuse)
            info, positions = npz_info(reader, source, refuse)
            return info.with_positions(npz_frames(reader, refuse, positions, None))


def read_motion_info(path: str | os.PathLike) -> MotionInfo:
    """Everything of the motion file ``path`` but its frames, checked; the frame count comes from the
    positions' headers, none of their data is read."""
    with open_motion(path, say=True) as (fp, source, kind):
        if kind == "log":
            return read_log(fp, source).info
        refuse = refuser(source)
        with damaged_as(refuse):
            return npz_info(NpzReader(fp, refuse), source, refuse)[0]


def read_frames(path: str | os.PathLike, indices) -> np.ndarray:
    """(n, V, 3) float32: the frames ``indices`` (n,) (ints in 0..F-1, any order, repeats allowed) of the
    motion file ``path``, checked to be finite, reading only them (format 3 and 1: their bytes, by offset;
    a log: the chunks that hold them). Indices outside the motion are a ``ValueError``."""
    wanted = np.asarray(indices).reshape(-1)
    if wanted.size and wanted.dtype.kind not in "iu":
        raise TypeError(f"indices: expected integers, got {wanted.dtype}")
    order, inverse = np.unique(wanted.astype(np.int64), return_inverse=True)
    with open_motion(path) as (fp, source, kind):
        refuse = refuser(source)
        if kind == "log":
            chunks = open_chunks(fp, source)
            n_frames = chunks[-1].first + chunks[-1].count
        else:
            with damaged_as(refuse):
                reader = NpzReader(fp, refuse)
                positions = npz_positions(reader, refuse)
            n_frames = positions.shape[0]
        if order.size and (order[0] < 0 or order[-1] >= n_frames):
            bad = order[(order < 0) | (order >= n_frames)]
            raise ValueError(f"indices: {source} has frames 0..{n_frames - 1}, got {bad.tolist()}")
        if kind == "log":
            frames = chunk_frames(source, chunks, order)
        else:
            with damaged_as(refuse):
                frames = npz_frames(reader, refuse, positions, order)
    return frames[inverse]


def iter_frames(path: str | os.PathLike, indices, batch: int = 256) -> Iterator[np.ndarray]:
    """The frames ``indices`` of ``path`` (as :func:`read_frames`) in order, ``batch`` at a time: arrays
    (<= batch, V, 3) float32, so that going through a long motion holds only a batch."""
    indices = np.asarray(indices).reshape(-1)
    for start in range(0, len(indices), batch):
        yield read_frames(path, indices[start : start + batch])


def frame_bounds(path: str | os.PathLike, transform=None, batch: int = 256) -> np.ndarray:
    """(2, 3) float64: the lower and upper corners of the box every frame of the motion ``path`` lies in,
    after ``transform`` (points (..., 3) -> (..., 3), e.g. world -> the asset's frame) when given; reads
    ``batch`` frames at a time."""
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for frames in iter_frames(path, np.arange(read_motion_info(path).n_frames), batch):
        points = np.asarray(frames if transform is None else transform(frames), np.float64).reshape(-1, 3)
        lo, hi = np.minimum(lo, points.min(axis=0)), np.maximum(hi, points.max(axis=0))
    return np.stack([lo, hi])
