"""Procedure 4 end to end: stage 1 -> adaptive-shell extraction -> stage 2 -> an asset on disk.

Each phase leaves its result in ``OUT/checkpoints`` (stage checkpoints, the extracted shells, the wall time
of the runs so far), then the asset in ``OUT``, so an interrupted run resumes where it stopped.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import time
from pathlib import Path

import numpy as np
import torch

from .asset import command_line, save_asset
from .config import FieldConfig, NarrowBandConfig, PipelineConfig, Stage2Config
from .data import SceneData, load_dataset
from .device import processor
from .errors import InputError
from .field import ShellField
from .field.contraction import CONTRACTED_RADIUS
from .files import write_atomically, write_text_atomically
from .shell.from_field import FieldShells, extract_field_shells
from .train import Continuation, train_stage1, train_stage2, unseen_prior
from .visibility import VISIBILITY_RESOLUTION, Visibility, measure_visibility

log = logging.getLogger(__name__)


def build_field(
    data: SceneData, config: FieldConfig, device: str, seed: int = 0, space: str = "auto"
) -> ShellField:
    """A freshly initialised field over the dataset's normalised box. Photos without alpha (a real capture:
    every pixel sees something) get an environment map (``FieldConfig.env_map``) and, with ``space`` "auto"
    or "contracted", a field in contracted space (``FieldConfig.contract``): the object's box is the unit
    ball of the contraction and the field's box holds the whole contracted world, twice as wide.
    Its random initial weights are drawn from ``seed`` (torch's global generator is left as it was), so that
    the same command trains the same asset."""
    norm = data.normalisation
    photos = data.alphas is None
    contract = space == "contracted" or (space == "auto" and photos)
    config = dataclasses.replace(config, env_map=config.env_map or photos, contract=contract)
    scale = float(norm.scale) / (CONTRACTED_RADIUS if contract else 1.0)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        field_ = ShellField(config, center=tuple(float(c) for c in norm.center), scale=scale)
    return field_.to(device)


def train_asset(
    data_dir,
    out_dir,
    config: PipelineConfig,
    device: str,
    name: str | None = None,
    keep_checkpoints: bool = False,
    init=None,
) -> Path:
    """Run Procedure 4 on the dataset in ``data_dir`` and write the asset to ``out_dir``. With ``init`` (an
    asset trained on the same dataset), stage 1 continues that asset's field from the step its own stage 1
    reached to ``config.stage1.steps``, on the asset's field settings; the curve's minutes go on from the
    asset's training minutes."""
    out_dir = Path(out_dir)
    _refuse_finished(out_dir)
    with _counted_runs(out_dir / "checkpoints") as (runs, started):
        return _train(data_dir, out_dir, config, device, name, keep_checkpoints, runs, started, init)


def finetune_asset(
    asset_spec,
    data_dir,
    out_dir,
    config: Stage2Config,
    narrowband: NarrowBandConfig,
    device: str,
    name: str | None = None,
    keep_checkpoints: bool = False,
) -> Path:
    """Stage 2 again (Procedure 4 lines 8-13) on a finished asset: its field fine-tuned inside its own shells
    with the narrow-band sampling ``narrowband`` (world units), so that it adapts to denser or sparser
    samples, unseen surface kept in the nearest seen colour (:mod:`neural.visibility`); written as a new
    asset to ``out_dir`` (resumed from ``out_dir/checkpoints``). ``data_dir`` must
    hold the asset's training data. The new ``asset.json`` keeps the asset's record; ``training.finetune``
    lists the fine-tunings and the curve goes on from the asset's minutes."""
    from .asset import load_asset, load_field, load_mesh

    out_dir = Path(out_dir)
    _refuse_finished(out_dir)
    asset = load_asset(asset_spec)
    meta, training = asset.meta, asset.meta.get("training", {})
    data = load_dataset(
        data_dir,
        downscale=training.get("downscale", 1),
        background=meta.get("background", PipelineConfig.background),
        bound=1.0 / asset.scale,  # the asset's: then only the centre can differ
    )
    _check_same_data(asset, data)
    field_ = load_field(asset, device).train()
    outer, inner = (load_mesh(asset.file(key)) for key in ("shell_outer", "shell_inner"))
    with _counted_runs(out_dir / "checkpoints") as (runs, started):
        resolution = _visibility_resolution(meta.get("shell", {}).get("resolution", VISIBILITY_RESOLUTION))
        prior = unseen_prior(field_, data, resolution=resolution) if config.lambda_paint > 0 else None
        stage2 = train_stage2(field_, data, outer, inner, out_dir, config, narrowband, device, prior)
        wall_minutes = (runs["seconds"] + time.time() - started) / 60.0
    minutes = _asset_minutes(asset)
    curve = [
        {**p, "minutes": round(minutes + p["minutes"], 2)} for p in training_curve([], 0.0, stage2["history"])
    ]
    done = {
        "asset": asset.name,
        "command": command_line(),
        "stage2": dataclasses.asdict(config),
        "narrowband_before": meta.get("narrowband"),
        "narrow_band_before": meta.get("metrics", {}).get("stage2_narrow_band"),
        "minutes_before": minutes,
        "wall_minutes": round(wall_minutes, 2),
    }
    new_meta = {k: v for k, v in meta.items() if k not in ("format", "format_version", "files", "field")}
    new_meta.update(
        name=name or out_dir.name,
        narrowband=dataclasses.asdict(narrowband),
        training={
            **training,
            "curve": [*training.get("curve", []), *curve],
            "wall_minutes": round(float(training.get("wall_minutes", 0.0)) + wall_minutes, 2),
            "finetune": [*training.get("finetune", []), done],
        },
        # the figures of the field before (the eval's and the earlier shells' too) no longer hold
        metrics={
            **{k: v for k, v in meta.get("metrics", {}).items() if k == "stage1_full_ray"},
            "stage2_narrow_band": stage2["final"],
        },
    )
    save_asset(out_dir, field_, outer, inner, new_meta, asset_visibility(field_, data, resolution))
    if not keep_checkpoints:
        _remove_checkpoints(out_dir)
    log.info("fine-tuned asset written to %s: %s", out_dir, json.dumps(stage2["final"]))
    return out_dir


def _visibility_resolution(shell_resolution) -> int:
    """The visibility grid of a field whose shells were extracted at ``shell_resolution``: as fine, at most
    :data:`~neural.visibility.VISIBILITY_RESOLUTION` cells a side."""
    try:
        return max(8, min(VISIBILITY_RESOLUTION, int(shell_resolution)))
    except (TypeError, ValueError):
        return VISIBILITY_RESOLUTION


def asset_visibility(field_: ShellField, data: SceneData, resolution: int) -> Visibility | None:
    """The trained field's :class:`~neural.visibility.Visibility` from its training views on a
    ``resolution``^3 grid: what an asset records of what its cameras saw. None for a field in contracted
    space (a capture's room; see :func:`~neural.train.unseen_prior`)."""
    if field_.contraction is not None:
        return None
    visibility, _ = measure_visibility(field_, data, resolution=resolution)
    log.info(
        "%.1f%% of the surface lies where no training view saw it", 100 * visibility.unseen_surface_share
    )
    return visibility


def _refuse_finished(out_dir: Path) -> None:
    """Training writes into an output directory only while its checkpoints are there."""
    if (out_dir / "asset.json").is_file() and not (out_dir / "checkpoints").is_dir():
        raise InputError(
            f"{out_dir}: holds a finished asset already; choose another output directory or delete it"
        )


@contextlib.contextmanager
def _counted_runs(ckpt_dir: Path):
    """Yields the earlier runs' ``{"seconds", "runs"}`` and this run's start; on leaving, also on an interrupt
    or an error, this run is added to them, so that the next run adds its time to this one's."""
    runs, started = _read_runs(ckpt_dir), time.time()
    try:
        yield runs, started
    finally:
        if ckpt_dir.is_dir():
            _write_runs(ckpt_dir, runs["seconds"] + time.time() - started, runs["runs"] + 1)


def _train(data_dir, out_dir: Path, config, device, name, keep_checkpoints, runs: dict, started: float, init):
    start = _start_asset(init, config.stage1.steps) if init is not None else None
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
    if start is None:
        field_ = build_field(data, config.field, device, config.stage1.seed, config.space)
        continuation, earlier = None, None
    else:
        field_, continuation, earlier = _continued_field(start, data, device)
    stage1 = train_stage1(field_, data, out_dir, config.stage1, device, continuation)
    shells, extraction_seconds = _load_shells(out_dir / "checkpoints", config) or (None, 0.0)
    if shells is None:
        tick = time.perf_counter()
        shells = extract_field_shells(field_, config.shell, device)
        extraction_seconds = time.perf_counter() - tick
        _save_shells(out_dir / "checkpoints", config, shells, extraction_seconds)
    narrowband = config.narrowband.scaled(1.0 / float(data.normalisation.scale))  # unit cube -> world
    prior, resolution = None, _visibility_resolution(config.shell.resolution)
    if config.stage2.lambda_paint > 0 and (config.stage1.lambda_carve > 0 or config.stage1.lambda_paint > 0):
        prior = unseen_prior(field_, data, resolution=resolution)
    stage2 = train_stage2(
        field_, data, shells.outer, shells.inner, out_dir, config.stage2, narrowband, device, prior
    )
    visibility = asset_visibility(field_, data, resolution)
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
            "processor": processor(device),
            "stage1": dataclasses.asdict(config.stage1),
            "stage2": dataclasses.asdict(config.stage2),
            "train_views": len(data.train_idx),
            "heldout_views": [int(v) for v in data.test_idx],
            "wall_minutes": round((runs["seconds"] + time.time() - started) / 60.0, 2),  # all runs
            "runs": runs["runs"] + 1,
            "torch": torch.__version__,
            "curve": training_curve(stage1["history"], extraction_seconds, stage2["history"]),
            **({"init": earlier} if earlier else {}),
        },
        "metrics": {"stage1_full_ray": stage1["final"], "stage2_narrow_band": stage2["final"]},
    }
    save_asset(out_dir, field_, shells.outer, shells.inner, meta, visibility)
    if not keep_checkpoints:
        _remove_checkpoints(out_dir)
    log.info("asset written to %s:\n%s", out_dir, json.dumps(meta["metrics"], indent=1))
    return out_dir


