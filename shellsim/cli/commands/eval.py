"""``shellsim eval``: held-out quality and speed of an asset, narrow-band against full-ray rendering."""

from __future__ import annotations

import argparse

from shellsim.cli.options import add_options, from_args, options_named
from shellsim.jobs.eval import EvalSettings, evaluate


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "eval",
        help="PSNR, SSIM, samples per pixel and ms per frame on held-out views (narrow band vs full ray)",
        description="Renders the held-out views (every 8th) of a dataset with the narrow-band renderer "
        "(Procedure 3) and with full-ray rendering of the same field, and reports PSNR, SSIM, samples per "
        "pixel and ms per frame for both.",
    )
    add_options(p, EvalSettings)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    with options_named(EvalSettings):
        result = evaluate(from_args(EvalSettings, args))
    for name in ("narrow_band", "full_ray"):
        r = getattr(result, name)
        if r is not None:
            print(
                f"{name:12s} PSNR {r.psnr:.2f} dB  SSIM {r.ssim:.4f}  "
                f"{r.samples_per_pixel:.2f} samples/pixel  {r.ms_per_frame:.0f} ms/frame"
            )
    if result.full_ray is not None:
        gain = result.narrow_band.psnr - result.full_ray.psnr
        print(f"narrow band is {result.speedup:.1f}x faster, {gain:+.2f} dB")
    if result.unseen_surface_share is not None:
        print(f"surface no training view saw: {100 * result.unseen_surface_share:.1f}%")
    print(result.lpips)
