"""``shellsim extract``: re-extract an asset's adaptive shells (Procedure 2) with other parameters."""

from __future__ import annotations

import argparse

from shellsim.cli.options import add_options, from_args, options_named
from shellsim.jobs.extract import ExtractSettings, extract


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "extract",
        help="re-extract the shells M+/M- of an asset with other level-set parameters",
        description="Samples the asset's SDF f and kernel size s on a grid over its unit cube, dilates and "
        "erodes the level set (paper Procedures 1-2) and replaces shell_outer.ply / shell_inner.ply. "
        "Unset options keep the values the asset was extracted with. The cage is rebuilt on next use.",
    )
    add_options(p, ExtractSettings)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    with options_named(ExtractSettings):
        extract(from_args(ExtractSettings, args))