def _start_asset(init, steps: int):
    """The asset a training continues, checked before the dataset is loaded."""
    from .asset import load_asset

    asset = load_asset(init)
    done = asset.meta.get("training", {}).get("stage1", {}).get("steps")
    if not isinstance(done, int) or isinstance(done, bool) or done < 1:
        raise InputError(f"{asset.root / 'asset.json'}: records no stage-1 steps (training.stage1.steps)")
    if done >= steps:
        raise InputError(
            f"{asset.root}: its stage 1 ran {done} steps already; continuing it takes more stage-1 steps "
            f"than that (asked for {steps})"
        )
    return asset


def _continued_field(asset, data: SceneData, device: str):
    """``asset``'s field in training mode, the :class:`Continuation` of its stage 1 and the facts of it that
    the new ``asset.json`` records under ``training.init``. The dataset must be normalised as the asset is."""
    from .asset import load_field

    _check_same_data(asset, data)
    training = asset.meta["training"]
    minutes = _asset_minutes(asset)
    curve = training.get("curve") or [{}]
    field_ = load_field(asset, device).train()
    earlier = {
        "asset": asset.name,
        "stage1_steps": training["stage1"]["steps"],
        "minutes": minutes,
        "command": training.get("command"),
        "curve": curve,
    }
    return field_, Continuation(training["stage1"]["steps"], 60.0 * minutes), earlier


