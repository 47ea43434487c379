"""Writing a motion as it is made: :class:`MotionWriter` appends frames to the log of a run in progress
(:mod:`shellsim.motion.log`) and, once closed, publishes the finished format-3 file
(:mod:`shellsim.motion.format`)."""

from __future__ import annotations

import itertools
import json
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from neural.errors import InputError, write_failures
from neural.files import write_atomically
from shellsim.io.npz import Blocks, damaged_as
from shellsim.motion.format import Motion, MotionInfo, Surface, refuser, to_json, write_motion_npz
from shellsim.motion.log import (
    append_record,
    chunk_frames,
    chunk_record,
    create_log,
    header_record,
    partial_path,
    read_log,
)
from shellsim.motion.read import iter_frames, open_motion, read_frames, read_motion_info

#: Frames per chunk when a finished file is copied into a new log.
_COPY_BATCH = 256


class MotionWriter:
    """Collects frames and appends them in chunks to the log ``OUT.partial`` beside the motion file ``path``
    (OUT); :meth:`close` publishes OUT in format 3 (atomically) and then removes the log.

    ``append`` adds one frame (V, 3) and the producer's state after it; the frames gathered are appended as
    one chunk when ``flush_seconds`` have passed since the last write, and always by ``flush`` and ``close``
    (also on an exception inside a ``with`` block). The first chunk creates the log (atomically, replacing
    any log there) and, unless the writer continues OUT, removes an older OUT; each later chunk costs its
    own size (and an fsync); ``close`` one pass over the frames. ``producer``, ``settings``, ``asset``,
    ``placement`` (asset frame -> world) and ``cage_digest`` (of the cage in the asset's frame; default that
    of ``rest_vertices`` and ``tets``) go to the header; ``meta`` (``writer.motion.meta``, kept up to date
    by the producer) goes with every chunk. ``surface``: the optional :class:`Surface` the cage carries.
    :meth:`resume` continues a motion.

    ``writer.motion`` holds the header, meta and state; its ``positions`` are not kept (see
    :attr:`last_positions`).
    """

    def __init__(
        self,
        path,
        rest_vertices,
        tets,
        meta: dict | None = None,
        flush_seconds: float = 2.0,
        surface: Surface | None = None,
        *,
        producer: str = "",
        settings: dict | None = None,
        asset: dict | None = None,
        placement: dict | None = None,
        cage_digest: str | None = None,
    ):
        self.path = Path(path)
        self.partial = partial_path(self.path)
        rest = np.asarray(rest_vertices, np.float64)
        self.motion = Motion(
            rest,
            np.asarray(tets, np.int64),
            np.zeros((0, len(rest), 3), np.float32),
            np.zeros(0),
            dict(meta or {}),
            surface,
            producer,
            json.loads(to_json(settings or {})),
            dict(asset or {}),
            path=str(self.path),
            placement=json.loads(to_json(placement or {})),
            cage_digest=cage_digest or "",
        )
        self._frames: list[np.ndarray] = []  # appended, not yet on disk
        self._times: list[float] = []
        self._written = 0  # frames on disk
        self._size = 0  # bytes of complete records in the log; 0: no log yet
        self._base: MotionInfo | None = None  # a finished file at ``path`` whose frames come first
        self._last: tuple[np.ndarray, float] | None = None
        self.flush_seconds = flush_seconds
        self._last_flush = time.monotonic()

    @classmethod
    def resume(cls, path, flush_seconds: float = 2.0) -> MotionWriter:
        """A writer continuing the motion ``path`` after its last frame: from its log when there is one
        (it is newer than any file at ``path``), else from the finished file (format 3 or 2), copied into
        a new log at the first flush. An :class:`InputError` for a file that is not a motion, or one of
        format 1."""
        path = Path(path)
        if partial_path(path).is_file():
            with open_motion(partial_path(path)) as (fp, source, kind):
                if kind != "log":
                    raise refuser(source)("not a motion log")
                contents = read_log(fp, source)
                motion, size, base = contents.info, contents.end, None
                last = chunk_frames(source, contents.chunks, np.array([motion.n_frames - 1]))[0]
        else:
            motion, size = read_motion_info(path), 0
            if motion.format_version == 1:
                raise InputError(
                    f"{path}: motion format 1 (written by an older shellsim) cannot be continued; make it "
                    "again"
                )
            base, last = motion, read_frames(path, [motion.n_frames - 1])[0]
        writer = cls(
            path,
            motion.rest_vertices,
            motion.tets,
            motion.meta,
            flush_seconds,
            motion.surface,
            producer=motion.producer,
            settings=motion.settings,
            asset=motion.asset,
            placement=motion.placement,
            cage_digest=motion.cage_digest,
        )
        writer.motion.state = motion.state
        writer._written, writer._size, writer._base = motion.n_frames, size, base
        writer._last = (last, float(motion.times[-1]))
        return writer

    @property
    def n_frames(self) -> int:
        return self._written + len(self._frames)

    @property
    def last_positions(self) -> np.ndarray:
        """(V, 3) float32: the last frame appended."""
        return self._frames[-1] if self._frames else self._last[0]

    @property
    def last_time(self) -> float:
        return self._times[-1] if self._times else self._last[1]

    def append(self, positions: np.ndarray, t: float, state: dict | None = None) -> None:
        """Add a frame: positions (V, 3), time ``t`` [s] and ``state`` (name -> array) after it."""
        positions = np.asarray(positions, dtype=np.float32)
        if positions.shape != self.motion.rest_vertices.shape:
            raise ValueError(f"positions: expected {self.motion.rest_vertices.shape}, got {positions.shape}")
        self._frames.append(positions.copy())
        self._times.append(float(t))
        if state is not None:
            self.motion.state = {k: np.array(v) for k, v in state.items()}
        if time.monotonic() - self._last_flush >= self.flush_seconds:
            self.flush()

    def flush(self) -> None:
        """Append the frames appended since the last flush to the log as one chunk."""
        if not self._frames:
            return
        chunk = chunk_record(np.stack(self._frames), self._times, self.motion.meta, self.motion.state)
        doing = f"writing frames {self._written}-{self.n_frames - 1}"
        kept = f"{self.path.name} is unchanged" if self.path.is_file() else ""
        with write_failures(self.partial, doing, f"{self._written} frames kept" if self._size else kept):
            if self._size == 0:
                records = itertools.chain([header_record(self.motion)], self._copied(), [chunk])
                size = create_log(self.partial, records)  # the copied chunks one at a time
            else:
                append_record(self.partial, self._size, chunk)
                size = self._size + len(chunk)
        replaces = self._size == 0 and self._base is None  # a new motion: what OUT held is gone
        self._size, self._base = size, None
        self._written += len(self._frames)
        self._last = (self._frames[-1], self._times[-1])
        self._frames, self._times = [], []
        if replaces:
            kept = f"{self._written} frames kept in {self.partial.name}"
            with write_failures(self.path, "removing the motion it replaces", kept):
                self.path.unlink(missing_ok=True)
        self._last_flush = time.monotonic()

    def _copied(self) -> Iterator[bytes]:
        """The chunk records of the finished file this writer continues (none for a new motion), the state
        with the last."""
        base = self._base
        if base is None:
            return
        start = 0
        for frames in iter_frames(self.path, np.arange(base.n_frames), _COPY_BATCH):
            end = start + len(frames)
            state = base.state if end == base.n_frames else {}
            yield chunk_record(frames, base.times[start:end], base.meta, state)
            start = end

    def close(self) -> None:
        """Flush, publish the motion file in format 3 (atomically) and remove the log. Nothing is written
        when no frame was: a finished file continued without a new frame stays as it was."""
        self.flush()
        if self._size == 0:
            return
        with open_motion(self.partial) as (fp, source, _):
            contents = read_log(fp, source)
            info = contents.info
            chunks = _chunk_positions(contents.chunks, refuser(source))
            positions = Blocks((info.n_frames, len(info.rest_vertices), 3), np.dtype(np.float32), chunks)
            kept = f"its {info.n_frames} frames are kept in {self.partial.name}"
            with write_failures(self.path, f"publishing {info.n_frames} frames", kept):
                write_atomically(self.path, lambda tmp: write_motion_npz(tmp, info, positions))
        self.partial.unlink()
        info.path = str(self.path)
        self._size, self._base = 0, info

    def __enter__(self) -> MotionWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _chunk_positions(chunks, refuse) -> Iterator[np.ndarray]:
    """The positions (n, V, 3) of each of the log's ``chunks``, CRC-checked."""
    for chunk in chunks:
        with damaged_as(refuse):
            positions = chunk.reader.read("positions")
        yield positions


def motion_exists(path) -> bool:
    """Whether ``path`` holds a file or the log of a run in progress writing it: what
    :meth:`MotionWriter.resume` would continue (or refuse, for a file that is not a motion)."""
    return Path(path).is_file() or partial_path(path).is_file()
