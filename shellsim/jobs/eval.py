"""Held-out quality and speed of an asset: narrow-band rendering (Procedure 3) against full-ray rendering of
the same field, on the held-out views (every 8th) of the dataset it was trained on."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from neural.device import DEVICES, processor
from shellsim.errors import SettingError
from shellsim.settings import check_choice, device_setting, option


@dataclass(frozen=True)
class EvalSettings:
    """What ``shellsim eval`` takes."""

    asset: str = option(help="shipped asset name or asset directory", required=True)
    data: str = option(help="dataset directory the asset was trained on", required=True)
    downscale: int | None = option(help="image downscale factor", shown_default="the asset's training one")
    views: int | None = option(help="evaluate only the first N held-out views", shown_default="all")
    full_ray: bool = option(
        True, flag="--no-full-ray", negate=True, help="skip the (slow) full-ray reference"
    )
    json: str | None = option(help="also write the figures to this JSON file")
    record: bool = option(
        False, help="also record the figures and this command in the asset's asset.json (metrics.eval)"
    )
    device: str = option("auto", help="cpu, cuda or auto")

    def __post_init__(self):
        for name in ("downscale", "views"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise SettingError(name, f"expected a positive integer, got {value}")
        check_choice("device", self.device, DEVICES)


def evaluate(settings: EvalSettings) -> dict:
    """PSNR, SSIM, samples per pixel and ms per frame of each renderer (``narrow_band``, ``full_ray``), the
    ``speedup`` and the LPIPS status; written to ``settings.json`` and recorded in the asset as asked."""
    import numpy as np
    import torch

    from neural.asset import command_line, load_asset, load_field, refuse_shipped, write_meta
    from neural.data import load_dataset
    from neural.metrics import lpips_status
    from neural.render.view import asset_sampler, full_ray_sampler
    from neural.train import evaluate as evaluate_views
    from shellsim.io.outputs import check_writable_dir, check_writable_file

    if settings.json:
        check_writable_file(settings.json, "json")
    asset = load_asset(settings.asset)
    if settings.record:
        refuse_shipped(asset, "recording the figures")
        check_writable_dir(asset.root, "record")  # asset.json is rewritten there
    device = device_setting(settings.device)
    downscale = settings.downscale or asset.training_downscale
    data = load_dataset(settings.data, downscale=downscale, background=asset.background)
    views = np.asarray(data.test_idx)[: settings.views]
    field = load_field(asset, device)
    bg = torch.as_tensor(asset.background, dtype=torch.float32, device=device)
    samplers = {"narrow_band": asset_sampler(asset)}  # the sampler of 'shellsim render' at rest
    if settings.full_ray:
        samplers["full_ray"] = full_ray_sampler(field)
    report = {
        "asset": str(asset.root),
        "data": str(settings.data),
        "downscale": downscale,
        "processor": processor(device),  # what ms_per_frame was measured on
        "heldout_views": [int(v) for v in views],
        "lpips": lpips_status(),
    }
    for name, sampler in samplers.items():
        report[name] = evaluate_views(field, data, views, sampler, bg)
    if settings.full_ray:
        report["speedup"] = report["full_ray"]["ms_per_frame"] / report["narrow_band"]["ms_per_frame"]
    if settings.json:
        Path(settings.json).write_text(json.dumps(report, indent=1))
    if settings.record:
        asset.meta.setdefault("metrics", {})["eval"] = {**report, "command": command_line()}
        write_meta(asset.root, asset.meta)
    return report
