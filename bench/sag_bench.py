"""The sag said before simulating against the sag of a settled run: a body set on the ground as one material
with several Young's moduli, each settled (``[world] settle``) and then simulated for a few frames.

Prints, per modulus: the standing column's estimate (:func:`shellsim.physics.sag.column_sag`, as the scene's
warning computes it) and the settled sag (the drop of the top of the visible surface at frame 0 and at the
last frame, both as a share of its height), their ratio, and whether the warning fired.

    python bench/sag_bench.py --asset furry_bunny --material jelly --youngs 1e4 2e4 4e4 1e5 --out /tmp/sag
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np

from neural.device import configure_process
from shellsim.jobs.scene import SceneSettings, scene
from shellsim.motion.read import load_motion
from shellsim.physics.materials import get_material
from shellsim.physics.sag import column_sag
from shellsim.shot.bodies import build_body, lowest_start
from shellsim.shot.file import read_scene

SCENE = """
[world]
fps = 30
frames = {frames}
substeps = 4
settle = {settle}

[[body]]
name = "body"
asset = "{asset}"
size = {size}
material = "{material}"
youngs = {youngs}
"""


class _Warnings(logging.Handler):
    def __init__(self):
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record):
        self.messages.append(record.getMessage())


def visible_heights(motion) -> tuple[float, float, np.ndarray]:
    """(top [m], height [m], top of each frame (F,) [m]) of the visible surface at rest and in the frames."""
    s = motion.surface
    rest = np.einsum("sk,skd->sd", s.bary, motion.rest_vertices[motion.tets[s.tet]])
    tops = np.array([motion.surface_points(k)[:, 2].max() for k in range(motion.n_frames)])
    return float(rest[:, 2].max()), float(np.ptp(rest[:, 2])), tops


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--asset", default="furry_bunny")
    parser.add_argument("--material", default="jelly")
    parser.add_argument("--size", type=float, default=0.3, help="[m] the body's largest extent")
    parser.add_argument("--youngs", type=float, nargs="+", default=[1e4, 2e4, 4e4, 1e5])
    parser.add_argument("--settle", type=float, default=1.0, help="[s]")
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--out", default="sag_bench")
    args = parser.parse_args()
    configure_process()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    warnings = _Warnings()
    logging.getLogger("shellsim.shot.simulation").addHandler(warnings)
    print("youngs [Pa]  estimate  settled (frame 0)  settled (last)  ratio  warned")
    for youngs in args.youngs:
        path = out / f"{args.asset}_{youngs:g}.toml"
        path.write_text(
            SCENE.format(
                frames=args.frames,
                settle=args.settle,
                asset=args.asset,
                size=args.size,
                material=args.material,
                youngs=youngs,
            )
        )
        spec = read_scene(path)
        body = build_body(spec.bodies[0], lowest_start(spec.world))
        material = get_material(args.material, youngs)
        surface = body.surface_world
        height = float(np.ptp(surface[:, 2]))
        estimate = column_sag(
            body.rest, body.tets, material.density, youngs, spec.world.gravity, base=surface[:, 2].min()
        )
        warnings.messages.clear()
        result = scene(SceneSettings(scene=str(path), out=str(path.with_suffix(""))), progress=False)
        top, rest_height, tops = visible_heights(load_motion(result.out))
        first, last = (top - tops[0]) / rest_height, (top - tops[-1]) / rest_height
        print(
            f"{youngs:11g}  {100 * estimate / height:7.1f}%  {100 * first:16.1f}%  {100 * last:13.1f}%  "
            f"{first / (estimate / height):5.2f}  {'yes' if warnings.messages else 'no'}"
        )


if __name__ == "__main__":
    main()
