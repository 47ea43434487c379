"""Wind animation of a neural asset (paper Sec. 5, Fig. 12 left): analytic wind on the cage, then a clip.

The asset's cage bends like a cantilever in a gusty wind (:mod:`shellsim.jobs.wind`); every frame is rendered
by deforming the adaptive shells with the cage (:func:`shellsim.film.motion_frames.render_motion`), seen by a
fixed camera from the side (the sway crosses the image). Writes ``OUT/wind.npz`` (the motion),
``OUT/frames/00000.png ...`` and ``OUT/wind.mp4``. Re-running continues the motion when it was made with the
same wind (else it is refused, naming what changed, unless ``--overwrite``) and the render where it stopped.

    python examples/wind_animation.py                        # the shipped lego, 48 frames, 160x160
    python examples/wind_animation.py --asset PATH --frames 12 --size 96x64
    python examples/wind_animation.py --asset furry_bunny --anchor "z<10%"   # pedestal held, bunny sways
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from neural.device import configure_process
from neural.errors import ShellsimError
from shellsim.cli.options import options_named
from shellsim.film.cameras import CameraSettings
from shellsim.film.result import RenderResult
from shellsim.jobs.wind import WindSettings, wind
from shellsim.settings import pixels


def main(argv: list[str] | None = None) -> RenderResult:
    """Run the example; returns the render's result."""
    from shellsim.film.motion_frames import render_motion  # loads torch, after configure_process

    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--asset", default="lego", help="asset directory or shipped name (default lego)")
    parser.add_argument("--frames", type=int, default=48, help="frames of the clip (default 48)")
    parser.add_argument("--fps", type=float, default=24.0, help="frames per second (default 24)")
    parser.add_argument("--strength", type=float, default=0.08, help="mean tip deflection / height (0.08)")
    parser.add_argument(
        "--anchor", help='the cage nodes held still, "AXIS OP VALUE[%%]" (default: the lowest 5%%)'
    )
    parser.add_argument(
        "--size", type=pixels, default=(512, 512), metavar="WxH", help="frames in pixels (default 512x512)"
    )
    parser.add_argument("--out", default="wind_animation", help="output directory (default wind_animation)")
    parser.add_argument("--overwrite", action="store_true", help="make the motion anew")
    parser.add_argument("--device", default="auto", help="cpu, cuda or auto (default)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    out = Path(args.out)
    settings = dict(strength=args.strength, gust=0.4, frequency=0.8, anchor=args.anchor)
    try:
        with options_named(WindSettings):  # setting errors name the options of this script
            result = wind(
                WindSettings(
                    asset=args.asset,
                    frames=args.frames,
                    fps=args.fps,
                    out=str(out / "wind.npz"),
                    overwrite=args.overwrite,
                    **settings,
                )
            )
        rendered = render_motion(
            args.asset,
            result.out,
            out / "frames",
            camera=CameraSettings(camera="side"),
            size=args.size,
            video=out / "wind.mp4",
            device=args.device,
        )
    except ShellsimError as err:
        raise SystemExit(f"wind_animation: error: {err}") from None
    print(f"{result.frames} frames in {out}: {rendered.rendered} rendered, video {rendered.video}")
    return rendered


if __name__ == "__main__":
    configure_process()
    main()
