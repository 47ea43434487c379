"""``shellsim wind``: animate an asset's cage with the analytic wind of :mod:`shellsim.wind`."""

from __future__ import annotations

import argparse
import logging

log = logging.getLogger(__name__)


def register(sub: argparse._SubParsersAction) -> None:
    from shellsim.commands.args import add_resume_options
    from shellsim.wind import WindSettings as W  # numpy only: cheap to import

    p = sub.add_parser(
        "wind",
        help="animate an asset's cage in an analytic wind; writes a motion file",
        description="Bend the asset's cage like a cantilever anchored at its base, in a wind with gusts and "
        "travelling turbulence. Writes the same motion file as 'shellsim simulate' (render it with "
        "'shellsim render'). Interrupt at any time: run again, and an OUT made with the same settings is "
        "continued; one made with other settings is refused unless --overwrite.",
    )
    p.add_argument("--asset", required=True, help="asset directory or shipped asset name")
    p.add_argument(
        "--frames", type=int, default=120, help="number of frames, the first at rest (default 120)"
    )
    p.add_argument("--fps", type=float, default=30.0, help="frames per second (default 30)")
    p.add_argument(
        "--strength",
        type=float,
        default=None,
        help=f"mean tip deflection / height, 0-1 (default {W.strength})",
    )
    p.add_argument(
        "--direction",
        default=None,
        help=f"wind direction x,y,z (default {','.join(f'{c:g}' for c in W.direction)})",
    )
    p.add_argument(
        "--gust", type=float, default=None, help=f"relative gust amplitude, 0-1 (default {W.gust})"
    )
    p.add_argument(
        "--frequency",
        type=float,
        default=None,
        help=f"gust frequency in Hz, at most fps / 6 (default {W.frequency})",
    )
    p.add_argument(
        "--turbulence",
        type=float,
        default=None,
        help=f"relative turbulence amplitude, 0-1 (default {W.turbulence})",
    )
    p.add_argument(
        "--anchor",
        default=None,
        help="fixed vertices as AXIS OP VALUE in world units or in %% of the cage's extent, as for "
        "'simulate --pin': 'z<0.05', 'z<5%%', 'y>0.9' (default: the lowest "
        f"{100 * W.base_fraction:g}%% of the cage along the asset's up axis)",
    )
    p.add_argument("--seed", type=int, default=None, help=f"turbulence seed (default {W.seed})")
    p.add_argument(
        "--margin",
        type=float,
        default=None,
        help="dilation of the outer shell when the cage is built, relative to its diagonal (default 0.02)",
    )
    p.add_argument("--out", default=None, help="motion file to write (default ASSETNAME_wind.npz)")
    add_resume_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from pathlib import Path

    from neural.asset import load_asset
    from neural.errors import InputError
    from shellsim.cage import CageConfig, load_or_build_cage
    from shellsim.commands.args import MAX_FPS, MAX_FRAMES, check_range, parse_floats
    from shellsim.motion import MotionWriter
    from shellsim.outputs import check_writable_file
    from shellsim.selection import parse_selection
    from shellsim.wind import RANGES, WindSettings, animate_wind, max_frequency, wind_meta

    check_range("--frames", args.frames, 1, MAX_FRAMES, "an integer")
    check_range("--fps", args.fps, 0, MAX_FPS, "a number of frames per second", "(]")
    for name, what in (
        ("strength", "a tip deflection / height"),
        ("gust", "a relative amplitude"),
        ("turbulence", "a relative amplitude"),
        ("seed", "an integer"),
    ):
        if getattr(args, name) is not None:
            check_range(f"--{name}", getattr(args, name), *RANGES[name], what)
    frequency = WindSettings.frequency if args.frequency is None else args.frequency
    low, high = RANGES["frequency"]
    if not low <= frequency <= min(high, max_frequency(args.fps)):  # faster turbulence aliases
        raise InputError(
            f"--frequency: expected a number of Hz in [{low:g}, {high:g}] and at most "
            f"{max_frequency(args.fps):.4g} (--fps / {args.fps / max_frequency(args.fps):g}: faster "
            f"turbulence would alias), got {frequency:g}"
        )
    if args.margin is not None:
        check_range("--margin", args.margin, 0, 1, "a fraction of the shell's diagonal", "(]")
    if args.anchor is not None:
        parse_selection(args.anchor, "--anchor")
    asset = load_asset(args.asset)
    options = {
        "strength": args.strength,
        "gust": args.gust,
        "frequency": args.frequency,
        "turbulence": args.turbulence,
        "anchor": args.anchor,
        "seed": args.seed,
    }
    if args.direction is not None:
        options["direction"] = parse_floats("--direction", args.direction, 3)  # WindSettings rejects 0,0,0
    settings = WindSettings(up=tuple(asset.up), **{k: v for k, v in options.items() if v is not None})
    out = check_writable_file(Path(args.out) if args.out else Path(f"{asset.name}_wind.npz"), "--out")
    # the stored cage whatever its settings (unless --margin asks for another), else a default one
    cage = load_or_build_cage(asset, None if args.margin is None else CageConfig(margin=args.margin))
    meta = {**wind_meta(settings, args.fps), "asset": asset.name}
    if out.is_file() and not args.overwrite:
        writer = _reopen(out, meta, cage)
    else:
        if out.exists():
            log.info("--overwrite: replacing %s", out)
        elif args.resume:
            log.info("%s does not exist: nothing to resume, starting it", out)
        writer = MotionWriter(out, cage.vertices, cage.tets, meta)
    with writer:
        animate_wind(cage.vertices, cage.tets, settings, args.frames, args.fps, writer)
    stats = writer.motion.meta.get("stats", {})
    log.info(
        "wrote %d frames to %s (smallest tet volume ratio %.3g)",
        writer.n_frames,
        out,
        stats.get("min_volume_ratio", 1.0),
    )


def _reopen(out, meta: dict, cage):
    """A :class:`MotionWriter` continuing the wind motion ``out`` when it was made with ``meta``'s settings
    of this ``cage``; else an InputError listing what differs (old -> new) and how to start anew."""
    from neural.errors import InputError
    from shellsim.motion import MotionWriter
    from shellsim.wind import motion_changes

    replace = "give --overwrite to start it anew, or another --out"
    writer = MotionWriter.resume(out)  # not a motion file: refused as it is, never replaced
    if "settings" not in writer.motion.meta:
        raise InputError(f"{out}: not a 'shellsim wind' motion file; {replace}")
    changes = motion_changes(writer.motion, meta, cage.vertices, cage.tets)
    if changes:
        raise InputError(f"{out}: made with other settings ({'; '.join(changes)}); {replace}")
    log.info("continuing %s after frame %d", out, writer.n_frames - 1)
    return writer
