"""The motion file: per-frame cage vertex positions written by the simulator and the wind animator.

**Format 2** (written by :class:`MotionWriter` and :func:`save_motion`): the line :data:`MAGIC`, then
records, each ``b"SSMR"``, its length (8 bytes, little-endian) and an ``.npz`` archive (no pickle):

- the **header** (first record): ``format`` ("shellsim-motion"), ``format_version`` (2), ``rest_vertices``
  (V, 3) float64 (the rest cage, in the asset's world frame), ``tets`` (T, 4) int64, ``header``: JSON of
  ``producer`` (what made it: "shellsim simulate", ...), ``settings`` (the producer's settings),
  ``asset`` (``name`` and content ``digest`` of the asset, or the mesh simulated) and ``cage`` (the
  :func:`cage_digest` of the rest cage: the identity :meth:`Motion.check_against` compares), and optionally
  the surface of what moves (``simulate --mesh``: the mesh), embedded in the cage: ``surface_tet`` (S,)
  int64, ``surface_bary`` (S, 4) float64 and ``surface_faces`` (F, 3) int64;
- **chunks** of frames, in order: ``positions`` (n, V, 3) float32, ``times`` (n,) float64 (seconds),
  ``meta`` (JSON of facts: world scale, statistics, wall time; the last chunk's holds) and the producer's
  state after the chunk's last frame as arrays ``state/NAME`` (the simulator's velocities).

:class:`MotionWriter` appends a chunk at most every ``flush_seconds`` (the first one creates the file
atomically: temporary file + rename) and merges them into one when it is closed, so writing N frames costs
O(N) and a killed run keeps the frames of every complete chunk: an incomplete last record (a write cut
short) is dropped on reading, and a writer continuing the file (:meth:`MotionWriter.resume`) cuts it off
first.

**Format 1** (a single ``.npz`` of ``rest_vertices``, ``tets``, ``positions``, ``times``, ``meta`` and the
optional surface arrays) is still read, for rendering and viewing; it cannot be continued.

Loading never unpickles anything. :func:`parse_frames` reads a ``--frames`` range of a motion;
:func:`describe_changes` names the settings that differ between a file's and a new run's.
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
import os
import struct
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from neural.errors import InputError
from shellsim.cage.geometry import check_tets
from shellsim.io.npz import load_npz, read_npz

log = logging.getLogger(__name__)


FORMAT = "shellsim-motion"


FORMAT_VERSION = 2


#: The first bytes of a format-2 motion file.
MAGIC = b"\x93SHELLSIM-MOTION\n"


#: Each record: this tag, the length of the npz that follows (uint64 little-endian), the npz.
RECORD = b"SSMR"


_LENGTH = struct.Struct("<Q")


#: The arrays of a format-1 file.
KEYS = ("rest_vertices", "tets", "positions", "times", "meta")


SURFACE_KEYS = ("surface_tet", "surface_bary", "surface_faces")


_ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")


MAX_FRAMES = 10_000  # frames of one motion (about 1 GB of positions for a 10,000-vertex cage)


MAX_FPS = 1000.0


def cage_digest(vertices: np.ndarray, tets: np.ndarray) -> str:
    """sha256 (hex) of a rest cage: its vertices (V, 3) as float64 and tets (T, 4) as int64, with shapes."""
    h = hashlib.sha256()
    for array in (np.asarray(vertices, np.float64), np.asarray(tets, np.int64)):
        h.update(str(array.shape).encode())
        h.update(np.ascontiguousarray(array).tobytes())
    return h.hexdigest()


@dataclass
class Surface:
    """A triangle surface carried by the cage: vertex ``i`` lies in tet ``tet[i]`` at barycentric coordinates
    ``bary[i]``. Shapes: tet (S,), bary (S, 4), faces (F, 3)."""

    tet: np.ndarray
    bary: np.ndarray
    faces: np.ndarray


@dataclass
class Motion:
    """A motion. Shapes: rest_vertices (V, 3), tets (T, 4), positions (F, V, 3), times (F,).

    meta : facts (world scale, statistics); producer, settings, asset : what made it (module docstring);
    state : the producer's state after the last frame, name -> array (e.g. ``velocities`` (V, 3));
    format_version : of the file it was read from; path : that file ("" for one only in memory).
    """

    rest_vertices: np.ndarray
    tets: np.ndarray
    positions: np.ndarray
    times: np.ndarray
    meta: dict = field(default_factory=dict)
    surface: Surface | None = None
    producer: str = ""
    settings: dict = field(default_factory=dict)
    asset: dict = field(default_factory=dict)
    state: dict = field(default_factory=dict)
    format_version: int = FORMAT_VERSION
    path: str = ""

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    @property
    def cage_digest(self) -> str:
        """:func:`cage_digest` of the rest cage: the identity of the cage this motion moves."""
        return cage_digest(self.rest_vertices, self.tets)

    def check_against(self, cage, source: str | None = None) -> None:
        """:class:`InputError` (``source: problem``, default the file's path) unless this motion moves
        ``cage`` (vertices (V, 3), tets (T, 4), e.g. a :class:`shellsim.cage.build.Cage`): the cage it was made
        for has the same :func:`cage_digest`."""
        source = source or self.path or "motion"
        n_motion, n_cage = self.positions.shape[1], len(cage.vertices)
        if n_motion != n_cage:
            raise InputError(
                f"{source}: the motion moves {n_motion} cage vertices but the asset's cage has {n_cage}; it "
                "was made for another cage"
            )
        theirs = cage_digest(cage.vertices, cage.tets)
        if theirs != self.cage_digest:
            raise InputError(
                f"{source}: the motion's rest cage differs from the asset's cage (its digest "
                f"{self.cage_digest[:12]}, the cage's {theirs[:12]}; rebuilt since?); make the motion again"
            )

    def surface_points(self, k: int) -> np.ndarray:
        """(S, 3) float64: the points of :attr:`surface` in frame ``k``."""
        from shellsim.cage.embed import interpolate

        s = self.surface
        return interpolate(np.asarray(self.positions[k], np.float64), self.tets, s.tet, s.bary)


def _record(**arrays) -> bytes:
    """One record: tag, length, npz of ``arrays``."""
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    payload = buffer.getvalue()
    return RECORD + _LENGTH.pack(len(payload)) + payload


def _header_record(motion: Motion) -> bytes:
    header = {
        "producer": motion.producer,
        "settings": motion.settings,
        "asset": motion.asset,
        "cage": motion.cage_digest,
    }
    surface = {}
    if motion.surface is not None:
        surface = {
            "surface_tet": np.asarray(motion.surface.tet, np.int64),
            "surface_bary": np.asarray(motion.surface.bary, np.float64),
            "surface_faces": np.asarray(motion.surface.faces, np.int64),
        }
    return _record(
        format=np.array(FORMAT),
        format_version=np.array(FORMAT_VERSION),
        rest_vertices=np.asarray(motion.rest_vertices, np.float64),
        tets=np.asarray(motion.tets, np.int64),
        header=np.array(json.dumps(header)),
        **surface,
    )


def _chunk_record(positions, times, meta: dict, state: dict) -> bytes:
    return _record(
        positions=np.asarray(positions, np.float32),
        times=np.asarray(times, np.float64),
        meta=np.array(json.dumps(meta)),
        **{f"state/{k}": np.asarray(v) for k, v in state.items()},
    )


def _replace(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temporary file + rename); creates the parent directory."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def save_motion(path: str | os.PathLike, motion: Motion) -> None:
    """Write ``motion`` to ``path`` in format 2, atomically: readers see the old file or the new one."""
    data = _header_record(motion) + _chunk_record(motion.positions, motion.times, motion.meta, motion.state)
    _replace(Path(path), MAGIC + data)


class MotionWriter:
    """Collects frames and appends them to ``path`` in chunks.

    ``append`` adds one frame (V, 3) and the producer's state after it; the frames gathered are appended as
    one chunk when ``flush_seconds`` have passed since the last write, and always by ``flush`` and ``close``
    (also on an exception inside a ``with`` block). The first chunk creates the file (atomically, replacing
    any file there); each later one costs its own size; ``close`` rewrites the chunks as one. ``producer``,
    ``settings`` and ``asset`` go to the header (module docstring); ``meta`` (``writer.motion.meta``, kept
    up to date by the producer) goes with every chunk. ``MotionWriter.resume(path)`` continues a format-2
    file after its last complete chunk. ``surface``: the optional :class:`Surface` the cage carries.

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
    ):
        self.path = Path(path)
        rest = np.asarray(rest_vertices, np.float64)
        self.motion = Motion(
            rest,
            np.asarray(tets, np.int64),
            np.zeros((0, len(rest), 3), np.float32),
            np.zeros(0),
            dict(meta or {}),
            surface,
            producer,
            json.loads(json.dumps(settings or {})),
            dict(asset or {}),
            path=str(self.path),
        )
        self._frames: list[np.ndarray] = []  # appended, not yet on disk
        self._times: list[float] = []
        self._written = 0  # frames on disk
        self._size = 0  # bytes of complete records on disk; 0: the file is not created yet
        self._chunks = 0  # chunks on disk
        self._last: tuple[np.ndarray, float] | None = None
        self.flush_seconds = flush_seconds
        self._last_flush = time.monotonic()

    @classmethod
    def resume(cls, path, flush_seconds: float = 2.0) -> MotionWriter:
        """A writer continuing the motion file ``path`` after its last frame; an :class:`InputError` for a
        file that is not a motion, or one of format 1."""
        motion, size = _load(Path(path))
        if motion.format_version != FORMAT_VERSION:
            raise InputError(
                f"{path}: motion format {motion.format_version} (written by an older shellsim) cannot be "
                "continued; make it again"
            )
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
        )
        writer.motion.state = motion.state
        writer._written, writer._size, writer._chunks = motion.n_frames, size, 1
        writer._last = (motion.positions[-1], float(motion.times[-1]))
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
        """Write the frames appended since the last flush as one chunk."""
        if not self._frames:
            return
        chunk = _chunk_record(np.stack(self._frames), self._times, self.motion.meta, self.motion.state)
        if self._size == 0:
            data = MAGIC + _header_record(self.motion) + chunk
            _replace(self.path, data)
        else:
            with self.path.open("r+b") as f:
                f.truncate(self._size)  # an incomplete record of an interrupted run
                f.seek(self._size)
                f.write(chunk)
            data = chunk
        self._size += len(data)
        self._chunks += 1
        self._written += len(self._frames)
        self._last = (self._frames[-1], self._times[-1])
        self._frames, self._times = [], []
        self._last_flush = time.monotonic()

    def close(self) -> None:
        """Flush, then rewrite a file of several chunks as one (atomically), so that reading it is fast."""
        self.flush()
        if self._chunks > 1:
            motion, _ = _load(self.path)
            data = MAGIC + _header_record(motion)
            data += _chunk_record(motion.positions, motion.times, motion.meta, motion.state)
            _replace(self.path, data)
            self._size, self._chunks = len(data), 1

    def __enter__(self) -> MotionWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def load_motion(path: str | os.PathLike) -> Motion:
    """Read and validate a motion file (format 2, or 1); any problem is one :class:`InputError` naming
    the file. An incomplete last record (a write cut short) is dropped with a warning."""
    return _load(Path(path))[0]


