"""Option parsers shared by the sub-commands: strict grammars, never evaluated; junk is an InputError."""

from __future__ import annotations

import math

from neural.errors import InputError


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


MAX_FRAMES = 10_000  # frames of one motion (about 1 GB of positions for a 10,000-vertex cage)
MAX_FPS = 1000.0


def check_range(flag: str, value, low: float, high: float, what: str = "a number", open_ends: str = "[]"):
    """InputError naming ``flag`` and the valid range unless ``low <= value <= high`` (NaN never is);
    ``open_ends`` "()" / "(]" / "[)" excludes an end. Returns ``value``."""
    above = value > low if open_ends[0] == "(" else value >= low
    below = value < high if open_ends[1] == ")" else value <= high
    if not (above and below):

        def plain(x):
            return str(x) if isinstance(x, int) else f"{x:g}"

        span = f"{open_ends[0]}{plain(low)}, {plain(high)}{open_ends[1]}"
        raise InputError(f"{flag}: expected {what} in {span}, got {plain(value)}")
    return value


def device_option(name: str, warp: bool = False) -> str:
    """:func:`neural.device.pick_device` for ``--device``: its errors name the option."""
    from neural.device import pick_device

    try:
        return pick_device(name, warp)
    except InputError as err:
        raise InputError(f"--device: {err}") from None


def add_resume_options(parser) -> None:
    """``--resume`` / ``--overwrite`` of a command writing the motion file OUT (argparse parser)."""
    again = parser.add_mutually_exclusive_group()
    again.add_argument(
        "--resume",
        action="store_true",
        help="continue OUT after its last frame (what happens anyway when OUT exists and was made with the "
        "same settings; other settings are refused)",
    )
    again.add_argument(
        "--overwrite", action="store_true", help="start OUT anew even if it was made with other settings"
    )
