"""``shellsim inspect``: view an asset's shells, cage and a motion's frames, or render the view to a PNG."""

from __future__ import annotations

import argparse
import logging

log = logging.getLogger(__name__)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "inspect",
        help="view an asset's shells and cage (and a motion's frames) with pyvista, or save a PNG",
        description="Show the outer shell M+ (translucent, coloured by the shell width or the field's kernel "
        "size), the inner shell M- and the cage as a wireframe. With --motion, a slider moves the cage and "
        "the shells through the frames. --screenshot renders the same view off-screen (no display needed).",
    )
    p.add_argument("--asset", required=True, help="asset directory or shipped asset name")
    p.add_argument("--motion", default=None, help="motion file (.npz) of the asset's cage")
    p.add_argument(
        "--frame",
        type=int,
        default=None,
        help="frame of the motion to show first (negative counts from the end)",
    )
    p.add_argument(
        "--color",
        choices=("width", "kernel"),
        default="width",
        help="colour M+ by the shell width (distance to M-, default) or the field's kernel size s",
    )
    p.add_argument(
        "--screenshot", default=None, metavar="OUT.png", help="render off-screen to this PNG and exit"
    )
    p.add_argument(
        "--size", default="1024x768", metavar="WxH", help="window or image size (default 1024x768)"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from neural.asset import load_asset
    from neural.errors import InputError
    from shellsim.cage import load_or_build_cage
    from shellsim.commands.args import parse_size
    from shellsim.commands.outputs import check_writable_file
    from shellsim.inspect import check_motion, screenshot, show
    from shellsim.motion import load_motion

    size = parse_size("--size", args.size)
    if args.screenshot:
        check_writable_file(args.screenshot, "--screenshot")
    asset = load_asset(args.asset)
    motion = load_motion(args.motion) if args.motion else None
    frame = 0 if args.frame is None else args.frame
    if motion is None and args.frame is not None:
        raise InputError("--frame: needs --motion")
    if motion is not None and not -motion.n_frames <= frame < motion.n_frames:
        raise InputError(f"--frame: {args.motion} has frames 0..{motion.n_frames - 1}, got {frame}")
    cage = load_or_build_cage(asset)
    if motion is not None:
        check_motion(motion, cage, args.motion)
    if args.screenshot:
        path = screenshot(asset, cage, args.screenshot, motion, frame, args.color, size)
        log.info("wrote %s", path)
    else:
        show(asset, cage, motion, frame, args.color, size)
