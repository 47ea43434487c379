"""Whole images: render a camera of a ``Cameras`` set with any sampler, and the samplers themselves.

A *sampler* is a callable ``sampler(origins (R, 3), dirs (R, 3)) -> RaySamples``:

- :func:`narrow_band_sampler`: Procedure 3 against the shells (the fast renderer),
- :func:`occupancy_sampler`: Instant-NGP-style marching of an occupancy grid,
- :func:`full_ray_sampler`: fixed steps through the field's whole box (the reference full-ray renderer).
"""

from __future__ import annotations

import time

import numpy as np
import torch

from ..data import Cameras, camera_rays
from .fullray import ray_aabb, render_rays, stepped_samples
from .occupancy import OccupancyConfig, OccupancyGrid

DEFAULT_STEP = 2.0 * np.sqrt(3.0) / 512  # marching step in the field's unit space (Instant-NGP's)


def field_box(field) -> tuple[torch.Tensor, torch.Tensor]:
    """World-space corners (3,), (3,) of the field's domain, the unit cube."""
    half = 1.0 / float(field.scale)
    return field.center - half, field.center + half


def full_ray_sampler(field, step_size: float = DEFAULT_STEP, max_samples: int = 1024):
    """Fixed steps of ``step_size`` (unit space) through the field's box: every ray, no skipping."""
    lo, hi = field_box(field)
    step = step_size / float(field.scale)

    def sample(origins, dirs):
        near, far = ray_aabb(origins, dirs, lo.to(origins), hi.to(origins))
        return stepped_samples(near, far, step, max_samples)

    return sample


def occupancy_sampler(
    grid: OccupancyGrid,
    field,
    step_size: float = DEFAULT_STEP,
    max_samples: int = 1024,
    perturb: bool = False,
):
    """Steps of ``step_size`` (unit space) through the occupied cells of ``grid`` only."""
    step = step_size / float(field.scale)

    def sample(origins, dirs):
        return grid.sample(origins, dirs, step_size=step, max_samples_per_ray=max_samples, perturb=perturb)

    return sample


def narrow_band_sampler(intersector, config):
    """Procedure 3: samples only inside the shells (``intersector`` is a built ``ShellIntersector``)."""
    from .narrowband import narrow_band_samples

    def sample(origins, dirs):
        samples, _ = narrow_band_samples(intersector, origins, dirs, config, device=origins.device)
        return samples

    return sample


def sdf_kernel_fn(field):
    """``fn(x (N, 3)) -> (sdf (N,), inv_s (N,))`` of ``field``, the probe an occupancy grid updates from."""

    def fn(x):
        geo = field.geometry(x)
        return geo.sdf, geo.inv_s

    return fn


def field_occupancy_grid(
    field, resolution: int = 128, config: OccupancyConfig | None = None
) -> OccupancyGrid:
    """An occupancy grid over the field's box (the unit cube in world coordinates), not yet probed."""
    lo, hi = field_box(field)
    return OccupancyGrid(lo, hi, resolution, config, device=lo.device)


def fitted_occupancy_grid(field, resolution: int = 128) -> OccupancyGrid:
    """An occupancy grid over the field's box with every cell probed once (for rendering a trained field)."""
    grid = field_occupancy_grid(field, resolution, OccupancyConfig(jitter=False))
    with torch.no_grad():
        grid.update(sdf_kernel_fn(field), step=0)
    return grid


@torch.no_grad()
def render_camera(
    field, cameras: Cameras, index: int, sampler, background: torch.Tensor, chunk: int = 16384
) -> tuple[np.ndarray, dict]:
    """Render camera ``index``: image (H, W, 3) float32 in [0, 1] and stats (``samples_per_pixel``,
    ``ms``, ``counts`` (H, W) samples per pixel)."""
    device = background.device
    start = time.perf_counter()
    origins, dirs = camera_rays(cameras, index, device=device)
    colors, counts = [], []
    for i in range(0, len(origins), chunk):
        o, d = origins[i : i + chunk], dirs[i : i + chunk]
        samples = sampler(o, d)
        counts.append(samples.counts())
        colors.append(render_rays(field, o, d, samples, background)["color"])
    h, w = int(cameras.height[index]), int(cameras.width[index])
    image = torch.cat(colors).clamp(0, 1).reshape(h, w, 3).cpu().numpy()
    counts_np = torch.cat(counts).reshape(h, w).cpu().numpy()
    ms = 1000.0 * (time.perf_counter() - start)
    return image, {"samples_per_pixel": float(counts_np.mean()), "ms": ms, "counts": counts_np}