def _load(path: Path) -> tuple[Motion, int]:
    """The motion in ``path`` and the bytes of its complete records (0 for format 1)."""
    if path.is_dir():
        raise InputError(f"{path}: is a directory, not a motion file")
    if not path.is_file():
        raise InputError(f"{path}: motion file not found")
    try:
        data = path.read_bytes()
    except OSError as err:
        raise InputError(f"{path}: cannot read motion file ({err.strerror})") from None
    if data.startswith(MAGIC):
        return _load_format2(path, data)
    if data[:4] in _ZIP_MAGIC:
        return _load_format1(path), 0
    raise _refuse(path, "not an .npz archive" if data else "the file is empty")


def _refuse(path: Path, reason: str) -> InputError:
    return InputError(f"{path}: not a shellsim motion file ({reason})")


def _records(path: Path, data: bytes) -> tuple[list[bytes], int]:
    """The complete records of a format-2 file and the bytes they end at; a cut-short last one is dropped."""
    records, pos = [], len(MAGIC)
    while pos < len(data):
        tag, body = data[pos : pos + 4], pos + 4 + _LENGTH.size
        if tag != RECORD[: len(tag)]:
            raise _refuse(path, f"no record at byte {pos}")
        if body > len(data) or body + _LENGTH.unpack_from(data, pos + 4)[0] > len(data):
            log.warning("%s: dropping an incomplete last record (the writer was interrupted)", path)
            break
        end = body + _LENGTH.unpack_from(data, pos + 4)[0]
        records.append(data[body:end])
        pos = end
    return records, pos


