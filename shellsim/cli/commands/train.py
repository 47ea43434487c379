"""``shellsim train``: Procedure 4 (stage 1 -> shell extraction -> stage 2) from posed photos to an asset."""

from __future__ import annotations

import argparse

from neural.config import QUICK_STEPS, Stage1Config, scaled_defaults
from shellsim.cli.options import add_options, from_args, options_named
from shellsim.jobs.train import TrainSettings, train


def register(sub: argparse._SubParsersAction) -> None:
    quick = scaled_defaults(1)
    p = sub.add_parser(
        "train",
        help="train an adaptive-shell asset from posed photos (NeRF-synthetic or instant-ngp format)",
        description="Stage 1 full-ray NeuS training with a spatially varying kernel, adaptive-shell "
        "extraction, stage 2 narrow-band fine-tuning; writes an asset directory. Interrupt at any time: "
        "running the same command again resumes from the last checkpoint (written every "
        f"{Stage1Config.checkpoint_every} steps, every "
        "--checkpoint-minutes and on Ctrl-C or SIGTERM; the extracted shells are kept too). Stage 2 and the "
        "shell extraction scale with --steps unless set: stage 2 runs --steps / 6, and fewer than "
        f"{QUICK_STEPS} steps are a quick try ({quick['target_samples']} samples a batch, "
        f"{quick['occupancy_resolution']}^3 occupancy and {quick['shell_resolution']}^3 shell grids): "
        "--steps 200 --downscale 8 makes a rough asset in a few minutes.",
    )
    add_options(p, TrainSettings)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    with options_named(TrainSettings):
        train(from_args(TrainSettings, args))
