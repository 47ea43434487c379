"""Training (paper Procedure 4): stage 1 full-ray NeuS with a spatially varying kernel (Eq. 8-12), stage 2
narrow-band fine-tuning with the color loss only.

Both stages draw random pixels from the training views, write a checkpoint (safetensors, atomic) every
``checkpoint_every`` steps, every ``checkpoint_seconds`` and when interrupted (Ctrl-C, SIGTERM through the
CLI), resume from it, show a progress bar with loss and PSNR, and evaluate on held-out views every
``eval_every`` steps.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from .checkpoint import load_checkpoint, save_checkpoint
from .config import Stage1Config, Stage2Config
from .data import SceneData, pixel_to_ray
from .field import ShellField
from .losses import (
    color_loss,
    eikonal_loss,
    finite_difference_gradient,
    kernel_sharpness_loss,
    kernel_smoothness_loss,
    mask_loss,
    normal_loss,
    total_loss,
)
from .metrics import psnr, ssim
from .render.fullray import render_rays, visible_samples
from .render.view import (
    field_occupancy_grid,
    narrow_band_sampler,
    occupancy_sampler,
    render_camera,
    sdf_kernel_fn,
)
from .visibility import VISIBILITY_RESOLUTION, UnseenPrior, measure_visibility

log = logging.getLogger(__name__)


GRID_PARAMETERS = ("encoding", "kernel_grid")  # name prefixes of the grid parameters (the encoding's rate)


def make_optimizer(field: ShellField, lr_encoding: float, lr_network: float) -> torch.optim.Adam:
    """Adam with Instant-NGP's settings: one group for the grids (:data:`GRID_PARAMETERS`), one for MLPs."""
    enc = [p for n, p in field.named_parameters() if n.startswith(GRID_PARAMETERS)]
    net = [p for n, p in field.named_parameters() if not n.startswith(GRID_PARAMETERS)]
    return torch.optim.Adam(
        [
            {"params": enc, "lr": lr_encoding, "base_lr": lr_encoding},
            {"params": net, "lr": lr_network, "base_lr": lr_network},
        ],
        betas=(0.9, 0.99),
        eps=1e-15,
        fused=True,  # fused: about 6x faster than foreach on a CPU
    )


def set_learning_rate(
    optimizer: torch.optim.Optimizer, step: int, steps: int, warmup: int, final: float, fresh_at: int = 0
) -> None:
    """Linear warm-up over ``warmup`` steps from ``fresh_at`` (the step the optimizer's state started at),
    times exponential decay to ``final`` x the base rate at the last step."""
    factor = min(1.0, (step - fresh_at + 1) / max(warmup, 1)) * final ** (step / max(steps, 1))
    for group in optimizer.param_groups:
        group["lr"] = group["base_lr"] * factor


