"""The record log of a motion in progress, ``OUT.partial`` beside the motion file ``OUT``
(:func:`partial_path`), and the layout of format-2 motion files.

The line :data:`MAGIC`, then records, each ``b"SSMR"``, its length (8 bytes, little-endian) and an ``.npz``:

- the **header** (first record): ``format`` ("shellsim-motion"), ``format_version`` (3 in a log; 2 in a
  format-2 file), ``rest_vertices`` (V, 3) float64, ``tets`` (T, 4) int64, ``header`` (JSON: format 3's
  header without ``meta``, :func:`shellsim.motion.format.header_json`; in format 2 ``producer``,
  ``settings``, ``asset`` and ``cage``, the digest of the rest cage) and the optional surface arrays;
- **chunks** of frames, in order: ``positions`` (n, V, 3) float32, ``times`` (n,) float64, ``meta`` (JSON;
  the last chunk's holds) and the producer's state after the chunk's last frame as arrays ``state/NAME``.

A chunk is appended with :func:`append_record` (written, flushed and fsynced), so writing N frames costs
O(N) and a killed writer loses at most the chunk it was writing: a cut-short last record, or a last
chunk whose archive cannot be opened, is dropped on reading (with a warning) and cut off by the next
append. Reading walks the records by their lengths and opens each chunk's archive by its headers only:
:func:`read_log` reads everything but the frames (all of them with ``full``), :func:`log_frames` reads
some frames, opening only the chunks that hold them.
"""

from __future__ import annotations

import io
import logging
import os
import struct
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from neural.errors import InputError
from neural.files import write_atomically
from shellsim.io.npz import Member, NpzReader, damaged_as
from shellsim.motion.format import (
    FORMAT,
    FORMAT_VERSION,
    SURFACE_KEYS,
    Motion,
    MotionInfo,
    check_cage,
    check_finite,
    check_frames,
    check_surface,
    header_json,
    json_object,
    motion_info,
    parse_header,
    refuser,
    surface_arrays,
    to_json,
)
from shellsim.tetcage.geometry import cage_digest

log = logging.getLogger(__name__)

#: The first bytes of a log (and of a format-2 motion file).
MAGIC = b"\x93SHELLSIM-MOTION\n"

#: Each record: this tag, the length of the npz that follows (uint64 little-endian), the npz.
RECORD = b"SSMR"

_LENGTH = struct.Struct("<Q")

_PREFIX = len(RECORD) + _LENGTH.size

_HEAD_KEYS = ("format", "format_version", "rest_vertices", "tets", "header")

_CHUNK_KEYS = ("positions", "times", "meta")

#: Prefix of the state arrays in a chunk.
STATE = "state/"


def partial_path(path: str | os.PathLike) -> Path:
    """The log of a run in progress writing the motion file ``path``: ``path`` + ``.partial``."""
    path = Path(path)
    return path.with_name(path.name + ".partial")


def _record(**arrays) -> bytes:
    """One record: tag, length, npz of ``arrays``."""
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    payload = buffer.getvalue()
    return RECORD + _LENGTH.pack(len(payload)) + payload


def header_record(motion: Motion | MotionInfo) -> bytes:
    """The header record of a log of ``motion`` (module docstring)."""
    return _record(
        format=np.array(FORMAT),
        format_version=np.array(FORMAT_VERSION),
        rest_vertices=np.asarray(motion.rest_vertices, np.float64),
        tets=np.asarray(motion.tets, np.int64),
        header=np.array(header_json(motion, with_meta=False)),
        **surface_arrays(motion.surface),
    )


def chunk_record(positions, times, meta: dict, state: dict) -> bytes:
    """A chunk record: ``positions`` (n, V, 3), ``times`` (n,), ``meta`` and ``state`` (name -> array)."""
    return _record(
        positions=np.asarray(positions, np.float32),
        times=np.asarray(times, np.float64),
        meta=np.array(to_json(meta)),
        **{f"{STATE}{k}": np.asarray(v) for k, v in state.items()},
    )


def create_log(path: Path, records: Iterable[bytes]) -> int:
    """Write a log of ``records`` (the header's first) to ``path`` atomically; returns its size in bytes."""
    size = len(MAGIC)

    def write(tmp: Path) -> None:
        nonlocal size
        with open(tmp, "wb") as f:
            f.write(MAGIC)
            for data in records:
                f.write(data)
                size += len(data)

    write_atomically(path, write)
    return size


