"""Errors a user can act on. The CLI prints their message alone (no traceback) and exits non-zero."""


class ShellsimError(Exception):
    """A failure the user can act on; the message names the file or option and the problem."""


class InputError(ShellsimError, ValueError):
    """Bad user input: a malformed or missing file, an unknown option value, an inconsistent asset."""
