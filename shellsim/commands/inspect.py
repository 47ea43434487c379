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
        "the shells through the frames. A --motion without --asset (e.g. from 'simulate --mesh') shows the "
        "surface it carries (else its cage's boundary). --screenshot renders the same view off-screen (no "
        "display needed).",
    )
    p.add_argument("--asset", default=None, help="asset directory or shipped asset name")
    p.add_argument(
        "--motion", default=None, help="motion file (.npz) of the asset's cage, or of a mesh without --asset"
    )
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
    from pathlib import Path

    from neural.errors import InputError
    from shellsim.commands.args import parse_size
    from shellsim.motion import load_motion
    from shellsim.outputs import check_writable_file

    size = parse_size("--size", args.size)
    if args.asset is None and args.motion is None:
        raise InputError("give --asset (its shells and cage), --motion (a motion's surface) or both")
    if args.motion is None and args.frame is not None:
        raise InputError("--frame: needs --motion")
    if args.asset is None and args.color != "width":
        raise InputError("--color: colours an asset's shell; it needs --asset")
    if args.screenshot is not None:
        shot = Path(args.screenshot)
        if shot.suffix.lower() != ".png":
            raise InputError(f"--screenshot {shot}: screenshots are written as PNG; give a name ending .png")
        check_writable_file(shot, "--screenshot")
        if not shot.parent.is_dir():
            raise InputError(f"--screenshot {shot}: directory {shot.parent} does not exist")
    motion = load_motion(args.motion) if args.motion else None
    frame = 0 if args.frame is None else args.frame
    if motion is not None and not -motion.n_frames <= frame < motion.n_frames:
        raise InputError(f"--frame: {args.motion} has frames 0..{motion.n_frames - 1}, got {frame}")

    from shellsim import inspect

    if not args.verbose:
        inspect.quiet_vtk()
    if not args.screenshot:
        inspect.check_display()
    if args.asset is None:
        from shellsim.surface import surface_plotter

        def plotter(off_screen, slider):
            return surface_plotter(motion, frame, size, off_screen=off_screen, slider=slider)
    else:
        from neural.asset import load_asset
        from shellsim.cage import cage_for_motion, load_or_build_cage

        asset = load_asset(args.asset)
        cage = load_or_build_cage(asset) if motion is None else cage_for_motion(asset, motion, args.motion)

        def plotter(off_screen, slider):
            return inspect.make_plotter(
                asset, cage, motion, frame, args.color, size, off_screen=off_screen, slider=slider
            )

    if args.screenshot:
        log.info("wrote %s", inspect.save_screenshot(plotter(True, False), args.screenshot))
    else:
        inspect.show_plotter(plotter(None, True))