def append_record(path: Path, size: int, data: bytes) -> None:
    """Append the record ``data`` to the log ``path`` after its first ``size`` bytes (the complete records:
    a cut-short one after them is cut off), then flush it to disk."""
    with open(path, "r+b") as f:
        f.truncate(size)
        f.seek(size)
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


@dataclass
class Chunk:
    """A chunk of a log open for reading: its frames ``first .. first + count - 1``, its archive (``reader``)
    and the headers of its ``positions``."""

    first: int
    count: int
    reader: NpzReader
    positions: Member


@dataclass
class Log:
    """A log read by :func:`read_log`: ``info``, its ``chunks``, ``end`` (the bytes of its complete records)
    and, when read ``full``, ``positions`` (F, V, 3) float32."""

    info: MotionInfo
    chunks: list[Chunk]
    end: int
    positions: np.ndarray | None


class _Window:
    """The bytes ``start .. start + length - 1`` of the binary file ``fp`` as a seekable file (one record's
    archive, for :mod:`zipfile`)."""

    def __init__(self, fp, start: int, length: int):
        self.fp, self.start, self.length, self.pos = fp, start, length, 0

    def seekable(self) -> bool:
        return True

    def tell(self) -> int:
        return self.pos

    def seek(self, offset: int, whence: int = 0) -> int:
        pos = offset + (0, self.pos, self.length)[whence]
        if pos < 0:
            raise ValueError(f"seek to {pos}, before the record's first byte")
        self.pos = pos
        return pos

    def read(self, n: int | None = -1) -> bytes:
        left = max(self.length - self.pos, 0)
        n = left if n is None or n < 0 else min(n, left)
        self.fp.seek(self.start + self.pos)
        data = self.fp.read(n)
        self.pos += len(data)
        return data


def _spans(fp, refuse) -> tuple[list[tuple[int, int]], int, bool]:
    """(start, length) of each complete record's npz, the bytes they end at, and whether a cut-short record
    follows them."""
    fp.seek(0)
    if fp.read(len(MAGIC)) != MAGIC:
        raise refuse("not a motion log")
    fp.seek(0, os.SEEK_END)
    size = fp.tell()
    spans, pos = [], len(MAGIC)
    while pos < size:
        fp.seek(pos)
        head = fp.read(_PREFIX)
        if head[: len(RECORD)] != RECORD[: len(head)]:
            raise refuse(f"no record at byte {pos}")
        length = _LENGTH.unpack(head[len(RECORD) :])[0] if len(head) == _PREFIX else None
        if length is None or pos + _PREFIX + length > size:
            return spans, pos, True
        spans.append((pos + _PREFIX, length))
        pos += _PREFIX + length
    return spans, pos, False


def _head(fp, span: tuple[int, int], refuse) -> tuple[dict, int, np.ndarray, np.ndarray, dict]:
    """The header record: (its arrays, its format version, rest (V, 3), tets (T, 4), its header JSON)."""
    with damaged_as(refuse):
        reader = NpzReader(_Window(fp, *span), refuse)
        reader.require(_HEAD_KEYS)
        arrays = {k: reader.read(k) for k in (*_HEAD_KEYS, *SURFACE_KEYS) if k in reader.keys}
    version = arrays["format_version"]
    if str(arrays["format"]) != FORMAT or version.shape != () or version.dtype.kind not in "iu":
        raise refuse(f"its header is not that of a {FORMAT} file")
    rest, tets = check_cage(refuse, arrays["rest_vertices"], arrays["tets"])
    if int(version) == FORMAT_VERSION:
        header = parse_header(refuse, arrays["header"], with_meta=False)
    elif int(version) == 2:
        header = json_object(refuse, "header", arrays["header"])
        if header.get("cage") != cage_digest(rest, tets):
            raise refuse("its cage digest does not match its rest cage")
    else:
        raise refuse(f"motion format {int(version)}; this shellsim reads formats 1 to {FORMAT_VERSION}")
    return arrays, int(version), rest, tets, header


