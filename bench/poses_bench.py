"""``shellsim poses`` on a real capture against the capture's own poses: photos posed, minutes, camera
centre error after a similarity alignment (Umeyama) as a fraction of the scene size.

The scene size is the diameter of the capture's camera path (largest distance between two of its camera
centres); the error is also given as a fraction of the mean camera distance from the point the capture
looks at. The photos are read in place; the output goes to ``--out`` (under /tmp by default).

    python bench/poses_bench.py                         # the 45 fox photos at full resolution, 2 cores
    python bench/poses_bench.py --matching sequential   # each photo with the next 10 only
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path

import numpy as np

from neural.device import configure_process
from shellsim.cli.options import add_options, from_args
from shellsim.jobs.poses import PosesSettings, poses

FOX = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "fox"


def run(args: argparse.Namespace) -> None:
    from neural.data.colmap import align_similarity  # loads torch, after configure_process
    from neural.data.datasets import _focus_point

    reference = json.loads(Path(args.reference).read_text())
    truth = {Path(f["file_path"]).name: np.asarray(f["transform_matrix"], float) for f in reference["frames"]}
    photos = sorted(p.name for p in Path(args.images).iterdir() if p.name in truth)
    load_before = os.getloadavg()
    start = time.perf_counter()
    poses(from_args(PosesSettings, args, overwrite=True))
    minutes = (time.perf_counter() - start) / 60
    load_after = os.getloadavg()

    meta = json.loads((Path(args.out) / "transforms.json").read_text())
    found = {Path(f["file_path"]).name: np.asarray(f["transform_matrix"]) for f in meta["frames"]}
    names = [n for n in photos if n in found]
    ours = np.stack([found[n] for n in names])
    theirs = np.stack([truth[n] for n in names])
    s, rot, t = align_similarity(ours[:, :3, 3], theirs[:, :3, 3])
    error = np.linalg.norm(s * ours[:, :3, 3] @ rot.T + t - theirs[:, :3, 3], axis=1)
    centres = theirs[:, :3, 3]
    diameter = max(np.linalg.norm(a - b) for a in centres for b in centres)
    distance = np.linalg.norm(centres - _focus_point(theirs), axis=1).mean()
    angles = [
        math.degrees(math.acos(np.clip((np.trace(rot @ a[:3, :3] @ b[:3, :3].T) - 1) / 2, -1, 1)))
        for a, b in zip(ours, theirs, strict=True)
    ]
    print(f"photos:               {len(photos)} ({args.images})")
    print(f"posed:                {len(found)} ({100 * len(found) / len(photos):.1f}%)")
    print(f"unregistered:         {[u['file_path'] for u in meta['unregistered']]}")
    print(
        f"time:                 {minutes:.2f} min on {args.threads or len(os.sched_getaffinity(0))} threads"
    )
    print(f"load average:         {load_before[0]:.2f} before, {load_after[0]:.2f} after (1 min)")
    print(f"scene size:           camera path diameter {diameter:.3f}, mean camera distance {distance:.3f}")
    for label, size in (("diameter", diameter), ("camera distance", distance)):
        print(
            f"centre error / {label + ':':16s} max {100 * error.max() / size:.3f}%  "
            f"mean {100 * error.mean() / size:.3f}%  median {100 * np.median(error) / size:.3f}%"
        )
    print(f"rotation error:       max {max(angles):.3f} deg, mean {np.mean(angles):.3f} deg")
    print(
        "intrinsics (ours / capture): "
        + ", ".join(f"{k} {meta[k]:.4g} / {reference.get(k, 0):.4g}" for k in ("fl_x", "fl_y", "cx", "cy"))
        + ", "
        + ", ".join(f"{k} {meta[k]:.3g} / {reference.get(k, 0):.3g}" for k in ("k1", "k2", "p1", "p2"))
    )


if __name__ == "__main__":
    configure_process()
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--images", default=str(FOX / "images"), help="photos (default: the fox capture)")
    parser.add_argument(
        "--reference", default=str(FOX / "transforms.json"), help="the capture's own transforms.json"
    )
    parser.add_argument("--out", default="/tmp/poses_bench_fox", help="output of shellsim poses")
    add_options(parser, PosesSettings, skip=("images", "out", "overwrite"))
    run(parser.parse_args())
