"""Time to quality on the LEGO scene: ``shellsim train`` end to end (stage 1, shell extraction, stage 2) at
200x200, as a user runs it.

Runs ``shellsim train --data DATA --out OUT --downscale 4 --steps N --eval-every K --eval-views 0`` (any
further ``shellsim train`` options after ``--``) in a child process, then reads the curve of held-out PSNR
(all 12 held-out views, every 8th) against training minutes that the command records in ``asset.json``:
stage-1 points rendered with the training occupancy grid (within 0.01 dB of full-ray rendering on lego),
then stage-2 points in the narrow band (what ``shellsim eval`` reports), after the shell extraction's time.
Minutes leave the evaluations out. Prints the curve, the first minute at which it reached 27 and 28 dB, the
final narrow-band figures and the command's whole wall time. Target on a 2-core CPU: 28 dB held-out
(narrow band) within 25 minutes. Run it on a quiet machine.

    python bench/train_lego.py [--steps N] [--every K] [--data DIR] [--out DIR] [-- TRAIN_OPTIONS]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

from neural.config import Stage1Config
from neural.device import configure_process


def crossing(curve: list[dict], level: float) -> float | None:
    """First training minute at which a curve point reached ``level`` dB (None: never)."""
    return next((p["minutes"] for p in curve if p["psnr"] >= level), None)


def main() -> None:
    here = Path(__file__).resolve().parents[1]
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", default=str(here.parent / "shared" / "data" / "lego"))
    parser.add_argument("--out", default=str(here / "runs" / "bench_lego"))
    parser.add_argument("--steps", type=int, default=Stage1Config.steps, help="stage-1 steps")
    parser.add_argument("--every", type=int, default=1000, help="stage-1 steps between curve points")
    parser.add_argument("train_options", nargs="*", help="more shellsim train options (after --)")
    args = parser.parse_args()
    shutil.rmtree(args.out, ignore_errors=True)
    command = [
        *("train", "--data", args.data, "--out", args.out, "--downscale", "4"),
        *("--steps", str(args.steps), "--eval-every", str(args.every), "--eval-views", "0"),
        *args.train_options,
    ]
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "shellsim.cli.main", *command], check=True)
    wall = (time.perf_counter() - start) / 60.0
    meta = json.loads((Path(args.out) / "asset.json").read_text())
    curve = meta["training"]["curve"]
    print("stage  step  minutes  held-out PSNR  samples/pixel")
    for p in curve:
        print(
            f"{p['stage']:>5} {p['step']:>5} {p['minutes']:8.2f} {p['psnr']:10.2f} dB "
            f"{p['samples_per_pixel']:10.2f}"
        )
    final = meta["metrics"]["stage2_narrow_band"]
    figures = {
        "command": meta["training"]["command"],
        "processor": meta["training"]["processor"],
        "training_minutes": curve[-1]["minutes"],
        "command_wall_minutes": round(wall, 2),
        "heldout_views": len(final["views"]),
        "narrow_band_psnr": round(final["psnr"], 3),
        "narrow_band_ssim": round(final["ssim"], 4),
        "narrow_band_samples_per_pixel": round(final["samples_per_pixel"], 2),
        "minute_27dB": crossing(curve, 27.0),
        "minute_28dB": crossing(curve, 28.0),
    }
    print(json.dumps(figures, indent=1))


if __name__ == "__main__":
    configure_process()
    main()