def _chunks(fp, path: Path, spans, end: int, n_vertices: int, refuse) -> tuple[list[Chunk], int]:
    """The chunks of the records ``spans`` (after the header) opened by their headers, and the bytes of
    complete records (less a damaged last chunk, dropped with a warning)."""
    chunks, first = [], 0
    for k, (start, length) in enumerate(spans):
        try:
            with damaged_as(refuse):
                reader = NpzReader(_Window(fp, start, length), refuse)
                reader.require(_CHUNK_KEYS)
                headers = {key: reader.member(key) for key in reader.keys}  # refuses Python objects
            positions = headers["positions"]
        except InputError:
            if k + 1 < len(spans) or not chunks:
                raise
            log.warning("%s: dropping a damaged last chunk (the writer was interrupted)", path)
            return chunks, start - _PREFIX
        shape, dtype = positions.shape, positions.dtype
        if len(shape) != 3 or shape[1:] != (n_vertices, 3) or not np.issubdtype(dtype, np.floating):
            raise refuse(f"chunk {k}: positions must be (n, {n_vertices}, 3) floats, got {shape} {dtype}")
        chunks.append(Chunk(first, shape[0], reader, positions))
        first += shape[0]
    return chunks, end


def read_log(fp, path: Path, full: bool = False) -> Log:
    """The log (or format-2 file) open as ``fp`` (binary, at any position; ``path`` names it in errors):
    everything but the frames, and the frames too with ``full`` (CRC-checked). Any problem is one
    :class:`InputError` naming ``path``."""
    refuse = refuser(path)
    spans, end, torn = _spans(fp, refuse)
    if torn:
        log.warning("%s: dropping an incomplete last record (the writer was interrupted)", path)
    if len(spans) < 2:
        raise refuse("no complete chunk of frames")
    arrays, version, rest, tets, header = _head(fp, spans[0], refuse)
    chunks, end = _chunks(fp, path, spans[1:], end, len(rest), refuse)
    with damaged_as(refuse):
        times = np.concatenate([chunk.reader.read("times") for chunk in chunks])
        last = chunks[-1].reader
        meta = json_object(refuse, "meta", last.read("meta"))
        state = {k[len(STATE) :]: last.read(k) for k in last.keys if k.startswith(STATE)}
        positions = np.concatenate([c.reader.read("positions") for c in chunks]) if full else None
    n_frames = chunks[-1].first + chunks[-1].count  # the chunks' positions: checked (n, V, 3) floats
    times = check_frames(refuse, (n_frames, len(rest), 3), np.dtype(np.float32), len(rest), times)
    if positions is not None:
        check_finite(refuse, np.isfinite(positions).all(axis=(1, 2)))
        positions = positions.astype(np.float32, copy=False)
    surface = check_surface(refuse, arrays, len(tets))
    info = motion_info(header, rest, tets, times, meta, surface, state, version, path)
    return Log(info, chunks, end, positions)


def open_chunks(fp, path: Path) -> list[Chunk]:
    """The chunks of the log open as ``fp``, opened by their headers (no frame is read)."""
    refuse = refuser(path)
    spans, end, _ = _spans(fp, refuse)
    if len(spans) < 2:
        raise refuse("no complete chunk of frames")
    rest = _head(fp, spans[0], refuse)[2]
    return _chunks(fp, path, spans[1:], end, len(rest), refuse)[0]


def chunk_frames(path: Path, chunks: list[Chunk], indices: np.ndarray) -> np.ndarray:
    """(n, V, 3) float32: the frames ``indices`` (ascending, distinct, below the frame count) of the log
    ``path`` whose ``chunks`` (:func:`open_chunks`) are open, reading only their bytes."""
    refuse = refuser(path)
    which = np.searchsorted([c.first for c in chunks], indices, side="right") - 1
    parts = [np.zeros((0, *chunks[0].positions.shape[1:]), np.float32)]
    with damaged_as(refuse):
        for k in np.unique(which):
            chunk = chunks[k]
            parts.append(chunk.reader.rows(chunk.positions, indices[which == k] - chunk.first))
    frames = np.concatenate(parts)
    check_finite(refuse, np.isfinite(frames).all(axis=(1, 2)), indices)
    return frames.astype(np.float32, copy=False)
