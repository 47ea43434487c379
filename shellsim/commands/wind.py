"""``shellsim wind``: animate an asset's cage with the analytic wind of :mod:`shellsim.wind`."""

from __future__ import annotations

import argparse
import logging

log = logging.getLogger(__name__)


def register(sub: argparse._SubParsersAction) -> None:
    from shellsim.wind import WindSettings as W  # numpy only: cheap to import

    p = sub.add_parser(
        "wind",
        help="animate an asset's cage in an analytic wind; writes a motion file",
        description="Bend the asset's cage like a cantilever anchored at its base, in a wind with gusts and "
        "travelling turbulence. Writes the same motion file as 'shellsim simulate' (render it with "
        "'shellsim render'). Interrupt at any time; --resume continues a file.",
    )
    p.add_argument("--asset", required=True, help="asset directory or shipped asset name")
    p.add_argument(
        "--frames", type=int, default=120, help="number of frames, the first at rest (default 120)"
    )
    p.add_argument("--fps", type=float, default=30.0, help="frames per second (default 30)")
    p.add_argument(
        "--strength", type=float, default=None, help=f"mean tip deflection / height (default {W.strength})"
    )
    p.add_argument(
        "--direction",
        default=None,
        help=f"wind direction x,y,z (default {','.join(f'{c:g}' for c in W.direction)})",
    )
    p.add_argument("--gust", type=float, default=None, help=f"relative gust amplitude (default {W.gust})")
    p.add_argument(
        "--frequency", type=float, default=None, help=f"gust frequency in Hz (default {W.frequency})"
    )
    p.add_argument(
        "--turbulence",
        type=float,
        default=None,
        help=f"relative turbulence amplitude (default {W.turbulence})",
    )
    p.add_argument(
        "--anchor",
        default=None,
        help="fixed vertices as AXIS<VALUE or AXIS>VALUE in world units, e.g. 'z<0.05' "
        f"(default: the lowest {100 * W.base_fraction:g}%% of the cage along the asset's up axis)",
    )
    p.add_argument("--seed", type=int, default=None, help=f"turbulence seed (default {W.seed})")
    p.add_argument("--out", default=None, help="motion file to write (default ASSETNAME_wind.npz)")
    p.add_argument("--resume", action="store_true", help="continue OUT after its last frame")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from pathlib import Path

    from neural.asset import load_asset
    from neural.errors import InputError
    from shellsim.cage import load_or_build_cage
    from shellsim.commands.args import parse_floats
    from shellsim.commands.outputs import check_writable_file
    from shellsim.motion import MotionWriter
    from shellsim.wind import WindSettings, animate_wind, wind_meta

    if args.frames < 1:
        raise InputError(f"--frames: expected a positive integer, got {args.frames}")
    if not 0 < args.fps < float("inf"):
        raise InputError(f"--fps: expected a positive number, got {args.fps}")
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
    cage = load_or_build_cage(asset)  # the stored cage whatever its settings, else a default one
    if args.resume and out.is_file():
        writer = MotionWriter.resume(out)
        log.info("resuming %s after frame %d", out, writer.n_frames - 1)
    else:
        if out.exists():
            log.info("overwriting %s", out)
        meta = {**wind_meta(settings, args.fps), "asset": asset.name}
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
