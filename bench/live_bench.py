"""Frames per second of live mode (:class:`shellsim.view.live.LiveShot`) with a poke held on each body.

Builds the live shot of ``--scene`` (its coarse cages are built by fTetWild once and cached), then for each
``--substeps`` count, each cap on ``--newton-iterations`` and each body: back to t = 0, ``--settle`` frames
(the bodies coming to rest), a poke on the body's highest display vertex pulled ``--pull`` metres sideways
and up (the cursor circling slowly, as a hand would), one frame to warm up, then ``--frames`` frames timed
(each with the body's display mesh interpolated). Prints one row per run (frames per second, ms per frame,
Newton iterations per substep, the largest force) and the cages' sizes.

    python bench/live_bench.py [--scene examples/scenes/lego_on_bunny.toml] [--frames 20] [--settle 15]
        [--substeps 2 1] [--newton-iterations 3 0]
"""

from __future__ import annotations

import argparse
import itertools
import logging
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's shellsim


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--scene", default="examples/scenes/lego_on_bunny.toml")
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--substeps", type=int, nargs="+", default=[2, 1], help="0: the scene's")
    parser.add_argument("--pull", type=float, default=0.05, help="the cursor's offset from the point [m]")
    parser.add_argument("--newton-iterations", type=int, nargs="+", default=[3, 0], help="0: the solver's")
    parser.add_argument("--settle", type=int, default=0, help="frames run before each poke")
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    logging.getLogger("warp").setLevel(logging.WARNING)

    import warp as wp

    wp.config.quiet = True
    from shellsim.shot.file import read_scene
    from shellsim.view.live import LiveShot

    spec = read_scene(args.scene)
    for substeps, newton in itertools.product(args.substeps, args.newton_iterations):
        start = time.perf_counter()
        shot = LiveShot(spec, substeps=substeps or None, newton_iterations=newton or None, device=args.device)
        built = time.perf_counter() - start
        sizes = ", ".join(f"{b.name} {len(b.tets)} tets" for b in shot.simulation.bodies)
        print(
            f"substeps {substeps or 'of the scene'}, Newton iterations at most "
            f"{newton or 'the solver default'}: live shot built in {built:.1f} s ({sizes})",
            flush=True,
        )
        for name in shot.names:
            shot.reset()
            for _ in range(args.settle):
                shot.step()
            vertices = shot.display_positions(name)
            point = vertices[np.argmax(vertices[:, 2])]
            shot.poke(name, point, point + (args.pull, 0.0, args.pull))
            shot.step()  # warm-up (kernels, factorisations)
            times, iterations, steps, largest, unconverged = [], 0, 0, 0.0, 0
            for k in range(args.frames):
                angle = 2 * math.pi * k / max(args.frames, 1)
                offset = args.pull * np.array([math.cos(angle), math.sin(angle), 1.0])
                shot.poke(name, point, point + offset)
                t0 = time.perf_counter()
                shot.step()
                shot.display_positions(name)
                times.append(time.perf_counter() - t0)
                iterations += shot.stats.newton_iterations
                steps += shot.stats.substeps
                unconverged += shot.stats.unconverged_substeps
                largest = max(largest, float(np.linalg.norm(shot.spring_force())))
            line = shot.spring()
            shot.release()
            per_frame = float(np.mean(times))
            print(
                f"  poke on {name:8s} ({shot.masses[shot.names.index(name)]:.3f} kg): "
                f"{1 / per_frame:5.1f} frames/s, {1e3 * per_frame:6.1f} ms per frame "
                f"(median {1e3 * float(np.median(times)):.1f}), {iterations / max(steps, 1):.2f} Newton "
                f"iterations per substep ({unconverged} substeps unconverged), largest force "
                f"{largest:.2f} N, spring {np.linalg.norm(np.subtract(*line)) * 100:.1f} cm",
                flush=True,
            )


if __name__ == "__main__":
    main()
