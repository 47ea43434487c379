"""``shellsim poses``: camera poses for plain photos by structure from motion (COLMAP via pycolmap)."""

from __future__ import annotations

import argparse

from shellsim.cli.options import add_options, from_args, options_named
from shellsim.jobs.poses import PosesSettings, poses


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "poses",
        help="recover camera poses of plain photos (structure from motion) -> transforms.json",
        description="Runs COLMAP (pycolmap, on the CPU): SIFT features, matching with two-view geometric "
        "verification, incremental mapping with one OPENCV camera (fx fy cx cy k1 k2 p1 p2) shared by all "
        "photos. Writes OUT/transforms.json (instant-ngp / nerfstudio format, OpenGL camera axes, file_path "
        "relative to OUT, the scene centred on the point the cameras look at, mean up along +z, mean camera "
        "distance 4) for `shellsim train --data OUT`, and the COLMAP database and model in OUT/colmap (this "
        "command's working folder, rebuilt on every run). "
        "Photos that could not be posed are listed in the log and under 'unregistered' in the JSON. "
        'Needs pycolmap: pip install -e ".[sfm]".',
    )
    add_options(p, PosesSettings)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    with options_named(PosesSettings):
        poses(from_args(PosesSettings, args))
