"""``shellsim finetune``: stage 2 again on a finished asset, with other narrow-band samples -> a new asset."""

from __future__ import annotations

import argparse

from neural.config import Stage2Config
from shellsim.cli.options import add_options, from_args, options_named
from shellsim.jobs.finetune import FinetuneSettings, finetune


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "finetune",
        help="fine-tune an asset's field in its narrow band again (e.g. for denser samples) into a new asset",
        description="Runs stage 2 of the training (narrow-band fine-tuning with the colour loss, paper "
        "Procedure 4 lines 8-13) on a finished asset: its field, inside its own shells, on the dataset it "
        "was trained on, with the narrow-band sample settings given (the asset's where unset), and writes a "
        "new asset whose asset.json keeps the old one's record and goes on with its training curve. Denser "
        "samples (smaller --delta-s / --w-s) bring the narrow band closer to the full-ray image at more "
        "samples per pixel; fine-tuning lets the field adapt to them. Interrupt at any time: the same "
        f"command resumes from OUT/checkpoints (written every {Stage2Config.checkpoint_every} steps and "
        "every --checkpoint-minutes).",
    )
    add_options(p, FinetuneSettings)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    with options_named(FinetuneSettings):
        finetune(from_args(FinetuneSettings, args))
