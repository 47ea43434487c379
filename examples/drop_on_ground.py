"""Drop a neural asset on the ground (paper Sec. 5, Fig. 12 right): elastic FEM on the cage, then a clip.

The asset's cage, scaled so that its largest extent measures ``--meters``, falls ``--drop-height`` metres
onto a ground plane under gravity (along the asset's down axis) as a hyperelastic body
(:mod:`shellsim.fem`, stable Neo-Hookean, backward Euler, penalty contact with friction); every frame is
rendered by deforming the adaptive shells with the cage and mapping each sample back to the rest space
of the field (:mod:`shellsim.render`), seen by a camera orbiting the motion's bounding box (the ground
itself is not drawn). Writes ``OUT/drop.npz`` (the motion), ``OUT/frames/00000.png ...`` and
``OUT/drop.mp4``. Re-running continues the simulation (refused, naming what changed, when it was made with
other settings) and the render where they stopped (a frame is kept only when it records the same motion
frame, camera and size).

    python examples/drop_on_ground.py                          # the shipped lego, rubber, 45 frames
    python examples/drop_on_ground.py --asset PATH --frames 10 --size 96 --material foam
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np

from neural.asset import load_asset
from neural.device import pick_device, warp_device
from neural.errors import InputError, ShellsimError
from shellsim.cage import load_or_build_cage
from shellsim.fem import SimSettings, Simulator, WorldMap, restore_state, simulate
from shellsim.materials import PRESETS, get_material
from shellsim.motion import MotionWriter, describe_changes
from shellsim.render import render_motion


class Example:
    """Drop ``asset`` (name or directory) made of ``material`` from ``drop_height`` metres; motion in ``out``.

    State: the :class:`shellsim.fem.Simulator` and the motion writer (fresh, or resumed from ``out``).
    """

    def __init__(
        self,
        asset: str,
        out: Path,
        material: str = "rubber",
        meters: float = 0.3,
        drop_height: float = 0.1,
        fps: float = 30.0,
        device: str | None = None,
    ):
        self.asset_spec = asset
        self.asset = load_asset(asset)
        cage = load_or_build_cage(self.asset)
        self.out = Path(out)
        self.motion_path = self.out / "drop.npz"
        self.world = WorldMap.fit(cage.vertices, meters)
        up = self.asset.up / np.linalg.norm(self.asset.up)
        rest = self.world.to_sim(cage.vertices)
        settings = SimSettings(
            dt=1.0 / fps, up=tuple(up), ground=float((rest @ up).min() - drop_height), damping=0.002
        )
        self.sim = Simulator(rest, cage.tets, get_material(material), settings, device=device)
        meta = {
            "producer": "examples/drop_on_ground.py",
            "material": material,
            "fps": fps,
            "world": {"origin": list(self.world.origin), "scale": self.world.scale},
            "settings": settings.as_dict(),
        }
        if self.motion_path.is_file():
            self.writer = MotionWriter.resume(self.motion_path)
            stored = self.writer.motion.meta
            changes = describe_changes({k: stored.get(k) for k in meta}, meta, {"world.scale": "--meters"})
            if changes:
                raise InputError(
                    f"{self.motion_path}: made with other settings ({'; '.join(changes)}); use another --out "
                    "or delete it"
                )
            restore_state(self.sim, self.writer, self.world)
        else:
            self.writer = MotionWriter(self.motion_path, cage.vertices, cage.tets, meta)

    def step(self, frames: int) -> None:
        """Simulate until the motion has ``frames`` frames (frame 0 is the initial state)."""
        with self.writer:
            simulate(self.sim, max(frames - max(self.writer.n_frames, 1), 0), self.writer, self.world)

    def render(self, size: int, device: str) -> dict:
        """Render the clip with an orbiting camera; returns :func:`render_motion`'s summary."""
        return render_motion(
            self.asset_spec,
            self.motion_path,
            self.out / "frames",
            orbit=True,
            size=(size, size),
            video=self.out / "drop.mp4",
            device=device,
        )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--asset", default="lego", help="asset directory or shipped name (default lego)")
    parser.add_argument("--frames", type=int, default=45, help="frames of the clip (default 45)")
    parser.add_argument("--material", default="rubber", help=f"one of {', '.join(PRESETS)} (default rubber)")
    parser.add_argument("--meters", type=float, default=0.3, help="physical size of the asset (default 0.3)")
    parser.add_argument(
        "--drop-height", type=float, default=0.1, help="metres above the ground (default 0.1)"
    )
    parser.add_argument("--size", type=int, default=160, help="images are SIZE x SIZE (default 160)")
    parser.add_argument("--out", default="drop_on_ground", help="output directory (default drop_on_ground)")
    parser.add_argument("--device", default="auto", help="cpu, cuda or auto (default)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        device = pick_device(args.device)
        example = Example(
            args.asset,
            Path(args.out),
            args.material,
            args.meters,
            args.drop_height,
            device=warp_device(device),
        )
        example.step(args.frames)
        summary = example.render(args.size, device)
    except ShellsimError as err:
        raise SystemExit(f"drop_on_ground: error: {err}") from None
    print(
        f"{args.frames} frames in {example.out}: {summary['rendered']} rendered "
        f"({summary.get('ms', 0.0):.0f} ms/frame), video {summary['video']}"
    )


if __name__ == "__main__":
    main()
