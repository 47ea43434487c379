"""``shellsim render``: PNG frames (and an MP4) of an asset, at rest or moved by a motion file."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "render",
        help="render an asset at rest (every camera of a camera file) or a motion file (PNG frames, MP4)",
        description="Without --motion: render every camera of a transforms*.json-style camera file (its "
        "images may be absent) to OUT/<frame name>.png with narrow-band rendering (paper Sec. 3.4). With "
        "--motion: render each motion frame k, seen by the first camera of --cameras or by a camera "
        "orbiting the asset (--orbit), to OUT/<k:05d>.png, deforming the shells with the cage and mapping "
        "every sample back to rest space (paper Sec. 5). Each PNG records what made it (motion frame, "
        "camera, size, asset, renderer settings): one already in OUT is kept only when all of these match, "
        "so an interrupted render resumes, and rendered again otherwise; --overwrite renders all again.",
    )
    p.add_argument(
        "--asset",
        default=None,
        help="asset directory or shipped asset name; without it, --motion --orbit draws the surface the "
        "motion carries (e.g. from 'simulate --mesh') with pyvista",
    )
    p.add_argument(
        "--motion", default=None, help="motion file (.npz) from 'shellsim simulate' or 'shellsim wind'"
    )
    view = p.add_mutually_exclusive_group(required=True)
    view.add_argument(
        "--cameras",
        default=None,
        help="camera file or dataset directory, any format 'train --data' reads (NeRF-synthetic "
        "transforms_*.json, instant-ngp / nerfstudio transforms.json with fl_x fl_y cx cy k1 k2 p1 p2 w h); "
        "every listed frame is a camera, its image may be absent",
    )
    view.add_argument(
        "--orbit", action="store_true", help="with --motion: one camera revolution around the asset per clip"
    )
    p.add_argument("--out", required=True, help="directory of the PNG frames")
    p.add_argument(
        "--frames", default=None, help="with --motion: frames START:END (END exclusive), default all"
    )
    p.add_argument(
        "--width", type=int, default=None, help="image width (default: the camera file's; orbit 400)"
    )
    p.add_argument(
        "--height",
        type=int,
        default=None,
        help="image height (default: the camera file's, or the file's aspect ratio with --width alone; "
        "orbit: as --width); the file's pixel intrinsics are scaled to the size",
    )
    p.add_argument("--video", default=None, help="with --motion: also write the frames as this MP4")
    p.add_argument("--fps", type=float, default=None, help="video frame rate (default: the motion's)")
    p.add_argument("--overwrite", action="store_true", help="render frames already in OUT again")
    p.add_argument("--device", default="auto", help="cpu, cuda or auto (default)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    import math

    from neural.errors import InputError
    from shellsim.commands.args import device_option
    from shellsim.outputs import check_writable_dir, check_writable_file

    check_writable_dir(args.out, "--out")
    if args.video:
        check_writable_file(args.video, "--video")

    size = None
    if args.width is not None or args.height is not None:
        for flag in ("width", "height"):
            if getattr(args, flag) is not None and getattr(args, flag) < 1:
                raise InputError(f"--{flag}: expected a positive size, got {getattr(args, flag)}")
        size = (args.width, args.height)  # a missing one keeps the camera file's aspect ratio
        if args.orbit:
            size = (args.width or args.height, args.height or args.width)
    if args.motion is None:
        for flag in ("orbit", "frames", "video", "fps"):
            if getattr(args, flag) not in (None, False):
                raise InputError(f"--{flag} needs --motion (without it every camera is rendered at rest)")
    if args.fps is not None and not (args.fps > 0 and math.isfinite(args.fps)):
        raise InputError(f"--fps: expected a positive number, got {args.fps}")
    device = device_option(args.device) if args.asset is not None else None  # only the field needs one

    if args.motion is not None:
        from shellsim.motion import load_motion, parse_frames

        parse_frames(args.frames, load_motion(args.motion).n_frames, str(args.motion))
    # the heavy imports (torch, pyvista) come after the options are checked
    if args.asset is None:
        if args.motion is None or not args.orbit:
            raise InputError("--asset: needed, unless --motion and --orbit draw a motion's own surface")
        from shellsim.inspect import quiet_vtk
        from shellsim.surface import render_surface_motion

        if not args.verbose:
            quiet_vtk()
        summary = render_surface_motion(
            args.motion, args.out, args.frames, size, args.video, args.fps, args.overwrite
        )
    elif args.motion is None:
        from shellsim.render import render_views

        summary = render_views(args.asset, args.cameras, args.out, size, device, args.overwrite)
    else:
        from shellsim.render import render_motion

        summary = render_motion(
            args.asset,
            args.motion,
            args.out,
            cameras=args.cameras,
            orbit=args.orbit,
            frames=args.frames,
            size=size,
            video=args.video,
            fps=args.fps,
            device=device,
            overwrite=args.overwrite,
        )
    _report(summary)


def _report(summary: dict) -> None:
    line = f"{summary['rendered']} frames rendered to {summary['out']} ({summary['skipped']} already there"
    line += f", {summary['replaced']} replaced)" if summary["replaced"] else ")"
    if summary["rendered"] and "shade_ms" in summary:
        line += (
            f": {summary['ms']:.0f} ms/frame (deform + build {summary['build_ms']:.0f}, sample "
            f"{summary['sample_ms']:.0f}, inverse map {summary['map_ms']:.0f}, "
            f"field {summary['shade_ms']:.0f})"
        )
    elif summary["rendered"]:
        line += f": {summary['ms']:.0f} ms/frame"
    print(line)
    if "video" in summary:
        print(f"video: {summary['video']}")
