"""What the training cameras saw, and a prior for the space they did not see.

**Visibility.** A grid of ``R^3`` cells over the field's box counts, per cell, the training views that see
its centre: the centre projects into the view, and the view's ray through that pixel reaches it before its
transmittance through the trained field falls below :data:`SEEN_TRANSMITTANCE` (a pixel whose photo has
alpha below 0.5 saw nothing there, so its ray sees through). A cell no view sees is *unseen*: outside every
frustum, or behind an opaque surface from every camera (the underside of an object photographed from above).

**The prior** (:class:`UnseenPrior`), for an object photographed standing on something:

- *carve*: unseen space below the *seen support*, the lowest surface that a view sees where its photo
  shows the object (alpha >= 0.5; :data:`SUPPORT_QUANTILE` of its heights), holds nothing. A point ``d``
  below it is at least ``d`` from any surface, so its signed distance is pulled up to ``d`` (a hinge): the
  field closes flat at the support, no lower, and never sticks out past what was seen;
- *paint*: unseen surface takes the colour of the nearest seen surface, measured in the photos (the mean of
  the pixels of the views that see that surface point), never the training background's.

Both are losses on points drawn in their cells, added to training (:mod:`neural.train`). A field whose
photos show its whole surface has no unseen surface and no carve cells below it, and the prior does nothing.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .data import SceneData, camera_rays, project
from .errors import InputError
from .render.composite import log_transmittance
from .render.fullray import _opacity, _sections, field_space, visible_samples
from .render.view import fitted_occupancy_grid, occupancy_sampler

log = logging.getLogger(__name__)

#: A view sees a point while the transmittance of its ray through the field is above this.
SEEN_TRANSMITTANCE = 0.5
#: Cells per side of the visibility grid over the field's box.
VISIBILITY_RESOLUTION = 128
#: The longest side, in pixels, of the views' images of opaque depth (a pixel is about 0.6 of a 128^3 grid's
#: cell at the LEGO's camera distance, so no cell falls between pixels).
DEPTH_SIDE = 200
#: The seen support is this quantile of the seen surface's heights, not its lowest point: a field may draw a
#: seen surface deeper than it is in a few spots (the shipped LEGO, through a hole in its plate, shows the
#: plate's colours on the invented slab below it: 90 of 28,381 seen points lie below the plate's bottom).
SUPPORT_QUANTILE = 0.005
#: A photo's pixel shows the object where its alpha is at least this.
COVERED_ALPHA = 0.5
#: Cells per side of the occupancy grid the training views are rendered with.
OCCUPANCY_RESOLUTION = 128
#: Rays a depth pass renders at a time.
DEPTH_CHUNK = 16384
VISIBILITY_VERSION = 1


@dataclass
class Visibility:
    """The views that saw each cell of a grid over the field's box, and the seen support.

    Attributes:
        seen_views: (R, R, R) uint8 number of views that see each cell centre (capped at 255), indexed
            (x, y, z) from ``lo``.
        lo: (3,) world corner of the grid; ``cell``: world side of a cell.
        up: (3,) unit world up; ``support``: the seen support's height ``dot(p - lo, up)`` (world units), None
            when no view sees a surface point its photo covers.
        views: the number of training views.
        unseen_surface_share: the area share (0-1) of the field's zero-level surface that no view sees (each
            surface point tested against the views, not its cell).
    """

    seen_views: torch.Tensor
    lo: np.ndarray
    cell: float
    up: np.ndarray
    support: float | None
    views: int
    unseen_surface_share: float

    @property
    def resolution(self) -> int:
        return int(self.seen_views.shape[0])

    def centers(self) -> torch.Tensor:
        """(R^3, 3) float32 world cell centres, in the order of ``seen_views.reshape(-1)``."""
        return cell_centers(self.lo, self.cell, self.resolution)

    def heights(self, points: torch.Tensor) -> torch.Tensor:
        """(N,) height ``dot(p - lo, up)`` of world points (N, 3)."""
        return (points - torch.as_tensor(self.lo).to(points)) @ torch.as_tensor(self.up).to(points)

    def record(self) -> dict:
        """What ``asset.json`` records under ``visibility``."""
        return {
            "version": VISIBILITY_VERSION,
            "resolution": self.resolution,
            "seen_transmittance": SEEN_TRANSMITTANCE,
            "views": self.views,
            "support_height": self.support,
            "unseen_cells": float((self.seen_views == 0).float().mean()),
            "unseen_surface_share": self.unseen_surface_share,
        }

    def save(self, path: Path) -> None:
        from .asset import write_safetensors

        meta = {
            "version": str(VISIBILITY_VERSION),
            "lo": json.dumps([float(v) for v in self.lo]),
            "cell": repr(float(self.cell)),
            "up": json.dumps([float(v) for v in self.up]),
            "support": json.dumps(self.support),
            "views": str(self.views),
            "unseen_surface_share": repr(float(self.unseen_surface_share)),
        }
        write_safetensors(path, {"seen_views": self.seen_views.contiguous().cpu()}, meta)

    @classmethod
    def load(cls, path: Path) -> Visibility:
        """A saved grid; a file that is not one is an :class:`InputError` naming it."""
        from safetensors import safe_open

        try:
            with safe_open(str(path), framework="pt") as f:
                meta, seen = f.metadata() or {}, f.get_tensor("seen_views")
            if meta.get("version") != str(VISIBILITY_VERSION):
                raise ValueError(f"version {meta.get('version')!r}, this shellsim reads {VISIBILITY_VERSION}")
            lo, up = np.asarray(json.loads(meta["lo"]), float), np.asarray(json.loads(meta["up"]), float)
            support, cell, views = json.loads(meta["support"]), float(meta["cell"]), int(meta["views"])
            share = float(meta["unseen_surface_share"])
            r = seen.shape[0]
            if seen.dtype != torch.uint8 or seen.shape != (r, r, r) or lo.shape != (3,) or up.shape != (3,):
                raise ValueError("seen_views must be (R, R, R) uint8 with a 3-vector lo and up")
            if not (cell > 0 and math.isfinite(cell)):
                raise ValueError(f"cell {cell}")
        except Exception as err:  # safetensors, JSON and shape errors alike
            raise InputError(f"{path}: not a visibility grid ({err})") from None
        return cls(seen, lo, cell, up, None if support is None else float(support), views, share)


def cell_centers(lo: np.ndarray, cell: float, resolution: int) -> torch.Tensor:
    """(R^3, 3) float32 world centres of the cells of an ``R^3`` grid from corner ``lo`` (3,), x slowest."""
    axis = (torch.arange(resolution, dtype=torch.float64) + 0.5) * cell
    grid = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    return (grid + torch.as_tensor(lo, dtype=torch.float64)).float()


@torch.no_grad()
def opaque_depth(
    field, origins: torch.Tensor, dirs: torch.Tensor, sampler
) -> tuple[torch.Tensor, torch.Tensor]:
    """(R,) distance along unit rays ``dirs`` (R, 3) from ``origins`` (R, 3) at which the transmittance
    through ``field`` falls below :data:`SEEN_TRANSMITTANCE` (infinity where it never does), and (R,) the
    mean distance at which the field stops the light before that (its weights' mean; infinity where it stops
    none). ``sampler(origins, dirs)`` gives the rays' packed samples (an occupancy sampler of the field)."""
    depth = torch.full((len(origins),), math.inf, device=origins.device)
    mean = torch.full((len(origins),), math.inf, device=origins.device)
    for start in range(0, len(origins), DEPTH_CHUNK):
        o, d = origins[start : start + DEPTH_CHUNK], dirs[start : start + DEPTH_CHUNK]
        kept = visible_samples(field, o, d, sampler(o, d), SEEN_TRANSMITTANCE)
        if kept.ray_indices.numel() == 0:
            continue
        _, alpha = _opacity(field, *field_space(field, kept.points(o, d), *_sections(d, kept)), 1.0)
        log_before = log_transmittance(alpha, kept.ray_indices, kept.n_rays)
        log_after = log_before + torch.log1p(-alpha.double().clamp(max=1 - 1e-12))
        crossed = log_after < math.log(SEEN_TRANSMITTANCE)
        part = torch.full((len(o),), math.inf, device=o.device)
        part.scatter_reduce_(0, kept.ray_indices[crossed], kept.t_ends[crossed].float(), "amin")
        depth[start : start + len(o)] = part
        weights = (torch.exp(log_before) * alpha).float()
        total = torch.zeros(len(o), device=o.device).index_add_(0, kept.ray_indices, weights)
        moment = torch.zeros(len(o), device=o.device).index_add_(0, kept.ray_indices, weights * kept.t_mid)
        mean[start : start + len(o)] = torch.where(total > 1e-3, moment / total.clamp_min(1e-3), math.inf)
    return depth, mean


