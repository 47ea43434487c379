"""Fine-tune a finished asset in its narrow band again (stage 2 of Procedure 4) into a new asset.

Denser narrow-band samples render a field closer to its full-ray image; fine-tuning with them lets the field
adapt to the samples it is rendered with. Settings left unset keep the asset's narrow band and stage-2 error
sampling; the learning rates are a fraction of the asset's stage-1 base rates.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from neural.config import NarrowBandConfig, Stage1Config, Stage2Config
from neural.device import DEVICES
from shellsim.io.outputs import check_writable_dir, holds_outputs, lock_output
from shellsim.jobs.eval import ViewMetrics
from shellsim.settings import check_choice, check_required, config_bounds, device_setting, option

THE_ASSETS = "the asset's"
#: The config field each setting sets: its bound (:mod:`neural.config`) is the setting's.
CONFIG_FIELDS = {
    (Stage2Config, "steps"): "steps",
    (Stage2Config, "rays"): "rays",
    (Stage2Config, "lr_encoding"): "rate",
    (Stage2Config, "lr_network"): "rate",
    (Stage2Config, "error_sampling"): "error_sampling",
    (Stage2Config, "eval_views"): "eval_views",
    (Stage2Config, "checkpoint_seconds"): "checkpoint_minutes",
    (NarrowBandConfig, "delta_s"): "delta_s",
    (NarrowBandConfig, "w_s"): "w_s",
}


@dataclass(frozen=True)
class FinetuneSettings:
    """What ``shellsim finetune`` takes; None keeps the asset's value."""

    asset: str = option(help="shipped asset name or asset directory", required=True)
    data: str = option(help="the dataset the asset was trained on", required=True)
    out: str = option(help="directory of the new asset (checkpoints go in OUT/checkpoints)", required=True)
    steps: int = option(1000, help="fine-tuning steps")
    rate: float = option(
        0.1, help="learning rates as a fraction of the asset's stage-1 base rates (a converged field: ~0.1)"
    )
    delta_s: float | None = option(
        help="target spacing between narrow-band samples, world units (smaller: more samples per pixel)",
        shown_default=THE_ASSETS,
    )
    w_s: float | None = option(
        help="narrow-band intervals thinner than this get one sample, world units (smaller: more samples "
        "per pixel where the shells are thin)",
        shown_default=THE_ASSETS,
    )
    error_sampling: float | None = option(
        help="share of the rays drawn where the colour error is high", shown_default="the asset's stage 2's"
    )
    rays: int = option(Stage2Config.rays, help="rays per step")
    eval_views: int = option(
        Stage2Config.eval_views, help="held-out views of each evaluation but the last (0: all; the last: all)"
    )
    checkpoint_minutes: float = option(
        Stage2Config.checkpoint_seconds / 60.0,
        help="also write a checkpoint when this many minutes have passed since the last",
    )
    name: str | None = option(help="asset name", shown_default="the output directory's name")
    keep_checkpoints: bool = option(False, help="keep OUT/checkpoints after success")
    device: str = option("auto", help="cpu, cuda or auto")

    def __post_init__(self):
        check_required(self)
        with config_bounds(self, CONFIG_FIELDS):
            self.stage2_config({})
            NarrowBandConfig(**self.narrowband_overrides())
        check_choice("device", self.device, DEVICES)

    def narrowband_overrides(self) -> dict:
        """The narrow-band settings that are set: {NarrowBandConfig field: value}."""
        return {k: getattr(self, k) for k in ("delta_s", "w_s") if getattr(self, k) is not None}

    def stage2_config(self, training: dict) -> Stage2Config:
        """Stage 2's settings for an asset whose ``asset.json`` records ``training`` (its rates and error
        sampling where recorded, else the library's)."""
        stage1, stage2 = training.get("stage1", {}), training.get("stage2", {})
        error_sampling = self.error_sampling
        if error_sampling is None:
            error_sampling = stage2.get("error_sampling", Stage2Config.error_sampling)
        return dataclasses.replace(
            Stage2Config(),
            steps=self.steps,
            rays=self.rays,
            lr_encoding=self.rate * float(stage1.get("lr_encoding", Stage1Config.lr_encoding)),
            lr_network=self.rate * float(stage1.get("lr_network", Stage1Config.lr_network)),
            error_sampling=error_sampling,
            eval_views=self.eval_views,
            checkpoint_seconds=60.0 * self.checkpoint_minutes,
        )


@dataclass(frozen=True)
class FinetuneResult:
    """The asset :func:`finetune` wrote: ``before`` and ``after`` its narrow-band figures (held-out views)
    before and after the fine-tuning (``before`` None where the asset recorded none), ``wall_minutes`` the
    wall time of the fine-tuning over every run that resumed it."""

    asset: Path
    before: ViewMetrics | None
    after: ViewMetrics
    wall_minutes: float


@holds_outputs
def finetune(settings: FinetuneSettings) -> FinetuneResult:
    """Fine-tune ``settings.asset`` into the new asset ``settings.out`` (resuming from its checkpoints).
    The output is checked before anything is loaded."""
    from neural.asset import load_asset
    from neural.pipeline import finetune_asset

    lock_output(check_writable_dir(settings.out, "out"), "out")  # the asset and its checkpoints
    check_writable_dir(Path(settings.out) / "checkpoints", "out")
    asset = load_asset(settings.asset)
    config = settings.stage2_config(asset.meta.get("training", {}))
    narrowband = dataclasses.replace(asset.narrowband_config(), **settings.narrowband_overrides())
    root = finetune_asset(
        asset.root,
        settings.data,
        settings.out,
        config,
        narrowband,
        device_setting(settings.device),
        name=settings.name,
        keep_checkpoints=settings.keep_checkpoints,
    )
    meta = load_asset(root).meta
    done = meta["training"]["finetune"][-1]
    before = done.get("narrow_band_before")
    return FinetuneResult(
        asset=Path(root),
        before=ViewMetrics.of(before) if before else None,
        after=ViewMetrics.of(meta["metrics"]["stage2_narrow_band"]),
        wall_minutes=float(done["wall_minutes"]),
    )
