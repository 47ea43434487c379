"""Real-capture benchmark: ``shellsim train`` on the instant-ngp fox (phone photos with lens distortion, a
real background, ``aabb_scale`` 4), then held-out PSNR of the narrow band and of full-ray rendering of the
same field.

Trains exactly as ``shellsim train --data FOX --out OUT --downscale D --steps N`` (held out: every 8th
present view, the training split), loads the asset and renders every held-out view twice: with the
asset's shells (narrow band, paper Procedure 3) and with fixed steps through the field's whole box (the
reference full-ray renderer); rays that leave the box show the field's learnt environment map in both.
Prints the figures as JSON. Nothing trained on the fox may be shipped: OUT defaults to /tmp.

Measured on the shared 2-core CPU, ``--steps 1000 --downscale 8`` (135x240, 39 training and 6 held-out
views): 13.1 minutes in all (10.6 training), held-out PSNR 18.13 dB narrow band at 7.86 samples/pixel and
18.78 dB full ray at 164.5, shells of 176488 (M+) and 135228 (M-) faces, peak RSS 7.15 GiB (the full-ray
evaluation's 16384-ray chunks).

    python bench/fox_bench.py [--steps N] [--downscale 4|8] [--data DIR] [--out DIR] [--device cpu|cuda]
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import time
from pathlib import Path

import numpy as np

from neural.asset import load_asset, load_field
from neural.device import configure_process, pick_device
from shellsim.jobs.train import TrainSettings, train


def main() -> None:
    # here, after configure_process (run first): torch loads with them
    import torch

    from neural.data import load_dataset
    from neural.render.view import asset_sampler, full_ray_sampler
    from neural.train import evaluate

    here = Path(__file__).resolve().parents[1]
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", default=str(here.parent / "shared" / "data" / "fox"))
    parser.add_argument("--steps", type=int, default=1000, help="stage-1 steps (stage 2: steps / 6)")
    parser.add_argument("--downscale", type=int, choices=(4, 8), default=8)
    parser.add_argument("--out", default="/tmp/fox_bench", help="asset directory (deleted first)")
    parser.add_argument("--device", default="auto")
    args = parser.parse_args()
    device = pick_device(args.device)
    shutil.rmtree(args.out, ignore_errors=True)

    start = time.perf_counter()
    settings = TrainSettings(args.data, args.out, downscale=args.downscale, steps=args.steps, device=device)
    train(settings)
    minutes = (time.perf_counter() - start) / 60.0

    asset = load_asset(args.out)
    field = load_field(asset, device)
    data = load_dataset(args.data, downscale=args.downscale, background=asset.background)
    views = np.asarray(data.test_idx)
    background = torch.as_tensor(data.background, dtype=torch.float32, device=device)
    band = evaluate(field, data, views, asset_sampler(asset), background)
    full = evaluate(field, data, views, full_ray_sampler(field), background)
    shell = asset.meta["shell"]
    figures = {
        "device": device,
        "steps": args.steps,
        "downscale": args.downscale,
        "image": f"{int(data.cameras.width[0])}x{int(data.cameras.height[0])}",
        "train_views": len(data.train_idx),
        "heldout_views": len(views),
        "train_minutes": round(minutes, 2),
        "heldout_psnr_narrow_band": round(band["psnr"], 2),
        "heldout_psnr_full_ray": round(full["psnr"], 2),
        "samples_per_pixel_narrow_band": round(band["samples_per_pixel"], 2),
        "samples_per_pixel_full_ray": round(full["samples_per_pixel"], 2),
        "shell_faces": {k: shell.get(k) for k in ("outer_faces", "inner_faces") if k in shell},
        "peak_rss_gib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20, 2),
    }
    print(json.dumps(figures, indent=1))


if __name__ == "__main__":
    configure_process()
    main()
