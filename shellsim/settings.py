"""Settings of jobs as dataclass fields that are also command-line options (the library side).

A job's settings are a frozen dataclass whose fields are declared with :func:`option`: its name, help,
default and text grammar (``parse``) are written once, here in the library; :mod:`shellsim.cli.options`
derives the command line from them. ``__post_init__`` validates values with :func:`check_range` and
:func:`check_choice` and raises :class:`~shellsim.errors.SettingError`, which names the field; the command
line shows it as the option. Settings that set a field of a library config (:mod:`neural.config`) take its
bound from there (:func:`config_bounds`). Text values are parsed by strict grammars (:func:`floats`,
:func:`pixels`, :func:`parse_frames`), never evaluated.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import typing
from collections.abc import Callable

from neural.config import ConfigError
from neural.errors import InputError
from shellsim.errors import SettingError


def resume_option():
    """The ``resume`` field of a producer's settings (:mod:`shellsim.settings`): continue OUT."""
    return option(
        False,
        help="continue OUT after its last frame (what happens anyway when OUT exists and was made with the "
        "same settings; other settings are refused)",
        group="again",
    )


def overwrite_option():
    """The ``overwrite`` field of a producer's settings (:mod:`shellsim.settings`): start OUT anew."""
    return option(False, help="start OUT anew even if it was made with other settings", group="again")


def max_stretch_option():
    """The ``max_stretch`` field of a simulation's settings: the frame check of
    :class:`shellsim.physics.model.SolverSettings`."""
    return option(
        3.0,
        help="largest principal stretch of a tet (deformed over rest length along its most stretched "
        "direction) a frame may reach; a frame past it is redone with more substeps, then stops the run",
    )


def allow_stretch_option():
    """The ``allow_stretch`` field of a simulation's settings."""
    return option(False, help="only warn, once, when a frame passes --max-stretch, and go on")


def parse_frames(spec: str | None, n_frames: int, source="the motion") -> range:
    """The setting ``frames``: ``"a:b"`` or ``"a:b:step"`` (b exclusive; a or b may be left out; step a
    positive integer, ``"::2"`` every second frame), ``"k"`` or None (all) -> the frame indices, checked
    against ``n_frames``; a malformed or out-of-range spec is a :class:`~shellsim.errors.SettingError` of
    ``frames``."""
    if spec is None:
        return range(n_frames)
    text = str(spec).strip()
    parts = text.split(":")
    try:
        if len(parts) == 1:
            a, b, step = int(parts[0]), int(parts[0]) + 1, 1
        elif len(parts) <= 3:
            a = int(parts[0]) if parts[0].strip() else 0
            b = int(parts[1]) if parts[1].strip() else n_frames
            step = int(parts[2]) if len(parts) == 3 else 1
            if step < 1:
                raise ValueError
        else:
            raise ValueError
    except ValueError:
        raise SettingError(
            "frames",
            "expected START:END[:STEP] (END exclusive, START and END optional, STEP a positive integer) or "
            "one frame number, e.g. 0:60 or ::2",
            repr(text),
        ) from None
    if not 0 <= a < b <= n_frames:
        raise SettingError(
            "frames",
            f"{source} has {n_frames} frames (0..{n_frames - 1}); need 0 <= START < END <= {n_frames}",
            repr(text),
        )
    return range(a, b, step)


def option(
    default=None,
    *,
    help: str,
    flag: str | None = None,
    parse: Callable[[str], object] | None = None,
    metavar: str | None = None,
    choices: typing.Sequence[str] | None = None,
    repeat: bool = False,
    negate: bool = False,
    shown_default: str | None = None,
    group: str | None = None,
    required: bool = False,
    const: str | None = None,
) -> typing.Any:
    """A dataclass field that is also a command-line option.

    ``parse`` turns the option's text (each text with ``repeat``) into the field's value and raises
    ``ValueError`` with what it expected. ``repeat``: the option may be given several times (a tuple).
    ``negate``: a ``True``-by-default bool set off by ``flag`` (e.g. ``--no-ground``). ``shown_default``
    replaces the default in the help (e.g. "the asset's"); ``group`` names a mutually exclusive group, which
    is ``required`` when any of its fields says so. ``const``: the option may be given without a value,
    which then is ``const`` (``--ray`` alone, or ``--ray ADDRESS``).
    """
    meta = dict(
        help=help,
        flag=flag,
        parse=parse,
        metavar=metavar,
        choices=tuple(choices) if choices else None,
        repeat=repeat,
        negate=negate,
        shown_default=shown_default,
        group=group,
        required=required,
        const=const,
    )
    if repeat:
        return dataclasses.field(default=tuple(default or ()), metadata={"option": meta})
    return dataclasses.field(default=default, metadata={"option": meta})


