"""``shellsim wind``: the command line of :mod:`shellsim.jobs.wind`."""

from __future__ import annotations

import argparse
import logging

log = logging.getLogger(__name__)


def register(sub: argparse._SubParsersAction) -> None:
    from shellsim.cli.options import add_options
    from shellsim.jobs.wind import WindSettings  # numpy only: cheap to import

    p = sub.add_parser(
        "wind",
        help="animate an asset's cage in an analytic wind; writes a motion file",
        description="Bend the asset's cage like a cantilever anchored at its base, in a wind with gusts and "
        "travelling turbulence. Writes the same motion file as 'shellsim simulate' (render it with "
        "'shellsim render'). Interrupt at any time: run again, and an OUT made with the same settings is "
        "continued; one made with other settings is refused unless --overwrite.",
    )
    add_options(p, WindSettings)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from shellsim.cli.options import from_args, options_named
    from shellsim.jobs.wind import WindSettings, wind

    with options_named(WindSettings):
        result = wind(from_args(WindSettings, args))
    log.info(
        "wrote %d frames to %s (smallest tet volume ratio %.3g)",
        result.frames,
        result.out,
        result.stats.get("min_volume_ratio", 1.0),
    )
