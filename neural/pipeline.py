"""Procedure 4 end to end: stage 1 -> adaptive-shell extraction -> stage 2 -> an asset on disk.

Each phase leaves its result in the output directory (checkpoints, then the shells, then the asset), so
an interrupted run resumes where it stopped.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from .asset import command_line, save_asset
from .data import SceneData, load_dataset
from .errors import InputError
from .field import FieldConfig, ShellField
from .render.narrowband import NarrowBandConfig
from .shell import ShellConfig
from .shell.from_field import extract_field_shells
from .train import Stage1Config, Stage2Config, train_stage1, train_stage2

log = logging.getLogger(__name__)


@dataclass
class PipelineConfig:
    """Everything ``shellsim train`` sets. Lengths of the stage settings are in the field's unit space."""

    field: FieldConfig = dataclasses.field(default_factory=FieldConfig)
    stage1: Stage1Config = dataclasses.field(default_factory=Stage1Config)
    shell: ShellConfig = dataclasses.field(default_factory=ShellConfig)
    narrowband: NarrowBandConfig = dataclasses.field(default_factory=NarrowBandConfig)
    stage2: Stage2Config = dataclasses.field(default_factory=Stage2Config)
    downscale: int = 1
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    bound: float | None = None


def build_field(data: SceneData, config: FieldConfig, device: str) -> ShellField:
    """A freshly initialised field covering the dataset's normalised unit cube."""
    norm = data.normalisation
    return ShellField(config, center=tuple(float(c) for c in norm.center), scale=float(norm.scale)).to(device)


def train_asset(
    data_dir,
    out_dir,
    config: PipelineConfig,
    device: str,
    name: str | None = None,
    keep_checkpoints: bool = False,
) -> Path:
    """Run Procedure 4 on the dataset in ``data_dir`` and write the asset to ``out_dir``."""
    out_dir = Path(out_dir)
    if (out_dir / "asset.json").is_file() and not (out_dir / "checkpoints").is_dir():
        raise InputError(f"{out_dir}: holds a finished asset already; choose another --out or delete it")
    started = time.time()
    data = load_dataset(
        data_dir, downscale=config.downscale, background=config.background, bound=config.bound
    )
    log.info(
        "%s: %d training and %d held-out views of %dx%d",
        data_dir,
        len(data.train_idx),
        len(data.test_idx),
        int(data.cameras.width[0]),
        int(data.cameras.height[0]),
    )
    field_ = build_field(data, config.field, device)
    stage1 = train_stage1(field_, data, out_dir, config.stage1, device)
    shells = extract_field_shells(field_, config.shell, device)
    narrowband = config.narrowband.scaled(1.0 / float(data.normalisation.scale))  # unit cube -> world
    stage2 = train_stage2(
        field_, data, shells.outer, shells.inner, out_dir, config.stage2, narrowband, device
    )
    meta = {
        "name": name or out_dir.name,
        "normalisation": {
            "center": [float(c) for c in data.normalisation.center],
            "scale": float(data.normalisation.scale),
        },
        "up": [float(u) for u in data.up],
        "background": [float(b) for b in data.background],
        "narrowband": dataclasses.asdict(narrowband),
        "shell": {**dataclasses.asdict(config.shell), **shells.stats},
        "training": {
            "command": command_line(),
            "data": str(data_dir),
            "downscale": config.downscale,
            "device": device,
            "stage1": dataclasses.asdict(config.stage1),
            "stage2": dataclasses.asdict(config.stage2),
            "train_views": len(data.train_idx),
            "heldout_views": [int(v) for v in data.test_idx],
            "wall_minutes": round((time.time() - started) / 60.0, 2),
            "torch": torch.__version__,
        },
        "metrics": {"stage1_full_ray": stage1["final"], "stage2_narrow_band": stage2["final"]},
    }
    save_asset(out_dir, field_, shells.outer, shells.inner, meta)
    if not keep_checkpoints:
        for ckpt in (out_dir / "checkpoints").glob("*.safetensors"):
            ckpt.unlink()
        _rmdir(out_dir / "checkpoints")
    log.info("asset written to %s:\n%s", out_dir, json.dumps(meta["metrics"], indent=1))
    return out_dir


def _rmdir(path: Path) -> None:
    if path.is_dir() and not any(path.iterdir()):
        path.rmdir()


def parse_background(text: str) -> tuple[float, float, float]:
    """``white``, ``black`` or ``r,g,b`` in [0, 1]."""
    named = {"white": (1.0, 1.0, 1.0), "black": (0.0, 0.0, 0.0)}
    if text in named:
        return named[text]
    parts = text.split(",")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 3 or not all(0.0 <= v <= 1.0 for v in values):
        raise InputError(f"--background: expected white, black or r,g,b in [0, 1], got {text!r}")
    return values  # type: ignore[return-value]
