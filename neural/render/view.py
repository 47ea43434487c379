"""Whole images: the one rendering pipeline, and the samplers it takes.

Every image (``shellsim eval``, ``shellsim render`` at rest and deformed, the benches, training's
held-out views) is made by :func:`render_camera` / :func:`render_pixels`, chunk by chunk of rays (a
sampler's ``rays_per_chunk`` rays, else :data:`RAY_CHUNK`):

1. **sample**: ``sampler(origins (R, 3), dirs (R, 3)) -> RaySamples`` places samples along the rays;
2. **map** (optional): ``to_rest.map_rays(points (S, 3), unit_dirs (S, 3)) -> (x_rest (S, 3), d_rest (S, 3),
   stretch (S,), inside (S,) bool)`` takes each sample to the space where the field lives (deformed
   rendering, paper Sec. 5: ``shellsim.deform.InverseMap``); samples outside are dropped and every section
   length is multiplied by ``stretch``; without it the samples are already there;
3. **shade**: the field at the samples, composited along the rays (Eq. 2-3) over the background (or a
   ``backdrop``: any function of the rays, e.g. shellsim's lit ground with shadows and a sky, asked only for
   the rays that light still reaches) by
   :func:`~neural.render.fullray.shade_samples`, front to back: rays that light no longer reaches stop
   (their remaining samples are neither mapped nor evaluated) and the radiance network runs only where a
   sample's weight can change its pixel, each channel within ``WEIGHT_TOLERANCE`` (1e-3) of the full
   composite of every sample.

:func:`transmittance` runs steps 1-2 and the field's opacity only: the light a shadow ray lets through, front
to back until it is below :data:`SHADOW_CUTOFF`.

Samplers:

- :func:`narrow_band_sampler`: Procedure 3 against the shells (the fast renderer; :func:`asset_sampler` for
  an asset's rest shells and settings),
- :func:`occupancy_sampler`: Instant-NGP-style marching of an occupancy grid,
- :func:`full_ray_sampler`: fixed steps through the field's whole box (the reference full-ray renderer).
"""

from __future__ import annotations

import math
import time
from typing import Protocol

import numpy as np
import torch

from ..data import Cameras, camera_rays
from .bodies import FieldBody, body_share, locate, locate_samples, merged_samples
from .composite import MIN_TRANSMITTANCE
from .fullray import WEIGHT_TOLERANCE, ray_aabb, ray_background, sample_rounds, shade_samples, stepped_samples
from .neus import neus_alpha
from .occupancy import OccupancyConfig, OccupancyGrid

#: Rays rendered at once (bounds the memory of one pass) by samplers that may put hundreds of samples on
#: a ray.
RAY_CHUNK = 16384
#: Rays rendered at once in the narrow band (a few samples per ray): a 200x200 image in one pass, so that
#: the fixed costs of its rounds of shading (kernel launches, thread hand-offs) are paid once, not 3 times.
NARROW_BAND_CHUNK = 65536
#: :func:`bodies_transmittance` stops a shadow ray once its transmittance falls below this: the light it would
#: still let through changes a lit pixel by less than ``albedo * diffuse * SHADOW_CUTOFF`` <= 1e-3 per channel
#: (colours in [0, 1]), a quarter of an 8-bit step, the bound the camera rays' termination keeps
#: (:data:`~neural.render.fullray.WEIGHT_TOLERANCE`).
SHADOW_CUTOFF = WEIGHT_TOLERANCE
#: Samples a shadow ray takes in its first round; each later round is as long as all before it, and the rest
#: go in one round once at most :data:`SHADOW_LAST_ROUND_SAMPLES` samples of live rays remain. The ground's
#: shadow rays of a 512x512 frame of the README's main shot (42k of them crossing the LEGO's box): 90 ms with
#: these, 94 with rounds from 2, 103 with 4 and 4,096, 114 with the shading's 8 and 65,536 (one round for
#: them: no termination), 126 taking every sample (best of 3, AMD 26/2, 2026-12-07).
SHADOW_FIRST_ROUND = 4
SHADOW_LAST_ROUND_SAMPLES = 16384
#: Stages of the pipeline, timed in the stats of :func:`render_pixels` as ``<stage>_ms`` ("world": what the
#: rays see behind the field, a ``backdrop``'s ground and shadows; 0 without one).
STAGES = ("sample", "map", "shade", "world")

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
    """Steps of ``step_size`` (unit space) through the occupied cells of ``grid`` only; for a field in
    contracted space, steps of that contracted length along the world rays
    (:meth:`~neural.render.occupancy.OccupancyGrid.sample_contracted`)."""
    step = step_size / float(field.scale)
    contraction = getattr(field, "contraction", None)

    def sample(origins, dirs):
        if contraction is not None:
            return grid.sample_contracted(origins, dirs, contraction, step, max_samples, perturb)
        return grid.sample(origins, dirs, step_size=step, max_samples_per_ray=max_samples, perturb=perturb)

    return sample


