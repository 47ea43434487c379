"""Real-capture benchmark: ``shellsim train`` on the instant-ngp fox (phone photos with lens distortion, a
real room behind the object, ``aabb_scale`` 4) in contracted space (paper Sec. 4.7, the default for photos
without alpha) and, in the same run, bounded with an environment map beyond the object's box (what the
project did before), then held-out PSNR of both.

Trains exactly as ``shellsim train --data FOX --out OUT/SPACE --downscale D --steps N --space SPACE`` (held
out: every 8th present view, the training split; a finished asset in OUT/SPACE is reused, an interrupted
one resumed), loads each asset and renders every held-out view with its shells (narrow band, paper
Procedure 3) and with the training's occupancy-grid marcher (full ray). Reports PSNR over the whole frame
and over its centre half (the object's region: the fox fills it), SSIM, samples per pixel and the training
minutes ``asset.json`` records. Prints the figures as JSON. Nothing trained on the fox may be shipped: OUT
defaults to /tmp.

Measured on the shared 2-core CPU on 2026-12-06, the defaults (135x240, 3000 + 500 steps, 6 held-out
views): contracted 31.97 dB narrow band (33.34 centre half, SSIM 0.927) at 16.3 samples/pixel, 30.69 dB
full ray at 45.3, 23.9 training minutes; bounded 18.42 dB (20.47) at 6.6, 17.59 dB full ray at 37.5, 18.8
minutes; peak RSS 2.3 GiB.

    python bench/fox_bench.py [--steps N] [--downscale 4|8] [--space both|contracted|bounded] [--data DIR]
        [--out DIR] [--device cpu|cuda]
"""

from __future__ import annotations

import argparse
import json
import resource
from pathlib import Path

import numpy as np

from neural.asset import load_asset, load_field
from neural.device import configure_process, pick_device
from shellsim.jobs.train import TrainSettings, train


def centre_half(image: np.ndarray) -> np.ndarray:
    """The middle half of an (H, W, C) image in each direction."""
    h, w = image.shape[:2]
    return image[h // 4 : h - h // 4, w // 4 : w - w // 4]


def figures(asset_dir: Path, data, device: str) -> dict:
    """Held-out figures of the asset in ``asset_dir`` on ``data``'s held-out views."""
    import torch

    from neural.metrics import psnr, ssim
    from neural.render.view import asset_sampler, fitted_occupancy_grid, occupancy_sampler, render_camera

    asset = load_asset(asset_dir)
    field = load_field(asset, device)
    background = torch.as_tensor(data.background, dtype=torch.float32, device=device)
    samplers = {
        "narrow_band": asset_sampler(asset),
        "full_ray": occupancy_sampler(fitted_occupancy_grid(field), field),
    }
    out = {
        "train_minutes": asset.meta["training"]["wall_minutes"],
        "contracted": field.contraction is not None,
    }
    for name, sampler in samplers.items():
        rows = []
        for v in data.test_idx:
            image, stats = render_camera(field, data.cameras, int(v), sampler, background)
            photo = data.images[v]
            rows.append(
                (psnr(image, photo), psnr(centre_half(image), centre_half(photo)), ssim(image, photo),
                 stats["samples_per_pixel"])
            )  # fmt: skip
        frame, centre, ssim_, spp = np.mean(rows, axis=0)
        out[name] = {
            "psnr": round(float(frame), 2),
            "psnr_centre_half": round(float(centre), 2),
            "ssim": round(float(ssim_), 4),
            "samples_per_pixel": round(float(spp), 2),
        }
    shell = asset.meta["shell"]
    out["shell_faces"] = {k: shell.get(k) for k in ("outer_faces", "inner_faces")}
    return out


def main() -> None:
    from neural.data import load_dataset

    here = Path(__file__).resolve().parents[1]
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", default=str(here.parent / "shared" / "data" / "fox"))
    parser.add_argument("--steps", type=int, default=3000, help="stage-1 steps (stage 2: steps / 6)")
    parser.add_argument("--downscale", type=int, choices=(4, 8), default=8)
    parser.add_argument("--space", choices=("both", "contracted", "bounded"), default="both")
    parser.add_argument("--out", default="/tmp/fox_bench", help="directory of the assets, one per space")
    parser.add_argument("--device", default="auto")
    args = parser.parse_args()
    device = pick_device(args.device)
    spaces = ("contracted", "bounded") if args.space == "both" else (args.space,)
    result = {"device": device, "steps": args.steps, "downscale": args.downscale}
    for space in spaces:
        out = Path(args.out) / space
        if not (out / "asset.json").is_file() or (out / "checkpoints").is_dir():
            settings = TrainSettings(
                args.data, str(out), downscale=args.downscale, steps=args.steps, space=space, device=device
            )
            train(settings)
        data = load_dataset(args.data, downscale=args.downscale)
        result[space] = figures(out, data, device)
    result["image"] = f"{int(data.cameras.width[0])}x{int(data.cameras.height[0])}"
    result["heldout_views"] = len(data.test_idx)
    result["peak_rss_gib"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20, 2)
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    configure_process()
    main()
