"""``shellsim train``: Procedure 4 (stage 1 -> shell extraction -> stage 2) from posed photos to an asset."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "train",
        help="train an adaptive-shell asset from posed photos (NeRF-synthetic or instant-ngp format)",
        description="Stage 1 full-ray NeuS training with a spatially varying kernel, adaptive-shell "
        "extraction, stage 2 narrow-band fine-tuning; writes an asset directory. Interrupt at any time: "
        "running the same command again resumes from the last checkpoint (written every 250 steps, every "
        "--checkpoint-minutes and on Ctrl-C or SIGTERM; the extracted shells are kept too). Stage 2 and the "
        "shell extraction scale with --steps unless set: stage 2 runs --steps / 6, and fewer than 2000 steps "
        "are a quick try (4x smaller batches, 64^3 occupancy and 128^3 shell grids): --steps 200 "
        "--downscale 8 makes a rough asset in a few minutes.",
    )
    p.add_argument("--data", required=True, help="dataset dir: transforms*.json or COLMAP sparse/0")
    p.add_argument(
        "--out", required=True, help="asset directory to write (checkpoints go in OUT/checkpoints)"
    )
    p.add_argument("--downscale", type=int, default=1, help="image downscale factor (default 1)")
    p.add_argument(
        "--steps",
        type=int,
        default=None,
        help="stage-1 steps (default 6000); stage 2 and the shell grid follow",
    )
    p.add_argument(
        "--stage2-steps", type=int, default=None, help="stage-2 steps (default: --steps / 6, 1000 for 6000)"
    )
    p.add_argument(
        "--background",
        default="white",
        help="colour behind the asset: white, black or r,g,b (default white)",
    )
    p.add_argument(
        "--random-background",
        action="store_true",
        help="train with a random colour behind the fully transparent pixels of images with alpha, so that "
        "no floater can hide in background-coloured space (costs about 1.3 dB held-out on lego; small "
        "floaters apart from the object are dropped from the shells anyway)",
    )
    p.add_argument(
        "--bound",
        type=float,
        default=None,
        help="half-size of the object's box in world units (default: from the dataset)",
    )
    p.add_argument(
        "--shell-resolution",
        type=int,
        default=None,
        help="grid resolution of the shell extraction (default 256; 128 when --steps < 2000)",
    )
    p.add_argument(
        "--checkpoint-minutes",
        type=float,
        default=2.0,
        help="also write a checkpoint when this many minutes have passed since the last (default 2)",
    )
    p.add_argument("--table-size", type=int, default=None, help="log2 of the hash-table size (default 17)")
    p.add_argument(
        "--kernel-grid",
        type=int,
        default=None,
        help="nodes per axis of the grid that lets the kernel size vary in space on its own (default 64; 0: "
        "only the network's output, as in the paper)",
    )
    p.add_argument(
        "--sharpness",
        type=float,
        default=None,
        help="weight of the prior that makes the kernel sharp where the photos do not ask for a volume "
        "(default 0.001; 0: the paper's losses only)",
    )
    p.add_argument(
        "--view-encoding",
        choices=("reflected", "direction"),
        default=None,
        help="colour input: the view direction mirrored about the normal (default; glossy surfaces stay "
        "surfaces) or the view direction itself (the paper's)",
    )
    p.add_argument("--name", default=None, help="asset name (default: the output directory's name)")
    p.add_argument("--keep-checkpoints", action="store_true", help="keep OUT/checkpoints after success")
    p.add_argument("--device", default="auto", help="cpu, cuda or auto (default)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from neural.errors import InputError
    from neural.pipeline import PipelineConfig, parse_background, scaled_defaults, train_asset
    from shellsim.commands.args import device_option
    from shellsim.outputs import check_writable_dir

    config = PipelineConfig(background=parse_background(args.background), bound=args.bound)
    for flag, value in (
        ("--downscale", args.downscale),
        ("--steps", args.steps),
        ("--stage2-steps", args.stage2_steps),
        ("--shell-resolution", args.shell_resolution),
    ):
        if value is not None and value < 1:
            raise InputError(f"{flag}: expected a positive integer, got {value}")
    if args.kernel_grid is not None and args.kernel_grid not in range(2, 513) and args.kernel_grid != 0:
        raise InputError(f"--kernel-grid: expected 0 or an integer in 2..512, got {args.kernel_grid}")
    if args.sharpness is not None and not 0 <= args.sharpness < float("inf"):
        raise InputError(f"--sharpness: expected a number >= 0, got {args.sharpness}")
    if not 0 < args.checkpoint_minutes < float("inf"):
        raise InputError(f"--checkpoint-minutes: expected a positive number, got {args.checkpoint_minutes}")
    check_writable_dir(args.out, "--out")
    check_writable_dir(Path(args.out) / "checkpoints", "--out")
    config.downscale = args.downscale
    config.stage1.random_background = config.stage2.random_background = args.random_background
    config.stage1.checkpoint_seconds = config.stage2.checkpoint_seconds = 60.0 * args.checkpoint_minutes
    if args.steps is not None:
        config.stage1.steps = args.steps
    scaled = scaled_defaults(config.stage1.steps)
    config.stage1.target_samples = scaled["target_samples"]
    config.stage1.occupancy_resolution = scaled["occupancy_resolution"]
    config.stage2.steps = args.stage2_steps if args.stage2_steps is not None else scaled["stage2_steps"]
    config.shell.resolution = args.shell_resolution or scaled["shell_resolution"]
    if args.sharpness is not None:
        config.stage1.lambda_k = args.sharpness
    for name, value in (("kernel_grid", args.kernel_grid), ("view_encoding", args.view_encoding)):
        if value is not None:
            config.field = dataclasses.replace(config.field, **{name: value})
    if args.table_size is not None:
        grid = dataclasses.replace(config.field.hashgrid, log2_table_size=args.table_size)
        config.field = dataclasses.replace(config.field, hashgrid=grid)
    train_asset(
        args.data,
        args.out,
        config,
        device_option(args.device),
        name=args.name,
        keep_checkpoints=args.keep_checkpoints,
    )
