"""The motion file: per-frame cage vertex positions written by the simulator and the wind animator.

A ``.npz`` holding

- ``rest_vertices`` (V, 3) float64: the rest cage, in the asset's world frame,
- ``tets`` (T, 4) int64: cage tetrahedra,
- ``positions`` (F, V, 3) float32: cage vertices per frame; frame 0 is the initial state,
- ``times`` (F,) float64: seconds,
- ``meta``: a JSON string (what made it, parameters, solver statistics, wall time).

:class:`MotionWriter` rewrites the file atomically (temporary file + rename) at most every
``flush_seconds``, so a killed run keeps the frames written so far and ``--resume`` can continue.
Loading never unpickles anything.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from neural.errors import InputError

from .embed import check_tets
from .npz import load_npz, save_npz

KEYS = ("rest_vertices", "tets", "positions", "times", "meta")


@dataclass
class Motion:
    """A loaded motion file. Shapes: rest_vertices (V, 3), tets (T, 4), positions (F, V, 3), times (F,)."""

    rest_vertices: np.ndarray
    tets: np.ndarray
    positions: np.ndarray
    times: np.ndarray
    meta: dict = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])


def save_motion(path: str | os.PathLike, motion: Motion) -> None:
    """Write ``motion`` to ``path`` atomically: readers see the old file or the new one, never a torn one."""
    save_npz(
        path,
        rest_vertices=np.asarray(motion.rest_vertices, dtype=np.float64),
        tets=np.asarray(motion.tets, dtype=np.int64),
        positions=np.asarray(motion.positions, dtype=np.float32),
        times=np.asarray(motion.times, dtype=np.float64),
        meta=np.array(json.dumps(motion.meta)),
    )


def load_motion(path: str | os.PathLike) -> Motion:
    """Read and validate a motion file; any problem is one :class:`InputError` naming the file."""
    path = Path(path)
    arrays = load_npz(path, KEYS, "motion")

    def refuse(reason: str) -> InputError:
        return InputError(f"{path}: not a shellsim motion file ({reason})")

    rest, tets, pos, times, meta = (arrays[k] for k in KEYS)
    for name, value in (("rest_vertices", rest), ("positions", pos), ("times", times)):
        if not np.issubdtype(value.dtype, np.floating):
            raise refuse(f"{name} must hold floats, got {value.dtype}")
    if rest.ndim != 2 or rest.shape[1] != 3:
        raise refuse(f"rest_vertices must be (V, 3), got {rest.shape}")
    try:
        tets = check_tets(tets, len(rest), allow_empty=True)
    except ValueError as err:
        raise refuse(str(err)) from None
    if pos.ndim != 3 or pos.shape[1:] != rest.shape or pos.shape[0] < 1:
        raise refuse(f"positions must be (F, {len(rest)}, 3) with F >= 1, got {pos.shape}")
    if times.shape != (pos.shape[0],):
        raise refuse(f"times must be ({pos.shape[0]},), got {times.shape}")
    if not np.isfinite(rest).all():
        raise refuse("rest_vertices contains NaN or infinity")
    bad = ~(np.isfinite(pos).all(axis=(1, 2)) & np.isfinite(times))
    if bad.any():
        more = f" (and {int(bad.sum()) - 1} more frames)" if bad.sum() > 1 else ""
        raise refuse(f"frame {int(bad.argmax())} has NaN or infinite positions or time{more}")
    if meta.shape != () or meta.dtype.kind not in "US":
        raise refuse(f"meta must be one JSON string, got {meta.dtype} {meta.shape}")
    try:
        meta = json.loads(str(meta))
    except json.JSONDecodeError as err:
        raise refuse(f"meta is not valid JSON: {err}") from None
    if not isinstance(meta, dict):
        raise refuse(f"meta must be a JSON object, got {type(meta).__name__}")
    return Motion(
        rest.astype(np.float64), tets.astype(np.int64), pos.astype(np.float32), times.astype(np.float64), meta
    )


class MotionWriter:
    """Collects frames and keeps ``path`` up to date on disk.

    ``append`` adds one frame (V, 3); the file is rewritten when ``flush_seconds`` have passed since the
    last write, and always by ``close`` (also on an exception inside a ``with`` block).
    ``MotionWriter.resume(path)`` reopens an existing file to continue after its last frame.
    """

    def __init__(self, path, rest_vertices, tets, meta: dict, flush_seconds: float = 2.0):
        self.path = Path(path)
        self.motion = Motion(
            np.asarray(rest_vertices, np.float64),
            np.asarray(tets, np.int64),
            np.zeros((0, len(rest_vertices), 3), np.float32),
            np.zeros(0),
            dict(meta),
        )
        self._frames: list[np.ndarray] = []
        self._times: list[float] = []
        self.flush_seconds = flush_seconds
        self._last_flush = time.monotonic()

    @classmethod
    def resume(cls, path, flush_seconds: float = 2.0) -> MotionWriter:
        motion = load_motion(path)
        writer = cls(path, motion.rest_vertices, motion.tets, motion.meta, flush_seconds)
        writer._frames = list(motion.positions)
        writer._times = list(motion.times)
        return writer

    @property
    def n_frames(self) -> int:
        return len(self._frames)

    @property
    def last_positions(self) -> np.ndarray:
        """(V, 3) float32: the last frame appended."""
        return self._frames[-1]

    @property
    def last_time(self) -> float:
        return self._times[-1]

    def append(self, positions: np.ndarray, t: float) -> None:
        positions = np.asarray(positions, dtype=np.float32)
        if positions.shape != self.motion.rest_vertices.shape:
            raise ValueError(f"positions: expected {self.motion.rest_vertices.shape}, got {positions.shape}")
        self._frames.append(positions.copy())
        self._times.append(float(t))
        if time.monotonic() - self._last_flush >= self.flush_seconds:
            self.flush()

    def flush(self) -> None:
        if not self._frames:
            return
        self.motion.positions = np.stack(self._frames)
        self.motion.times = np.asarray(self._times, np.float64)
        save_motion(self.path, self.motion)
        self._last_flush = time.monotonic()

    def close(self) -> None:
        self.flush()

    def __enter__(self) -> MotionWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