def _check_same_data(asset, data: SceneData) -> None:
    """An :class:`InputError` of ``asset`` unless ``data`` is normalised as the asset's training data was."""
    norm = data.normalisation
    same = np.allclose(norm.center, asset.center, rtol=0, atol=1e-6 * asset.scale) and np.isclose(
        float(norm.scale), asset.scale, rtol=1e-6, atol=0
    )
    if not same:
        raise InputError(
            f"{asset.root}: trained on other data (its normalisation, centre {list(asset.center)} and scale "
            f"{asset.scale}, is not this dataset's, centre {[float(c) for c in norm.center]} and scale "
            f"{float(norm.scale)})"
        )


def _asset_minutes(asset) -> float:
    """The training minutes the asset's curve reached (0 without a curve)."""
    curve = asset.meta.get("training", {}).get("curve") or [{}]
    return float(curve[-1].get("minutes", 0.0))


def training_curve(stage1: list[dict], extraction_seconds: float, stage2: list[dict]) -> list[dict]:
    """Held-out PSNR against training minutes: the stage-1 evaluations (occupancy-grid rendering), then the
    stage-2 ones (narrow band) after stage 1's and the extraction's time. Minutes leave the evaluations out
    and add up over the runs that resumed the training."""
    keys = ("step", "psnr", "ssim", "samples_per_pixel")
    stage1_seconds = stage1[-1]["train_seconds"] if stage1 else 0.0
    points = [(1, m, m["train_seconds"]) for m in stage1]
    points += [(2, m, stage1_seconds + extraction_seconds + m["train_seconds"]) for m in stage2]
    return [
        {
            "stage": stage,
            "minutes": round(seconds / 60.0, 2),
            "views": len(m["views"]),
            **{k: m[k] for k in keys},
        }
        for stage, m, seconds in points
    ]


