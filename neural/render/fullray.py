"""Full-ray sampling inside the field's bounding box and volume rendering of a field (stage 1, Sec. 3.1-3.2).

:func:`stepped_samples` returns packed :class:`~neural.render.samples.RaySamples` (sections ``[t_start,
t_end]`` with the sample at their centre, where :func:`~neural.render.neus.neus_alpha` expects it): equal
sections of a fixed length (Instant-NGP marching), the candidates that the occupancy grid
(:mod:`neural.render.occupancy`) filters. (The uniform and NeuS importance samplers it was compared with
live in ``bench/fullray_samplers.py``.)

:func:`render_rays` evaluates a field once on all samples, turns SDF, kernel and predicted normal into opacity
and composites (Eq. 2-3). :func:`visible_samples` drops, before that, the samples that no light reaches
(training: the gradient pass then only pays for the samples that can change a pixel); it and
:func:`shade_samples` (rendering) take the samples front to back in rounds and stop a ray once light no
longer reaches it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import torch

from .composite import MIN_TRANSMITTANCE, _finish, composite, log_transmittance, transmittance
from .neus import neus_alpha
from .samples import RaySamples

#: :func:`shade_samples`'s default bound on how much leaving out nearly invisible samples may change a
#: pixel (each channel, colours in [0, 1]): a quarter of an 8-bit step.
WEIGHT_TOLERANCE = 1e-3
#: Samples per ray in :func:`shade_samples`'s first round; each later round is as long as all before it.
#: Eight, not two: the geometry network costs less per sample in larger calls on the CPU (on lego, 1.5 us
#: per sample at 27k samples, 0.8-1 us at 70k+), so one large first round and fewer rounds after it cost
#: less than the samples that early termination saves with smaller ones (a lego frame: 0.74-0.82x the time
#: of rounds from 2, at 1.93 instead of 1.84 samples per pixel).
FIRST_ROUND = 8
#: Once this few samples of live rays remain, :func:`shade_samples` takes them all in one last round: a round
#: has fixed costs on the CPU (Warp launches, thread hand-offs, small tensor operations) and a small call of
#: the geometry network costs more per sample than a large one, so after the first round of a 200x200 frame
#: one more takes the rest (lego: 2.00 rounds a frame instead of 3.08 with 4,096 here, 0.93x the time at
#: 1.95 instead of 1.93 samples per pixel; furry bunny: 2.00 instead of 3.38 rounds, 0.75x, 2.403 against
#: 2.400).
LAST_ROUND_SAMPLES = 65536
#: :func:`visible_samples`'s rounds (training's visibility pass): a first round of 16 samples a ray, then
#: doubling until this few samples of live rays remain. Candidates are skewed over a batch's rays (most of a
#: lego batch's rays have fewer than 8 of them, some more than 32), so rounds drop most of a ray's samples
#: behind its surface while the first one stays large. Lego, a 3500-step field, 9,000 rays: the network ran
#: on 88k of 166k candidates in 3 rounds, 121 against 188 ms for one pass over all (medians of 5 batches);
#: a 250-step field, 4,000 rays: 147 against 181 ms (first rounds of 8: 133 and 166 ms; of 32: 136 and 151).
VISIBLE_FIRST_ROUND = 16
VISIBLE_LAST_ROUND_SAMPLES = 16384


def _check_rays(origins: torch.Tensor, dirs: torch.Tensor) -> None:
    if origins.dim() != 2 or origins.shape[1] != 3 or origins.shape != dirs.shape:
        raise ValueError(
            f"origins and dirs must both have shape (R, 3), "
            f"got {tuple(origins.shape)} and {tuple(dirs.shape)}"
        )


def _check_near_far(near: torch.Tensor, far: torch.Tensor) -> None:
    if near.dim() != 1 or near.shape != far.shape:
        raise ValueError(
            f"near and far must both have shape (R,), got {tuple(near.shape)} and {tuple(far.shape)}"
        )


def ray_aabb(
    origins: torch.Tensor,
    dirs: torch.Tensor,
    aabb_min: torch.Tensor,
    aabb_max: torch.Tensor,
    near_plane: float = 0.0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Distances at which rays ``o + t d`` enter and leave an axis-aligned box (slab method).

    origins, dirs : (R, 3) ; aabb_min, aabb_max : (3,) world box corners ; near_plane : smallest allowed t.
    Returns ``near, far`` (R,), with ``near = max(t_enter, near_plane)``; a ray misses the box iff
    ``far <= near`` (both are then set to ``near_plane``).
    """
    _check_rays(origins, dirs)
    lo = torch.as_tensor(aabb_min, dtype=origins.dtype, device=origins.device)
    hi = torch.as_tensor(aabb_max, dtype=origins.dtype, device=origins.device)
    tiny = torch.finfo(dirs.dtype).tiny
    safe = torch.where(dirs.abs() < tiny, torch.full_like(dirs, tiny), dirs)  # zero components -> +tiny
    t0 = (lo - origins) / safe
    t1 = (hi - origins) / safe
    near = torch.minimum(t0, t1).amax(dim=1).clamp(min=near_plane)
    far = torch.maximum(t0, t1).amin(dim=1)
    miss = far <= near
    near = torch.where(miss, torch.full_like(near, near_plane), near)
    far = torch.where(miss, torch.full_like(far, near_plane), far)
    return near, far


