"""Stage-1 benchmark on the LEGO scene (paper Sec. 3.5 / Procedure 4 lines 1-5).

Trains stage 1 on ``../shared/data/lego`` at downscale 4 (200x200) on every 8th-view-held-out split and
prints held-out PSNR/SSIM (all held-out views, rendered with the training occupancy grid: within 0.01 dB of
full-ray rendering on lego), minutes, steps per minute and peak memory. Target on a 2-core CPU: PSNR >= 27
dB within 20 minutes (measured: 27.32 dB after 5000 steps in 22.1 minutes; 27.36 dB in 19.4 minutes in an
earlier run; 26.74 dB with ``random_background``).

    python bench/train_lego.py [--steps N] [--data DIR] [--out DIR] [--device cpu|cuda] [--resume]
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import time
from pathlib import Path

import numpy as np
import torch

from neural.data import load_dataset
from neural.device import pick_device
from neural.field import FieldConfig
from neural.pipeline import build_field
from neural.render.view import occupancy_sampler
from neural.train import Stage1Config, evaluate, train_stage1


def main() -> None:
    here = Path(__file__).resolve().parents[1]
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", default=str(here.parent / "shared" / "data" / "lego"))
    parser.add_argument(
        "--steps", type=int, default=5000, help="stage-1 steps (default 5000: about 20 minutes on 2 cores)"
    )
    parser.add_argument("--out", default=str(here / "runs" / "bench_lego"))
    parser.add_argument("--device", default="auto")
    parser.add_argument(
        "--resume", action="store_true", help="continue an earlier run instead of starting over"
    )
    args = parser.parse_args()
    device = pick_device(args.device)
    if not args.resume:
        shutil.rmtree(args.out, ignore_errors=True)
    torch.set_num_threads(max(1, torch.get_num_threads()))
    data = load_dataset(args.data, downscale=4, background=(1.0, 1.0, 1.0))
    config = Stage1Config(steps=args.steps, eval_every=max(args.steps // 4, 1))
    field = build_field(data, FieldConfig(), device)
    start = time.perf_counter()
    result = train_stage1(field, data, Path(args.out), config, device)
    minutes = (time.perf_counter() - start) / 60.0
    background = torch.as_tensor(data.background, dtype=torch.float32, device=device)
    sampler = occupancy_sampler(result["occupancy"], field, config.step_size, config.max_samples_per_ray)
    heldout = evaluate(field, data, np.asarray(data.test_idx), sampler, background)
    peak_gib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    figures = {
        "device": device,
        "steps": args.steps,
        "train_minutes": round(minutes, 2),
        "steps_per_minute": round(args.steps / minutes, 1) if minutes > 0 else None,
        "heldout_views": len(data.test_idx),
        "heldout_psnr": round(heldout["psnr"], 3),
        "heldout_ssim": round(heldout["ssim"], 4),
        "samples_per_pixel": round(heldout["samples_per_pixel"], 2),
        "ms_per_frame_occupancy_grid": round(heldout["ms_per_frame"], 1),
        "peak_rss_gib": round(peak_gib, 2),
    }
    print(json.dumps(figures, indent=1))


if __name__ == "__main__":
    main()