def narrow_band_sampler(caster, config, contraction=None):
    """Procedure 3: samples only inside the shells (``caster`` a :class:`~neural.render.raycast.ShellCaster`
    of them, ``config`` a ``NarrowBandConfig``; ``contraction``: the field's, for shells of a field in
    contracted space, whose intervals are then counted by their contracted widths)."""
    from .narrowband import narrow_band_samples

    def sample(origins, dirs):
        samples, _ = narrow_band_samples(
            caster, origins, dirs, config, device=origins.device, contraction=contraction
        )
        return samples

    sample.rays_per_chunk = NARROW_BAND_CHUNK
    return sample


def asset_sampler(asset, config=None, shells=None):
    """The narrow-band sampler of an :class:`~neural.asset.Asset`'s rest shells (Embree) with its settings:
    what every rest image of an asset uses. ``config``: a ``NarrowBandConfig`` instead of the asset's;
    ``shells``: its (M+, M-) meshes when already loaded."""
    from .raycast import EmbreeCaster

    outer, inner = (asset.outer_mesh(), asset.inner_mesh()) if shells is None else shells
    return narrow_band_sampler(
        EmbreeCaster(outer, inner),
        asset.narrowband_config() if config is None else config,
        asset.contraction,
    )


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


class RestMap(Protocol):
    """Where deformed-space samples are in the field's (rest) space (pipeline step 2)."""

    def map_rays(self, points: torch.Tensor, unit_dirs: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """``x_rest`` (S, 3), ``d_rest`` (S, 3) unit, ``stretch`` (S,) rest length per deformed length along
        the ray, ``inside`` (S,) bool (False: no rest point, the sample is dropped)."""


@torch.no_grad()
def transmittance(
    field,
    origins: torch.Tensor,
    dirs: torch.Tensor,
    sampler,
    to_rest: RestMap | None = None,
    cutoff: float = SHADOW_CUTOFF,
) -> torch.Tensor:
    """Transmittance (R,) of the field along rays ``origins``, ``dirs`` (R, 3), ``T = prod_i (1 - alpha_i)``
    over every sample (Eq. 2) with NeuS opacities alpha (Eq. 3): pipeline steps 1-2 (sample, map to rest
    space with ``to_rest``), then the field's geometry only (no radiance), a ray stopping once T is below
    ``cutoff`` (:func:`bodies_transmittance`). A shadow ray's visibility of the light through a body."""
    return bodies_transmittance([FieldBody(field, sampler, to_rest)], origins, dirs, cutoff)


@torch.no_grad()
def bodies_transmittance(
    bodies, origins: torch.Tensor, dirs: torch.Tensor, cutoff: float = SHADOW_CUTOFF
) -> torch.Tensor:
    """Transmittance (R,) of world rays ``origins``, ``dirs`` (R, 3) through every body of ``bodies``
    (:class:`~neural.render.bodies.FieldBody`, each ray only through those whose box it crosses): the
    product of each body's :func:`transmittance` along the ray in its frame. A ray's samples are taken
    front to back in rounds (:data:`SHADOW_FIRST_ROUND` a ray, then doubling), and a ray whose transmittance
    fell below ``cutoff`` takes part in no further round nor body: the true value then lies below the one
    returned, itself below ``cutoff``. ``cutoff`` = 0: every sample."""
    if not cutoff >= 0:
        raise ValueError(f"cutoff: expected >= 0, got {cutoff}")
    floor = math.log(cutoff) if cutoff > 0 else -math.inf
    log_t = torch.zeros(len(origins), dtype=torch.float64, device=origins.device)
    for body in bodies:
        lit = torch.nonzero(log_t > floor).squeeze(1)
        rays, o, d = body_share(body, origins.index_select(0, lit), dirs.index_select(0, lit))
        lit = lit if rays is None else lit.index_select(0, rays)
        chunk = getattr(body.sampler, "rays_per_chunk", RAY_CHUNK)
        for i in range(0, len(o), chunk):
            samples = body.sampler(o[i : i + chunk], d[i : i + chunk])
            mine = lit[i : i + chunk]  # (r,) the chunk's rays among all
            alive = torch.ones(len(mine), dtype=torch.bool, device=o.device)
            for index in sample_rounds(samples, SHADOW_FIRST_ROUND, SHADOW_LAST_ROUND_SAMPLES, alive):
                index, points, unit_dirs, deltas, fronts, _ = locate(
                    index, o[i : i + chunk], d[i : i + chunk], samples, body.rest_map
                )
                geometry = body.field.geometry(points)
                cos = (unit_dirs * geometry.normal).sum(dim=1)
                alpha = neus_alpha(geometry.sdf, geometry.inv_s, cos, deltas, 1.0, fronts)
                on = mine.index_select(0, samples.ray_indices.index_select(0, index))
                log_t.index_add_(0, on, torch.log(torch.clamp(1.0 - alpha.double(), min=MIN_TRANSMITTANCE)))
                alive.copy_(log_t.index_select(0, mine) > floor)
    return log_t.exp().to(origins.dtype)


@torch.no_grad()
def render_pixels(
    field,
    origins: torch.Tensor,
    dirs: torch.Tensor,
    sampler,
    background: torch.Tensor,
    to_rest: RestMap | None = None,
    chunk: int | None = None,
    backdrop=None,
    t_max: torch.Tensor | None = None,
) -> tuple[torch.Tensor, dict]:
    """Colours (R, 3) (unclamped) of rays ``origins``, ``dirs`` (R, 3) on the field's device: sample, map to
    rest space with ``to_rest`` (None: no map), shade over ``background`` (3,), ``chunk`` rays at a time
    (None: the sampler's ``rays_per_chunk``, else :data:`RAY_CHUNK`): :func:`render_bodies` of the one body,
    where ``backdrop`` and ``t_max`` are explained, and its stats."""
    body = FieldBody(field, sampler, to_rest)
    return render_bodies([body], origins, dirs, background, chunk, backdrop, t_max)


@torch.no_grad()
def render_bodies(
    bodies,
    origins: torch.Tensor,
    dirs: torch.Tensor,
    background: torch.Tensor,
    chunk: int | None = None,
    backdrop=None,
    t_max: torch.Tensor | None = None,
) -> tuple[torch.Tensor, dict]:
    """Colours (R, 3) (unclamped) of world rays ``origins``, ``dirs`` (R, 3) through every body of
    ``bodies`` (:class:`~neural.render.bodies.FieldBody`): each body's samples on the rays crossing its box,
    mapped to its rest space, merged by depth and shaded by their own fields, composited once over
    ``background`` (3,) (one body: its field's environment map when it has one), ``chunk`` rays at a time
    (None: the smallest of the samplers' ``rays_per_chunk``, else :data:`RAY_CHUNK`). ``backdrop(origins (r,
    3), dirs (r, 3), rays (r,) int64) -> (r, 3)``: what the rays ``rays`` (indices among the R) see behind
    the fields instead of ``background`` (a lit ground and a sky, drawn by shellsim); ``color = sum_i w_i c_i
    + T backdrop`` (Eq. 2), asked only for the rays that light still reaches through the fields
    (:func:`~neural.render.fullray.shade_samples`). ``t_max``
    (R,): the ray parameter of a surface in front of the backdrop that hides the fields beyond it (an
    obstacle or the ground): samples with ``t > t_max`` are dropped. Stats:
    ``ms``, per stage ``<stage>_ms`` (:data:`STAGES`), ``samples_per_pixel``, ``dropped_samples`` (outside a
    map to rest space) and ``counts`` (R,) int64 samples per ray that were mapped and evaluated (dropped ones
    included, those after a ray's termination or beyond ``t_max`` not)."""
    times = dict.fromkeys(STAGES, 0.0)
    start = time.perf_counter()
    chunk = chunk or min((getattr(b.sampler, "rays_per_chunk", RAY_CHUNK) for b in bodies), default=RAY_CHUNK)
    fields = bodies[0].field if len(bodies) == 1 else [b.field for b in bodies]
    colors, counts, dropped = [], [], 0
    for i in range(0, len(origins), chunk):
        o, d = origins[i : i + chunk], dirs[i : i + chunk]
        tick = time.perf_counter()
        near = None if t_max is None else t_max[i : i + chunk]
        merged = merged_samples(bodies, o, d, near)
        times["sample"] += time.perf_counter() - tick

        def locate(index, merged=merged):
            nonlocal dropped
            *located, which, n_out = locate_samples(bodies, merged, index, times)
            dropped += n_out
            return (*located, which) if len(bodies) > 1 else tuple(located)

        def behind(rays, o=o, d=d, i=i):
            tick = time.perf_counter()
            color = backdrop(o.index_select(0, rays), d.index_select(0, rays), rays + i)
            times["world"] += time.perf_counter() - tick
            return color

        tick = time.perf_counter()
        if backdrop is None:
            behind = ray_background(bodies[0].field, d, background) if len(bodies) == 1 else background
        color, located = shade_samples(fields, merged.samples, locate, behind)
        colors.append(color)
        counts.append(located)
        times["shade"] += time.perf_counter() - tick
    times["shade"] -= times["map"] + times["world"]
    colors = torch.cat(colors) if colors else origins.new_zeros(0, 3)
    counts = torch.cat(counts).cpu().numpy() if counts else np.zeros(0, np.int64)
    stats = {f"{k}_ms": 1000.0 * v for k, v in times.items()}
    stats.update(
        ms=1000.0 * (time.perf_counter() - start),
        samples_per_pixel=float(counts.mean()) if counts.size else 0.0,
        dropped_samples=dropped,
        counts=counts,
    )
    return colors, stats


@torch.no_grad()
def render_camera(
    field,
    cameras: Cameras,
    index: int,
    sampler,
    background: torch.Tensor,
    to_rest: RestMap | None = None,
    chunk: int | None = None,
    backdrop=None,
    t_max: torch.Tensor | None = None,
) -> tuple[np.ndarray, dict]:
    """Render camera ``index`` through :func:`render_pixels` (``backdrop``, ``t_max`` (H W,) of the rays
    of :func:`neural.data.camera_rays` as there): image (H, W, 3)
    float32 in [0, 1] and its stats, with ``counts`` (H, W) and ``ms`` including the camera rays."""
    start = time.perf_counter()
    origins, dirs = camera_rays(cameras, index, device=background.device)
    colors, stats = render_pixels(field, origins, dirs, sampler, background, to_rest, chunk, backdrop, t_max)
    h, w = int(cameras.height[index]), int(cameras.width[index])
    stats["counts"] = stats["counts"].reshape(h, w)
    image = colors.clamp(0, 1).reshape(h, w, 3).cpu().numpy()
    stats["ms"] = 1000.0 * (time.perf_counter() - start)
    return image, stats