def device_setting(name: str, warp: bool = False) -> str:
    """:func:`neural.device.pick_device` for the setting ``device``: its refusal is a :class:`SettingError`
    (so the command line names ``--device``)."""
    from neural.device import pick_device

    try:
        return pick_device(name, warp)
    except InputError as err:
        raise SettingError("device", str(err)) from None


def _finite_numbers(text: str) -> tuple[float, ...]:
    """The comma-separated numbers of ``text``; () when one is not a finite number."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        return ()
    return values if all(math.isfinite(v) for v in values) else ()


def floats(count: int) -> Callable[[str], tuple[float, ...]]:
    """A parser of ``count`` comma-separated finite numbers: ``"1,0,0.5"`` -> (1.0, 0.0, 0.5)."""

    def parse(text: str) -> tuple[float, ...]:
        values = _finite_numbers(text)
        if len(values) != count:
            raise ValueError(f"expected {count} comma-separated numbers")
        return values

    return parse


def float_list(text: str) -> tuple[float, ...]:
    """``"0.1,0.3"`` -> (0.1, 0.3): one or more comma-separated finite numbers."""
    values = _finite_numbers(text)
    if not values:
        raise ValueError("expected comma-separated numbers")
    return values


def name_list(text: str) -> tuple[str, ...]:
    """``"rubber, jelly"`` -> ("rubber", "jelly"): one or more comma-separated names."""
    names = tuple(v.strip() for v in text.split(","))
    if not all(names):
        raise ValueError("expected comma-separated names")
    return names


def pixels(text: str) -> tuple[int, int]:
    """A parser of an image size ``"800x600"`` -> (800, 600), each side in 1..16384."""
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() and 0 < int(p) <= 16384 for p in parts):
        raise ValueError("expected WIDTHxHEIGHT in pixels (e.g. 800x600)")
    return int(parts[0]), int(parts[1])


def show_pixels(size: tuple[int, int]) -> str:
    """``(800, 600)`` -> ``"800x600"``, as :func:`pixels` reads it."""
    return "x".join(map(str, size))


def check_range(name: str, value, low: float, high: float, what: str = "a number", open_ends: str = "[]"):
    """:class:`SettingError` for ``name`` unless ``low <= value <= high`` (NaN never is); ``open_ends`` "()",
    "(]" or "[)" excludes an end. Returns ``value``."""
    above = value > low if open_ends[0] == "(" else value >= low
    below = value < high if open_ends[1] == ")" else value <= high
    if not (above and below):

        def plain(x):
            return str(x) if isinstance(x, int) else f"{x:g}"

        span = f"{open_ends[0]}{plain(low)}, {plain(high)}{open_ends[1]}"
        raise SettingError(name, f"expected {what} in {span}, got {plain(value)}")
    return value


def check_required(settings) -> None:
    """:class:`SettingError` naming the first field of the settings dataclass ``settings`` that its
    :func:`option` marks ``required`` (outside a group) and that is None."""
    for field in dataclasses.fields(settings):
        meta = field.metadata.get("option")
        if meta and meta["required"] and not meta["group"] and getattr(settings, field.name) is None:
            raise SettingError(field.name, "needed")


@contextlib.contextmanager
def config_bounds(settings, fields: typing.Mapping[tuple[type, str], str]):
    """Within (where ``settings`` build the library's configs): a :class:`~neural.config.ConfigError` of a
    config field that ``fields`` maps ((config class, field) -> setting) becomes a :class:`SettingError` of
    that setting, with the config's bound and the setting's value; so each bound is written once, in the
    config."""
    try:
        yield
    except ConfigError as err:
        name = fields.get((err.config, err.field))
        if name is None:
            raise
        value = getattr(settings, name)
        shown = ",".join(map(_plain, value)) if isinstance(value, tuple) else _plain(value)
        raise SettingError(name, f"expected {err.expected}, got {shown}") from None


def _plain(x) -> str:
    return f"{x:g}" if isinstance(x, float) else str(x)


def check_choice(name: str, value, choices: typing.Sequence):
    """:class:`SettingError` for ``name`` unless ``value`` is one of ``choices``. Returns ``value``."""
    if value not in choices:
        raise SettingError(name, f"expected one of {', '.join(map(str, choices))}, got {value!r}")
    return value