class PixelSampler:
    """Random training pixels with their colours: uniform over all pixels of the training views, or partly
    where the field is still wrong.

    With ``random_background`` and images that have alpha, every fully transparent pixel (alpha 0) gets its
    own uniformly random colour, which the render then uses as its background (Instant-NGP's practice): an
    empty pixel only matches when its ray stays empty, so the field cannot hide floaters in
    background-coloured space. Pixels with any coverage keep the images' background: a partly covered edge
    pixel stays a composite that an opaque surface crossing the pixel can match.

    With ``error_sampling`` > 0, that share of the rays is drawn from an error map (Instant-NGP's): the
    training views are cut into tiles of ``tile`` x ``tile`` pixels, each keeping a running mean of the
    squared colour error of the rays drawn in it (:meth:`record`); those rays pick a tile with probability
    proportional to its error, then a pixel uniformly inside it. The other rays stay uniform, so every tile
    keeps being visited and its error stays current. Tiles start at an error of 1 (the most a colour in
    [0, 1] can have), so all are visited early. The loss is not reweighted: the rays go to edges and texture,
    and pixels that are already right would give little gradient anyway.
    """

    def __init__(
        self,
        data: SceneData,
        device: str,
        seed: int,
        random_background: bool = False,
        error_sampling: float = 0.0,
        tile: int = 16,
    ):
        self.data = data
        self.cameras = data.cameras
        idx = np.asarray(data.train_idx)
        self.views = torch.as_tensor(idx, device=device)
        self.images = torch.as_tensor(data.images[idx], device=device)  # (N, H, W, 3)
        self.empty = None  # (N, H, W) bool, alpha == 0: the pixels that get a random background
        if random_background and data.alphas is not None:
            self.empty = torch.as_tensor(data.alphas[idx] == 0, device=device)
        self.alphas = None if data.alphas is None else torch.as_tensor(data.alphas[idx], device=device)
        self.coverage = None  # (n,) the photos' alpha at the pixels last drawn, None without alpha
        self.background = torch.as_tensor(data.background, dtype=torch.float32, device=device)
        self.height, self.width = self.images.shape[1:3]
        self.device = device
        self.generator = torch.Generator(device="cpu").manual_seed(seed)
        self.error_sampling, self.tile = error_sampling, tile
        self.tiles = (-(-self.height // tile), -(-self.width // tile))  # tiles per column, per row
        self.errors = torch.ones(len(idx) * self.tiles[0] * self.tiles[1], device=device)  # (N * ty * tx,)
        self.drawn = torch.zeros(0, dtype=torch.long, device=device)  # (n,) tile of each ray last drawn

    def sample(self, n: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """n random pixels -> origins (n, 3), dirs (n, 3), rgb (n, 3), background (3,) or (n, 3); their
        photos' alpha is left in ``coverage`` (n,) (None for photos without alpha)."""
        g = self.generator
        k, py, px = self._uniform(n - round(n * self.error_sampling))
        if self.error_sampling > 0:
            k_e, py_e, px_e = self._by_error(n - len(k))
            k, py, px = torch.cat([k, k_e]), torch.cat([py, py_e]), torch.cat([px, px_e])
            self.drawn = (k * self.tiles[0] + py // self.tile) * self.tiles[1] + px // self.tile
        origins, dirs = pixel_to_ray(self.cameras, self.views[k], px + 0.5, py + 0.5)
        rgb = self.images[k, py, px]
        self.coverage = None if self.alphas is None else self.alphas[k, py, px]
        if self.empty is None:
            return origins, dirs, rgb, self.background
        empty = self.empty[k, py, px, None]
        colours = torch.rand((n, 3), generator=g).to(self.device)
        # the images hold fg a + bg0 (1 - a) = bg0 where a = 0: the new colour is the pixel's colour there
        return origins, dirs, torch.where(empty, colours, rgb), torch.where(empty, colours, self.background)

    def _uniform(self, n: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """n pixels uniform over the training views: view (n,), row (n,), column (n,)."""
        g = self.generator
        k = torch.randint(0, len(self.views), (n,), generator=g).to(self.device)
        py = torch.randint(0, self.height, (n,), generator=g).to(self.device)
        px = torch.randint(0, self.width, (n,), generator=g).to(self.device)
        return k, py, px

    def _by_error(self, n: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """n pixels in tiles drawn in proportion to their error, uniform inside: view, row, column (n,)."""
        cdf = torch.cumsum(self.errors.double(), 0)
        u = (torch.rand(n, generator=self.generator, dtype=torch.float64).to(self.device)) * cdf[-1]
        cell = torch.searchsorted(cdf, u).clamp_(max=len(cdf) - 1)
        per_view = self.tiles[0] * self.tiles[1]
        k, rest = cell // per_view, cell % per_view
        y0, x0 = (rest // self.tiles[1]) * self.tile, (rest % self.tiles[1]) * self.tile
        inside = torch.rand((2, n), generator=self.generator).to(self.device)  # tiles at an edge are cut
        py = y0 + (inside[0] * (self.height - y0).clamp(max=self.tile)).long()
        px = x0 + (inside[1] * (self.width - x0).clamp(max=self.tile)).long()
        return k, py, px

    def record(self, colors: torch.Tensor, targets: torch.Tensor) -> None:
        """Fold the squared colour errors of the rays last drawn, rendered ``colors`` (n, 3) against their
        ``targets`` (n, 3) (mean over the channels), into their tiles' running means."""
        if self.error_sampling > 0:
            squared_errors = ((colors.detach() - targets) ** 2).mean(-1).to(self.errors)
            sums = torch.zeros_like(self.errors).index_add_(0, self.drawn, squared_errors)
            counts = torch.bincount(self.drawn, minlength=len(self.errors))
            self.errors = (self.errors + sums) / (1 + counts)  # a tile not drawn keeps its error

    def state(self) -> dict[str, torch.Tensor]:
        """The error map for a training checkpoint: ``{"pixel_errors": (N * ty * tx,) float32}``."""
        return {"pixel_errors": self.errors.clone()} if self.error_sampling > 0 else {}

    def load_state(self, state: dict[str, torch.Tensor]) -> None:
        """Restore :meth:`state`; an error map of other tiles or none at all leaves the fresh one."""
        errors = state.get("pixel_errors")
        if errors is not None and errors.shape == self.errors.shape:
            self.errors = errors.to(self.errors)


def _pixel_sampler(data: SceneData, device: str, config, start: int, extra: dict) -> PixelSampler:
    """The pixel sampler of a training stage resumed at step ``start``, its error map from the checkpoint's
    ``extra`` tensors."""
    pixels = PixelSampler(
        data, device, config.seed + start, config.random_background, config.error_sampling, config.error_tile
    )
    pixels.load_state(extra)
    return pixels


def regularisers(
    field: ShellField,
    points: torch.Tensor,
    normals: torch.Tensor,
    inv_s: torch.Tensor,
    config: Stage1Config,
    generator: torch.Generator,
) -> dict[str, torch.Tensor]:
    """Eikonal (Eq. 10), normal (Eq. 12), kernel-smoothness (Eq. 11) and kernel-sharpness losses
    (:mod:`neural.losses`) of the field on a subset of samples.

    points (N, 3) world positions (detached), normals (N, 3) predicted normals, inv_s (N,) at them.
    Lengths in ``config`` are in unit space and converted with the field's scale: the finite-difference
    step, the perturbation of Eq. 11 and the sharpness floor ``s_floor = sharp_floor * step_size``.
    """
    scale = float(field.scale)
    grad = finite_difference_gradient(field.sdf, points, config.fd_eps / scale)
    noise = torch.randn(points.shape, generator=generator).to(points) * (config.smooth_eps / scale)
    inv_s_perturbed = field.geometry(points + noise).inv_s
    return {
        "eikonal": eikonal_loss(grad),
        "normal": normal_loss(normals, grad),
        "smooth": kernel_smoothness_loss(inv_s, inv_s_perturbed),
        "sharp": kernel_sharpness_loss(inv_s, config.sharp_floor * config.step_size / scale),
    }


def evaluate(
    field: ShellField, data: SceneData, views, sampler, background: torch.Tensor, render=render_camera
) -> dict:
    """Mean PSNR, SSIM, samples per pixel and ms per frame over dataset ``views`` with ``sampler``;
    ``render`` takes and returns what :func:`~neural.render.view.render_camera` does."""
    psnrs, ssims, spps, times = [], [], [], []
    for v in views:
        image, stats = render(field, data.cameras, int(v), sampler, background)
        psnrs.append(psnr(image, data.images[v]))
        ssims.append(ssim(image, data.images[v]))
        spps.append(stats["samples_per_pixel"])
        times.append(stats["ms"])
    return {
        "psnr": float(np.mean(psnrs)),
        "ssim": float(np.mean(ssims)),
        "samples_per_pixel": float(np.mean(spps)),
        "ms_per_frame": float(np.mean(times)),
        "views": [int(v) for v in views],
    }


def _psnr(color: torch.Tensor, target: torch.Tensor) -> float:
    """PSNR of a training batch (for the progress bar)."""
    return -10.0 * math.log10(max(float(((color.detach() - target) ** 2).mean()), 1e-10))


class _TrainingClock:
    """Seconds a stage has spent training: ``before`` (its earlier runs, from the checkpoint) plus the wall
    time since this run started, evaluations excluded."""

    def __init__(self, before: float = 0.0):
        self.before, self.start, self.excluded = before, time.perf_counter(), 0.0

    def seconds(self) -> float:
        return self.before + time.perf_counter() - self.start - self.excluded


def _periodic_evaluation(
    stage: str, done: int, config, field, data: SceneData, sampler, background, bar, clock: _TrainingClock
) -> dict | None:
    """Held-out evaluation every ``config.eval_every`` steps on ``config.eval_views`` views, and at the last
    step on every held-out view; None on the other steps. The metrics hold ``train_seconds``, this run's
    training time so far (``clock``, which then leaves the evaluation's time out)."""
    if done % config.eval_every and done != config.steps:
        return None
    every_view = done == config.steps or config.eval_views == 0
    views = data.test_idx if every_view else np.asarray(data.test_idx)[: config.eval_views]
    tick, seconds = time.perf_counter(), clock.seconds()
    metrics = {**evaluate(field, data, views, sampler, background), "step": done}
    metrics["train_seconds"] = round(seconds, 2)
    clock.excluded += time.perf_counter() - tick
    bar.write(
        f"{stage} step {done}: held-out PSNR {metrics['psnr']:.2f} dB, SSIM {metrics['ssim']:.3f}, "
        f"{metrics['samples_per_pixel']:.2f} samples/pixel"
    )
    return metrics


def _resumed_history(meta: dict) -> tuple[list[dict], _TrainingClock]:
    """The evaluations and the training clock of a stage, carried on from its checkpoint's ``meta`` (empty
    for a fresh stage): a run resumed across sessions keeps one curve against its whole training time."""
    return list(meta.get("history", [])), _TrainingClock(float(meta.get("seconds", 0.0)))


def _progress(total: int, start: int, desc: str):
    return tqdm(total=total, initial=start, desc=desc, dynamic_ncols=True, mininterval=1.0)


class _Checkpointer:
    """Saves a stage's checkpoint every ``checkpoint_every`` steps, every ``checkpoint_seconds`` and at the
    last step (``due``), and on an interrupt (``interrupted``). ``save(done)`` writes the checkpoint."""

    def __init__(self, config, save, start: int):
        self.config, self.save, self.saved = config, save, start
        self.last = time.monotonic()

    def due(self, done: int) -> None:
        c = self.config
        elapsed = time.monotonic() - self.last
        if done % c.checkpoint_every == 0 or done == c.steps or elapsed >= c.checkpoint_seconds:
            self.save(done)
            self.saved, self.last = done, time.monotonic()

    def interrupted(self, done: int, stage: str) -> None:
        if done > self.saved:
            self.save(done)
            log.info("%s: interrupted; checkpoint saved at step %d", stage, done)


@dataclass(frozen=True)
class Continuation:
    """Where a stage 1 starts that continues a trained field (an asset's): the step its schedule had reached
    and the training seconds spent on it so far (the curve's minutes go on from them)."""

    step: int
    seconds: float


def train_stage1(
    field: ShellField,
    data: SceneData,
    out_dir: Path,
    config: Stage1Config,
    device: str,
    continuation: Continuation | None = None,
) -> dict:
    """Stage 1 (Procedure 4 lines 1-5): full-ray volume rendering with Eq. 8, on the occupancy grid's samples
    that light reaches (:func:`~neural.render.fullray.visible_samples`, ``config.min_transmittance``). Resumes
    from ``out_dir/checkpoints/stage1.safetensors``; without one, a ``continuation`` starts at its step with
    the field as given and a fresh optimizer, warmed up again. Returns the final held-out evaluation."""
    torch.manual_seed(config.seed)
    ckpt = Path(out_dir) / "checkpoints" / "stage1.safetensors"
    optimizer = make_optimizer(field, config.lr_encoding, config.lr_network)
    grid = field_occupancy_grid(field, config.occupancy_resolution)
    start, n_rays, final, extra, meta = 0, config.initial_rays, None, {}, {}
    if continuation is not None:
        start, meta = continuation.step, {"fresh_at": continuation.step, "seconds": continuation.seconds}
    if ckpt.is_file():
        meta, extra = load_checkpoint(ckpt, field, optimizer)
        grid.load_state(extra)
        start, n_rays, final = int(meta["step"]), int(meta["n_rays"]), meta.get("final")
        log.info("resuming stage 1 from %s at step %d", ckpt, start)
    pixels = _pixel_sampler(data, device, config, start, extra)
    reg_gen = torch.Generator().manual_seed(config.seed + 7 + start)
    sampler = occupancy_sampler(grid, field, config.step_size, config.max_samples_per_ray, perturb=True)
    eval_sampler = occupancy_sampler(grid, field, config.step_size, config.max_samples_per_ray)
    scale = float(field.scale)
    weights = {
        "eikonal": config.lambda_e,
        "normal": config.lambda_n,
        "smooth": config.lambda_s,
        "sharp": config.lambda_k,
        "mask": config.lambda_mask,
        "carve": config.lambda_carve,
        "paint": config.lambda_paint,
    }
    prior, prior_at = None, None
    bar = _progress(config.steps, start, "stage 1")
    history, clock = _resumed_history(meta)
    fresh_at = int(meta.get("fresh_at", 0))

    def save(done: int) -> None:
        meta = {"step": done, "n_rays": n_rays, "final": final if done == config.steps else None}
        meta.update(history=history, seconds=clock.seconds(), fresh_at=fresh_at)
        save_checkpoint(ckpt, field, optimizer, {**grid.state(), **pixels.state()}, meta)

    checkpoints, done = _Checkpointer(config, save, start), start
    try:
        for step in range(start, config.steps):
            if step % config.occupancy_every == 0:
                with torch.no_grad():
                    grid.update(sdf_kernel_fn(field), step)
            set_learning_rate(
                optimizer, step, config.steps, config.warmup_steps, config.final_lr_factor, fresh_at
            )
            if _prior_due(config, step, prior_at, fresh_at):
                prior, prior_at = unseen_prior(field, data, bar), step
            origins, dirs, target, ray_background = pixels.sample(n_rays)
            anneal = min(1.0, step / max(config.cos_anneal_steps, 1))
            candidates = sampler(origins, dirs)
            samples = visible_samples(field, origins, dirs, candidates, config.min_transmittance, anneal)
            n_samples = len(samples.ray_indices)
            if n_samples == 0:
                bar.update(1)
                continue
            out = render_rays(field, origins, dirs, samples, ray_background, cos_anneal=anneal)
            pixels.record(out["color"], target)
            k = max(1, int(n_samples * config.reg_fraction))
            pick = torch.randperm(n_samples, generator=reg_gen)[:k].to(origins.device)
            reg = regularisers(
                field, out["points"][pick].detach(), out["normal"][pick], out["inv_s"][pick], config, reg_gen
            )
            terms = {"color": color_loss(out["color"], target), **reg}  # Eq. 8
            if pixels.coverage is not None and config.lambda_mask > 0:
                terms["mask"] = mask_loss(out["opacity"], pixels.coverage)
            if prior is not None:
                for name, term in (("carve", prior.carve), ("paint", prior.paint)):
                    value = term(field, config.prior_points, reg_gen)
                    terms.update({} if value is None else {name: value})
            loss = total_loss(terms, weights)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            grow = min(config.target_samples / n_samples, config.max_candidates / len(candidates.ray_indices))
            n_rays = int(np.clip(n_rays * grow, 256, config.max_rays))
            bar.set_postfix(
                loss=f"{loss.item():.4f}",
                psnr=f"{_psnr(out['color'], target):.2f}",
                rays=n_rays,
                spp=f"{n_samples / len(origins):.1f}/{len(candidates.ray_indices) / len(origins):.1f}",
                s=f"{float(1 / out['inv_s'].detach().mean()) * scale:.4f}",
            )
            bar.update(1)
            done = step + 1
            final = _periodic_evaluation(
                "stage 1", done, config, field, data, eval_sampler, pixels.background, bar, clock
            )
            history += [final] if final else []
            checkpoints.due(done)
    except BaseException as err:  # the bar closed before the CLI's one line, not printed after it at exit
        bar.close()
        if isinstance(err, KeyboardInterrupt):
            checkpoints.interrupted(done, "stage 1")
        raise
    if final is None and done == config.steps:  # resumed after the last step, before its evaluation
        final = _periodic_evaluation(
            "stage 1", done, config, field, data, eval_sampler, pixels.background, bar, clock
        )
        history.append(final)
    bar.close()
    return {"history": history, "final": history[-1] if history else final, "occupancy": grid}


def _prior_due(config: Stage1Config, step: int, measured_at: int | None, fresh_at: int) -> bool:
    """Whether stage 1 measures the unseen prior again before ``step``: every ``visibility_every`` steps
    from that step on, at once when a continued (``fresh_at`` > 0) or resumed run is past it."""
    if config.lambda_carve == 0 and config.lambda_paint == 0:
        return False
    if measured_at is None:
        return step >= config.visibility_every or (fresh_at > 0 and step == fresh_at)
    return step - measured_at >= config.visibility_every


def unseen_prior(
    field: ShellField, data: SceneData, bar=None, resolution: int = VISIBILITY_RESOLUTION
) -> UnseenPrior | None:
    """The :class:`~neural.visibility.UnseenPrior` of the field as trained so far, from the training views
    on a ``resolution``^3 grid; logged on ``bar`` (a tqdm bar) when given. None for a field in contracted
    space: a real capture's photos see a room, whose unseen space is not an object's underside (the prior is
    for objects photographed with alpha)."""
    if field.contraction is not None:
        return None
    prior = UnseenPrior(*measure_visibility(field, data, resolution=resolution))
    (bar.write if bar is not None else log.info)(prior.summary())
    return prior


def train_stage2(
    field: ShellField,
    data: SceneData,
    outer,
    inner,
    out_dir: Path,
    config: Stage2Config,
    narrowband,
    device: str,
    prior: UnseenPrior | None = None,
) -> dict:
    """Stage 2 (Procedure 4 lines 8-13): fine-tune inside the shells M+ (``outer``) / M- (``inner``) with the
    color loss (Eq. 9), and with ``prior`` its paint term (unseen surface keeps the nearest seen colour).
    Resumes from ``out_dir/checkpoints/stage2.safetensors``."""
    from .render.raycast import EmbreeCaster

    torch.manual_seed(config.seed)
    ckpt = Path(out_dir) / "checkpoints" / "stage2.safetensors"
    optimizer = make_optimizer(field, config.lr_encoding, config.lr_network)
    start, final, extra, meta = 0, None, {}, {}
    if ckpt.is_file():
        meta, extra = load_checkpoint(ckpt, field, optimizer)
        start, final = int(meta["step"]), meta.get("final")
        log.info("resuming stage 2 from %s at step %d", ckpt, start)
    sampler = narrow_band_sampler(EmbreeCaster(outer, inner), narrowband, field.contraction)
    pixels = _pixel_sampler(data, device, config, start, extra)
    bar = _progress(config.steps, start, "stage 2")
    history, clock = _resumed_history(meta)
    paint_gen = torch.Generator().manual_seed(config.seed + 11 + start)
    prior = prior if config.lambda_paint > 0 else None

    def save(done: int) -> None:
        meta = {"step": done, "final": final if done == config.steps else None}
        meta.update(history=history, seconds=clock.seconds())
        save_checkpoint(ckpt, field, optimizer, pixels.state(), meta)

    checkpoints, done = _Checkpointer(config, save, start), start
    try:
        for step in range(start, config.steps):
            set_learning_rate(optimizer, step, config.steps, config.warmup_steps, config.final_lr_factor)
            origins, dirs, target, ray_background = pixels.sample(config.rays)
            samples = sampler(origins, dirs)
            out = render_rays(field, origins, dirs, samples, ray_background)
            pixels.record(out["color"], target)
            loss = color_loss(out["color"], target)  # Eq. 9: no regularisers in stage 2
            paint = None if prior is None else prior.paint(field, config.prior_points, paint_gen)
            if paint is not None:
                loss = loss + config.lambda_paint * paint
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            bar.set_postfix(
                loss=f"{loss.item():.4f}",
                psnr=f"{_psnr(out['color'], target):.2f}",
                spp=f"{len(samples.ray_indices) / len(origins):.2f}",
            )
            bar.update(1)
            done = step + 1
            final = _periodic_evaluation(
                "stage 2", done, config, field, data, sampler, pixels.background, bar, clock
            )
            history += [final] if final else []
            checkpoints.due(done)
    except BaseException as err:  # the bar closed before the CLI's one line, not printed after it at exit
        bar.close()
        if isinstance(err, KeyboardInterrupt):
            checkpoints.interrupted(done, "stage 2")
        raise
    if final is None and done == config.steps:  # resumed after the last step, before its evaluation
        final = _periodic_evaluation(
            "stage 2", done, config, field, data, sampler, pixels.background, bar, clock
        )
        history.append(final)
    bar.close()
    return {"history": history, "final": history[-1] if history else final}
