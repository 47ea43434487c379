"""Option parsers shared by the sub-commands: strict grammars, never evaluated; junk is an InputError."""

from __future__ import annotations

import math

from neural.errors import InputError
from shellsim.selection import Selection, parse_selection


def parse_size(flag: str, text: str) -> tuple[int, int]:
    """``"800x600"`` -> (800, 600); anything else is an InputError naming ``flag``."""
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() and 0 < int(p) <= 16384 for p in parts):
        raise InputError(f"{flag}: expected WIDTHxHEIGHT in pixels (e.g. 800x600), got {text!r}")
    return int(parts[0]), int(parts[1])


def parse_floats(flag: str, text: str, count: int) -> tuple[float, ...]:
    """``"1,0,0.5"`` -> (1.0, 0.0, 0.5); a wrong count or a non-finite value is an InputError."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise InputError(f"{flag}: expected {count} comma-separated numbers, got {text!r}")
    return values


def parse_rule(flag: str, text: str) -> Selection:
    """A vertex selection ``AXIS OP VALUE[%]`` (:mod:`shellsim.selection`); junk is an InputError naming
    ``flag``."""
    try:
        return parse_selection(text)
    except InputError as err:
        raise InputError(f"{flag} {err}") from None
