"""Time writing and reading a motion of the LEGO cage (format 3: a log while written, an npz once closed).

The shipped LEGO's cage (``assets/lego/cage.npz``) moved to random positions. Writing:
500, 1,000, 2,000 and 4,000 frames appended with a flush every ``--every`` frames (what the simulator gets
on the LEGO: its frames come slower than the writer's ``flush_seconds``), appending (the log's chunks, each
fsynced) and closing (the npz published from the log) timed apart: a cost linear in the frame count shows
as seconds doubling with the frames, a quadratic one as quadrupling. Reading: a 10-frame range of the
2,000-frame motion (:func:`shellsim.motion.read.read_frames`), from the finished npz and from the log of a
run in progress, against reading all of it (:func:`shellsim.motion.read.load_motion`). Each time is the
best of ``--repeat`` runs; files go to a temporary directory (``--dir`` picks its parent: a disk, not a
tmpfs, to time the fsyncs).

    python bench/motion_write_bench.py
    python bench/motion_write_bench.py --frames 500,1000 --every 5 --dir /var/tmp
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from shellsim.motion.log import partial_path
from shellsim.motion.read import load_motion, read_frames
from shellsim.motion.writer import MotionWriter

CAGE = Path(__file__).resolve().parents[1] / "assets" / "lego" / "cage.npz"


def write(path: Path, rest: np.ndarray, tets: np.ndarray, frames: int, every: int, close: bool = True):
    """Seconds to append ``frames`` random frames of the cage (V, 3) with the state the simulator keeps
    (velocities), flushing every ``every`` frames, and seconds to close the writer (0 without ``close``:
    the log is left as a run in progress leaves it)."""
    rng = np.random.default_rng(0)
    positions = (rest + rng.normal(scale=0.01, size=(every, *rest.shape))).astype(np.float32)
    velocities = np.zeros_like(rest)
    start = time.perf_counter()
    writer = MotionWriter(path, rest, tets, {"bench": True}, flush_seconds=float("inf"))
    for k in range(frames):
        writer.append(positions[k % every], k / 30.0, {"velocities": velocities})
        if (k + 1) % every == 0:
            writer.flush()
    writer.flush()
    appended = time.perf_counter()
    if close:
        writer.close()
    return appended - start, time.perf_counter() - appended


def best(repeat: int, run) -> float:
    """The least of ``repeat`` timings of ``run()`` in seconds."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--frames", default="500,1000,2000,4000", help="frame counts (default 500,1000,2000,4000)"
    )
    parser.add_argument("--every", type=int, default=10, help="frames per flush (default 10)")
    parser.add_argument(
        "--read-frames", type=int, default=2000, help="frames of the motion read (default 2000)"
    )
    parser.add_argument("--repeat", type=int, default=3, help="runs per timing, the best kept (default 3)")
    parser.add_argument(
        "--dir", default=None, help="parent of the temporary directory (default the system's)"
    )
    args = parser.parse_args()
    with np.load(CAGE) as cage:
        rest, tets = cage["vertices"], cage["tets"]
    print(f"LEGO cage: {len(rest)} vertices, {len(tets)} tets; a flush every {args.every} frames")
    print()
    print("| frames | append (s) | ms / frame | close (s) | ms / frame | file (MB) |")
    print("| ---: | ---: | ---: | ---: | ---: | ---: |")
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        for n in (int(f) for f in args.frames.split(",")):
            path = Path(tmp) / f"m{n}.npz"
            timings = [write(path, rest, tets, n, args.every) for _ in range(args.repeat)]
            appending, closing = min(t[0] for t in timings), min(t[1] for t in timings)
            assert load_motion(path).n_frames == n and not partial_path(path).exists()
            print(
                f"| {n:,} | {appending:.2f} | {1e3 * appending / n:.2f} | {closing:.2f} | "
                f"{1e3 * closing / n:.2f} | {path.stat().st_size / 1e6:.1f} |"
            )
            path.unlink()

        n = args.read_frames
        finished, running = Path(tmp) / "finished.npz", Path(tmp) / "running.npz"
        write(finished, rest, tets, n, args.every)
        write(running, rest, tets, n, args.every, close=False)
        middle = np.arange(n // 2, n // 2 + 10)
        print()
        print(f"| reading, of {n:,} frames | finished npz (ms) | log of a run in progress (ms) |")
        print("| --- | ---: | ---: |")
        for what, run in (
            ("10 frames (read_frames)", lambda p: read_frames(p, middle)),
            ("all (load_motion)", load_motion),
        ):
            times = [1e3 * best(args.repeat, lambda p=p, run=run: run(p)) for p in (finished, running)]
            print(f"| {what} | {times[0]:.1f} | {times[1]:.1f} |")


if __name__ == "__main__":
    main()
