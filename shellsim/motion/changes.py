"""The settings that differ between a motion file's producer and a new run's, named for the user."""

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
