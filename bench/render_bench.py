"""Rendering benchmark of an asset on held-out views (paper Table 1 / Sec. 4.8), all in one run:
samples per pixel, ms per frame, PSNR and SSIM for

- narrow-band rendering against the adaptive shells (Procedure 3),
- full-ray rendering (fixed steps through the field's whole box, no skipping),
- an occupancy-grid sampler (Instant-NGP style, 128^3 grid fitted to the field),

of the same field, with the ratios. Targets (assets/lego, 200x200): narrow-band PSNR >= 28 dB and within
0.3 dB of full-ray, <= 3 samples per pixel, >= 10x faster than full-ray, >= 2x faster than the occupancy grid.

    python bench/render_bench.py [--asset lego] [--data ../shared/data/lego] [--views N] [--device cpu|cuda]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from neural.asset import load_asset, load_field
from neural.device import configure_process, pick_device, processor


def main() -> None:
    # here, after configure_process (run first): torch loads with them
    import torch

    from neural.data import load_dataset
    from neural.render.view import asset_sampler, fitted_occupancy_grid, full_ray_sampler, occupancy_sampler
    from neural.train import evaluate

    here = Path(__file__).resolve().parents[1]
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--asset", default="lego")
    parser.add_argument("--data", default=str(here.parent / "shared" / "data" / "lego"))
    parser.add_argument("--views", type=int, default=None, help="first N held-out views (default: all)")
    parser.add_argument("--device", default="auto")
    args = parser.parse_args()
    device = pick_device(args.device)
    asset = load_asset(args.asset)
    field = load_field(asset, device)
    background = asset.background
    data = load_dataset(args.data, downscale=asset.training_downscale, background=background)
    views = np.asarray(data.test_idx)[: args.views]
    bg = torch.as_tensor(background, dtype=torch.float32, device=device)
    samplers = {
        "narrow_band": asset_sampler(asset),  # what 'shellsim eval' and 'shellsim render' use
        "occupancy_grid": occupancy_sampler(fitted_occupancy_grid(field), field),
        "full_ray": full_ray_sampler(field),
    }
    warm = data.test_idx[:1]
    results = {}
    for name, sampler in samplers.items():
        evaluate(field, data, warm, sampler, bg)  # warm-up: kernel compilation, first Embree build
        results[name] = evaluate(field, data, views, sampler, bg)
    nb = results["narrow_band"]
    report = {
        "asset": str(asset.root),
        "device": device,
        "processor": processor(device),
        "resolution": [int(data.cameras.width[0]), int(data.cameras.height[0])],
        "views": [int(v) for v in views],
        **{name: {k: round(v, 4) for k, v in r.items() if k != "views"} for name, r in results.items()},
        "speedup_vs_full_ray": round(results["full_ray"]["ms_per_frame"] / nb["ms_per_frame"], 2),
        "speedup_vs_occupancy_grid": round(results["occupancy_grid"]["ms_per_frame"] / nb["ms_per_frame"], 2),
        "psnr_narrow_minus_full_ray": round(nb["psnr"] - results["full_ray"]["psnr"], 3),
    }
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    configure_process()
    main()