CHECKPOINT_FILES = ("stage1.safetensors", "stage2.safetensors", "runs.json")
SHELL_FILES = ("shell_outer.ply", "shell_inner.ply", "shells.json")


def _read_runs(ckpt_dir: Path) -> dict:
    """Wall seconds and count of the earlier runs that trained into ``ckpt_dir`` (none: zeros)."""
    try:
        runs = json.loads((ckpt_dir / "runs.json").read_text())
        return {"seconds": float(runs["seconds"]), "runs": int(runs["runs"])}
    except (OSError, ValueError, KeyError, TypeError):
        return {"seconds": 0.0, "runs": 0}


def _write_runs(ckpt_dir: Path, seconds: float, runs: int) -> None:
    write_text_atomically(ckpt_dir / "runs.json", json.dumps({"seconds": seconds, "runs": runs}))


def _shell_key(config: PipelineConfig) -> dict:
    """What extracted shells depend on besides the stage-1 field: shell settings, stage-1 length (JSON)."""
    return json.loads(
        json.dumps({"shell": dataclasses.asdict(config.shell), "stage1_steps": config.stage1.steps})
    )


def _save_shells(ckpt_dir: Path, config: PipelineConfig, shells: FieldShells, seconds: float) -> None:
    """Keep the extracted shells (and the ``seconds`` their extraction took) so that a resumed run skips the
    extraction; shells.json is written last."""
    for name, mesh in (("shell_outer.ply", shells.outer), ("shell_inner.ply", shells.inner)):
        write_atomically(ckpt_dir / name, lambda tmp, m=mesh: m.export(tmp))
    saved = {**_shell_key(config), "stats": shells.stats, "seconds": seconds}
    write_text_atomically(ckpt_dir / "shells.json", json.dumps(saved))


def _load_shells(ckpt_dir: Path, config: PipelineConfig) -> tuple[FieldShells, float] | None:
    """The shells an earlier run extracted with the same settings after the same stage 1, with the seconds
    that took; else None."""
    import trimesh

    try:
        saved = json.loads((ckpt_dir / "shells.json").read_text())
    except (OSError, ValueError):
        return None
    if {k: saved.get(k) for k in _shell_key(config)} != _shell_key(config):
        log.info("%s: shell settings or stage-1 length changed; extracting the shells again", ckpt_dir)
        return None
    meshes = [trimesh.load(ckpt_dir / f, force="mesh", process=False) for f in SHELL_FILES[:2]]
    log.info("%s: reusing the shells extracted by an earlier run", ckpt_dir)
    return FieldShells(*meshes, saved["stats"]), float(saved.get("seconds", 0.0))


def _remove_checkpoints(out_dir: Path) -> None:
    checkpoints = out_dir / "checkpoints"
    for file in (*CHECKPOINT_FILES, *SHELL_FILES):
        (checkpoints / file).unlink(missing_ok=True)
    if checkpoints.is_dir() and not any(checkpoints.iterdir()):
        checkpoints.rmdir()
