"""Time to quality on the LEGO scene: ``shellsim train`` end to end (stage 1, shell extraction, stage 2) at
200x200 (or another ``--downscale``: 1 is the photos' 800x800), as a user runs it.

Runs ``shellsim train --data DATA --out OUT --downscale D --steps N --eval-every K --eval-views V`` (any
further ``shellsim train`` options after ``--``) in a child process, then reads the curve of held-out PSNR
(V = 0: all 12 held-out views, every 8th; the default, but the first 2 at 800x800, where each view takes
seconds) against training minutes that the command records in ``asset.json``: stage-1 points rendered with
the training occupancy grid (within 0.01 dB of full-ray rendering on lego), then stage-2 points in the narrow
band (what ``shellsim eval`` reports), after the shell extraction's time. Minutes leave the evaluations
out. Prints the curve, the first minute at which it reached 27, 28, 30 and 31 dB, the final narrow-band
figures (all 12 views) and the command's whole wall time. Targets on a 2-core CPU: 28 dB held-out (narrow
band) within 25 minutes at 200x200; 31 dB within 3 hours at 800x800. Run it on a quiet machine.

OUT is removed first, unless ``--resume``: then the command continues the run OUT holds (a run of hours,
interrupted with Ctrl-C, goes on across sessions) and the minutes add up over its runs. Where checkpoints do
not survive between sessions, ``-- --init ASSET --steps N`` continues the stage 1 of an asset this command
made (to N steps in all), and the curve's minutes go on from the asset's own; ``shellsim finetune`` then
fine-tunes the narrow band of the asset made with denser samples, and its curve goes on too.

    python bench/train_lego.py [--steps N] [--every K] [--downscale D] [--views V] [--data DIR] [--out DIR]
        [--resume] [-- TRAIN_OPTIONS]
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
    parser.add_argument("--downscale", type=int, default=4, help="image downscale factor (1: 800x800)")
    parser.add_argument(
        "--views",
        type=int,
        help="held-out views of each curve point but the last (default: all; 2 at 800x800)",
    )
    parser.add_argument("--resume", action="store_true", help="continue the run OUT holds")
    parser.add_argument("train_options", nargs="*", help="more shellsim train options (after --)")
    args = parser.parse_args()
    if not args.resume:
        shutil.rmtree(args.out, ignore_errors=True)
    views = args.views if args.views is not None else (2 if args.downscale == 1 else 0)
    command = [
        *("train", "--data", args.data, "--out", args.out, "--downscale", str(args.downscale)),
        *("--steps", str(args.steps), "--eval-every", str(args.every), "--eval-views", str(views)),
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
        **{f"minute_{level}dB": crossing(curve, float(level)) for level in (27, 28, 30, 31)},
    }
    print(json.dumps(figures, indent=1))


if __name__ == "__main__":
    configure_process()
    main()