def step_offsets(
    n_rays: int, like: torch.Tensor, perturb: bool, generator: torch.Generator | None
) -> torch.Tensor:
    """(R,) per-ray shift in [0, 1) of the section grid, in units of the step (0 without perturbation)."""
    if not perturb:
        return like.new_zeros(n_rays)
    return torch.rand(n_rays, dtype=like.dtype, device=like.device, generator=generator)


def pack_dense(t_starts: torch.Tensor, t_ends: torch.Tensor, valid: torch.Tensor) -> RaySamples:
    """Pack the valid entries of dense (R, M) section bounds into :class:`RaySamples` (row-major order)."""
    rays, cols = torch.nonzero(valid, as_tuple=True)
    return RaySamples(rays, t_starts[rays, cols], t_ends[rays, cols], valid.shape[0])


def step_range(
    near: torch.Tensor,
    far: torch.Tensor,
    step_size: float,
    max_samples: int,
    shift: torch.Tensor,
    window: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The steps ``first <= k < end`` (R,) each, float, of the sections ``t_start = near + (k + u) step_size``
    (``u`` = ``shift`` (R,)) of :func:`stepped_candidates` whose centre can lie in ``window = (lo, hi)``
    (default ``(near, far)``), with one step of slack on each side, within ``[0, max_samples)``."""
    _check_near_far(near, far)
    if step_size <= 0 or max_samples < 1:
        raise ValueError(f"need step_size > 0 and max_samples >= 1, got {step_size} and {max_samples}")
    lo, hi = window if window is not None else (near, far)
    first = torch.floor((lo - near) / step_size - shift - 1.5).clamp(0, max_samples)  # centre <= lo - step
    end = torch.ceil((hi - near) / step_size - shift + 0.5).clamp(0, max_samples)  # centre >= hi + step
    return first, torch.maximum(end, first)


def stepped_candidates(
    near: torch.Tensor,
    far: torch.Tensor,
    step_size: float,
    max_samples: int,
    perturb: bool = False,
    generator: torch.Generator | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Dense fixed-length sections: ``t_start = near + (k + u) step_size`` for ``0 <= k < max_samples``.

    A section is valid while ``t_start < far`` (so the last one may reach past ``far`` by less than a step);
    ``u`` is 0, or ``u ~ U[0, 1)`` per ray when ``perturb``. near, far : (R,). Returns ``t_starts, t_ends,
    valid``, each (R, M) with M <= ``max_samples``.
    """
    u = step_offsets(near.shape[0], near, perturb, generator)
    first, end = step_range(near, far, step_size, max_samples, u)
    n_cols = int((end - first).max()) if near.numel() > 0 else 0
    k = first[:, None] + torch.arange(n_cols, dtype=near.dtype, device=near.device)
    starts = near[:, None] + (k + u[:, None]) * step_size
    return starts, starts + step_size, (starts < far[:, None]) & (k < end[:, None])


def stepped_samples(
    near: torch.Tensor,
    far: torch.Tensor,
    step_size: float,
    max_samples: int,
    perturb: bool = False,
    generator: torch.Generator | None = None,
) -> RaySamples:
    """Packed :func:`stepped_candidates`: sections of length ``step_size`` from ``near`` to ``far``."""
    return pack_dense(*stepped_candidates(near, far, step_size, max_samples, perturb, generator))


def ray_background(field: Any, dirs: torch.Tensor, background: torch.Tensor | None) -> torch.Tensor | None:
    """What rays along ``dirs`` (R, 3) see behind the field: its environment map's colours (R, 3) when it
    has one, else ``background`` unchanged."""
    env = field.environment(dirs) if hasattr(field, "environment") else None
    return background if env is None else env.to(dirs.dtype)


def render_rays(
    field: Any,
    origins: torch.Tensor,
    dirs: torch.Tensor,
    samples: RaySamples,
    background: torch.Tensor | None = None,
    cos_anneal: float = 1.0,
) -> dict[str, Any]:
    """Render rays through a NeuS field with a spatially varying kernel (Eq. 2-3).

    The field is evaluated once on all S samples ``x = o + t_mid d`` (see :func:`render_samples`), with
    section lengths ``delta |d|`` in world units (a contracted field: where it lives, :func:`field_space`).

    origins, dirs : (R, 3) ; samples : packed samples of these R rays ; background : (3,), (R, 3) or None;
    a field with an environment map (``field.environment(dirs)`` not None) shows it instead.
    Returns :func:`render_samples`'s dictionary.
    """
    _check_rays(origins, dirs)
    background = ray_background(field, dirs, background)
    if samples.n_rays != origins.shape[0]:
        raise ValueError(f"samples are for {samples.n_rays} rays but {origins.shape[0]} rays were given")
    located = field_space(field, samples.points(origins, dirs), *_sections(dirs, samples))
    return render_samples(field, *located, samples, background, cos_anneal)


def _sections(dirs: torch.Tensor, samples: RaySamples) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per sample: unit ray direction (S, 3), section length and section-start-to-sample distance (S,) in
    world units, for rays along ``dirs`` (R, 3) (any length)."""
    norm = dirs.norm(dim=1)[samples.ray_indices]
    unit_dirs = dirs[samples.ray_indices] / norm[:, None].clamp_min(1e-12)
    return unit_dirs, samples.deltas * norm, (samples.t_mid - samples.t_starts) * norm


def field_space(field: Any, points, unit_dirs, deltas, fronts):
    """World samples ``points``, ``unit_dirs`` (S, 3), ``deltas``, ``fronts`` (S,) where ``field`` lives: for
    a field in contracted space (its ``contraction``, :class:`~neural.field.contraction.ContractionMap`) the
    contracted points and directions with both lengths times the map's stretch; for any other the same."""
    contraction = getattr(field, "contraction", None)
    if contraction is None:
        return points, unit_dirs, deltas, fronts
    points, unit_dirs, stretch, _ = contraction.map_rays(points, unit_dirs)
    return points, unit_dirs, deltas * stretch, fronts * stretch


def _opacity(field: Any, points, unit_dirs, deltas, fronts, cos_anneal: float):
    """The field's geometry at ``points`` (S, 3) and each section's NeuS opacity alpha (S,) (Eq. 3) with
    ``cos = dot(unit_dirs, normal)``; arguments as :func:`render_samples`'s."""
    geometry = field.geometry(points)
    cos = (unit_dirs * geometry.normal).sum(dim=1)
    return geometry, neus_alpha(geometry.sdf, geometry.inv_s, cos, deltas, cos_anneal, fronts)


def render_samples(
    field: Any,
    points: torch.Tensor,
    unit_dirs: torch.Tensor,
    deltas: torch.Tensor,
    fronts: torch.Tensor,
    samples: RaySamples,
    background: torch.Tensor | None = None,
    cos_anneal: float = 1.0,
) -> dict[str, Any]:
    """Shade and composite S samples given where the field is evaluated (Eq. 2-3).

    ``field.geometry(points)`` returns an object with ``sdf`` (S,), ``inv_s`` (S,), ``normal`` (S, 3) unit,
    and ``field.radiance(points, unit_dirs, geometry)`` the colours (S, 3). Opacity is
    :func:`~neural.render.neus.neus_alpha` with ``cos = dot(unit_dirs, normal)``. The deformed renderer
    passes rest-space points, directions and section lengths here.

    points, unit_dirs : (S, 3) ; deltas, fronts : (S,) section lengths and section-start-to-sample distances
    in world units ; samples : the packed layout (ray_indices, t_mid, n_rays) ; background : (3,), (R, 3)
    or None.
    Returns :func:`~neural.render.composite.composite`'s ``color`` (R, 3), ``opacity`` (R,), ``depth`` (R,),
    ``weights`` (S,) plus per sample ``alpha``, ``rgb`` (S, 3), ``sdf``, ``inv_s``, ``normal`` (S, 3),
    ``points`` (S, 3), ``ray_indices`` (S,) and ``geometry`` (the field's object, None without samples).
    Rays without samples show the background; with no samples at all the field is not called.
    """
    ray_indices = samples.ray_indices
    if ray_indices.numel() == 0:
        empty = points.new_zeros(0)
        out = composite(empty, points, ray_indices, samples.n_rays, empty, background)
        geometry = None
        rgb, sdf, inv_s, normal, alpha = points, empty, empty, points, empty
    else:
        geometry, alpha = _opacity(field, points, unit_dirs, deltas, fronts, cos_anneal)
        rgb = field.radiance(points, unit_dirs, geometry)
        sdf, inv_s, normal = geometry.sdf, geometry.inv_s, geometry.normal
        out = composite(alpha, rgb, ray_indices, samples.n_rays, samples.t_mid, background)
    out.update(
        alpha=alpha,
        rgb=rgb,
        sdf=sdf,
        inv_s=inv_s,
        normal=normal,
        points=points,
        ray_indices=ray_indices,
        geometry=geometry,
    )
    return out


def sample_rounds(samples: RaySamples, first_round: int, last_round_samples: int, alive: torch.Tensor):
    """Front-to-back rounds over packed samples, by their rank along their ray: ``[0, first_round)``, then
    each round as long as all before it (``[r, 2 r)``), and every rank left in one round once at most
    ``last_round_samples`` samples of live rays remain. From the second round on only rays where ``alive``
    (R,) bool is true take part (the caller updates it in place between rounds). Yields the sample indices
    (K,) int64, increasing, of each non-empty round."""
    ray_indices = samples.ray_indices
    per_ray = samples.counts()
    first = (per_ray.cumsum(0) - per_ray).index_select(0, ray_indices)
    rank = torch.arange(len(ray_indices), device=ray_indices.device) - first
    last_rank = int(rank.max()) if len(rank) else -1
    lo, hi = 0, first_round
    while lo <= last_rank and bool(alive.any()):
        member = rank >= lo
        if lo > 0:
            member &= alive.index_select(0, ray_indices)
        if hi <= last_rank and int(member.sum()) > last_round_samples:
            member &= rank < hi
        else:
            hi = last_rank + 1
        index = torch.nonzero(member).squeeze(1)
        lo, hi = hi, 2 * hi
        if index.numel() > 0:
            yield index


@torch.no_grad()
def visible_samples(
    field: Any,
    origins: torch.Tensor,
    dirs: torch.Tensor,
    samples: RaySamples,
    min_transmittance: float,
    cos_anneal: float = 1.0,
) -> RaySamples:
    """The samples that light still reaches: transmittance ``T_i > min_transmittance`` (Eq. 2).

    The geometry network (no colour, no gradient) gives each sample's NeuS opacity as :func:`render_rays`
    computes it, front to back in the rounds of :func:`shade_samples` (:data:`VISIBLE_FIRST_ROUND` samples a
    ray, then doubling until :data:`VISIBLE_LAST_ROUND_SAMPLES` remain): a ray whose transmittance fell to
    ``min_transmittance`` takes part in no further round, as T is non-increasing along a ray. What is dropped
    is a tail of each ray; rendering the kept samples changes a ray's colour by at most ``T`` at its first
    dropped sample times the largest colour difference, i.e. by at most ``min_transmittance`` for colours in
    [0, 1]. origins, dirs : (R, 3) ; samples : packed samples of these rays ; ``min_transmittance <= 0``
    keeps all.
    """
    rays = samples.ray_indices
    if min_transmittance <= 0 or rays.numel() == 0:
        return samples
    log_t = torch.zeros(samples.n_rays, dtype=torch.float64, device=rays.device)  # log T after each round
    alive = torch.ones(samples.n_rays, dtype=torch.bool, device=rays.device)
    keep = torch.zeros(len(rays), dtype=torch.bool, device=rays.device)
    log_min = math.log(min_transmittance)
    for index in sample_rounds(samples, VISIBLE_FIRST_ROUND, VISIBLE_LAST_ROUND_SAMPLES, alive):
        round_samples = samples.select(index)
        part = round_samples.ray_indices
        located = field_space(field, round_samples.points(origins, dirs), *_sections(dirs, round_samples))
        _, alpha = _opacity(field, *located, cos_anneal)
        keep[index] = log_t.index_select(0, part) + log_transmittance(alpha, part, samples.n_rays) > log_min
        log_t.index_add_(0, part, torch.log(torch.clamp(1.0 - alpha.double(), min=MIN_TRANSMITTANCE)))
        alive.copy_(log_t > log_min)
    return samples.select(keep)


@torch.no_grad()
def _shading(field, points, unit_dirs, deltas, fronts, which=None):
    """Opacities alpha (S,) of samples (arguments as :func:`render_samples`'s) and ``radiance(shown (K,)
    int64 increasing) -> (K, 3)``, the colours of those of them. ``field``: one field, or a sequence of
    fields with ``which`` (S,) int64 the index of each sample's field (each evaluates its own samples)."""
    if which is None:
        geometry, alpha = _opacity(field, points, unit_dirs, deltas, fronts, 1.0)

        def radiance(shown):
            picked = type(geometry)(*(g.index_select(0, shown) for g in geometry))
            return field.radiance(points.index_select(0, shown), unit_dirs.index_select(0, shown), picked)

        return alpha, radiance
    alpha = points.new_zeros(len(points))
    groups = []  # (body, its field, its samples (M,) increasing, their geometry)
    for body, one in enumerate(field):
        members = torch.nonzero(which == body).squeeze(1)
        if len(members):
            geometry, alpha[members] = _opacity(
                one, *(x.index_select(0, members) for x in (points, unit_dirs, deltas, fronts)), 1.0
            )
            groups.append((body, one, members, geometry))

    def radiance(shown):
        rgb = points.new_zeros(len(shown), 3)
        for body, one, members, geometry in groups:
            mine = torch.nonzero(which.index_select(0, shown) == body).squeeze(1)
            rows = shown.index_select(0, mine)
            local = torch.searchsorted(members, rows)  # their places among the body's samples
            picked = type(geometry)(*(g.index_select(0, local) for g in geometry))
            rgb[mine] = one.radiance(points.index_select(0, rows), unit_dirs.index_select(0, rows), picked)
        return rgb

    return alpha, radiance


def shade_samples(
    field: Any,
    samples: RaySamples,
    locate: Callable[[torch.Tensor], tuple[torch.Tensor, ...]],
    background: torch.Tensor | Callable[[torch.Tensor], torch.Tensor] | None = None,
    tolerance: float = WEIGHT_TOLERANCE,
    first_round: int = FIRST_ROUND,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Colours (R, 3) of :func:`render_samples` for rendering, without autograd, front to back with early ray
    termination, and the number of samples (R,) int64 each ray had located.

    The samples are taken in rounds by their rank along their ray: ``[0, first_round)``, then each round as
    long as all before it (``[r, 2 r)``), and every rank left in one round once at most
    :data:`LAST_ROUND_SAMPLES` samples remain to be taken. A round locates and evaluates the geometry only
    for rays whose transmittance is still above ``tolerance / 2``, and the radiance network only runs where
    a weight ``w_i = T_i alpha_i`` exceeds ``tolerance / (2 n)`` (``n`` the samples of its ray). What is
    left out weighs at most ``tolerance / 2`` per kind, and the colours and the background lie in [0, 1], so
    every channel of every pixel is within ``tolerance`` of :func:`render_samples`'s; ``tolerance = 0``
    gives the same colours.

    locate(index (K,) int64 of samples, increasing) -> ``(index (K',), points (K', 3), unit_dirs (K', 3),
    deltas (K',), fronts (K',))``: where the field is evaluated for those samples (as :func:`render_samples`'s
    arguments), leaving out samples it cannot place (a deformed frame's samples outside the cage).
    ``field.geometry`` returns a NamedTuple of per-sample tensors with ``sdf``, ``inv_s`` and ``normal``.
    With a sequence of fields for ``field`` (several bodies in one image, :mod:`neural.render.bodies`),
    ``locate`` also returns, sixth, the index (K',) int64 of each sample's field in it.

    ``background``: (3,), (R, 3), None (black), or ``background(rays (K,) int64) -> (K, 3)``, asked only for
    the rays whose transmittance is still above ``tolerance / 2`` after the last round (a lit ground's shadow
    rays are not cast behind an opaque body): the light it would add to the others is less than that, within
    what termination leaves out.
    """
    if not tolerance >= 0:
        raise ValueError(f"tolerance: expected >= 0, got {tolerance}")
    if first_round < 1:
        raise ValueError(f"first_round: expected >= 1, got {first_round}")
    ray_indices, n_rays = samples.ray_indices, samples.n_rays
    per_ray = samples.counts()
    log_t = torch.zeros(n_rays, dtype=torch.float64, device=ray_indices.device)  # log T after each round
    located = torch.zeros_like(per_ray)
    color = opacity = None
    alive = torch.ones_like(per_ray, dtype=torch.bool)
    for index in sample_rounds(samples, first_round, LAST_ROUND_SAMPLES, alive):
        located += torch.bincount(ray_indices.index_select(0, index), minlength=n_rays)
        index, points, unit_dirs, deltas, fronts, *which = locate(index)
        rays = ray_indices.index_select(0, index)
        alpha, radiance = _shading(field, points, unit_dirs, deltas, fronts, *which)
        before = log_t.index_select(0, rays).exp().to(alpha.dtype)
        weights = transmittance(alpha, rays, n_rays) * before * alpha
        log_t.index_add_(0, rays, torch.log(torch.clamp(1.0 - alpha.double(), min=MIN_TRANSMITTANCE)))
        if tolerance > 0:
            alive.copy_(log_t > math.log(tolerance / 2))
        shown = torch.nonzero(weights * per_ray.index_select(0, rays) > tolerance / 2).squeeze(1)
        rgb = points.new_zeros(len(points), 3)
        rgb[shown] = radiance(shown)
        part = _finish(weights, rgb, rays, n_rays, None, None)
        color = part["color"] if color is None else color + part["color"]
        opacity = part["opacity"] if opacity is None else opacity + part["opacity"]
    if color is None:  # nothing located: every ray shows the background
        dtype = background.dtype if isinstance(background, torch.Tensor) else torch.float32
        color = torch.zeros(n_rays, 3, dtype=dtype, device=ray_indices.device)
        opacity = torch.zeros(n_rays, dtype=dtype, device=ray_indices.device)
    if callable(background):
        seen = torch.nonzero(alive).squeeze(1)
        if len(seen):
            behind = background(seen).to(color.dtype)
            color = color.index_add(0, seen, (1.0 - opacity.index_select(0, seen))[:, None] * behind)
    elif background is not None:
        color = color + (1.0 - opacity)[:, None] * background.to(color.dtype).expand(n_rays, 3)
    return color, located
