"""Drop a neural asset on the ground (paper Sec. 5, Fig. 12 right): elastic FEM on the cage, then a clip.

The asset's cage, scaled so that its largest extent measures ``--meters``, falls ``--drop-height`` metres
onto a ground plane as a hyperelastic body (:mod:`shellsim.jobs.simulate`); every frame is rendered by
deforming the adaptive shells with the cage, seen by a camera orbiting the motion (the ground itself is not
drawn). Writes ``OUT/drop.npz`` (the motion), ``OUT/drop_frames/00000.png ...`` and ``OUT/drop.mp4``.
Re-running continues the simulation (refused, naming what changed, when it was made with other settings)
and the render where they stopped.

    python examples/drop_on_ground.py                          # the shipped lego, rubber, 45 frames
    python examples/drop_on_ground.py --asset PATH --frames 10 --size 96x64 --material foam
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from neural.device import configure_process
from neural.errors import ShellsimError
from shellsim.film.result import RenderResult
from shellsim.jobs.simulate import SimulateSettings, simulate
from shellsim.settings import pixels


def main(argv: list[str] | None = None) -> RenderResult:
    """Run the example; returns the render's result."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--asset", default="lego", help="asset directory or shipped name (default lego)")
    parser.add_argument("--frames", type=int, default=45, help="frames of the clip (default 45)")
    parser.add_argument("--material", default="rubber", help="material preset (default rubber)")
    parser.add_argument("--meters", type=float, default=0.3, help="physical size of the asset (default 0.3)")
    parser.add_argument(
        "--drop-height", type=float, default=0.1, help="metres above the ground (default 0.1)"
    )
    parser.add_argument(
        "--size", type=pixels, default=(512, 512), metavar="WxH", help="frames in pixels (default 512x512)"
    )
    parser.add_argument("--out", default="drop_on_ground", help="output directory (default drop_on_ground)")
    parser.add_argument("--device", default="auto", help="cpu, cuda or auto (default)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    out = Path(args.out)
    try:
        result = simulate(
            SimulateSettings(
                asset=args.asset,
                material=args.material,
                size=args.meters,
                drop_height=args.drop_height,
                damping=0.002,
                frames=args.frames,
                out=str(out / "drop.npz"),
                video=str(out / "drop.mp4"),
                video_size=args.size,
                device=args.device,
            )
        )
    except ShellsimError as err:
        raise SystemExit(f"drop_on_ground: error: {err}") from None
    print(f"{result.frames} frames in {out}: {result.video.rendered} rendered, video {result.video.video}")
    return result.video


if __name__ == "__main__":
    configure_process()
    main()
