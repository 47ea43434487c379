"""``shellsim sweep``: materials x drop heights (and wind strengths), simulated and rendered, side by side."""

from __future__ import annotations

import argparse
import logging

from shellsim.cli.options import add_options, from_args, options_named
from shellsim.jobs.sweep import SweepSettings

log = logging.getLogger(__name__)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "sweep",
        help="simulate and render the product of materials and drop heights (and wind strengths)",
        description="One sub-directory per combination with its motion file, frames and MP4; OUT/index.json "
        "lists them and OUT/contact_sheet.png shows the last frame of each, labelled. Run it again after an "
        "interruption to finish it: finished motions and frames are kept.",
    )
    add_options(p, SweepSettings)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from shellsim.jobs.sweep import sweep

    with options_named(SweepSettings):
        result = sweep(from_args(SweepSettings, args), progress=not args.verbose)
    log.info("%d combinations in %s (index.json, contact_sheet.png)", len(result.combinations), result.out)
