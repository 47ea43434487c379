"""Occupancy grid over the field's box for empty-space skipping in full-ray training (after Instant-NGP).

Each cell keeps a score ``exp(-inv_s * max(|f(p)| - r, 0))`` from probes ``p`` in the cell, where ``r`` is
the distance from ``p`` to the cell's farthest corner: for a unit-gradient SDF no point of the cell is closer
to the surface than ``|f(p)| - r``, and the NeuS density (Eq. 3) there is at most
``inv_s exp(-(|f(p)| - r) inv_s)``. Scores are kept as Instant-NGP does (``score <- max(decay * score, new)``
on the cells probed in an update) and a cell is occupied while its score exceeds ``exp(-band_widths)``,
i.e. while the surface may lie within ``band_widths`` kernel sizes ``s = 1 / inv_s`` of it. For a true SDF,
what the skipped cells could add to a ray's opacity is then at most about ``exp(-band_widths)`` per crossing
of a band's edge.

:meth:`OccupancyGrid.sample` keeps the fixed-step candidates of
:func:`~neural.render.fullray.stepped_candidates` whose centre lies in an occupied cell;
:meth:`OccupancyGrid.sample_reference` is its per-ray loop twin.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch

from ..field.contraction import contract
from .fullray import ray_aabb, step_offsets, step_range
from .occupancy_warp import march_occupied
from .samples import RaySamples

#: How far contracted rays are marched, in ball radii (contracted radius ``2 - 1 / FAR_RADIUS``); what lies
#: beyond is the field's environment map.
FAR_RADIUS = 100.0
#: Nodes measuring a ray's contracted curve: evenly spaced inside the ball, geometrically spaced beyond.
CURVE_NODES = (64, 64)

SdfKernelFn = Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor]]


@dataclass
class OccupancyConfig:
    """How the grid is refreshed (defaults follow Instant-NGP / nerfacc where they apply)."""

    band_widths: float = 8.0  # a cell stays occupied while the surface may be within this many kernel sizes
    ema_decay: float = 0.6  # score decay per update: a cell left by the surface empties within ~16 updates
    warmup_steps: int = 256  # updates before this step probe every cell
    update_fraction: float = 0.25  # after warm-up: this fraction of random cells + as many occupied ones
    jitter: bool = True  # probe a random point of each cell instead of its centre
    chunk: int = 1 << 18  # points per call of the SDF function


class OccupancyGrid:
    """A ``resolution^3`` grid of occupancy scores over the box ``[aabb_min, aabb_max]`` (world units).

    Cell ``(i, j, k)`` (x, y, z index) has flat index ``(i * res + j) * res + k``. Scores start at -1
    (never probed, counted as occupied), so an unprobed grid samples like the dense stepped sampler.
    """

    def __init__(
        self,
        aabb_min: Sequence[float] | torch.Tensor,
        aabb_max: Sequence[float] | torch.Tensor,
        resolution: int = 128,
        config: OccupancyConfig | None = None,
        device: str | torch.device | None = None,
    ) -> None:
        if device is None:
            device = aabb_min.device if isinstance(aabb_min, torch.Tensor) else "cpu"
        self.aabb_min = torch.as_tensor(aabb_min, dtype=torch.float32, device=device).reshape(-1)
        self.aabb_max = torch.as_tensor(aabb_max, dtype=torch.float32, device=device).reshape(-1)
        if (
            self.aabb_min.shape != (3,)
            or self.aabb_max.shape != (3,)
            or not bool((self.aabb_max > self.aabb_min).all())
        ):
            raise ValueError(f"need aabb_min < aabb_max, both (3,), got {aabb_min} and {aabb_max}")
        if resolution < 1:
            raise ValueError(f"resolution must be >= 1, got {resolution}")
        self.resolution = int(resolution)
        self.config = config or OccupancyConfig()
        self.cell_size = (self.aabb_max - self.aabb_min) / self.resolution  # (3,)
        self._set_scores(torch.full((self.resolution**3,), -1.0, device=device))

    @property
    def threshold(self) -> float:
        """Score above which a cell is occupied: ``exp(-band_widths)``."""
        return math.exp(-self.config.band_widths)

    def state(self) -> dict[str, torch.Tensor]:
        """The running state for a training checkpoint: ``{"occupancy_scores": (res^3,) float32}``."""
        return {"occupancy_scores": self.scores.clone()}

    def load_state(self, state: dict[str, torch.Tensor]) -> None:
        """Restore :meth:`state` (other keys of ``state`` are ignored)."""
        if "occupancy_scores" not in state:
            raise ValueError(f"occupancy state: no 'occupancy_scores' among the keys {sorted(state)}")
        scores = state["occupancy_scores"]
        if scores.shape != self.scores.shape:
            raise ValueError(
                f"occupancy_scores: expected shape {tuple(self.scores.shape)}, got {tuple(scores.shape)}"
            )
        self._set_scores(scores.to(self.scores))

    def _set_scores(self, scores: torch.Tensor) -> None:
        """Set scores, occupied mask and the box around the occupied cells (``box_min``, ``box_max``)."""
        self.scores = scores
        self.occupied = (scores > self.threshold) | (scores < 0)
        cells = torch.nonzero(self.occupied).squeeze(1)
        if cells.numel() == 0:
            self.box_min, self.box_max = self.aabb_min.clone(), self.aabb_min.clone()
        else:
            res = self.resolution
            ijk = torch.stack([cells // (res * res), (cells // res) % res, cells % res], dim=1)
            self.box_min = self.aabb_min + ijk.amin(dim=0) * self.cell_size
            self.box_max = self.aabb_min + (ijk.amax(dim=0) + 1) * self.cell_size

    def cell_indices(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Flat cell index (N,) int64 of points ``x`` (N, 3) and whether they lie inside the box (N,) bool."""
        ijk = torch.floor((x - self.aabb_min) / self.cell_size).long()
        inside = ((ijk >= 0) & (ijk < self.resolution)).all(dim=1)
        ijk = ijk.clamp(0, self.resolution - 1)
        return (ijk[:, 0] * self.resolution + ijk[:, 1]) * self.resolution + ijk[:, 2], inside

    def query(self, x: torch.Tensor) -> torch.Tensor:
        """(N,) bool: the points ``x`` (N, 3) lie inside the box in an occupied cell."""
        flat, inside = self.cell_indices(x)
        return self.occupied[flat] & inside

    def _cells_to_update(self, step: int, generator: torch.Generator | None) -> torch.Tensor:
        n_cells = self.scores.shape[0]
        device = self.scores.device
        if step < self.config.warmup_steps or bool((self.scores < 0).any()):
            return torch.arange(n_cells, device=device)
        n = max(1, int(n_cells * self.config.update_fraction))
        picks = [torch.randint(n_cells, (n,), device=device, generator=generator)]
        occupied = torch.nonzero(self.occupied).squeeze(1)
        if occupied.numel() > 0:
            pick = torch.randint(
                occupied.numel(), (min(n, occupied.numel()),), device=device, generator=generator
            )
            picks.append(occupied[pick])
        return torch.unique(torch.cat(picks))

    @torch.no_grad()
    def update(self, sdf_kernel_fn: SdfKernelFn, step: int, generator: torch.Generator | None = None) -> None:
        """Probe cells with the field and refresh their scores and the occupied mask.

        Before ``config.warmup_steps`` (or while any cell was never probed) every cell is probed, afterwards
        ``update_fraction`` of the cells at random plus as many occupied ones. Meant to be called every
        16 training steps or so.

        sdf_kernel_fn : x (N, 3) world points -> (sdf (N,), inv_s (N,)), called without gradient.
        step : the training step.
        """
        cells = self._cells_to_update(step, generator)
        res = self.resolution
        ijk = torch.stack([cells // (res * res), (cells // res) % res, cells % res], dim=1)
        lo = self.aabb_min + ijk * self.cell_size
        if self.config.jitter:
            frac = torch.rand(lo.shape, device=lo.device, generator=generator)
        else:
            frac = torch.full_like(lo, 0.5)
        probes = lo + frac * self.cell_size
        reach = (torch.maximum(frac, 1.0 - frac) * self.cell_size).norm(dim=1)  # to the farthest corner
        new = torch.empty(cells.shape[0], device=lo.device)
        for start in range(0, cells.shape[0], self.config.chunk):
            part = slice(start, start + self.config.chunk)
            sdf, inv_s = sdf_kernel_fn(probes[part])
            new[part] = torch.exp(-inv_s.float() * torch.relu(sdf.float().abs() - reach[part]))
        old = self.scores[cells]
        scores = self.scores.clone()
        scores[cells] = torch.where(old < 0, new, torch.maximum(old * self.config.ema_decay, new))
        self._set_scores(scores)

    def _near_far(
        self, origins: torch.Tensor, dirs: torch.Tensor, near_plane: float
    ) -> tuple[torch.Tensor, torch.Tensor]:
        return ray_aabb(origins, dirs, self.aabb_min.to(origins), self.aabb_max.to(origins), near_plane)

    @torch.no_grad()
    def sample(
        self,
        origins: torch.Tensor,
        dirs: torch.Tensor,
        step_size: float,
        max_samples_per_ray: int,
        perturb: bool = False,
        near_plane: float = 0.0,
        generator: torch.Generator | None = None,
    ) -> RaySamples:
        """Fixed-step sections inside the box whose centre lies in an occupied cell.

        The candidates are :func:`~neural.render.fullray.stepped_candidates`' sections between the rays' box
        entry and exit (so the result is a subset of :func:`~neural.render.fullray.stepped_samples` with the
        same arguments), marched by a Warp kernel (:mod:`neural.render.occupancy_warp`) only where the ray
        crosses the box around the occupied cells.
        origins, dirs : (R, 3) ; step_size : section length in t units.
        """
        near, far = self._near_far(origins, dirs, near_plane)
        margin = 0.01 * self.cell_size  # against rounding on rays that graze the box
        box_min, box_max = (self.box_min - margin).to(origins), (self.box_max + margin).to(origins)
        window = ray_aabb(origins, dirs, box_min, box_max, near_plane)
        shift = step_offsets(near.shape[0], near, perturb, generator)
        first, end = step_range(near, far, step_size, max_samples_per_ray, shift, window)
        return march_occupied(
            origins,
            dirs,
            near,
            far,
            shift,
            first,
            end,
            step_size,
            self.aabb_min,
            self.cell_size,
            self.occupied,
            self.resolution,
        )

    @torch.no_grad()
    def sample_contracted(
        self,
        origins: torch.Tensor,
        dirs: torch.Tensor,
        contraction,
        step_size: float,
        max_samples_per_ray: int,
        perturb: bool = False,
        generator: torch.Generator | None = None,
    ) -> RaySamples:
        """Sections of world rays ``origins``, ``dirs`` (R, 3) from their origin to :data:`FAR_RADIUS` ball
        radii whose contracted length is ``step_size`` (the grid's units: the box is the contracted space of
        ``contraction``, a :class:`~neural.field.contraction.ContractionMap`) and whose contracted centre lies
        in an occupied cell; sections in ``t`` units, near the object as long as ``step_size`` and growing
        away from it as ``1 / |J d|``.

        Each ray's contracted curve is measured by the chords of :data:`CURVE_NODES` nodes (evenly spaced up
        to where the ray leaves the unit ball, geometrically spaced beyond, where the curve bends less and
        less); the samples lie at equal steps of that length (shifted by a random fraction of a step with
        ``perturb``), each carried back to ``t`` linearly within its chord, and the sections between them
        meet halfway. A ray keeps its first ``max_samples_per_ray`` sections."""
        device = origins.device
        radius, center = contraction.radius, contraction.center.to(origins)
        norm = dirs.norm(dim=1).clamp_min(1e-30)
        o = (origins - center) / radius  # ball units
        d = dirs / norm[:, None]
        t_close = -(o * d).sum(1)
        miss2 = ((o * o).sum(1) - t_close**2).clamp_min(0.0)
        t_far = t_close + (FAR_RADIUS**2 - miss2).clamp_min(0.0).sqrt()
        t_exit = torch.where(miss2 < 1.0, t_close + (1.0 - miss2).clamp_min(0.0).sqrt(), t_close)
        t_bend = t_exit.clamp(min=0.0).minimum(t_far)
        even, far = CURVE_NODES
        u = torch.linspace(0.0, 1.0, even, device=device)
        v = torch.linspace(0.0, 1.0, far + 1, device=device)[1:]
        span = (t_far - t_bend).clamp_min(0.0)
        nodes = torch.cat(
            [u * t_bend[:, None], t_bend[:, None] + torch.expm1(v * torch.log1p(span)[:, None])], dim=1
        )  # (R, K) ball units along the ray
        curve = contract(o[:, None, :] + nodes[..., None] * d[:, None, :])
        length = torch.cat(
            [nodes.new_zeros(len(o), 1), (curve[:, 1:] - curve[:, :-1]).norm(dim=2).cumsum(1)], dim=1
        )  # (R, K) contracted length from the origin, ball units
        step = step_size / radius
        shift = torch.rand(len(o), generator=generator).to(origins) if perturb else nodes.new_zeros(len(o))
        rank = torch.floor(length / step + shift[:, None] - 0.5)  # centres (j + 1/2 - shift) step before
        rank = torch.minimum(rank, rank[:, :1] + max_samples_per_ray)
        counts = (rank[:, 1:] - rank[:, :-1]).long().reshape(-1)  # centres within each chord
        chord = torch.repeat_interleave(torch.arange(len(counts), device=device), counts)
        first = torch.repeat_interleave(counts.cumsum(0) - counts, counts)
        rays = torch.div(chord, nodes.shape[1] - 1, rounding_mode="floor")
        k = chord + rays  # the chord's first node, flat
        j = rank.reshape(-1).index_select(0, k) + 1 + (torch.arange(len(chord), device=device) - first)
        flat_length, flat_nodes = length.reshape(-1), nodes.reshape(-1)
        t0, l0 = flat_nodes.index_select(0, k), flat_length.index_select(0, k)
        chord_length = (flat_length.index_select(0, k + 1) - l0).clamp_min(1e-12)
        slope = (flat_nodes.index_select(0, k + 1) - t0) / chord_length
        mid = t0 + ((j + 0.5 - shift.index_select(0, rays)) * step - l0) * slope
        start, end = mid - 0.5 * step * slope, mid + 0.5 * step * slope
        inner = torch.nonzero(rays[1:] == rays[:-1]).squeeze(1)  # sections that meet the next one
        meet = 0.5 * (mid.index_select(0, inner) + mid.index_select(0, inner + 1))
        end[inner], start[inner + 1] = meet, meet
        points = o.index_select(0, rays) + mid[:, None] * d.index_select(0, rays)
        keep = torch.nonzero(self.query(center + radius * contract(points))).squeeze(1)
        scale = (radius / norm).index_select(0, rays[keep])  # ball units -> t
        t_starts, t_ends, t_mid = (v[keep] * scale for v in (start, end, mid))
        return RaySamples(rays[keep], t_starts, t_ends, len(o), t_mid)

    @torch.no_grad()
    def sample_reference(
        self,
        origins: torch.Tensor,
        dirs: torch.Tensor,
        step_size: float,
        max_samples_per_ray: int,
        near_plane: float = 0.0,
    ) -> RaySamples:
        """Slow twin of :meth:`sample` (no perturbation): march each ray in a python loop."""
        near, far = self._near_far(origins, dirs, near_plane)
        rays, starts = [], []
        for r in range(origins.shape[0]):
            for k in range(max_samples_per_ray):
                t = near[r] + k * step_size
                if t >= far[r]:
                    break
                mid = 0.5 * (t + (t + step_size))
                if self.query((origins[r] + mid * dirs[r])[None])[0]:
                    rays.append(r)
                    starts.append(t)
        t_starts = torch.stack(starts) if starts else near.new_zeros(0)
        ray_indices = torch.tensor(rays, dtype=torch.int64, device=origins.device)
        return RaySamples(ray_indices, t_starts, t_starts + step_size, origins.shape[0])
