"""The motion file: per-frame cage vertex positions written by the simulator and the wind animator.

A ``.npz`` holding

- ``rest_vertices`` (V, 3) float64: the rest cage, in the asset's world frame,
- ``tets`` (T, 4) int64: cage tetrahedra,
- ``positions`` (F, V, 3) float32: cage vertices per frame; frame 0 is the initial state,
- ``times`` (F,) float64: seconds,
- ``meta``: a JSON string (what made it, parameters, solver statistics, wall time),
- optionally the surface of what moves (``simulate --mesh``: the mesh), embedded in the cage:
  ``surface_tet`` (S,) int64, ``surface_bary`` (S, 4) float64 and ``surface_faces`` (F, 3) int64.

:class:`MotionWriter` rewrites the file atomically (temporary file + rename) at most every
``flush_seconds``, so a killed run keeps the frames written so far and a run with the same settings can
continue it. Loading never unpickles anything. :func:`parse_frames` reads a ``--frames`` range of a motion;
:func:`describe_changes` names the settings that differ between a file's meta and a new run's.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from neural.errors import InputError

from .geometry import check_tets
from .npz import load_npz, save_npz

KEYS = ("rest_vertices", "tets", "positions", "times", "meta")
SURFACE_KEYS = ("surface_tet", "surface_bary", "surface_faces")


@dataclass
class Surface:
    """A triangle surface carried by the cage: vertex ``i`` lies in tet ``tet[i]`` at barycentric coordinates
    ``bary[i]``. Shapes: tet (S,), bary (S, 4), faces (F, 3)."""

    tet: np.ndarray
    bary: np.ndarray
    faces: np.ndarray


@dataclass
class Motion:
    """A loaded motion file. Shapes: rest_vertices (V, 3), tets (T, 4), positions (F, V, 3), times (F,)."""

    rest_vertices: np.ndarray
    tets: np.ndarray
    positions: np.ndarray
    times: np.ndarray
    meta: dict = field(default_factory=dict)
    surface: Surface | None = None

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    def surface_points(self, k: int) -> np.ndarray:
        """(S, 3) float64: the points of :attr:`surface` in frame ``k``."""
        from .embed import interpolate

        s = self.surface
        return interpolate(np.asarray(self.positions[k], np.float64), self.tets, s.tet, s.bary)


def save_motion(path: str | os.PathLike, motion: Motion) -> None:
    """Write ``motion`` to ``path`` atomically: readers see the old file or the new one, never a torn one."""
    save_npz(
        path,
        rest_vertices=np.asarray(motion.rest_vertices, dtype=np.float64),
        tets=np.asarray(motion.tets, dtype=np.int64),
        positions=np.asarray(motion.positions, dtype=np.float32),
        times=np.asarray(motion.times, dtype=np.float64),
        meta=np.array(json.dumps(motion.meta)),
        **(
            {}
            if motion.surface is None
            else {
                "surface_tet": np.asarray(motion.surface.tet, np.int64),
                "surface_bary": np.asarray(motion.surface.bary, np.float64),
                "surface_faces": np.asarray(motion.surface.faces, np.int64),
            }
        ),
    )


def load_motion(path: str | os.PathLike) -> Motion:
    """Read and validate a motion file; any problem is one :class:`InputError` naming the file."""
    path = Path(path)
    arrays = load_npz(path, KEYS, "motion", optional=SURFACE_KEYS)

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
        rest.astype(np.float64),
        tets.astype(np.int64),
        pos.astype(np.float32),
        times.astype(np.float64),
        meta,
        _load_surface(path, arrays, len(tets)),
    )


def _load_surface(path: Path, arrays: dict, n_tets: int) -> Surface | None:
    """The optional surface of a motion file, checked; None when the file has none."""
    present = [k for k in SURFACE_KEYS if k in arrays]
    if not present:
        return None
    if len(present) != len(SURFACE_KEYS):
        raise InputError(f"{path}: has {', '.join(present)} but not all of {', '.join(SURFACE_KEYS)}")
    tet, bary, faces = (arrays[k] for k in SURFACE_KEYS)
    n = len(tet)
    ok = (
        tet.ndim == 1
        and np.issubdtype(tet.dtype, np.integer)
        and bary.shape == (n, 4)
        and faces.ndim == 2
        and faces.shape[1] == 3
        and np.issubdtype(faces.dtype, np.integer)
    )
    if not ok or not (tet.size == 0 or (tet.min() >= 0 and tet.max() < n_tets)):
        raise InputError(f"{path}: surface arrays must be tet (S,) < {n_tets}, bary (S, 4), faces (F, 3)")
    if not (np.isfinite(bary).all() and (faces.size == 0 or (faces.min() >= 0 and faces.max() < n))):
        raise InputError(f"{path}: surface_bary must be finite and surface_faces index its {n} points")
    return Surface(tet.astype(np.int64), bary.astype(np.float64), faces.astype(np.int64))


class MotionWriter:
    """Collects frames and keeps ``path`` up to date on disk.

    ``append`` adds one frame (V, 3); the file is rewritten when ``flush_seconds`` have passed since the
    last write, and always by ``close`` (also on an exception inside a ``with`` block).
    ``MotionWriter.resume(path)`` reopens an existing file to continue after its last frame. ``surface``: the
    optional :class:`Surface` the cage carries.
    """

    def __init__(
        self,
        path,
        rest_vertices,
        tets,
        meta: dict,
        flush_seconds: float = 2.0,
        surface: Surface | None = None,
    ):
        self.path = Path(path)
        self.motion = Motion(
            np.asarray(rest_vertices, np.float64),
            np.asarray(tets, np.int64),
            np.zeros((0, len(rest_vertices), 3), np.float32),
            np.zeros(0),
            dict(meta),
            surface,
        )
        self._frames: list[np.ndarray] = []
        self._times: list[float] = []
        self.flush_seconds = flush_seconds
        self._last_flush = time.monotonic()

    @classmethod
    def resume(cls, path, flush_seconds: float = 2.0) -> MotionWriter:
        motion = load_motion(path)
        writer = cls(path, motion.rest_vertices, motion.tets, motion.meta, flush_seconds, motion.surface)
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


def parse_frames(spec: str | None, n_frames: int, source="the motion") -> range:
    """``--frames``: ``"a:b"`` (b exclusive; either may be left out), ``"k"`` or None (all) -> the frame
    indices, checked against ``n_frames``; a malformed or out-of-range spec is an :class:`InputError`."""
    if spec is None:
        return range(n_frames)
    text = str(spec).strip()
    parts = text.split(":")
    try:
        if len(parts) == 1:
            a = int(parts[0])
            b = a + 1
        elif len(parts) == 2:
            a = int(parts[0]) if parts[0].strip() else 0
            b = int(parts[1]) if parts[1].strip() else n_frames
        else:
            raise ValueError
    except ValueError:
        raise InputError(
            f"--frames {text!r}: expected START:END (END exclusive, either optional) or one frame "
            f"number, e.g. 0:60"
        ) from None
    if not 0 <= a < b <= n_frames:
        raise InputError(
            f"--frames {text!r}: {source} has {n_frames} frames (0..{n_frames - 1}); need "
            f"0 <= START < END <= {n_frames}"
        )
    return range(a, b)


def _flatten(values: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in values.items():
        if isinstance(value, dict):
            out.update(_flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def _show(value) -> str:
    """A setting as a user typed it: 0.5, 1,0,0, z<0.1 (lists joined), "none" for None or an empty list."""
    if value is None or value == []:
        return "none"
    if isinstance(value, bool) or isinstance(value, str):
        return str(value)
    if isinstance(value, int | float):
        return f"{value:g}"
    if isinstance(value, list | tuple):
        joiner = "," if all(isinstance(v, int | float) and not isinstance(v, bool) for v in value) else " "
        return joiner.join(_show(v) for v in value)
    return str(value)


def describe_changes(stored: dict, wanted: dict, names: dict[str, str] | None = None) -> list[str]:
    """The settings that differ between a file's ``stored`` ones and the ``wanted`` ones, as
    ``"--material: rubber -> jelly"`` (nested dicts compared key by key, ``a.b``). ``names`` maps a
    (dotted) key to the option that sets it; others are shown as ``--key-with-dashes``."""
    names = names or {}
    old, new = _flatten(json.loads(json.dumps(stored))), _flatten(json.loads(json.dumps(wanted)))
    changes = []
    for key in [*new, *(k for k in old if k not in new)]:
        if old.get(key) != new.get(key):
            name = names.get(key, "--" + key.split(".")[-1].replace("_", "-"))
            changes.append(f"{name}: {_show(old.get(key))} -> {_show(new.get(key))}")
    return changes
