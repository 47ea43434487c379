"""``shellsim export``: a motion out to USD (Blender, Omniverse), a VTU series (ParaView) or PLY files."""

from __future__ import annotations

import argparse
import logging

from shellsim.cli.options import add_options, from_args, options_named
from shellsim.jobs.export import ExportSettings

log = logging.getLogger(__name__)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "export",
        help="export a motion to USD, a VTU series or PLY files",
        description="USD: the deformed outer shell M+ (or a simulated mesh's surface) and the cage's "
        "surface with time-sampled points, the up axis, metres per unit and the frame rate set. VTU: the tet "
        "cage per frame with displacement and det F (volume ratio), indexed by a .pvd. PLY: the deformed M+, "
        "one file per frame. A scene's motion (--motion its output directory): every body (a neural one's "
        "M+, a mesh's surface) and its cage, and every collider written once, in metres, z up.",
    )
    add_options(p, ExportSettings)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from shellsim.jobs.export import export

    with options_named(ExportSettings):
        result = export(from_args(ExportSettings, args), progress=not args.verbose)
    log.info("wrote %d file(s): %s", len(result.files), result.out)
