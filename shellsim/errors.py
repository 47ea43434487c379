"""Errors of settings, below every layer that raises them (the library, the jobs and the command line).

:class:`SettingError` names the setting (a dataclass field) whose value is out of its domain; the command
line (:mod:`shellsim.cli.options`) shows the field as its option. The other errors a user can act on are
:class:`neural.errors.ShellsimError` and :class:`neural.errors.InputError`.
"""

from __future__ import annotations

import re
import typing

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
