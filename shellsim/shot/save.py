"""A :class:`~shellsim.shot.spec.SceneSpec` written back as a scene file (TOML) that
:func:`shellsim.shot.file.read_scene` reads to the same spec: the keys each table's kind takes, values
that differ from nothing (None is left out), floats written exactly (``repr``), paths absolute.
"""

from __future__ import annotations

import dataclasses
import json
import math

from shellsim.shot.file import (
    ACTION_KEYS,
    ACTION_KINDS,
    BODY_KEYS,
    BODY_KINDS,
    CAMERA_KEYS,
    CAMERA_KINDS,
    COLLIDER_KEYS,
    COLLIDER_KINDS,
    LOOK_KEYS,
    WORLD_KEYS,
)
from shellsim.shot.spec import SceneSpec


def _value(value) -> str:
    """A TOML value: a boolean, number, string, array or inline table."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            raise ValueError("a scene file holds no nan")
        return repr(value) if math.isfinite(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)  # a TOML basic string
    if dataclasses.is_dataclass(value):
        value = {k: v for k, v in dataclasses.asdict(value).items() if v is not None}
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_value(v)}" for k, v in value.items()) + " }"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} {value!r} into a scene file")


def _table(header: str, entry, keys: tuple[str, ...]) -> list[str]:
    """The lines of ``[header]`` (or ``[[header]]``) with ``entry``'s ``keys`` that are not None."""
    lines = [header]
    for key in keys:
        value = getattr(entry, key)
        if value is not None and not (isinstance(value, tuple) and not value and key != "region"):
            lines.append(f"{key} = {_value(value)}")
    return lines


def scene_toml(spec: SceneSpec) -> str:
    """The text of a scene file that reads back to ``spec`` (its ``path`` and ``where`` aside)."""
    lines = _table("[world]", spec.world, tuple(k for k in WORLD_KEYS if k != "duration"))  # frames kept
    for body in spec.bodies:
        kind = "asset" if body.asset is not None else "mesh"
        keys = (*BODY_KEYS, *BODY_KINDS[kind])
        lines += ["", *_table("[[body]]", body, tuple(k for k in keys if k != "cage"))]
        cage = _table("[body.cage]", body.cage, ("target_tets", "margin"))
        if len(cage) > 1:
            lines += cage
    for collider in spec.colliders:
        keys = (*COLLIDER_KEYS, *COLLIDER_KINDS[collider.shape])
        lines += ["", *_table("[[collider]]", collider, keys)]
    for action in spec.actions:
        keys = (*ACTION_KEYS, *ACTION_KINDS[action.kind])
        lines += ["", *_table("[[action]]", action, keys)]
    for camera in spec.cameras:
        keys = (*CAMERA_KEYS, *CAMERA_KINDS[camera.kind])
        lines += ["", *_table("[[camera]]", camera, keys)]
    look = spec.look
    if len(look.sky) == 1:  # a plain sky is one colour, not a list of one
        look = dataclasses.replace(look, sky=look.sky[0])
    lines += ["", *_table("[look]", look, LOOK_KEYS)]
    return "\n".join(lines) + "\n"
