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

import json


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
    ``"{material}: rubber -> jelly"`` (nested dicts compared key by key, ``a.b``), each setting named as a
    ``{field}`` placeholder of :class:`shellsim.errors.SettingError` (the library shows the field, the
    command line its option). ``names`` maps a (dotted) key to another name for it."""
    names = names or {}
    old, new = _flatten(json.loads(json.dumps(stored))), _flatten(json.loads(json.dumps(wanted)))
    changes = []
    for key in [*new, *(k for k in old if k not in new)]:
        if old.get(key) != new.get(key):
            name = names.get(key, "{" + key.split(".")[-1] + "}")
            changes.append(f"{name}: {_show(old.get(key))} -> {_show(new.get(key))}")
    return changes
