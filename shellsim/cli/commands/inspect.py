"""``shellsim inspect``: view an asset's shells, cage and a motion's frames, or render the view to a PNG."""

from __future__ import annotations

import argparse
import logging

from shellsim.cli.options import add_options, from_args, options_named
from shellsim.jobs.inspect import InspectSettings, inspect

log = logging.getLogger(__name__)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "inspect",
        help="view an asset's shells and cage (and a motion's frames) with pyvista, or save a PNG",
        description="Show the outer shell M+ (translucent, coloured by the shell width or the field's kernel "
        "size), the inner shell M- and the cage as a wireframe. With --motion, a slider moves the cage and "
        "the shells through the frames. A --motion without --asset (e.g. from 'simulate --mesh') shows the "
        "surface it carries (else its cage's boundary). --screenshot renders the same view off-screen (no "
        "display needed).",
    )
    add_options(p, InspectSettings)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    with options_named(InspectSettings):
        shot = inspect(from_args(InspectSettings, args, quiet=not args.verbose))
    if shot is not None:
        log.info("wrote %s", shot)