def _load_format2(path: Path, data: bytes) -> tuple[Motion, int]:
    records, size = _records(path, data)
    if len(records) < 2:
        raise _refuse(path, "no complete chunk of frames")

    def refuse(reason: str) -> InputError:
        return _refuse(path, reason)

    keys = ("format", "format_version", "rest_vertices", "tets", "header")
    head = read_npz(io.BytesIO(records[0]), keys, SURFACE_KEYS, refuse)
    if str(head["format"]) != FORMAT or head["format_version"].shape != ():
        raise refuse(f"its header is not that of a {FORMAT} file")
    if int(head["format_version"]) != FORMAT_VERSION:
        raise InputError(
            f"{path}: motion format {int(head['format_version'])}; this shellsim reads formats 1 and "
            f"{FORMAT_VERSION}"
        )
    header = _json_object(refuse, "header", head["header"])
    chunks = []
    for k, record in enumerate(records[1:]):
        try:
            chunks.append(read_npz(io.BytesIO(record), ("positions", "times", "meta"), (), refuse, "state/"))
        except InputError:
            if k + 2 < len(records) or not chunks:
                raise
            log.warning("%s: dropping a damaged last chunk (the writer was interrupted)", path)
            size -= len(RECORD) + _LENGTH.size + len(record)
    rest, tets = head["rest_vertices"], head["tets"]
    for k, chunk in enumerate(chunks):
        pos, times = chunk["positions"], chunk["times"]
        if pos.ndim != 3 or pos.shape[1:] != rest.shape or times.shape != pos.shape[:1]:
            raise refuse(f"chunk {k}: positions {pos.shape} and times {times.shape} must be (n, V, 3), (n,)")
    positions = np.concatenate([c["positions"] for c in chunks])
    times = np.concatenate([c["times"] for c in chunks])
    rest, tets, positions, times = _check_arrays(refuse, rest, tets, positions, times)
    if header.get("cage") != cage_digest(rest, tets):
        raise refuse("its cage digest does not match its rest cage")
    last = chunks[-1]
    motion = Motion(
        rest,
        tets,
        positions,
        times,
        _json_object(refuse, "meta", last["meta"]),
        _load_surface(path, head, len(tets)),
        str(header.get("producer", "")),
        dict(header.get("settings") or {}),
        dict(header.get("asset") or {}),
        {k[len("state/") :]: v for k, v in last.items() if k.startswith("state/")},
        FORMAT_VERSION,
        str(path),
    )
    return motion, size


