"""Several fields in one image (issue 41): each camera ray is cast against every body's shells, the samples of
every body it enters are merged by depth and composited once, over one background.

A :class:`FieldBody` is a field with its sampler (the narrow band of its shells, at rest or deformed), its
optional map to rest space and the similarity ``x_world = s R x + T`` (any :class:`Similarity`, e.g.
``shellsim.world.Placement``) that places its frame in the world. The world ray ``o + t d`` is, in the body's
frame, the ray ``o_b + t d_b`` with ``o_b = R^T (o - T) / s`` and ``d_b = R^T d / s``: the same parameter
``t``, so the samples of different bodies on one ray are ordered by ``t`` alone. Only the rays that cross a
body's world ``box`` are cast against its shells, so a ray costs what the bodies it enters cost, not the
number of bodies.

Each sample is located (:func:`locate_samples`: mapped to its own body's rest space, its section measured in
its field's units, ``|d_b|`` times the map's stretch) and shaded by its own field
(:func:`~neural.render.fullray.shade_samples` with a sequence of fields). With one body whose frame is the
identity and no box, the samples, their places and so the image are exactly those of the body alone.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import torch

from .fullray import ray_aabb
from .samples import RaySamples


class Similarity(Protocol):
    """What places a body's frame in the world: ``x_world = scale * rotation @ x + translation``, scale > 0,
    rotation (3, 3) orthonormal, translation (3,) (the world's class is ``shellsim.world.Placement``)."""

    scale: float
    rotation: np.ndarray
    translation: np.ndarray


@dataclass
class FieldBody:
    """One body of an image.

    field : its ``ShellField`` (``geometry``, ``radiance``)
    sampler : ``sampler(origins (R, 3), dirs (R, 3)) -> RaySamples`` in its frame (e.g.
        :func:`neural.render.view.narrow_band_sampler`)
    to_rest : map of its samples to rest space (:class:`neural.render.view.RestMap`); None: none
    frame : the :class:`Similarity` placing its frame in the world; None: the identity
    box : (2, 3) world corners of a box holding everything it shows (its deformed shells); None: every ray
        is cast against its shells
    """

    field: Any
    sampler: Any
    to_rest: Any = None
    frame: Similarity | None = None
    box: np.ndarray | None = None

    @property
    def rest_map(self):
        """Where its samples are evaluated: ``to_rest``, then its field's contraction when it lives in
        contracted space (:class:`~neural.field.contraction.ContractionMap`); None: where they are."""
        contraction = getattr(self.field, "contraction", None)
        if contraction is None or self.to_rest is None:
            return self.to_rest if contraction is None else contraction
        return ChainedMap(self.to_rest, contraction)

    @property
    def identity(self) -> bool:
        """Whether the body's frame is the world's."""
        f = self.frame
        if f is None:
            return True
        return f.scale == 1.0 and np.array_equal(f.rotation, np.eye(3)) and not np.any(f.translation)


@dataclass
class ChainedMap:
    """Two maps of samples (:class:`neural.render.view.RestMap`) one after the other: ``second`` of ``first``,
    stretches multiplied, a sample kept where both keep it."""

    first: Any
    second: Any

    def map_rays(self, points: torch.Tensor, unit_dirs: torch.Tensor):
        points, unit_dirs, stretch, inside = self.first.map_rays(points, unit_dirs)
        points, unit_dirs, more, within = self.second.map_rays(points, unit_dirs)
        return points, unit_dirs, stretch * more, inside & within


def body_rays(body: FieldBody, origins: torch.Tensor, dirs: torch.Tensor):
    """World rays ``origins``, ``dirs`` (R, 3) in ``body``'s frame: ``R^T (o - T) / s``, ``R^T d / s`` (R, 3)
    in their dtype, the same ray parameter."""
    if body.identity:
        return origins, dirs
    f = body.frame
    rotation = torch.as_tensor(f.rotation, dtype=torch.float64, device=origins.device)
    translation = torch.as_tensor(f.translation, dtype=torch.float64, device=origins.device)
    o = (origins.double() - translation) @ rotation / f.scale
    d = dirs.double() @ rotation / f.scale
    return o.to(origins.dtype), d.to(dirs.dtype)


def body_share(body: FieldBody, origins: torch.Tensor, dirs: torch.Tensor):
    """The world rays ``origins``, ``dirs`` (R, 3) that cross ``body``'s box in front of their origin:
    ``(rays (K,) int64 their indices or None for all (no box), o, d (K, 3) them in the body's frame)``."""
    if body.box is None:
        return None, *body_rays(body, origins, dirs)
    lo, hi = (torch.as_tensor(c, dtype=origins.dtype, device=origins.device) for c in body.box)
    near, far = ray_aabb(origins, dirs, lo, hi)
    rays = torch.nonzero(far > near).squeeze(1)
    return rays, *body_rays(body, origins.index_select(0, rays), dirs.index_select(0, rays))


@dataclass
class _Part:
    """A body's share of a chunk of rays: ``rays`` (K,) their indices (None: all), the rays in its frame
    ``origins``, ``dirs`` (K, 3), its ``samples`` over them and ``merged`` (S_b,) int64 the place of each in
    the merged samples."""

    rays: torch.Tensor | None
    origins: torch.Tensor
    dirs: torch.Tensor
    samples: RaySamples
    merged: torch.Tensor


@dataclass
class MergedSamples:
    """The samples of every body along the same rays, sorted by ray and then by ``t``: ``samples``, ``which``
    (S,) int64 each one's body, ``local`` (S,) int64 its index among its body's samples, and each body's
    :class:`_Part` (None where no ray meets it)."""

    samples: RaySamples
    which: torch.Tensor
    local: torch.Tensor
    parts: list


def merged_samples(bodies, origins: torch.Tensor, dirs: torch.Tensor, t_max=None) -> MergedSamples:
    """Sample world rays ``origins``, ``dirs`` (R, 3) with every body's sampler (only the rays crossing its
    box) and merge the samples by ray and ``t`` (a stable sort: a body's own order is kept). ``t_max`` (R,):
    samples beyond it are dropped (a surface in front hides them)."""
    device, n_rays = origins.device, len(origins)
    pieces, parts = [], []
    for b, body in enumerate(bodies):
        rays, o, d = body_share(body, origins, dirs)
        if rays is not None and not len(rays):
            parts.append(None)
            continue
        samples = body.sampler(o, d)
        if t_max is not None:
            global_rays = samples.ray_indices if rays is None else rays.index_select(0, samples.ray_indices)
            near = t_max.to(device, torch.float64).index_select(0, global_rays)
            keep = torch.nonzero(samples.t_mid.double() <= near).squeeze(1)
            samples = samples.select(keep)
        global_rays = samples.ray_indices if rays is None else rays.index_select(0, samples.ray_indices)
        local = torch.arange(len(samples.ray_indices), device=device)
        pieces.append((global_rays, samples, torch.full_like(local, b), local))
        parts.append(_Part(rays, o, d, samples, local))
    if len(pieces) == 1:  # one body: its samples in its order, nothing to merge
        rays, samples, which, local = pieces[0]
        order = torch.arange(len(rays), device=device)
        samples = RaySamples(rays, samples.t_starts, samples.t_ends, n_rays, samples.t_mid)
    elif pieces:
        rays = torch.cat([p[0] for p in pieces])
        t_mid = torch.cat([p[1].t_mid for p in pieces])
        by_t = torch.sort(t_mid, stable=True).indices
        order = by_t.index_select(0, torch.sort(rays.index_select(0, by_t), stable=True).indices)
        starts, ends = (torch.cat([getattr(p[1], name) for p in pieces]) for name in ("t_starts", "t_ends"))
        samples = RaySamples(rays, starts, ends, n_rays, t_mid).select(order)
        which = torch.cat([p[2] for p in pieces]).index_select(0, order)
        local = torch.cat([p[3] for p in pieces]).index_select(0, order)
    else:
        empty = torch.zeros(0, dtype=torch.int64, device=device)
        none = torch.zeros(0, dtype=torch.float32, device=device)
        return MergedSamples(RaySamples(empty, none, none, n_rays), empty, empty, parts)
    place = torch.empty_like(order)
    place[order] = torch.arange(len(order), device=device)
    offset = 0
    for part in parts:
        if part is not None:
            part.merged = place[offset : offset + len(part.samples.ray_indices)]
            offset += len(part.samples.ray_indices)
    return MergedSamples(samples, which, local, parts)


def locate(index, origins, dirs, samples: RaySamples, to_rest, times=None):
    """Where one body's field is evaluated for its samples ``index`` (K,) (of ``samples`` on its rays
    ``origins``, ``dirs`` (R, 3) in its frame): ``(index (K',), points (K', 3), unit_dirs (K', 3), deltas
    (K',), fronts (K',), dropped)`` in its (rest) space through ``to_rest`` (None: as placed), section lengths
    in its units; ``dropped`` samples had no rest point. The map's seconds are added to ``times["map"]``."""
    rays = samples.ray_indices.index_select(0, index)
    norm = dirs.norm(dim=1).index_select(0, rays)  # field-space length per unit of t
    t = samples.t_mid.index_select(0, index)
    points = origins.index_select(0, rays) + t[:, None] * dirs.index_select(0, rays)
    unit_dirs = dirs.index_select(0, rays) / norm[:, None].clamp_min(1e-12)
    dropped = 0
    if to_rest is not None:
        tick = time.perf_counter()
        points, unit_dirs, stretch, inside = to_rest.map_rays(points, unit_dirs)
        keep = torch.nonzero(inside).squeeze(1)
        index, points, unit_dirs = index[keep], points[keep], unit_dirs[keep]
        norm = (norm * stretch)[keep]
        dropped = len(inside) - len(keep)
        if times is not None:
            times["map"] += time.perf_counter() - tick
    deltas = samples.deltas.index_select(0, index) * norm
    fronts = (samples.t_mid - samples.t_starts).index_select(0, index) * norm
    return index, points, unit_dirs, deltas, fronts, dropped


def locate_samples(bodies, merged: MergedSamples, index: torch.Tensor, times=None):
    """:func:`locate` of the merged samples ``index`` (K,) increasing, each in its own body: ``(index
    (K',), points, unit_dirs, deltas, fronts, which (K',), dropped)`` in merged order (``which``: each
    one's body)."""
    outs, dropped = [], 0
    which = merged.which.index_select(0, index)
    for b, (body, part) in enumerate(zip(bodies, merged.parts, strict=True)):
        mine = index if len(bodies) == 1 else index.index_select(0, torch.nonzero(which == b).squeeze(1))
        if part is None or not len(mine):
            continue
        local = merged.local.index_select(0, mine)
        located = locate(local, part.origins, part.dirs, part.samples, body.rest_map, times)
        dropped += located[5]
        outs.append((part.merged.index_select(0, located[0]), *located[1:5], torch.full_like(located[0], b)))
    if not outs:
        none = torch.zeros(0, dtype=torch.float32, device=index.device)
        return index[:0], none.reshape(0, 3), none.reshape(0, 3), none, none, index[:0], dropped
    joined = [torch.cat(x) for x in zip(*outs, strict=True)]
    if len(outs) > 1:
        order = torch.sort(joined[0]).indices
        joined = [x.index_select(0, order) for x in joined]
    return (*joined, dropped)