def _depth_cameras(cameras):
    """The cameras at a resolution whose longest side is at most :data:`DEPTH_SIDE`."""
    factor = np.maximum(cameras.width, cameras.height) / DEPTH_SIDE
    factor = np.maximum(factor, 1.0)
    return cameras.resized(
        np.maximum(np.round(cameras.width / factor), 1), np.maximum(np.round(cameras.height / factor), 1)
    )


def _corners(image: torch.Tensor, x: torch.Tensor, y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The four pixels of ``image`` (H, W, ...) around continuous positions ``x, y`` (N,) (centres at +0.5;
    clamped at the border), (N, 4, ...), and their bilinear weights (N, 4)."""
    h, w = image.shape[:2]
    x0, y0 = torch.floor(x - 0.5), torch.floor(y - 0.5)
    fx, fy = (x - 0.5 - x0).float(), (y - 0.5 - y0).float()
    x0, y0 = x0.long(), y0.long()
    values = [image[(y0 + dy).clamp(0, h - 1), (x0 + dx).clamp(0, w - 1)] for dy in (0, 1) for dx in (0, 1)]
    weights = torch.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], 1)
    return torch.stack(values, 1), weights


def _depth_at(depth: torch.Tensor, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """(N,) depth of the image ``depth`` (H, W) at continuous pixel positions ``x, y`` (N,) (centres at
    +0.5): bilinear between the four nearest pixels when all four see a surface; where some see through
    (infinite), the nearest surface among the others, so that no point behind an edge is seen past it;
    infinite where all four see through."""
    d, weights = _corners(depth, x, y)
    finite = torch.isfinite(d)
    bilinear = (torch.where(finite, d, torch.zeros_like(d)) * weights).sum(1)
    nearest = torch.where(finite, d, torch.full_like(d, math.inf)).min(1).values
    return torch.where(finite.all(1), bilinear, nearest)


class _Views:
    """The training views' opaque-depth images (:func:`opaque_depth` at :data:`DEPTH_SIDE`, infinite where
    the photo's alpha is below :data:`COVERED_ALPHA`) and the tests of points against them."""

    def __init__(self, field, data: SceneData, sampler, progress=None):
        self.data, self.views = data, [int(v) for v in data.train_idx]
        self.small = _depth_cameras(data.cameras)
        self.depths = []
        for v in self.views:
            o, d = camera_rays(self.small, v, device=field.center.device)
            h, w = int(self.small.height[v]), int(self.small.width[v])
            depth, mean = (x.reshape(h, w).cpu() for x in opaque_depth(field, o, d, sampler))
            if data.alphas is not None:
                alpha = torch.as_tensor(data.alphas[v])[None, None]
                covered = torch.nn.functional.adaptive_max_pool2d(alpha, (h, w))[0, 0] >= COVERED_ALPHA
                # where the photo shows something the field still lets light through, it stops at the mean
                # of the field's weights; where the photo shows nothing, the ray sees through
                depth = torch.where(
                    covered, torch.where(torch.isinf(depth), mean, depth), torch.full_like(depth, math.inf)
                )
            self.depths.append(depth)
            if progress is not None:
                progress.update(1)

    def seeing(self, k: int, points: torch.Tensor, margin: float) -> tuple[torch.Tensor, torch.Tensor]:
        """Which of ``points`` (N, 3) the ``k``-th training view sees within ``margin`` behind its opaque
        depth: (N,) bool, and their full-resolution pixel coordinates (N, 2)."""
        v, cams = self.views[k], self.data.cameras
        idx = torch.full((len(points),), v, dtype=torch.long)
        px, py = project(cams, idx, points.double(), dtype=torch.float64)
        c2w = torch.as_tensor(cams.c2w[v])
        offset = points.double() - c2w[:3, 3]
        ahead = (offset @ -c2w[:3, 2]) > 0
        w, h = float(cams.width[v]), float(cams.height[v])
        inside = ahead & (px >= 0) & (px < w) & (py >= 0) & (py < h)
        depth = self.depths[k]
        scale = (depth.shape[1] / w, depth.shape[0] / h)
        distance = offset.norm(dim=1)
        reach = _depth_at(depth, px * scale[0], py * scale[1]).double()
        footprint = distance / float(self.small.fx[v])  # a depth pixel's width at the point
        seen = inside & (distance <= reach + margin + footprint)
        return seen, torch.stack([px, py], 1)


def measure_visibility(
    field, data: SceneData, sampler=None, resolution: int = VISIBILITY_RESOLUTION, progress=None
) -> tuple[Visibility, dict]:
    """The field's :class:`Visibility` from the training views of ``data`` (rendered with ``sampler``, by
    default an occupancy sampler of the field fitted at :data:`OCCUPANCY_RESOLUTION`), and its surface:
    ``{"mesh": the field's zero level on the grid (a ``trimesh.Trimesh``), "sdf": (R^3,) the field's signed
    distance at the cell centres, "points": (P, 3), "colors": (P, 3)}``, the mesh's vertices that a view
    sees where its photo covers them (alpha >= 0.5, any pixel without alpha) with the mean of those photos'
    pixels (float32). ``progress``: a tqdm bar, one update a view."""
    import trimesh

    from .shell.extract import marching_cubes_mesh

    half = 1.0 / float(field.scale)
    lo = field.center.detach().double().cpu().numpy() - half
    cell = 2.0 * half / resolution
    margin = 0.5 * math.sqrt(3.0) * cell  # a cell that a surface crosses counts as seen
    up = np.asarray(data.up, dtype=np.float64)
    if sampler is None:
        sampler = occupancy_sampler(fitted_occupancy_grid(field, OCCUPANCY_RESOLUTION), field)
    was_training = getattr(field, "training", False)
    if was_training:
        field.eval()
    try:
        views = _Views(field, data, sampler, progress)
    finally:
        if was_training:
            field.train()
    centers = cell_centers(lo, cell, resolution)
    counts = torch.zeros(len(centers), dtype=torch.int32)
    for k in range(len(views.views)):
        counts += views.seeing(k, centers, margin)[0].int()
    sdf = field.sdf_and_kernel(centers)[0].float().cpu()
    mesh = trimesh.Trimesh()
    if sdf.min() < 0 < sdf.max():
        mesh = marching_cubes_mesh(
            sdf.reshape(resolution, resolution, resolution).numpy(), lo + 0.5 * cell, cell
        )
    points = torch.as_tensor(np.asarray(mesh.vertices, dtype=np.float32)).reshape(-1, 3)
    surface = {"mesh": mesh, "sdf": sdf, **_seen_surface(views, data, points, margin)}
    heights = (surface["points"].double() - torch.as_tensor(lo)) @ torch.as_tensor(up)
    support = float(torch.quantile(heights, SUPPORT_QUANTILE)) if len(heights) else None
    seen = counts.clamp(max=255).to(torch.uint8).reshape(resolution, resolution, resolution)
    share = _unseen_share(mesh, surface.pop("seen"))
    return Visibility(seen, lo, cell, up, support, len(views.views), share), surface


def _unseen_share(mesh, seen: torch.Tensor) -> float:
    """Area share of ``mesh``'s faces that no view sees: each face weighted by the share of its three
    vertices that no view sees (``seen`` (V,) bool)."""
    if len(mesh.faces) == 0:
        return 0.0
    unseen = (~seen).double().numpy()[np.asarray(mesh.faces)].mean(1)
    area = np.asarray(mesh.area_faces)
    return float((unseen * area).sum() / max(area.sum(), 1e-30))


def _seen_surface(views: _Views, data: SceneData, points: torch.Tensor, margin: float) -> dict:
    """The ``points`` (P, 3) that at least one view sees where its photo covers them, with the mean colour
    of those views' pixels (see :func:`measure_visibility`), and ``"seen"`` (P,) bool: which of all the
    points any view sees, covered or not."""
    total = torch.zeros((len(points), 3), dtype=torch.float64)
    seen_by = torch.zeros(len(points), dtype=torch.int32)
    seen_any = torch.zeros(len(points), dtype=torch.bool)
    for k, v in enumerate(views.views):
        seen, pixels = views.seeing(k, points, margin)
        seen_any |= seen
        values, weights = _corners(torch.as_tensor(data.images[v]), pixels[:, 0], pixels[:, 1])
        colors = (values.double() * weights[..., None].double()).sum(1)
        if data.alphas is not None:  # where the photo covers the point (its alpha, bilinear)
            alpha, weights = _corners(torch.as_tensor(data.alphas[v]), pixels[:, 0], pixels[:, 1])
            seen &= (alpha * weights).sum(1) >= COVERED_ALPHA
        total += colors * seen[:, None]
        seen_by += seen.int()
    keep = seen_by > 0
    return {
        "points": points[keep].float(),
        "colors": (total[keep] / seen_by[keep, None]).float(),
        "seen": seen_any,
    }


class UnseenPrior:
    """The carve and paint losses of a field's unseen space (see the module's docstring), drawn from the
    cells of a :class:`Visibility` and the surface :func:`measure_visibility` found with it.

    ``carve_cells`` (C, 3) world centres of unseen cells whose centre lies less than a cell above the seen
    support; ``paint_cells`` (P, 3) centres of unseen cells within ``paint_band`` cells of the field's zero
    level (or of the support, from below it up to the band), with ``paint_colors`` (P, 3) the colour of the
    nearest seen surface point.
    """

    def __init__(self, visibility: Visibility, surface: dict, paint_band: float = 2.0):
        from scipy.spatial import cKDTree

        self.visibility = visibility
        centers = visibility.centers()
        unseen = visibility.seen_views.reshape(-1) == 0
        heights = visibility.heights(centers)
        cell = visibility.cell
        support = visibility.support
        if support is None or len(surface["points"]) == 0:
            self.carve_cells = torch.zeros((0, 3))
            self.paint_cells, self.paint_colors = torch.zeros((0, 3)), torch.zeros((0, 3))
            return
        self.carve_cells = centers[unseen & (heights < support + cell)]
        candidates = unseen & (heights >= support - cell)
        sdf = surface["sdf"][candidates]
        near = (sdf.abs() < paint_band * cell) | (
            (heights[candidates] < support + paint_band * cell) & (sdf < paint_band * cell)
        )
        self.paint_cells = centers[candidates][near]
        _, nearest = cKDTree(surface["points"].numpy()).query(self.paint_cells.numpy())
        self.paint_colors = surface["colors"][torch.as_tensor(nearest, dtype=torch.long)]

    def summary(self) -> str:
        v = self.visibility
        return (
            f"unseen prior: {len(self.carve_cells)} cells carved below the seen support at height "
            f"{v.support:.4f}, {len(self.paint_cells)} painted"
            if v.support is not None
            else "unseen prior: no view sees a covered surface point; nothing to carve or paint"
        )

    def _draw(
        self, cells: torch.Tensor, n: int, generator: torch.Generator
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """n random points (n, 3) in random ``cells`` and the indices (n,) of their cells."""
        index = torch.randint(0, len(cells), (n,), generator=generator)
        jitter = (torch.rand((n, 3), generator=generator) - 0.5) * self.visibility.cell
        return cells[index] + jitter, index

    def carve(self, field, n: int, generator: torch.Generator) -> torch.Tensor | None:
        """Mean of ``max(0, (support - height) - f(p))`` in the field's unit lengths over ``n`` points drawn
        in the carve cells, those below the support (the signed distance ``f`` at least the depth below it);
        None without carve cells or points below the support."""
        if not len(self.carve_cells):
            return None
        points = self._draw(self.carve_cells, n, generator)[0]
        depth = self.visibility.support - self.visibility.heights(points)
        device = field.center.device
        points, depth = points[depth > 0].to(device), depth[depth > 0].to(device)
        if not len(points):
            return None
        return torch.relu(depth - field.sdf(points)).mean() * float(field.scale)

    def paint(self, field, n: int, generator: torch.Generator) -> torch.Tensor | None:
        """Mean absolute colour error against the nearest seen surface's colour of ``n`` points drawn in the
        paint cells, each seen along a random direction; None without paint cells."""
        if not len(self.paint_cells):
            return None
        points, index = self._draw(self.paint_cells, n, generator)
        dirs = torch.nn.functional.normalize(torch.randn((n, 3), generator=generator), dim=1)
        device = field.center.device
        points, dirs = points.to(device), dirs.to(device)
        color = field.radiance(points, dirs, field.geometry(points))
        return (color - self.paint_colors[index].to(device)).abs().mean()
