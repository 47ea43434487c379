"""Time writing a motion of the LEGO cage: 500, 1000 and 2000 frames, flushed every ``--every`` frames.

The shipped LEGO's cage (``neural.asset.load_asset('lego')`` + :func:`shellsim.cage.store.load_or_build_cage`)
moved to random positions; a flush every few frames is what a producer slower than the writer's
``flush_seconds`` per few frames gets (the simulator on the LEGO). Cost linear in the frame count shows as
seconds doubling with the frames; quadratic as quadrupling. Runs against either motion writer (format 1,
which rewrote the file at each flush, or format 2, which appends a chunk):

    python bench/motion_write_bench.py                 # this tree
    PYTHONPATH=/tmp/old python bench/motion_write_bench.py   # another tree
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from neural.asset import load_asset
from shellsim.cage.store import load_or_build_cage
from shellsim.motion.format import MotionWriter, load_motion


def write(path: Path, rest: np.ndarray, tets: np.ndarray, frames: int, every: int, seed: int = 0):
    """Seconds to append ``frames`` random frames of the cage (V, 3), flushing every ``every`` frames, and
    seconds to close the writer (format 2 merges its chunks then)."""
    rng = np.random.default_rng(seed)
    positions = (rest + rng.normal(scale=0.01, size=(every, *rest.shape))).astype(np.float32)
    start = time.perf_counter()
    writer = MotionWriter(path, rest, tets, {"bench": True}, flush_seconds=float("inf"))
    for k in range(frames):
        writer.append(positions[k % every], k / 30.0)
        if (k + 1) % every == 0:
            writer.flush()
    appended = time.perf_counter()
    writer.close()
    return appended - start, time.perf_counter() - appended


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--frames", default="500,1000,2000", help="frame counts (default 500,1000,2000)")
    parser.add_argument("--every", type=int, default=10, help="frames per flush (default 10)")
    args = parser.parse_args()
    cage = load_or_build_cage(load_asset("lego"))
    print(
        f"LEGO cage: {len(cage.vertices)} vertices, {len(cage.tets)} tets; a flush every {args.every} frames"
    )
    with tempfile.TemporaryDirectory() as tmp:
        for n in (int(f) for f in args.frames.split(",")):
            path = Path(tmp) / f"m{n}.npz"
            appending, closing = write(path, cage.vertices, cage.tets, n, args.every)
            assert load_motion(path).n_frames == n
            total = appending + closing
            print(
                f"{n:6d} frames: {total:7.2f} s ({1e3 * total / n:.2f} ms/frame; appending "
                f"{appending:.2f} s, closing {closing:.2f} s), file {path.stat().st_size / 1e6:.1f} MB"
            )


if __name__ == "__main__":
    main()
