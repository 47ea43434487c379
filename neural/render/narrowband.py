"""Narrow-band sampling between the adaptive shells M+ and M- (paper Sec. 3.4, Procedure 3).

Each ray is cast against the outer mesh M+ (every hit, in order, up to the depth-peeling cap ``dp_max``) and
against the inner mesh M- (first hit only, at ``d_M-``). Consecutive entering/exiting hits of M+ bound the
in-shell intervals; an interval's exit is clipped at ``d_M-`` and the ray stops there, as the inside of M- is
solid. An interval of width ``w`` gets ``N = min(ceil(max(w - w_s, 0) / delta_s) + 1, N_max)`` samples at
``linspace(d_enter, d_exit, N + 2)[1:-1]`` (Procedure 3, line 19-20). All rays are handled at once by any
:class:`~neural.render.raycast.ShellCaster` (Embree for shells at rest, refitted Warp meshes for moving ones):
one cast of M+ for every ray, then, for the rays that meet M+ only, one cast of M- and one per depth-peeling
round of the still-active rays (:meth:`~neural.render.raycast.ShellCaster.band_hits`; Warp makes them all in
one kernel); then pure numpy packing into ``RaySamples``.

Rules where Procedure 3 leaves a case open (they only matter for origins inside M+ or for meshes that are
not closed and nested) are followed alike by :func:`narrow_band_samples` and its per-ray twin
:func:`neural.render._reference.narrow_band_samples_reference`:

- a ray whose first M+ hit exits starts inside M+: its first interval opens at its origin (``near``);
- an exit opens an interval only when the hit before it is an entry (or it is the first hit); an exit that
  follows an exit is skipped instead of re-using a stale ``d_enter``; of two entries in a row the later wins;
- an interval that would open beyond ``d_M-`` ends the ray without samples (Procedure 3 would emit a
  reversed interval there); with nested meshes this coincides with line 21's ``break``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from neural.config import NarrowBandConfig
from neural.render.raycast import ShellCaster, as_rays, ray_lengths
from neural.render.samples import RaySamples


@dataclass
class NarrowBandStats:
    """What the sampler found, on the CPU; distances in units of the ray directions as given."""

    counts: np.ndarray  # (R,) int64 samples per ray
    interval_rays: np.ndarray  # (I,) int64 ray of each in-shell interval, sorted
    interval_enter: np.ndarray  # (I,) float64 start of each interval
    interval_exit: np.ndarray  # (I,) float64 end of each interval (clipped at t_inner)
    t_inner: np.ndarray  # (R,) float64 first hit of M- (d_M-), inf where the ray misses M- or M+

    @property
    def mean_samples_per_ray(self) -> float:
        """Mean number of samples per ray (per pixel for camera rays)."""
        return float(self.counts.mean()) if self.counts.size else 0.0


def intervals_from_hits(
    ray_idx: np.ndarray, t: np.ndarray, entering: np.ndarray, t_inner: np.ndarray, max_peel: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """In-shell intervals from the ordered M+ hits of all rays (Procedure 3, lines 10-22, vectorised).

    Args:
        ray_idx, t, entering: (H,) M+ hits sorted by ray then distance (``ShellCaster.all_hits``),
            possibly cut at ``d_M-`` (``t_stop``); only the first ``max_peel`` of each ray are used.
        t_inner: (R,) first M- hit per ray (``d_M-``), ``inf`` on a miss.
        max_peel: the depth-peeling cap ``dp_max``.

    Returns ``interval_rays`` (I,) int64, ``d_enter`` (I,) and ``d_exit`` (I,) float64, sorted by ray and
    distance; ``d_exit`` is clipped at ``d_M-`` and intervals opening beyond ``d_M-`` are dropped (which
    also drops everything after line 21's ``break``). A ray whose last hit enters M+, with fewer than
    ``max_peel`` hits and a finite ``d_M-``, closes its interval at ``d_M-``: M+ is closed, so the hit
    Procedure 3 would take next is an exit, and only ``d_M-`` matters of it (the exit need not be cast).
    Rules for open cases: see the module docstring.
    """
    first = np.ones(len(ray_idx), dtype=bool)
    first[1:] = ray_idx[1:] != ray_idx[:-1]
    rank = np.arange(len(ray_idx)) - np.maximum.accumulate(np.where(first, np.arange(len(ray_idx)), 0))
    ray_idx, t, entering, first = (x[rank < max_peel] for x in (ray_idx, t, entering, first))
    last = np.append(first[1:], True)
    after_entry = np.zeros(len(ray_idx), dtype=bool)
    after_entry[1:] = entering[:-1] & ~first[1:]
    # Exits that close an interval, opened by the previous hit or, for a first hit, at the origin.
    closing = np.flatnonzero(~entering & (first | after_entry))
    # Entries left open by a cast cut at d_M-.
    n_hits = np.bincount(ray_idx, minlength=len(t_inner))
    unclosed = np.flatnonzero(entering & last)
    unclosed = unclosed[(n_hits[ray_idx[unclosed]] < max_peel) & np.isfinite(t_inner[ray_idx[unclosed]])]

    rays = np.concatenate([ray_idx[closing], ray_idx[unclosed]])
    d_enter = np.concatenate([np.where(first[closing], 0.0, t[np.maximum(closing - 1, 0)]), t[unclosed]])
    d_inner = t_inner[rays]
    d_exit = np.minimum(np.concatenate([t[closing], d_inner[len(closing) :]]), d_inner)
    order = np.argsort(rays, kind="stable")  # an unclosed interval is the last of its ray
    order = order[d_enter[order] <= d_inner[order]]
    return rays[order], d_enter[order], d_exit[order]


def samples_per_interval(width: np.ndarray, config: NarrowBandConfig) -> np.ndarray:
    """(I,) int64 ``N = min(ceil(max(w - w_s, 0) / delta_s) + 1, N_max)`` for world widths ``w`` (I,)
    (Procedure 3, line 19)."""
    n = np.ceil(np.maximum(width - config.w_s, 0.0) / config.delta_s) + 1
    return np.minimum(n, config.n_max).astype(np.int64)


def interval_widths(starts, units, rays, d_enter, d_exit, contraction=None) -> np.ndarray:
    """(I,) widths of the intervals ``[d_enter, d_exit]`` (I,) along unit rays ``starts``, ``units`` (R, 3) of
    ``rays`` (I,): world widths, or for a ``contraction`` the chords between the contracted ends."""
    if contraction is None:
        return d_exit - d_enter
    origin, unit = torch.as_tensor(starts[rays]), torch.as_tensor(units[rays])
    ends = [contraction.to_field(origin + torch.as_tensor(d)[:, None] * unit) for d in (d_enter, d_exit)]
    return (ends[1] - ends[0]).norm(dim=-1).numpy()


def samples_from_intervals(
    interval_rays: np.ndarray, d_enter: np.ndarray, d_exit: np.ndarray, n: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Pack ``n`` (I,) equidistant samples per interval (Procedure 3, line 20).

    Sample ``k`` of an interval of width ``w`` sits at ``d_enter + (k + 1) w / (n + 1)``, i.e.
    ``linspace(d_enter, d_exit, n + 2)[1:-1]``; its section runs between the midpoints to its neighbours,
    the first section starting at ``d_enter`` and the last ending at ``d_exit``, so the sections tile the
    interval. Returns ``ray_indices`` (S,) int64, ``t_starts``, ``t_ends``, ``t_positions`` (S,) float64.
    """
    owner = np.repeat(np.arange(len(n)), n)
    first = np.cumsum(n) - n  # (I,) each interval's first sample
    k = np.arange(len(owner)) - first[owner]
    gap = ((d_exit - d_enter) / (n + 1))[owner]
    positions = d_enter[owner] + (k + 1) * gap
    starts = positions - 0.5 * gap
    ends = positions + 0.5 * gap
    some = n > 0  # an interval's first section starts at d_enter, its last ends at d_exit
    starts[first[some]] = d_enter[some]
    ends[(first + n - 1)[some]] = d_exit[some]
    return interval_rays[owner], starts, ends, positions


def _pack(rays, starts, ends, positions, n_rays: int, device) -> RaySamples:
    """``RaySamples`` from numpy sample arrays (S,)."""

    def f32(x):
        return torch.as_tensor(np.asarray(x, dtype=np.float32), device=device)

    return RaySamples(
        ray_indices=torch.as_tensor(np.asarray(rays, dtype=np.int64), device=device),
        t_starts=f32(starts),
        t_ends=f32(ends),
        n_rays=n_rays,
        t_positions=f32(positions),
    )


def narrow_band_samples(
    caster: ShellCaster,
    origins,
    dirs,
    config: NarrowBandConfig | None = None,
    near: float = 0.0,
    device: torch.device | str = "cpu",
    contraction=None,
) -> tuple[RaySamples, NarrowBandStats]:
    """Samples of all rays in the narrow band between M+ and M- (Procedure 3, vectorised over rays).

    Args:
        caster: ray casting against the shells (any backend).
        origins, dirs: (R, 3) rays (numpy or torch); ``dirs`` need not be unit length: distances are in
            units of ``dirs`` (sample = origin + t * dir) while widths, ``delta_s`` and ``w_s`` are in world
            units.
        config: sampling settings; ``NarrowBandConfig()`` when omitted.
        near: rays start at ``t = near``; a ray starting inside M+ has an interval opening there.
        device: where the returned tensors live.
        contraction: for shells of a field in contracted space, its
            :class:`~neural.field.contraction.ContractionMap`: an interval's width is then its length there
            (the chord between its contracted ends), so that a wall far behind the object gets the samples
            its contracted width needs, not those of its world width.

    Returns ``RaySamples`` (with ``t_positions``: samples at the ends of an interval are not at their
    section midpoints) and ``NarrowBandStats``.
    """
    config = NarrowBandConfig() if config is None else config
    origins, dirs = as_rays(origins, dirs)
    if not (np.isfinite(near) and near >= 0):
        raise ValueError(f"near must be finite and >= 0, got {near}")
    n_rays = len(origins)
    norms = ray_lengths(dirs)
    units = dirs / norms[:, None]
    starts = origins + near * dirs
    # World distances from the near point along unit directions from here on. A ray that misses M+ has no
    # interval (M+ is closed, so it never is inside M+): M- and the peeling rounds are cast only for the rays
    # that meet M+ (a fifth to a third of a lego view's), by ShellCaster.band_hits.
    meets, t_meets, ray_idx, t, entering = caster.band_hits(starts, units, config.max_peel)
    t_inner = np.full(n_rays, np.inf)
    t_inner[meets] = t_meets
    rays, d_enter, d_exit = intervals_from_hits(ray_idx, t, entering, t_inner, config.max_peel)
    n = samples_per_interval(interval_widths(starts, units, rays, d_enter, d_exit, contraction), config)
    # Back to units of dirs from the ray origin: an affine map per ray, so sample placement commutes with it.
    scale = 1.0 / norms[rays]
    d_enter, d_exit = near + d_enter * scale, near + d_exit * scale
    samples = _pack(*samples_from_intervals(rays, d_enter, d_exit, n), n_rays, device)
    stats = NarrowBandStats(
        counts=np.bincount(rays, weights=n, minlength=n_rays).astype(np.int64),
        interval_rays=rays,
        interval_enter=d_enter,
        interval_exit=d_exit,
        t_inner=near + t_inner / norms,
    )
    return samples, stats
