"""Settings dataclasses as command-line options: one source of truth for names, help and defaults.

:func:`add_options` adds one argparse option per field declared with :func:`shellsim.settings.option`
(``--field-name`` unless the field names its own flag) whose help ends with the dataclass default;
:func:`from_args` builds the settings from the parsed namespace and turns a
:class:`~shellsim.errors.SettingError`, which names the field, into an :class:`~neural.errors.InputError`
naming the option instead: the library speaks of values, the command line of flags. An option that takes
one value refuses a second occurrence (:func:`from_args`); a ``repeat`` option says in its help that it
may be repeated.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import typing

from neural.errors import InputError
from shellsim.errors import SettingError


def flag_of(field: dataclasses.Field) -> str:
    """The option string of ``field``: its own ``flag`` or ``--name-with-dashes``."""
    return field.metadata["option"]["flag"] or "--" + field.name.replace("_", "-")


def options(cls) -> list[dataclasses.Field]:
    """The fields of the settings dataclass ``cls`` that are command-line options, in declaration order."""
    return [f for f in dataclasses.fields(cls) if "option" in f.metadata]


#: The namespace attribute where :class:`_Once` keeps every value given to each single-valued option.
_GIVEN = "given values"


class _Once(argparse._StoreAction):
    """Store the option's value, as ``store`` does, and keep each value given (in ``_GIVEN``) so that
    :func:`from_args` refuses an option given more than once instead of keeping the last."""

    def __call__(self, parser, namespace, values, option_string=None):
        given = vars(namespace).setdefault(_GIVEN, {})
        given.setdefault(self.dest, []).append(values)
        super().__call__(parser, namespace, values, option_string)


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
        if meta["repeat"]:
            help_text += " (repeat for several)"
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
            kwargs["action"] = "append" if meta["repeat"] else _Once
            for key in ("metavar", "choices"):
                if meta[key]:
                    kwargs[key] = meta[key]
            if meta["const"] is not None:
                kwargs.update(nargs="?", const=meta["const"])
            if meta["required"] and not meta["group"]:
                kwargs["required"] = True
        target.add_argument(flag_of(field), **kwargs)


def from_args(cls, args: argparse.Namespace, **values):
    """The settings ``cls`` from parsed ``args`` (plus ``values`` for fields that are not options); an option
    that takes one value given more than once, and every parse or :class:`SettingError`, becomes one
    :class:`InputError` naming the option."""
    flags = {f.name: flag_of(f) for f in options(cls)}
    for name, given in getattr(args, _GIVEN, {}).items():
        if name in flags and len(given) > 1:
            times = "twice" if len(given) == 2 else f"{len(given)} times"
            shown = ", then ".join(_show(v) for v in given)
            raise InputError(f"{flags[name]} given {times} ({shown}); it takes one value")
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
