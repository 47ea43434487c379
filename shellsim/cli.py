"""The ``shellsim`` command line: one sub-command per module in :mod:`shellsim.commands`.

Every sub-command module defines ``register(subparsers)``, which adds its parser and sets
``func=run`` on it. Errors a user can act on (:class:`neural.errors.ShellsimError`) print one line
``shellsim: error: ...`` and exit with status 2; an interrupt exits with 130 after the command has saved
what it made.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from neural.errors import ShellsimError

COMMANDS = ("train", "extract", "render", "eval", "cage", "simulate", "wind", "inspect")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="shellsim",
        description="Turn posed photos into an adaptive-shell neural asset, then simulate, animate and "
        "render it (Wang et al., Adaptive Shells, SIGGRAPH Asia 2023).",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        importlib.import_module(f"shellsim.commands.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s %(name)s: %(message)s"
    )
    if not args.verbose:
        import warp

        warp.config.quiet = True  # no banner or kernel-cache lines on stdout; -v shows them
    try:
        args.func(args)
    except ShellsimError as err:
        print(f"shellsim: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("shellsim: interrupted; what was written so far is kept", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
