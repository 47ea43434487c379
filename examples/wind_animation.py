"""Wind animation of a neural asset (paper Sec. 5, Fig. 12 left): analytic wind on the cage, then a clip.

The asset's cage bends like a cantilever in a gusty wind (:mod:`shellsim.wind`); every frame is rendered by
deforming the adaptive shells with the cage and mapping each sample back to the rest space of the field
(:mod:`shellsim.render`), seen by a camera orbiting the asset. Writes ``OUT/wind.npz`` (the motion),
``OUT/frames/00000.png ...`` and ``OUT/wind.mp4``. Re-running continues: the motion is kept when it was
made with the same wind (else it is recomputed, with a log line saying what changed), and a frame in
``OUT/frames`` is kept only when it records the same motion frame, camera and size (else it is rendered
again).

    python examples/wind_animation.py                        # the shipped lego, 48 frames, 160x160
    python examples/wind_animation.py --asset PATH --frames 12 --size 96
    python examples/wind_animation.py --asset furry_bunny --anchor "z<10%"   # pedestal held, bunny sways
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from neural.asset import load_asset
from neural.errors import ShellsimError
from shellsim.cage import load_or_build_cage
from shellsim.motion import MotionWriter
from shellsim.render import render_motion
from shellsim.wind import WindSettings, animate_wind, motion_changes, wind_meta

log = logging.getLogger(__name__)


class Example:
    """Animate ``asset`` (name or directory) in the wind for ``frames`` frames at ``fps`` into ``out``."""

    def __init__(
        self,
        asset: str,
        out: Path,
        frames: int = 48,
        fps: float = 24.0,
        strength: float = 0.08,
        anchor: str | None = None,
    ):
        self.asset_spec = asset
        self.asset = load_asset(asset)
        self.cage = load_or_build_cage(self.asset)
        self.settings = WindSettings(
            up=tuple(self.asset.up), strength=strength, gust=0.4, frequency=0.8, anchor=anchor
        )
        self.frames, self.fps = frames, fps
        self.out = Path(out)
        self.motion_path = self.out / "wind.npz"

    def animate(self) -> None:
        """Write the motion file, continuing one made with the same wind, cage and at most ``frames``
        frames; one made otherwise is replaced, with a log line naming what changed."""
        meta = {**wind_meta(self.settings, self.fps), "asset": self.asset.name}
        writer = None
        if self.motion_path.is_file():
            old = MotionWriter.resume(self.motion_path)
            changes = motion_changes(old.motion, meta, self.cage.vertices, self.cage.tets)
            if old.n_frames > self.frames:
                changes.append(f"--frames: {old.n_frames} -> {self.frames}")
            if changes:
                log.info("replacing %s, made with other settings (%s)", self.motion_path, "; ".join(changes))
            else:
                writer = old
        if writer is None:
            writer = MotionWriter(self.motion_path, self.cage.vertices, self.cage.tets, meta)
        with writer:
            animate_wind(self.cage.vertices, self.cage.tets, self.settings, self.frames, self.fps, writer)

    def render(self, size: int, device: str) -> dict:
        """Render the clip with an orbiting camera; returns :func:`render_motion`'s summary."""
        return render_motion(
            self.asset_spec,
            self.motion_path,
            self.out / "frames",
            orbit=True,
            size=(size, size),
            video=self.out / "wind.mp4",
            device=device,
        )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--asset", default="lego", help="asset directory or shipped name (default lego)")
    parser.add_argument("--frames", type=int, default=48, help="frames of the clip (default 48)")
    parser.add_argument("--fps", type=float, default=24.0, help="frames per second (default 24)")
    parser.add_argument("--strength", type=float, default=0.08, help="mean tip deflection / height (0.08)")
    parser.add_argument(
        "--anchor",
        default=None,
        help='the cage nodes held still, "AXIS OP VALUE[%%]" as in shellsim wind (default: the lowest 5%%)',
    )
    parser.add_argument("--size", type=int, default=160, help="images are SIZE x SIZE (default 160)")
    parser.add_argument("--out", default="wind_animation", help="output directory (default wind_animation)")
    parser.add_argument("--device", default="auto", help="cpu, cuda or auto (default)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        example = Example(args.asset, Path(args.out), args.frames, args.fps, args.strength, args.anchor)
        example.animate()
        summary = example.render(args.size, args.device)
    except ShellsimError as err:
        raise SystemExit(f"wind_animation: error: {err}") from None
    print(
        f"{args.frames} frames in {example.out}: {summary['rendered']} rendered "
        f"({summary.get('ms', 0.0):.0f} ms/frame), video {summary['video']}"
    )


if __name__ == "__main__":
    main()
