"""Train an asset from posed photos: Procedure 4 (stage 1 -> shell extraction -> stage 2) on one dataset.

Defaults are those of :mod:`neural.config`; stage 2's length, the shell grid and the batch and occupancy
sizes follow the stage-1 steps unless set (:func:`neural.config.scaled_defaults`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

from neural.config import (
    QUICK_STEPS,
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
from shellsim.errors import SettingError
from shellsim.io.outputs import check_writable_dir
from shellsim.settings import check_choice, check_range, device_setting, option

COLOURS = {"white": (1.0, 1.0, 1.0), "black": (0.0, 0.0, 0.0)}


def parse_background(text: str) -> tuple[float, float, float]:
    """``white``, ``black`` or ``r,g,b`` in [0, 1] -> (r, g, b); ValueError otherwise."""
    if text in COLOURS:
        return COLOURS[text]
    try:
        values = tuple(float(p) for p in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(0.0 <= v <= 1.0 for v in values):
        raise ValueError("expected white, black or r,g,b in [0, 1]")
    return values  # type: ignore[return-value]


def _colour_name(rgb: tuple[float, ...]) -> str:
    return next((name for name, value in COLOURS.items() if value == tuple(rgb)), ",".join(map(str, rgb)))


_DEFAULT_STEPS = Stage1Config.steps
_QUICK = scaled_defaults(1)


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
    bound: float | None = option(
        help="half-size of the object's box in world units", shown_default="from the dataset"
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
    name: str | None = option(help="asset name", shown_default="the output directory's name")
    keep_checkpoints: bool = option(False, help="keep OUT/checkpoints after success")
    device: str = option("auto", help="cpu, cuda or auto")

    def __post_init__(self):
        if self.eval_views < 0:
            raise SettingError("eval_views", f"expected an integer >= 0, got {self.eval_views}")
        for name in ("downscale", "steps", "stage2_steps", "eval_every"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise SettingError(name, f"expected a positive integer, got {value}")
        if self.shell_resolution is not None and self.shell_resolution < 8:
            raise SettingError("shell_resolution", f"expected an integer >= 8, got {self.shell_resolution}")
        if self.kernel_grid not in range(2, 513) and self.kernel_grid != 0:
            raise SettingError("kernel_grid", f"expected 0 or an integer in 2..512, got {self.kernel_grid}")
        if not 0 <= self.sharpness < math.inf:
            raise SettingError("sharpness", f"expected a number >= 0, got {self.sharpness}")
        for name in ("checkpoint_minutes", "bound"):
            value = getattr(self, name)
            if value is not None and not 0 < value < math.inf:
                raise SettingError(name, f"expected a positive number, got {value}")
        check_range("table_size", self.table_size, 1, 30, "an integer")
        check_range("seed", self.seed, 0, 2**31 - 1, "an integer")
        check_choice("view_encoding", self.view_encoding, VIEW_ENCODINGS)
        check_choice("device", self.device, DEVICES)

    def pipeline_config(self) -> PipelineConfig:
        """The library's settings: these, with what goes with the stage-1 steps where not set."""
        scaled = scaled_defaults(self.steps)
        config = PipelineConfig(background=self.background, bound=self.bound, downscale=self.downscale)
        seconds = 60.0 * self.checkpoint_minutes
        config.stage1 = dataclasses.replace(
            config.stage1,
            steps=self.steps,
            target_samples=scaled["target_samples"],
            occupancy_resolution=scaled["occupancy_resolution"],
            lambda_k=self.sharpness,
            random_background=self.random_background,
            checkpoint_seconds=seconds,
            eval_every=self.eval_every,
            eval_views=self.eval_views,
            seed=self.seed,
        )
        config.stage2 = dataclasses.replace(
            config.stage2,
            steps=self.stage2_steps or scaled["stage2_steps"],
            seed=self.seed + 1,
            random_background=self.random_background,
            checkpoint_seconds=seconds,
            eval_views=self.eval_views,
        )
        config.shell = dataclasses.replace(
            config.shell, resolution=self.shell_resolution or scaled["shell_resolution"]
        )
        grid = dataclasses.replace(config.field.hashgrid, log2_table_size=self.table_size)
        config.field = dataclasses.replace(
            config.field, hashgrid=grid, kernel_grid=self.kernel_grid, view_encoding=self.view_encoding
        )
        return config


def train(settings: TrainSettings) -> Path:
    """Train the asset ``settings.out`` from the dataset ``settings.data`` (resuming from its checkpoints);
    returns the asset directory. The output is checked before anything is loaded."""
    from neural.pipeline import train_asset

    check_writable_dir(settings.out, "out")
    check_writable_dir(Path(settings.out) / "checkpoints", "out")
    return train_asset(
        settings.data,
        settings.out,
        settings.pipeline_config(),
        device_setting(settings.device),
        name=settings.name,
        keep_checkpoints=settings.keep_checkpoints,
    )
