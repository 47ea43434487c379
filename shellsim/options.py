"""Settings dataclasses as command-line options: one source of truth for names, help and defaults.

A job's settings are a dataclass whose fields are declared with :func:`option`. :func:`add_options` adds
one argparse option per field (``--field-name`` unless the field names its own flag) whose help ends with
the dataclass default; :func:`from_args` builds the settings from the parsed namespace. Text values are
parsed by the field's ``parse`` (strict grammars, never evaluated). The library validates values in
``__post_init__`` and raises :class:`SettingError`, which names the field; :func:`from_args` turns it into
an :class:`~neural.errors.InputError` naming the option instead, so the library speaks of values and the
command line of flags.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import math
import re
import typing
from collections.abc import Callable

from neural.errors import InputError


class SettingError(InputError):
    """A setting's value is out of its domain: ``name`` is the field, ``message`` says what was expected.

    ``value`` (e.g. a path) is shown after the name: ``"out /tmp/x: cannot write here"``. The message may
    name other settings as ``{field}``: the library shows the field's name, the command line its option
    (``"give {overwrite} to replace it"``). ``name`` None: an error of the job as a whole whose message
    names the settings to change."""

    def __init__(self, name: str | None, message: str, value=None):
        self.name, self.message, self.value = name, message, value
        super().__init__(self.render({}))

    def render(self, flags: typing.Mapping[str, str]) -> str:
        """The message with each setting named by ``flags`` (field -> option) where it has one."""
        message = re.sub(r"[{]([a-z_]+)[}]", lambda m: flags.get(m[1], m[1]), self.message)
        if self.name is None:
            return message
        where = flags.get(self.name, self.name) + ("" if self.value is None else f" {self.value}")
        return f"{where}: {message}"


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


def flag_of(field: dataclasses.Field) -> str:
    """The option string of ``field``: its own ``flag`` or ``--name-with-dashes``."""
    return field.metadata["option"]["flag"] or "--" + field.name.replace("_", "-")


def options(cls) -> list[dataclasses.Field]:
    """The fields of the settings dataclass ``cls`` that are command-line options, in declaration order."""
    return [f for f in dataclasses.fields(cls) if "option" in f.metadata]


def _show(value) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, tuple):
        return ",".join(_show(v) for v in value)
    return str(value)


def add_options(parser: argparse.ArgumentParser, cls, skip: typing.Collection[str] = ()) -> None:
    """Add an option to ``parser`` for each option field of ``cls`` (but those named in ``skip``)."""
    hints = typing.get_type_hints(cls)
    groups: dict[str, argparse._MutuallyExclusiveGroup] = {}
    fields = [f for f in options(cls) if f.name not in skip]
    required = {f.metadata["option"]["group"] for f in fields if f.metadata["option"]["required"]}
    for field in fields:
        meta = field.metadata["option"]
        kind = hints[field.name]
        target = parser
        if meta["group"]:
            if meta["group"] not in groups:
                groups[meta["group"]] = parser.add_mutually_exclusive_group(
                    required=meta["group"] in required
                )
            target = groups[meta["group"]]
        help_text = meta["help"]
        hidden = field.default is None or isinstance(field.default, bool) or field.default == ()
        shown = meta["shown_default"] or (None if hidden else _show(field.default))
        if shown:
            help_text += f" (default {shown})"
        kwargs: dict = {"dest": field.name, "help": help_text.replace("%", "%%")}
        if kind is bool:
            kwargs["action"] = "store_false" if meta["negate"] else "store_true"
            kwargs["default"] = field.default
        else:
            scalar = {int: int, float: float, int | None: int, float | None: float}.get(kind)
            kwargs["type"] = scalar if scalar and not meta["parse"] else str
            kwargs["default"] = list(field.default) if meta["repeat"] else field.default
            if meta["repeat"]:
                kwargs["action"] = "append"
            for key in ("metavar", "choices"):
                if meta[key]:
                    kwargs[key] = meta[key]
            if meta["const"] is not None:
                kwargs.update(nargs="?", const=meta["const"])
            if meta["required"] and not meta["group"]:
                kwargs["required"] = True
        target.add_argument(flag_of(field), **kwargs)


def from_args(cls, args: argparse.Namespace, **values):
    """The settings ``cls`` from parsed ``args`` (plus ``values`` for fields that are not options); every
    parse or :class:`SettingError` becomes one :class:`InputError` naming the option."""
    flags = {f.name: flag_of(f) for f in options(cls)}
    for field in options(cls):
        if field.name in values or not hasattr(args, field.name):
            continue
        value = getattr(args, field.name)
        meta = field.metadata["option"]
        try:
            if meta["parse"] and meta["repeat"]:
                value = tuple(meta["parse"](v) for v in value)
            elif meta["parse"] and isinstance(value, str):
                value = meta["parse"](value)
        except ValueError as err:
            raise InputError(f"{flags[field.name]}: {err}, got {value!r}") from None
        values[field.name] = tuple(value) if meta["repeat"] else value
    with options_named(cls):
        return cls(**values)


@contextlib.contextmanager
def options_named(cls):
    """Within: a :class:`SettingError` of the settings ``cls`` (raised by the settings or by the job that
    runs them) becomes one :class:`InputError` naming the options instead of the fields."""
    try:
        yield
    except SettingError as err:
        flags = {f.name: flag_of(f) for f in options(cls)}
        if err.name is not None and err.name not in flags:
            raise
        raise InputError(err.render(flags)) from None


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


def check_choice(name: str, value, choices: typing.Sequence):
    """:class:`SettingError` for ``name`` unless ``value`` is one of ``choices``. Returns ``value``."""
    if value not in choices:
        raise SettingError(name, f"expected one of {', '.join(map(str, choices))}, got {value!r}")
    return value
