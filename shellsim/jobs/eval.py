"""Held-out quality and speed of an asset: narrow-band rendering (Procedure 3) against full-ray rendering of
the same field, on the held-out views (every 8th) of the dataset it was trained on."""

from __future__ import annotations

import dataclasses
import functools
import json
from dataclasses import dataclass

from neural.config import PipelineConfig
from neural.device import DEVICES, processor
from shellsim.errors import SettingError
from shellsim.film.cameras import check_antialias
from shellsim.io.outputs import holds_outputs
from shellsim.settings import check_choice, check_required, config_bounds, device_setting, option


@dataclass(frozen=True)
class EvalSettings:
    """What ``shellsim eval`` takes."""

    asset: str = option(help="shipped asset name or asset directory", required=True)
    data: str = option(help="dataset directory the asset was trained on", required=True)
    downscale: int | None = option(help="image downscale factor", shown_default="the asset's training one")
    views: int | None = option(help="evaluate only the first N held-out views", shown_default="all")
    antialias: int = option(
        1,
        help="jittered rays per pixel, averaged: a box filter over each pixel, as the photos' when they are "
        "shrunk (1: one ray through each pixel's centre)",
    )
    full_ray: bool = option(
        True, flag="--no-full-ray", negate=True, help="skip the (slow) full-ray reference"
    )
    json: str | None = option(help="also write the figures to this JSON file")
    record: bool = option(
        False, help="also record the figures and this command in the asset's asset.json (metrics.eval)"
    )
    device: str = option("auto", help="cpu, cuda or auto")

    def __post_init__(self):
        check_required(self)
        if self.downscale is not None:
            with config_bounds(self, {(PipelineConfig, "downscale"): "downscale"}):  # as training's
                PipelineConfig(downscale=self.downscale)
        if self.views is not None and self.views < 1:
            raise SettingError("views", f"expected a positive integer, got {self.views}")
        check_antialias(self.antialias)
        check_choice("device", self.device, DEVICES)


@dataclass(frozen=True)
class ViewMetrics:
    """Means over the held-out views of one renderer: ``psnr`` (dB), ``ssim``, ``samples_per_pixel`` (those
    evaluated), ``ms_per_frame``; ``views`` the dataset indices of the views."""

    psnr: float
    ssim: float
    samples_per_pixel: float
    ms_per_frame: float
    views: list[int]

    @classmethod
    def of(cls, figures: dict) -> ViewMetrics:
        """From the figures of :func:`neural.train.evaluate`."""
        return cls(**{f.name: figures[f.name] for f in dataclasses.fields(cls)})


@dataclass(frozen=True)
class EvalResult:
    """What :func:`evaluate` measured.

    asset, data : the asset directory and the dataset; downscale : the images' downscale factor
    antialias : jittered rays per pixel of every render
    processor : what ``ms_per_frame`` was measured on; heldout_views : the dataset indices evaluated
    narrow_band : the asset's renderer (Procedure 3); full_ray : full-ray rendering of the same field (None
        when not asked for); speedup : full ray's ms per frame over narrow band's (None without full ray)
    lpips : why LPIPS is not reported
    unseen_surface_share : the area share (0-1) of the field's surface that no training view saw (the
        asset's record, :mod:`neural.visibility`, else measured from the dataset's training views; None for
        a field in contracted space, a capture's room)
    """

    asset: str
    data: str
    downscale: int
    antialias: int
    processor: str
    heldout_views: list[int]
    narrow_band: ViewMetrics
    full_ray: ViewMetrics | None
    speedup: float | None
    lpips: str
    unseen_surface_share: float | None

    def as_dict(self) -> dict:
        """The figures as written to ``settings.json`` and recorded in the asset (None ones left out)."""
        return {k: v for k, v in dataclasses.asdict(self).items() if v is not None}


def _unseen_share(asset, field, data) -> float | None:
    """The share of ``asset``'s surface no training view saw: its record, else measured on ``data``; None
    for a field in contracted space."""
    from neural.visibility import measure_visibility

    if field.contraction is not None:
        return None
    visibility = asset.visibility()
    if visibility is None:
        visibility, _ = measure_visibility(field, data)
    return visibility.unseen_surface_share


@holds_outputs
def evaluate(settings: EvalSettings) -> EvalResult:
    """Render the held-out views with each renderer and compare them with the photos; the figures are
    written to ``settings.json`` and recorded in the asset as asked."""
    import numpy as np
    import torch

    from neural.asset import command_line, load_asset, load_field, refuse_shipped, write_meta
    from neural.data import load_dataset
    from neural.files import write_text_atomically
    from neural.metrics import lpips_status
    from neural.render.view import asset_sampler, full_ray_sampler, render_camera
    from neural.train import evaluate as evaluate_views
    from shellsim.film.antialias import antialiased
    from shellsim.io.outputs import check_writable_dir, check_writable_file, lock_output

    if settings.json:
        lock_output(check_writable_file(settings.json, "json"), "json")
    asset = load_asset(settings.asset)
    if settings.record:
        refuse_shipped(asset, "recording the figures")
        lock_output(check_writable_dir(asset.root, "record"), "record")  # asset.json is rewritten there
    device = device_setting(settings.device)
    downscale = settings.downscale or asset.training_downscale
    data = load_dataset(settings.data, downscale=downscale, background=asset.background)
    views = np.asarray(data.test_idx)[: settings.views]
    field = load_field(asset, device)
    bg = torch.as_tensor(asset.background, dtype=torch.float32, device=device)

    def render(field, cameras, index, sampler, background):  # render_camera with settings.antialias rays
        one = functools.partial(render_camera, field, index=0, sampler=sampler, background=background)
        return antialiased(one, settings.antialias)(cameras.subset([index]))

    narrow_band = evaluate_views(field, data, views, asset_sampler(asset), bg, render)  # 'shellsim render'
    full_ray = (
        evaluate_views(field, data, views, full_ray_sampler(field), bg, render) if settings.full_ray else None
    )
    result = EvalResult(
        asset=str(asset.root),
        data=str(settings.data),
        downscale=downscale,
        antialias=settings.antialias,
        processor=processor(device),
        heldout_views=[int(v) for v in views],
        narrow_band=ViewMetrics.of(narrow_band),
        full_ray=None if full_ray is None else ViewMetrics.of(full_ray),
        speedup=None if full_ray is None else full_ray["ms_per_frame"] / narrow_band["ms_per_frame"],
        lpips=lpips_status(),
        unseen_surface_share=_unseen_share(asset, field, data),
    )
    if settings.json:
        write_text_atomically(settings.json, json.dumps(result.as_dict(), indent=1))
    if settings.record:
        asset.meta.setdefault("metrics", {})["eval"] = {**result.as_dict(), "command": command_line()}
        write_meta(asset.root, asset.meta)
    return result
