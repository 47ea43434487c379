"""Serial vs Ray: the same orbit frames of a wind motion rendered both ways in one run, with wall times and a
byte-for-byte comparison of the PNGs.

The serial path is one process whose torch and Warp kernels use every core; the Ray path starts a local
instance (one worker per core, one thread each) unless ``--address`` names a cluster. The wall time of the
Ray path includes starting Ray and loading the asset in every worker.

    python bench/ray_render_bench.py                    # lego, 24 frames at 200x200
    python bench/ray_render_bench.py --frames 48 --size 400 --address auto
    python bench/ray_render_bench.py --serial-threads 1   # the serial path on one core
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from neural.device import configure_process
from shellsim.jobs.wind import WindSettings, wind


def main() -> None:
    # here, after configure_process (run first): torch loads with them
    import torch

    from shellsim.film.motion_frames import render_motion

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--asset", default="lego")
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--size", type=int, default=200, help="frame width and height in pixels")
    parser.add_argument("--address", default="local", help="Ray cluster address (default: a local instance)")
    parser.add_argument("--out", default=None, help="directory to keep the frames in (default: temporary)")
    parser.add_argument(
        "--serial-threads",
        type=int,
        default=None,
        help="torch threads of the serial path (default: all cores)",
    )
    args = parser.parse_args()
    if args.serial_threads:
        torch.set_num_threads(args.serial_threads)
    out = Path(args.out or tempfile.mkdtemp(prefix="ray_render_bench_"))
    motion = out / "wind.npz"
    wind(WindSettings(asset=args.asset, frames=args.frames, out=str(motion), overwrite=True), progress=False)
    size = (args.size, args.size)
    times = {}
    for name, ray in (("serial", None), ("ray", args.address)):
        start = time.perf_counter()
        result = render_motion(
            args.asset, motion, out / name, size=size, overwrite=True, progress=False, ray=ray
        )
        times[name] = time.perf_counter() - start
        print(
            f"{name:6s} {result.rendered} frames in {times[name]:.1f} s "
            f"({1e3 * times[name] / result.rendered:.0f} ms per frame wall; "
            f"{result.ms:.0f} ms per frame in the renderer)"
        )
    same = [
        (out / "serial" / p.name).read_bytes() == p.read_bytes() for p in sorted((out / "ray").glob("*.png"))
    ]
    print(
        f"speed-up {times['serial'] / times['ray']:.2f}x (serial torch threads: {torch.get_num_threads()}); "
        f"{sum(same)} of {len(same)} PNGs identical byte for byte; frames in {out}"
    )


if __name__ == "__main__":
    configure_process()
    main()
