"""The motion file: per-frame cage vertex positions written by the simulator and the wind animator.

**Format 3** (:func:`save_motion`, and :class:`shellsim.motion.writer.MotionWriter` when it is closed) is a
plain, uncompressed ``.npz`` (``np.savez``'s layout: :func:`numpy.load` opens it, no pickle):

- ``rest_vertices`` (V, 3) float64: the rest cage where the motion starts (world metres), ``tets`` (T, 4)
  int64, ``positions`` (F, V, 3) float32 and ``times`` (F,) float64 (seconds);
- ``header``: a 0-d string of JSON: ``format`` ("shellsim-motion"), ``format_version`` (3), ``producer`` (what
  made it: "shellsim simulate", ...), ``settings`` (the producer's), ``asset`` (``name`` and content
  ``digest`` of the asset, or the mesh simulated), ``cage`` (the
  :func:`~shellsim.tetcage.geometry.cage_digest` of the cage in the asset's own frame: the identity
  :meth:`Motion.check_against` compares), ``placement`` (the similarity from the asset's frame to the world,
  :class:`shellsim.world.Placement`; ``{}`` for none), ``meta`` (facts: statistics, wall time) and ``units``
  ("m");
- optionally the surface of what moves (``simulate --mesh``), embedded in the cage: ``surface_tet`` (S,)
  int64, ``surface_bary`` (S, 4) float64, ``surface_faces`` (F, 3) int64;
- the producer's state after the last frame as arrays ``state_NAME`` (the simulator's velocities).

A scene motion (``producer`` "shellsim scene") moves several bodies: its cage is every body's cage one after
the other, its surface their collision surfaces, its ``settings`` the scene as read, and its ``asset`` holds
``bodies``, a list of each body's ``name``, ``source`` (``name`` and ``digest`` of an asset, or ``mesh``
and ``digest``), ``cage`` (digest in the asset's frame), ``placement`` and ``vertices`` / ``tets`` ranges
([start, end) of the concatenated arrays); its ``placement`` is ``{}``.

A run in progress writes the record log of :mod:`shellsim.motion.log` beside the file; that log's layout
is also that of **format 2** files, still read and continued. **Format 1** (one ``.npz`` of
``rest_vertices``, ``tets``, ``positions``, ``times``, ``meta`` and the optional surface arrays) is still
read, never continued. Formats 1 and 2 identify their cage by the digest of their rest cage.

This module holds what is read (:class:`Motion`, :class:`MotionInfo`), the checks every reader makes, and
the format-3 archive: written by :func:`write_motion_npz`, read by :func:`npz_info` and :func:`npz_frames`
(format 1 too). :mod:`shellsim.motion.read` picks the reader for a path.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from neural.errors import InputError
from neural.files import write_atomically
from shellsim.io.npz import Blocks, NpzReader, write_npz
from shellsim.tetcage.geometry import cage_digest, check_tets

FORMAT = "shellsim-motion"


FORMAT_VERSION = 3


#: The unit of every length a format-3 file stores.
UNITS = "m"


#: The arrays of a format-1 file.
FORMAT1_KEYS = ("rest_vertices", "tets", "positions", "times", "meta")


#: The arrays every format-3 file has.
KEYS = ("rest_vertices", "tets", "positions", "times", "header")


SURFACE_KEYS = ("surface_tet", "surface_bary", "surface_faces")


#: Prefix of the producer's state arrays in a format-3 file.
STATE = "state_"


MAX_FRAMES = 10_000  # frames of one motion (about 1 GB of positions for a 10,000-vertex cage)


MAX_FPS = 1000.0


@dataclass
class Surface:
    """A triangle surface carried by the cage: vertex ``i`` lies in tet ``tet[i]`` at barycentric coordinates
    ``bary[i]``. Shapes: tet (S,), bary (S, 4), faces (F, 3)."""

    tet: np.ndarray
    bary: np.ndarray
    faces: np.ndarray


class _MovesACage:
    """What :class:`Motion` and :class:`MotionInfo` share: the check that they move a given cage."""

    def check_against(self, cage, source: str | None = None) -> None:
        """:class:`InputError` (``source: problem``, default the file's path) unless this motion moves
        ``cage`` (vertices (V, 3), tets (T, 4) in the asset's frame, e.g. a
        :class:`shellsim.tetcage.build.Cage`): the cage it was made for has the same :func:`cage_digest`."""
        source = source or self.path or "motion"
        n_motion, n_cage = len(self.rest_vertices), len(cage.vertices)
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


@dataclass
class Motion(_MovesACage):
    """A motion. Shapes: rest_vertices (V, 3), tets (T, 4), positions (F, V, 3), times (F,).

    meta : facts (statistics, wall time); producer, settings, asset : what made it (module docstring);
    state : the producer's state after the last frame, name -> array (e.g. ``velocities`` (V, 3));
    format_version : of the file it was read from; path : that file ("" for one only in memory);
    placement : asset frame -> world (module docstring); cage_digest : :func:`cage_digest` of the cage it
    moves in the asset's frame (default: of ``rest_vertices`` and ``tets``).
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
    placement: dict = field(default_factory=dict)
    cage_digest: str = ""

    def __post_init__(self):
        self.cage_digest = self.cage_digest or cage_digest(self.rest_vertices, self.tets)

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    def surface_points(self, k: int) -> np.ndarray:
        """(S, 3) float64: the points of :attr:`surface` in frame ``k``."""
        from shellsim.tetcage.embed import interpolate

        s = self.surface
        return interpolate(np.asarray(self.positions[k], np.float64), self.tets, s.tet, s.bary)


@dataclass
class MotionInfo(_MovesACage):
    """Everything of a motion file but its frames (:func:`shellsim.motion.read.read_motion_info`): the
    fields of :class:`Motion` without ``positions``; ``n_frames`` F = len(times)."""

    rest_vertices: np.ndarray
    tets: np.ndarray
    times: np.ndarray
    meta: dict
    surface: Surface | None
    producer: str
    settings: dict
    asset: dict
    state: dict
    format_version: int
    path: str
    placement: dict
    cage_digest: str

    @property
    def n_frames(self) -> int:
        return len(self.times)

    def with_positions(self, positions: np.ndarray) -> Motion:
        """The :class:`Motion` of these fields and ``positions`` (F, V, 3)."""
        return Motion(positions=positions, **{f.name: getattr(self, f.name) for f in fields(self)})


def refuser(path: Path):
    """``refuse(reason)``: the :class:`InputError` ``PATH: not a shellsim motion file (REASON)``."""
    return lambda reason: InputError(f"{path}: not a shellsim motion file ({reason})")


def to_json(value) -> str:
    """``value`` as JSON, numpy arrays and scalars as lists and numbers."""

    def plain(v):
        if isinstance(v, np.ndarray | np.generic):
            return v.tolist()
        raise TypeError(f"{type(v).__name__} is not JSON serialisable")

    return json.dumps(value, default=plain)


def header_json(motion: Motion | MotionInfo, with_meta: bool = True) -> str:
    """The format-3 ``header`` of ``motion`` (module docstring); ``meta`` left out with ``with_meta`` False
    (the log keeps it in its chunks)."""
    header = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "producer": motion.producer,
        "settings": motion.settings,
        "asset": motion.asset,
        "cage": motion.cage_digest,
        "placement": motion.placement,
        "units": UNITS,
    }
    if with_meta:
        header["meta"] = motion.meta
    return to_json(header)


