"""The ``shellsim`` command line: one sub-command per module in :mod:`shellsim.cli.commands`.

Every sub-command module defines ``register(subparsers)``, which adds its parser and sets
``func=run`` on it. Errors a user can act on (:class:`neural.errors.ShellsimError`) print one line
``shellsim: error: ...`` and exit with status 2. Ctrl-C (SIGINT) and SIGTERM both unwind the command as a
``KeyboardInterrupt``, so it saves what it made; they exit with 130 and 143 (128 + the signal number). A
signal that arrives while a finalizer runs (Warp frees arrays in ``__del__``, where Python ignores exceptions)
is sent again a moment later, so that it is never lost. The process-wide settings
(:func:`neural.device.configure_process`) are made once the arguments are parsed: Warp's banner, module-load
lines and CUDA probe are shown only with ``--verbose``.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import signal
import sys
import threading
from pathlib import Path

from neural.device import configure_process
from neural.errors import ShellsimError

COMMANDS = (
    "poses",
    "train",
    "finetune",
    "extract",
    "cut",
    "render",
    "eval",
    "cage",
    "simulate",
    "scene",
    "wind",
    "inspect",
    "export",
    "sweep",
    "view",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="shellsim",
        description="Turn posed photos into an adaptive-shell neural asset, then simulate, animate and "
        "render it (Wang et al., Adaptive Shells, SIGGRAPH Asia 2023).",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    parser.add_argument(
        "--cache-dir",
        default=None,
        help="where cages are kept that may not be written beside their asset (those of shipped assets, "
        "or built with other settings); default $SHELLSIM_CACHE, else $XDG_CACHE_HOME/shellsim, else "
        "~/.cache/shellsim",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        importlib.import_module(f"shellsim.cli.commands.{name}").register(sub)
    return parser


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the program is so that ``with`` blocks and writers close as for Ctrl-C."""


#: Seconds after which a signal that arrived inside a finalizer is sent again.
REDELIVERY_SECONDS = 0.01


def _in_finalizer(frame) -> bool:
    """Whether ``frame`` or a frame that called it runs a ``__del__``, where Python prints an exception raised
    by a signal handler ("Exception ignored in ...") and drops it."""
    while frame is not None:
        if frame.f_code.co_name == "__del__":
            return True
        frame = frame.f_back
    return False


def _interrupt(signum, frame) -> None:
    """SIGINT and SIGTERM: raise ``KeyboardInterrupt`` or :class:`Terminated` where the program is; inside a
    finalizer, send the signal again in :data:`REDELIVERY_SECONDS` instead."""
    if _in_finalizer(frame):
        again = threading.Timer(REDELIVERY_SECONDS, os.kill, (os.getpid(), signum))
        again.daemon = True
        again.start()
        return
    raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s %(name)s: %(message)s"
    )
    configure_process(verbose=args.verbose)
    if args.cache_dir is not None:
        os.environ["SHELLSIM_CACHE"] = str(Path(args.cache_dir).resolve())
    previous = {signum: signal.signal(signum, _interrupt) for signum in (signal.SIGINT, signal.SIGTERM)}
    try:
        args.func(args)
    except ShellsimError as err:
        print(f"shellsim: error: {err}", file=sys.stderr)
        return 2
    except Terminated:
        print("shellsim: terminated; what was written so far is kept", file=sys.stderr)
        return 128 + signal.SIGTERM
    except KeyboardInterrupt:
        print("shellsim: interrupted; what was written so far is kept", file=sys.stderr)
        return 130
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    return 0


if __name__ == "__main__":
    sys.exit(main())
