"""Train an asset from posed photos: Procedure 4 (stage 1 -> shell extraction -> stage 2) on one dataset.

Defaults are those of :mod:`neural.config`; stage 2's length, the shell grid and the batch and occupancy
sizes follow the stage-1 steps unless set (:func:`neural.config.scaled_defaults`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from neural.config import (
    MAX_SEED,
    QUICK_STEPS,
    SPACES,
    VIEW_ENCODINGS,
    FieldConfig,
    HashGridConfig,
    PipelineConfig,
    ShellConfig,
    Stage1Config,
    Stage2Config,
    scaled_defaults,
)
from neural.device import DEVICES
from shellsim.io.outputs import check_writable_dir, holds_outputs, lock_output
from shellsim.jobs.eval import ViewMetrics
from shellsim.memory import check_memory, shell_bytes
from shellsim.settings import check_choice, check_required, config_bounds, device_setting, option

COLOURS = {"white": (1.0, 1.0, 1.0), "black": (0.0, 0.0, 0.0)}


def parse_background(text: str) -> tuple[float, float, float]:
    """``white``, ``black`` or ``r,g,b`` -> (r, g, b); ValueError otherwise (their bounds:
    :class:`~neural.config.PipelineConfig`)."""
    if text in COLOURS:
        return COLOURS[text]
    try:
        values = tuple(float(p) for p in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3:
        raise ValueError("expected white, black or r,g,b")
    return values  # type: ignore[return-value]


def _colour_name(rgb: tuple[float, ...]) -> str:
    return next((name for name, value in COLOURS.items() if value == tuple(rgb)), ",".join(map(str, rgb)))


_DEFAULT_STEPS = Stage1Config.steps
_QUICK = scaled_defaults(1)

#: The config field each setting sets: its bound (:mod:`neural.config`) is the setting's.
CONFIG_FIELDS = {
    (PipelineConfig, "downscale"): "downscale",
    (PipelineConfig, "background"): "background",
    (PipelineConfig, "bound"): "bound",
    (PipelineConfig, "space"): "space",
    (Stage1Config, "steps"): "steps",
    (Stage2Config, "steps"): "stage2_steps",
    (ShellConfig, "resolution"): "shell_resolution",
    (Stage1Config, "checkpoint_seconds"): "checkpoint_minutes",
    (Stage2Config, "checkpoint_seconds"): "checkpoint_minutes",
    (HashGridConfig, "log2_table_size"): "table_size",
    (FieldConfig, "kernel_grid"): "kernel_grid",
    (Stage1Config, "lambda_k"): "sharpness",
    (FieldConfig, "view_encoding"): "view_encoding",
    (Stage1Config, "eval_every"): "eval_every",
    (Stage1Config, "eval_views"): "eval_views",
    (Stage2Config, "eval_views"): "eval_views",
    (Stage1Config, "seed"): "seed",
    (Stage1Config, "error_sampling"): "error_sampling",
    (Stage2Config, "error_sampling"): "error_sampling",
    (Stage2Config, "lr_encoding"): "stage2_rate",
    (Stage2Config, "lr_network"): "stage2_rate",
}


@dataclass(frozen=True)
class TrainSettings:
    """What ``shellsim train`` takes; :meth:`pipeline_config` turns it into the library's settings."""

    data: str = option(help="dataset dir: transforms*.json or COLMAP sparse/0", required=True)
    out: str = option(help="asset directory to write (checkpoints go in OUT/checkpoints)", required=True)
    downscale: int = option(PipelineConfig.downscale, help="image downscale factor")
    steps: int = option(_DEFAULT_STEPS, help="stage-1 steps; stage 2 and the shell grid follow")
    stage2_steps: int | None = option(
        help="stage-2 steps",
        shown_default=f"stage-1 steps / 6, {scaled_defaults(_DEFAULT_STEPS)['stage2_steps']} for "
        f"{_DEFAULT_STEPS}",
    )
    background: tuple[float, float, float] = option(
        PipelineConfig.background,
        parse=parse_background,
        help="colour behind the asset: white, black or r,g,b",
        shown_default=_colour_name(PipelineConfig.background),
    )
    random_background: bool = option(
        False,
        help="train with a random colour behind the fully transparent pixels of images with alpha, so that "
        "no floater can hide in background-coloured space (costs about 1.3 dB held-out on lego; small "
        "floaters apart from the object are dropped from the shells anyway)",
    )
    unseen_prior: bool = option(
        True,
        flag="--no-unseen-prior",
        negate=True,
        help="leave out the prior for what no training camera saw (an object's underside): by default the "
        "unseen space below the lowest seen surface is carved empty and unseen surface takes the colour of "
        "the nearest seen surface",
    )
    error_sampling: float = option(
        Stage1Config.error_sampling,
        help="share of the training rays drawn where the colour error is high (tiles of the training views "
        "in proportion to their running error, as Instant-NGP's error map); the rest are uniform",
    )
    bound: float | None = option(
        help="half-size of the object's box in world units", shown_default="from the dataset"
    )
    space: str = option(
        PipelineConfig.space,
        choices=SPACES,
        help="where the field lives: contracted (the object's box is the unit ball and the whole world "
        "beyond it is pulled into a ball twice as wide, so the room around a real capture is learnt: paper "
        "Sec. 4.7), bounded (the box only, an environment map beyond it) or auto (contracted for photos "
        "without alpha)",
    )
    shell_resolution: int | None = option(
        help="grid resolution of the shell extraction",
        shown_default=f"{ShellConfig.resolution}; {_QUICK['shell_resolution']} when --steps < {QUICK_STEPS}",
    )
    checkpoint_minutes: float = option(
        Stage1Config.checkpoint_seconds / 60.0,
        help="also write a checkpoint when this many minutes have passed since the last",
    )
    table_size: int = option(HashGridConfig.log2_table_size, help="log2 of the hash-table size")
    kernel_grid: int = option(
        FieldConfig.kernel_grid,
        help="nodes per axis of the grid that lets the kernel size vary in space on its own (0: only the "
        "network's output, as in the paper)",
    )
    sharpness: float = option(
        Stage1Config.lambda_k,
        help="weight of the prior that makes the kernel sharp where the photos do not ask for a volume (0: "
        "the paper's losses only)",
    )
    view_encoding: str = option(
        FieldConfig.view_encoding,
        choices=VIEW_ENCODINGS,
        help="colour input: the view direction mirrored about the normal (reflected: glossy surfaces stay "
        "surfaces) or the view direction itself (direction: the paper's)",
    )
    eval_every: int = option(
        Stage1Config.eval_every,
        help="stage-1 steps between held-out evaluations (stage 2: every "
        f"{Stage2Config.eval_every}); asset.json records them as a curve of PSNR against minutes",
    )
    eval_views: int = option(
        Stage1Config.eval_views, help="held-out views of each evaluation but the last (0: all; the last: all)"
    )
    seed: int = option(
        Stage1Config.seed,
        help="random seed of the initial weights and of the rays drawn: the same command trains the same "
        "asset (on the CPU); another seed is another draw",
    )
    init: str | None = option(
        help="continue the training of this asset (a name or directory, trained on the same data): stage 1 "
        "goes on from its field and the step its stage 1 reached, to --steps, with a fresh optimizer; the "
        "field's settings (table size, kernel grid, view encoding, space) are the asset's, and the minutes "
        "of the training curve go on from its own. A long training thus accumulates across sessions",
        shown_default="a fresh field",
    )
    stage2_rate: float = option(
        1.0,
        help="stage 2's learning rates as a fraction of stage 1's base rates (1 suits a field still "
        "learning; a converged one, as after --init, keeps more of its quality with about 0.1)",
    )
    name: str | None = option(help="asset name", shown_default="the output directory's name")
    keep_checkpoints: bool = option(False, help="keep OUT/checkpoints after success")
    device: str = option("auto", help="cpu, cuda or auto")

    def __post_init__(self):
        check_required(self)
        with config_bounds(self, CONFIG_FIELDS):
            self.pipeline_config()
        check_choice("device", self.device, DEVICES)

    def pipeline_config(self) -> PipelineConfig:
        """The library's settings: these, with what goes with the stage-1 steps where not set."""
        scaled = scaled_defaults(self.steps)
        config = PipelineConfig(
            background=self.background, bound=self.bound, downscale=self.downscale, space=self.space
        )
        seconds = 60.0 * self.checkpoint_minutes
        config.stage1 = dataclasses.replace(
            config.stage1,
            steps=self.steps,
            target_samples=scaled["target_samples"],
            occupancy_resolution=scaled["occupancy_resolution"],
            lambda_k=self.sharpness,
            random_background=self.random_background,
            error_sampling=self.error_sampling,
            visibility_every=scaled["visibility_every"],
            **({} if self.unseen_prior else {"lambda_carve": 0.0, "lambda_paint": 0.0}),
            checkpoint_seconds=seconds,
            eval_every=self.eval_every,
            eval_views=self.eval_views,
            seed=self.seed,
        )
        config.stage2 = dataclasses.replace(
            config.stage2,
            lr_encoding=config.stage1.lr_encoding * self.stage2_rate,
            lr_network=config.stage1.lr_network * self.stage2_rate,
            steps=scaled["stage2_steps"] if self.stage2_steps is None else self.stage2_steps,
            seed=(self.seed + 1) % (MAX_SEED + 1),
            random_background=self.random_background,
            error_sampling=self.error_sampling,
            lambda_paint=config.stage2.lambda_paint if self.unseen_prior else 0.0,
            checkpoint_seconds=seconds,
            eval_views=self.eval_views,
        )
        resolution = scaled["shell_resolution"] if self.shell_resolution is None else self.shell_resolution
        config.shell = dataclasses.replace(config.shell, resolution=resolution)
        grid = dataclasses.replace(config.field.hashgrid, log2_table_size=self.table_size)
        config.field = dataclasses.replace(
            config.field, hashgrid=grid, kernel_grid=self.kernel_grid, view_encoding=self.view_encoding
        )
        return config