def parse_header(refuse, value: np.ndarray, with_meta: bool = True) -> dict:
    """The format-3 ``header`` (a 0-d JSON string array) checked: the format, its version, a cage digest and
    JSON objects for settings, asset, placement (and meta); else ``refuse(reason)``."""
    header = json_object(refuse, "header", value)
    if header.get("format") != FORMAT:
        raise refuse(f"its header is not that of a {FORMAT} file")
    if header.get("format_version") != FORMAT_VERSION:
        version = header.get("format_version")
        raise refuse(f"motion format {version!r}; this shellsim reads formats 1 to {FORMAT_VERSION}")
    if not isinstance(header.get("cage"), str) or not header["cage"]:
        raise refuse("its header has no cage digest")
    for key in ("settings", "asset", "placement", *(("meta",) * with_meta)):
        if not isinstance(header.get(key, {}), dict):
            raise refuse(f"header.{key} must be a JSON object, got {type(header[key]).__name__}")
    return header


def json_object(refuse, name: str, value: np.ndarray) -> dict:
    """The JSON object in the 0-d string array ``value`` (the array ``name``); else ``refuse(reason)``."""
    if value.shape != () or value.dtype.kind not in "US":
        raise refuse(f"{name} must be one JSON string, got {value.dtype} {value.shape}")
    try:
        obj = json.loads(str(value))
    except json.JSONDecodeError as err:
        raise refuse(f"{name} is not valid JSON: {err}") from None
    if not isinstance(obj, dict):
        raise refuse(f"{name} must be a JSON object, got {type(obj).__name__}")
    return obj


