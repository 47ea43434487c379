"""The viewer's edits written back into the scene file it was opened with, its comments and layout kept.

:class:`SceneEditor` loads the file with tomlkit and changes only what it is asked to: a body's or a
collider's pose (:meth:`~SceneEditor.set_pose`), a new ``[[action]]`` (a recorded poke:
:meth:`~SceneEditor.add_action`), a new ``fixed`` ``[[camera]]`` (:meth:`~SceneEditor.add_camera`).
:meth:`~SceneEditor.save` writes the one file it was opened with, atomically
(:func:`neural.files.write_atomically`), and only when the new text reads back through
:func:`shellsim.shot.file.read_scene` (read from the temporary file beside it, so relative paths resolve as
in the file; a refusal leaves the file as it was). Names follow :mod:`shellsim.shot.file`: an entry without
``name`` is ``body2``, ``collider1``, ``camera3`` by its position.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

from shellsim.shot.file import ACTION_KEYS, ACTION_KINDS
from shellsim.shot.spec import ActionSpec, SceneError, SceneSpec

#: Decimals kept of a position [m] (a micrometre) and of a rotation or field of view [degrees].
METRE_DECIMALS = 6
DEGREE_DECIMALS = 4


def action_keys(action: ActionSpec) -> dict:
    """The keys of ``action`` as an ``[[action]]`` table writes them: the keys its kind takes
    (:data:`shellsim.shot.file.ACTION_KINDS`), those that are None or empty left out."""
    keys = {}
    for key in (*ACTION_KEYS, *ACTION_KINDS[action.kind]):
        value = getattr(action, key)
        if value is None or (isinstance(value, tuple) and not value):
            continue
        if key == "keyframes":
            value = [
                {"time": k.time, "position": list(k.position), "rotation": list(k.rotation)} for k in value
            ]
        elif isinstance(value, tuple):
            value = list(value)
        keys[key] = value
    return keys


class SceneEditor:
    """The scene file ``path`` opened for edits (module docstring); ``path`` is fixed: :meth:`save` writes
    there and nowhere else. The file must read (:func:`read_scene`) as it is: ``spec`` is what it says."""

    def __init__(self, path: str | os.PathLike):
        import tomlkit

        from shellsim.shot.file import read_scene

        self._path = Path(path).resolve()
        self.spec: SceneSpec = read_scene(self._path)
        self._loaded = self._path.read_bytes()
        self._doc = tomlkit.parse(self._loaded.decode("utf-8-sig"))

    @property
    def path(self) -> Path:
        return self._path

    def text(self) -> str:
        """The file's text with the edits so far."""
        return self._doc.as_string()

    # -- edits -------------------------------------------------------------------------------------------

    def set_pose(self, name: str, position=None, rotation=None) -> None:
        """Set the ``position`` [m] and/or ``rotation`` [degrees about world x, y, z] (3 numbers each; None:
        unchanged) of the ``[[body]]`` or ``[[collider]]`` called ``name``; any other name is a
        ``ValueError`` naming it."""
        entry = self._entry(name)
        if position is not None:
            entry["position"] = _numbers("position", position, METRE_DECIMALS)
        if rotation is not None:
            entry["rotation"] = _numbers("rotation", rotation, DEGREE_DECIMALS)

    def add_action(self, action: ActionSpec | dict) -> None:
        """Append an ``[[action]]`` (an :class:`ActionSpec`, e.g. a recorded poke's push, or its keys as
        :func:`action_keys` gives them); its ``body`` must be a ``[[body]]`` of the file."""
        keys = action_keys(action) if isinstance(action, ActionSpec) else dict(action)
        body = keys.get("body")
        if body is not None and body not in self._names("body"):
            raise ValueError(f"body: {body!r} is not a [[body]] of {self._path}")
        self._append("action", keys)

    def add_camera(self, name: str | None, position, target, fov: float = 40.0) -> str:
        """Append a ``fixed`` ``[[camera]]`` at ``position`` [m] looking at ``target`` [m] with the horizontal
        field of view ``fov`` [degrees] ("camera from this view"); ``name`` None: the first free
        ``cameraK``. A name a camera of the file already has is a ``ValueError``. Returns the name."""
        names = self._names("camera")
        if name is None:
            k = len(names) + 1
            while f"camera{k}" in names:
                k += 1
            name = f"camera{k}"
        if not (isinstance(name, str) and name and name.isprintable()):
            raise ValueError(f"name: expected a non-empty string of printable characters, got {name!r}")
        if name in names:
            raise ValueError(f"name: {name!r} is already the name of a [[camera]] of {self._path}")
        position = _numbers("position", position, METRE_DECIMALS)
        target = _numbers("target", target, METRE_DECIMALS)
        if position == target:
            raise ValueError(f"target: must differ from position, got {target}")
        fov = float(fov)
        if not 0 < fov < 180:
            raise ValueError(f"fov: expected degrees in (0, 180), got {fov!r}")
        keys = {"name": name, "kind": "fixed", "position": position, "target": target}
        self._append("camera", {**keys, "fov": round(fov, DEGREE_DECIMALS)})
        return name

    # -- saving ------------------------------------------------------------------------------------------

    def save(self) -> SceneSpec:
        """Write the edited text to :attr:`path` atomically, when it reads back (module docstring); a text
        that does not, or a file changed on disk since it was opened, is a one-line :class:`SceneError`
        and the file is left as it was. Returns the saved file's spec."""
        from neural.files import write_atomically
        from shellsim.shot.file import read_scene

        text = self.text()
        if self._path.read_bytes() != self._loaded:
            raise SceneError(f"{self._path}: changed on disk since the viewer opened it; not saved")

        def write(tmp: Path) -> None:
            tmp.write_text(text, encoding="utf-8")
            try:
                read_scene(tmp)
            except SceneError as err:
                message = str(err).replace(str(tmp), str(self._path))
                raise SceneError(f"{message} (not saved; the file is unchanged)") from None

        write_atomically(self._path, write)
        self._loaded = self._path.read_bytes()
        self.spec = read_scene(self._path)
        return self.spec

    # -- the file's entries ------------------------------------------------------------------------------

    def _names(self, table: str) -> list[str]:
        """The names of the ``[[table]]`` entries, by default ``tableK`` (K from 1, by position)."""
        entries = self._doc.get(table, [])
        return [str(e.get("name", f"{table}{k}")) for k, e in enumerate(entries, 1)]

    def _entry(self, name):
        for table in ("body", "collider"):
            names = self._names(table)
            if isinstance(name, str) and name in names:
                return self._doc[table][names.index(name)]
        known = ", ".join(self._names("body") + self._names("collider"))
        raise ValueError(f"name: {name!r} is not a [[body]] or [[collider]] of {self._path} ({known})")

    def _append(self, table: str, keys: dict) -> None:
        import tomlkit

        entry = tomlkit.table()
        for key, value in keys.items():
            entry[key] = value
        if table in self._doc:
            entry.trivia.indent = "\n"  # a blank line after the entry before it
            self._doc[table].append(entry)
        else:
            aot = tomlkit.aot()
            aot.append(entry)
            self._doc.append(table, aot)


def _numbers(name: str, value, decimals: int) -> list[float]:
    """``value`` as 3 finite floats rounded to ``decimals``; anything else is a ``ValueError`` naming
    ``name``."""
    try:
        numbers = [float(v) for v in value]
    except (TypeError, ValueError):
        numbers = []
    if len(numbers) != 3 or not all(math.isfinite(v) for v in numbers):
        raise ValueError(f"{name}: expected 3 finite numbers [x, y, z], got {value!r}")
    return [round(v, decimals) + 0.0 for v in numbers]