@dataclass(frozen=True)
class TrainResult:
    """The asset :func:`train` wrote, with the held-out figures its ``asset.json`` records.

    asset : the asset directory
    stage1 : full-ray rendering at the end of stage 1; stage2 : narrow-band rendering (the asset's renderer)
        at the end of stage 2 (None where none was recorded)
    wall_minutes : wall time of the training, over every run that resumed it
    """

    asset: Path
    stage1: ViewMetrics | None
    stage2: ViewMetrics | None
    wall_minutes: float


@holds_outputs
def train(settings: TrainSettings) -> TrainResult:
    """Train the asset ``settings.out`` from the dataset ``settings.data`` (resuming from its checkpoints).
    The output is checked before anything is loaded."""
    from neural.asset import load_asset
    from neural.pipeline import train_asset

    lock_output(check_writable_dir(settings.out, "out"), "out")  # the asset and its checkpoints
    check_writable_dir(Path(settings.out) / "checkpoints", "out")
    config, device = settings.pipeline_config(), device_setting(settings.device)
    resolution = config.shell.resolution
    grid = f"a shell grid of {resolution}^3 nodes"
    check_memory("shell_resolution", shell_bytes(resolution), grid, "to extract the shells", device)
    root = train_asset(
        settings.data,
        settings.out,
        config,
        device,
        name=settings.name,
        keep_checkpoints=settings.keep_checkpoints,
        init=settings.init,
    )
    meta = load_asset(root).meta
    metrics = meta.get("metrics", {})
    stage1, stage2 = metrics.get("stage1_full_ray"), metrics.get("stage2_narrow_band")
    return TrainResult(
        asset=Path(root),
        stage1=ViewMetrics.of(stage1) if stage1 else None,
        stage2=ViewMetrics.of(stage2) if stage2 else None,
        wall_minutes=float(meta["training"]["wall_minutes"]),
    )
