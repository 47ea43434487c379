"""``shellsim simulate``: the command line of :mod:`shellsim.jobs.simulate`."""

from __future__ import annotations

import argparse
import logging

log = logging.getLogger(__name__)


def register(sub: argparse._SubParsersAction) -> None:
    from shellsim.cli.options import add_options
    from shellsim.jobs.simulate import SimulateSettings  # numpy only; warp is imported when it runs

    p = sub.add_parser(
        "simulate",
        help="simulate an asset's cage (or a closed mesh) as an elastic body; writes a motion file",
        description="Implicit hyperelastic FEM (stable Neo-Hookean, backward Euler) of the cage under "
        "gravity, with ground and obstacle contact and friction. Writes a motion file (render it with "
        "'shellsim render'). Interrupt at any time: run again, and an OUT made with the same settings is "
        "continued; one made with other settings is refused unless --overwrite.",
    )
    add_options(p, SimulateSettings)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from shellsim.cli.options import from_args, options_named
    from shellsim.jobs.simulate import SimulateSettings, simulate

    settings = from_args(SimulateSettings, args)
    if settings.video and settings.mesh and not args.verbose:
        from shellsim.viz.inspect import quiet_vtk

        quiet_vtk()
    with options_named(SimulateSettings):
        result = simulate(settings)
    log.info("motion written to %s (%d frames)", result.out, result.frames)
    if result.history:
        from shellsim.physics.driver import summary

        log.info("%s", summary(result.history))
    if result.video is not None:
        log.info(
            "rendered %d frames (%d already there) and the video %s",
            result.video.rendered,
            result.video.skipped,
            result.video.video,
        )
