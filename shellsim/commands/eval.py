"""``shellsim eval``: held-out quality and speed of an asset, narrow-band against full-ray rendering."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "eval",
        help="PSNR, SSIM, samples per pixel and ms per frame on held-out views (narrow band vs full ray)",
        description="Renders the held-out views (every 8th) of a dataset with the narrow-band renderer "
        "(Procedure 3) and with full-ray rendering of the same field, and reports PSNR, SSIM, samples per "
        "pixel and ms per frame for both.",
    )
    p.add_argument("--asset", required=True, help="shipped asset name or asset directory")
    p.add_argument("--data", required=True, help="dataset directory the asset was trained on")
    p.add_argument("--downscale", type=int, default=None, help="default: the asset's training downscale")
    p.add_argument("--views", type=int, default=None, help="evaluate only the first N held-out views")
    p.add_argument("--no-full-ray", action="store_true", help="skip the (slow) full-ray reference")
    p.add_argument("--json", default=None, help="also write the figures to this JSON file")
    p.add_argument(
        "--record",
        action="store_true",
        help="also record the figures and this command in the asset's asset.json (metrics.eval)",
    )
    p.add_argument("--device", default="auto", help="cpu, cuda or auto (default)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    import json
    from pathlib import Path

    import numpy as np
    import torch

    from neural.asset import command_line, load_asset, load_field, refuse_shipped, write_meta
    from neural.data import load_dataset
    from neural.metrics import lpips_status
    from neural.render.view import asset_sampler, full_ray_sampler
    from neural.train import evaluate
    from shellsim.commands.args import device_option
    from shellsim.outputs import check_writable_dir, check_writable_file

    if args.json:
        check_writable_file(args.json, "--json")
    asset = load_asset(args.asset)
    if args.record:
        refuse_shipped(asset, "--record")
        check_writable_dir(asset.root, "--record")  # asset.json is rewritten there
    device = device_option(args.device)
    downscale = args.downscale or asset.training_downscale
    background = asset.background
    data = load_dataset(args.data, downscale=downscale, background=background)
    views = np.asarray(data.test_idx)[: args.views]
    field = load_field(asset, device)
    bg = torch.as_tensor(background, dtype=torch.float32, device=device)
    samplers = {"narrow_band": asset_sampler(asset)}  # the sampler of 'shellsim render' at rest
    if not args.no_full_ray:
        samplers["full_ray"] = full_ray_sampler(field)
    report = {
        "asset": str(asset.root),
        "data": str(args.data),
        "downscale": downscale,
        "heldout_views": [int(v) for v in views],
        "lpips": lpips_status(),
    }
    for name, sampler in samplers.items():
        report[name] = evaluate(field, data, views, sampler, bg)
        r = report[name]
        print(
            f"{name:12s} PSNR {r['psnr']:.2f} dB  SSIM {r['ssim']:.4f}  "
            f"{r['samples_per_pixel']:.2f} samples/pixel  {r['ms_per_frame']:.0f} ms/frame"
        )
    if "full_ray" in report:
        nb, fr = report["narrow_band"], report["full_ray"]
        report["speedup"] = fr["ms_per_frame"] / nb["ms_per_frame"]
        print(f"narrow band is {report['speedup']:.1f}x faster, {nb['psnr'] - fr['psnr']:+.2f} dB")
    print(report["lpips"])
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1))
    if args.record:
        asset.meta.setdefault("metrics", {})["eval"] = {**report, "command": command_line()}
        write_meta(asset.root, asset.meta)
