"""Grain at the size users render: an asset's held-out views rendered at SIZE x SIZE (its narrow-band
renderer, what ``shellsim render`` draws at rest) with one ray through each pixel centre and with K jittered
rays per pixel (:func:`shellsim.film.antialias.antialiased`), against the photos area-resized to that size
(the dataset loader's box filter).

With ``--full-ray`` it also renders the field along whole rays (one per pixel), which tells grain of the
field from grain of the narrow band's few samples. Per renderer it prints the mean over the views of:

- PSNR against the photos;
- the high-frequency ratio: RMS of the render's high frequencies over the photo's (an image's high
  frequencies: itself minus its Gaussian blur of sigma 1 pixel). Grain is detail the photo does not have:
  above 1. Blur is detail missing: below 1;
- the high-frequency error: RMS of the high frequencies of render - photo, in 8-bit levels;
- grain on flat surfaces: RMS of the render's high frequencies, in 8-bit levels, over the object's pixels
  (photo alpha 1) where the photo is flat (its own high frequencies below :data:`FLAT_LEVELS` within
  :data:`FLAT_RADIUS` pixels), beside the photo's there. The global ratio mixes grain with missing detail
  (which pulls it below 1); this one sees grain alone;
- samples per pixel and milliseconds per frame.

Run it on a quiet machine.

    python bench/grain_bench.py --asset lego --data ../shared/data/lego [--size 512] [--views 4]
        [--antialias 4] [--full-ray] [--save DIR]
"""

from __future__ import annotations

import argparse
import functools
import json
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter, maximum_filter

from neural.device import configure_process

SIGMA = 1.0  # pixels: the blur that the high frequencies are taken against
FLAT_LEVELS = 2.0  # 8-bit levels: a photo pixel whose high frequencies stay below this nearby is flat
FLAT_RADIUS = 2  # pixels: how far "nearby" reaches


def high_frequencies(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) -> (H, W, 3): the image minus its Gaussian blur of :data:`SIGMA` pixels (per channel)."""
    return image - gaussian_filter(image, sigma=(SIGMA, SIGMA, 0), mode="nearest")


def flat_mask(photo: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """(H, W) bool: the object's pixels (``alpha`` (H, W) of 1) where ``photo`` (H, W, 3) is flat."""
    busy = np.abs(high_frequencies(photo)).max(axis=2) * 255.0 >= FLAT_LEVELS
    near_busy = maximum_filter(busy, size=2 * FLAT_RADIUS + 1)
    return ~near_busy & (alpha >= 0.999)


def grain_figures(render: np.ndarray, photo: np.ndarray, alpha: np.ndarray) -> dict:
    """PSNR, high-frequency ratio, high-frequency error and grain on flat surfaces (render's and photo's,
    8-bit levels; module docstring) of ``render`` against ``photo``, both (H, W, 3) in [0, 1], the photo's
    ``alpha`` (H, W)."""
    from neural.metrics import psnr

    hf_render, hf_photo = high_frequencies(render), high_frequencies(photo)
    rms = lambda x: float(np.sqrt(np.mean(np.square(x)))) if x.size else float("nan")  # noqa: E731
    flat = flat_mask(photo, alpha)
    return {
        "psnr": psnr(render, photo),
        "hf_ratio": rms(hf_render) / max(rms(hf_photo), 1e-12),
        "hf_error_levels": 255.0 * rms(hf_render - hf_photo),
        "flat_grain_levels": 255.0 * rms(hf_render[flat]),
        "flat_photo_levels": 255.0 * rms(hf_photo[flat]),
        "flat_share": float(flat.mean()),
    }


def save(path: Path, image: np.ndarray) -> None:
    """Write an (H, W, 3) image in [0, 1] as an 8-bit PNG."""
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.round(np.clip(image, 0, 1) * 255).astype(np.uint8)).save(path)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--asset", default="lego", help="shipped asset name or asset directory")
    parser.add_argument("--data", required=True, help="the dataset the asset was trained on")
    parser.add_argument("--size", type=int, default=512, help="square render size in pixels")
    parser.add_argument("--views", type=int, default=4, help="first N held-out views")
    parser.add_argument(
        "--antialias", type=int, default=4, help="jittered rays per pixel of the second render"
    )
    parser.add_argument(
        "--full-ray", action="store_true", help="also full-ray rendering of the field (the grain's source)"
    )
    parser.add_argument("--save", help="also write each render and photo here as PNG (VIEW_RENDERER.png)")
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    import torch  # after configure_process

    from neural.asset import load_asset, load_field
    from neural.data import load_dataset
    from neural.device import processor
    from neural.render.view import asset_sampler, full_ray_sampler, render_camera
    from shellsim.film.antialias import antialiased

    asset = load_asset(args.asset)
    field = load_field(asset, args.device)
    background = torch.as_tensor(asset.background, dtype=torch.float32, device=args.device)
    full_width = int(load_dataset(args.data, background=asset.background).cameras.width[0])
    downscale = full_width / args.size
    data = load_dataset(args.data, downscale=downscale, background=asset.background)
    if data.alphas is None:
        parser.error(f"{args.data}: the photos have no alpha, which tells the object's pixels")
    alphas = data.alphas
    sampler = asset_sampler(asset)

    def render(view, sampler=sampler):
        return render_camera(field, view, 0, sampler, background)

    renderers = {
        "1 ray per pixel": render,
        f"{args.antialias} rays per pixel": antialiased(render, args.antialias),
    }
    if args.full_ray:
        renderers["full ray"] = functools.partial(render, sampler=full_ray_sampler(field))
    report = {
        "asset": str(asset.root),
        "size": args.size,
        "processor": processor(args.device),
        "renderers": {},
    }
    for name, render_one in renderers.items():
        rows = []
        for v in np.asarray(data.test_idx)[: args.views]:
            view = data.cameras.subset([int(v)])
            image, stats = render_one(view)
            if args.save:
                save(Path(args.save) / f"{v:03d}_{name.replace(' ', '_')}.png", image)
                save(Path(args.save) / f"{v:03d}_photo.png", data.images[v])
            rows.append(
                {
                    **grain_figures(image, data.images[v], alphas[v]),
                    "spp": stats["samples_per_pixel"],
                    "ms": stats["ms"],
                }
            )
        mean = {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}
        report["renderers"][name] = mean
        print(
            f"{name:>18}: PSNR {mean['psnr']:.2f} dB, high frequencies x{mean['hf_ratio']:.3f} of the "
            f"photo's, their error {mean['hf_error_levels']:.2f} levels, on flat surfaces "
            f"{mean['flat_grain_levels']:.2f} levels (photo {mean['flat_photo_levels']:.2f}, "
            f"{100 * mean['flat_share']:.0f}% of pixels), {mean['spp']:.2f} samples/pixel, "
            f"{mean['ms']:.0f} ms/frame"
        )
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    configure_process()
    main()