def check_cage(refuse, rest: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """rest (V, 3) finite floats and tets (T, 4) indices into them, as float64 and int64; else
    ``refuse(reason)``."""
    if not np.issubdtype(rest.dtype, np.floating):
        raise refuse(f"rest_vertices must hold floats, got {rest.dtype}")
    if rest.ndim != 2 or rest.shape[1] != 3:
        raise refuse(f"rest_vertices must be (V, 3), got {rest.shape}")
    try:
        tets = check_tets(tets, len(rest), allow_empty=True)
    except ValueError as err:
        raise refuse(str(err)) from None
    if not np.isfinite(rest).all():
        raise refuse("rest_vertices contains NaN or infinity")
    return rest.astype(np.float64), tets


def check_frames(refuse, shape: tuple, dtype: np.dtype, n_vertices: int, times: np.ndarray) -> np.ndarray:
    """The header of ``positions`` (``shape`` (F, V, 3) with F >= 1, float ``dtype``) against the cage and
    ``times`` (F,) finite floats; returns times as float64; else ``refuse(reason)``."""
    for name, kind in (("positions", dtype), ("times", times.dtype)):
        if not np.issubdtype(kind, np.floating):
            raise refuse(f"{name} must hold floats, got {kind}")
    if len(shape) != 3 or shape[1:] != (n_vertices, 3) or shape[0] < 1:
        raise refuse(f"positions must be (F, {n_vertices}, 3) with F >= 1, got {tuple(shape)}")
    if times.shape != shape[:1]:
        raise refuse(f"times must be ({shape[0]},), got {times.shape}")
    check_finite(refuse, np.isfinite(times))
    return times.astype(np.float64)


def check_finite(refuse, finite: np.ndarray, frames: np.ndarray | None = None) -> None:
    """``refuse`` naming the first frame (of ``frames``, default 0..) whose ``finite`` (n,) flag is False."""
    bad = np.flatnonzero(~finite)
    if bad.size:
        first = int(bad[0] if frames is None else frames[bad[0]])
        more = f" (and {bad.size - 1} more frames)" if bad.size > 1 else ""
        raise refuse(f"frame {first} has NaN or infinite positions or time{more}")


def check_surface(refuse, arrays: dict, n_tets: int) -> Surface | None:
    """The optional surface arrays among ``arrays``, checked; None when there are none."""
    present = [k for k in SURFACE_KEYS if k in arrays]
    if not present:
        return None
    if len(present) != len(SURFACE_KEYS):
        raise refuse(f"has {', '.join(present)} but not all of {', '.join(SURFACE_KEYS)}")
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
        raise refuse(f"surface arrays must be tet (S,) < {n_tets}, bary (S, 4), faces (F, 3)")
    if not (np.isfinite(bary).all() and (faces.size == 0 or (faces.min() >= 0 and faces.max() < n))):
        raise refuse(f"surface_bary must be finite and surface_faces index its {n} points")
    return Surface(tet.astype(np.int64), bary.astype(np.float64), faces.astype(np.int64))


def surface_arrays(surface: Surface | None) -> dict[str, np.ndarray]:
    """The arrays :data:`SURFACE_KEYS` of ``surface`` (none for None)."""
    if surface is None:
        return {}
    return {
        "surface_tet": np.asarray(surface.tet, np.int64),
        "surface_bary": np.asarray(surface.bary, np.float64),
        "surface_faces": np.asarray(surface.faces, np.int64),
    }


def write_motion_npz(file, motion: Motion | MotionInfo, positions: Blocks | np.ndarray) -> None:
    """Write the format-3 archive of ``motion``'s header, cage, times, surface and state with ``positions``
    (F, V, 3) (an array, or :class:`shellsim.io.npz.Blocks` streamed chunk by chunk) to ``file``."""
    arrays = {
        "header": np.array(header_json(motion)),
        "rest_vertices": np.asarray(motion.rest_vertices, np.float64),
        "tets": np.asarray(motion.tets, np.int64),
        "times": np.asarray(motion.times, np.float64),
        **surface_arrays(motion.surface),
        **{f"{STATE}{k}": np.asarray(v) for k, v in motion.state.items()},
        "positions": positions if isinstance(positions, Blocks) else np.asarray(positions, np.float32),
    }
    write_npz(file, arrays)


def save_motion(path: str | os.PathLike, motion: Motion) -> None:
    """Write ``motion`` to ``path`` in format 3, atomically: readers see the old file or the new one."""
    write_atomically(path, lambda tmp: write_motion_npz(tmp, motion, motion.positions))


def npz_info(reader: NpzReader, path: Path, refuse) -> tuple[MotionInfo, object]:
    """The :class:`MotionInfo` of the format-3 or format-1 archive open in ``reader`` and the
    :class:`shellsim.io.npz.Member` of its positions (headers only: no frame is read). Errors by
    ``refuse(reason)``; wrap in :func:`shellsim.io.npz.damaged_as`."""
    version = _npz_version(reader)
    rest, tets = check_cage(refuse, reader.read("rest_vertices"), reader.read("tets"))
    positions = reader.member("positions")
    times = check_frames(refuse, positions.shape, positions.dtype, len(rest), reader.read("times"))
    surface = check_surface(refuse, {k: reader.read(k) for k in SURFACE_KEYS if k in reader.keys}, len(tets))
    if version == 1:
        meta = json_object(refuse, "meta", reader.read("meta"))
        header = {"producer": meta.get("producer") or meta.get("made_by"), "cage": cage_digest(rest, tets)}
    else:
        header = parse_header(refuse, reader.read("header"))
        meta = header.get("meta") or {}
    state = {k[len(STATE) :]: reader.read(k) for k in reader.keys if k.startswith(STATE)}
    return motion_info(header, rest, tets, times, meta, surface, state, version, path), positions


def _npz_version(reader: NpzReader) -> int:
    """3, or 1 for an archive with a ``meta`` array and no ``header``; ``refuse`` unless it holds every
    array of its format."""
    version = 1 if "meta" in reader.keys and "header" not in reader.keys else FORMAT_VERSION
    reader.require(FORMAT1_KEYS if version == 1 else KEYS)
    return version


def motion_info(header: dict, rest, tets, times, meta: dict, surface, state: dict, version: int, path):
    """The :class:`MotionInfo` of a file's checked parts; ``header``: its JSON (producer, settings, asset,
    placement and ``cage``, the cage digest)."""
    return MotionInfo(
        rest_vertices=rest,
        tets=tets,
        times=times,
        meta=dict(meta),
        surface=surface,
        producer=str(header.get("producer") or ""),
        settings=dict(header.get("settings") or {}),
        asset=dict(header.get("asset") or {}),
        state=state,
        format_version=version,
        path=str(path),
        placement=dict(header.get("placement") or {}),
        cage_digest=header["cage"],
    )


def npz_positions(reader: NpzReader, refuse):
    """The :class:`shellsim.io.npz.Member` of the archive's ``positions``, from its headers: (F, V, 3) floats
    for its V rest vertices (format 3: with a good header); else ``refuse(reason)``."""
    if _npz_version(reader) == FORMAT_VERSION:
        parse_header(refuse, reader.read("header"))
    n_vertices = reader.member("rest_vertices").shape[0]
    member = reader.member("positions")
    if not np.issubdtype(member.dtype, np.floating):
        raise refuse(f"positions must hold floats, got {member.dtype}")
    if len(member.shape) != 3 or member.shape[1:] != (n_vertices, 3):
        raise refuse(f"positions must be (F, {n_vertices}, 3), got {member.shape}")
    return member


def npz_frames(reader: NpzReader, refuse, member, indices: np.ndarray | None) -> np.ndarray:
    """(n, V, 3) float32: the frames ``indices`` (ascending, distinct; None: all, CRC-checked) of the
    positions ``member`` (:func:`npz_positions`) of the archive open in ``reader``, checked to be finite;
    only their bytes are read when the member is stored."""
    frames = reader.read("positions") if indices is None else reader.rows(member, indices)
    check_finite(refuse, np.isfinite(frames).all(axis=(1, 2)), indices)
    return frames.astype(np.float32, copy=False)