def _load_format1(path: Path) -> Motion:
    arrays = load_npz(path, KEYS, "motion", optional=SURFACE_KEYS)

    def refuse(reason: str) -> InputError:
        return _refuse(path, reason)

    rest, tets, pos, times = _check_arrays(refuse, *(arrays[k] for k in KEYS[:4]))
    meta = _json_object(refuse, "meta", arrays["meta"])
    producer = str(meta.get("producer") or meta.get("made_by") or "")
    surface = _load_surface(path, arrays, len(tets))
    return Motion(rest, tets, pos, times, meta, surface, producer, format_version=1, path=str(path))


def _check_arrays(refuse, rest, tets, pos, times):
    """rest (V, 3), tets (T, 4), positions (F, V, 3) with F >= 1 and times (F,), finite, as float64, int64,
    float32, float64; else ``refuse(reason)``."""
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
    return rest.astype(np.float64), tets.astype(np.int64), pos.astype(np.float32), times.astype(np.float64)


def _json_object(refuse, name: str, value: np.ndarray) -> dict:
    if value.shape != () or value.dtype.kind not in "US":
        raise refuse(f"{name} must be one JSON string, got {value.dtype} {value.shape}")
    try:
        obj = json.loads(str(value))
    except json.JSONDecodeError as err:
        raise refuse(f"{name} is not valid JSON: {err}") from None
    if not isinstance(obj, dict):
        raise refuse(f"{name} must be a JSON object, got {type(obj).__name__}")
    return obj


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
