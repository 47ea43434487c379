"""Adaptive-shell extraction (paper Sec. 3.3, Eq. 6-7, Procedure 2): grid sampling of ``f`` and ``s``,
dilation and erosion of the ``f = 0`` level set, marching cubes -> outer mesh M+ and inner mesh M-.

Units. All lengths (``f``, ``s``, ``spacing``, ``zeta``) are in the field's unit space, where the object
spans about ``[-1, 1]^3``; the paper's ``zeta = 0.1 / 0.05`` are read in these units. The time-evolution
parameters are per voxel, as in Procedure 2 where ``alpha`` is the opacity across one voxel ``tau_d`` and the
flow is integrated with the paper's ``dt = 0.1`` by forward Euler, which is stable only for speeds below
a voxel per step: velocities (``beta_d * alpha``, ``v_max``, ``beta_e / alpha``) are in voxels per unit
time and ``lambda_curv`` in voxels^2 per unit time. They are turned into lengths (times ``spacing``,
``spacing^2``) before :func:`~neural.shell.levelset.evolve_level_set`. With these units the shell's width
in world terms depends on ``s`` and hardly on the grid resolution (see :class:`ShellConfig`).

Kernel convention (Eq. 3): ``Phi_s(f) = sigmoid(f / s)``, ``s`` > 0 is a length; large ``s`` is fuzzy.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch
import torch.nn.functional as F

from ..config import ShellConfig
from .levelset import evolve_level_set

if TYPE_CHECKING:
    import trimesh

log = logging.getLogger(__name__)

_SLAB_NODES = 1 << 22  # nodes per slab when mapping a function over a whole grid
# Grid values within this fraction of a voxel of zero count as outside (no vertex exactly on a node).
_SNAP_REL = 1e-3


@dataclass
class ShellResult:
    """Output of :func:`extract_shells`. Meshes in the grid's coordinates ``origin + index * spacing``."""

    outer: trimesh.Trimesh  # M+, watertight, outward normals
    inner: trimesh.Trimesh  # M-, watertight, outward normals; empty if everything eroded
    f_dilate: torch.Tensor  # (X, Y, Z) SDF+ = min(f0, dilated f), +spacing on dropped parts
    f_erode: torch.Tensor  # (X, Y, Z) SDF- = max(f0, eroded f), >= spacing on dropped parts


def _check_fields(f: torch.Tensor, s: torch.Tensor, spacing: float) -> None:
    if not isinstance(f, torch.Tensor) or not isinstance(s, torch.Tensor):
        raise TypeError(f"f and s must be torch tensors, got {type(f).__name__} and {type(s).__name__}")
    if f.dim() != 3 or min(f.shape) < 3:
        raise ValueError(f"f must be an (X, Y, Z) grid with every side >= 3, got shape {tuple(f.shape)}")
    if s.shape != f.shape:
        raise ValueError(f"s must have the shape of f {tuple(f.shape)}, got {tuple(s.shape)}")
    if f.device != s.device:
        raise ValueError(f"f and s must be on one device, got {f.device} and {s.device}")
    if not (isinstance(spacing, int | float | np.floating) and 0 < spacing < math.inf):
        raise ValueError(f"spacing must be a positive number, got {spacing!r}")
    if not bool(torch.isfinite(f).all()):
        raise ValueError("f has NaN or infinite values")
    if not bool((s > 0).all()) or not bool(torch.isfinite(s).all()):
        raise ValueError(f"s must be finite and > 0 everywhere, got min {float(s.min()):.3g}")


def voxel_alpha(f: torch.Tensor, s: torch.Tensor, tau_d: float) -> torch.Tensor:
    """NeuS opacity of one voxel of length ``tau_d`` crossed along the normal (Procedure 2 line 1, Eq. 3).

        alpha = (Phi(f + tau_d/2) - Phi(f - tau_d/2)) / Phi(f + tau_d/2),   Phi(x) = sigmoid(x / s)

    i.e. the discrete NeuS alpha of a ray entering the surface with ``f`` going from ``f + tau_d/2`` to
    ``f - tau_d/2``. Procedure 2 prints the two sigmoids the other way round, which is never positive; this
    is the meaningful order. Evaluated as ``-expm1(logsigmoid((f - tau/2)/s) - logsigmoid((f + tau/2)/s))``:
    exact deep inside (``alpha -> 1 - exp(-tau_d/s)``) and far outside (``~ (tau_d/s) exp(-f/s)``).

    f, s : same shape (s > 0). Returns alpha, same shape, in [0, 1).
    """
    if f.shape != s.shape:
        raise ValueError(f"f and s must have one shape, got {tuple(f.shape)} and {tuple(s.shape)}")
    if not tau_d > 0:
        raise ValueError(f"tau_d must be > 0, got {tau_d}")
    half = 0.5 * tau_d
    return -torch.expm1(F.logsigmoid((f - half) / s) - F.logsigmoid((f + half) / s))


def dilation_velocity(f: torch.Tensor, s: torch.Tensor, config: ShellConfig) -> torch.Tensor:
    """Eq. 6 in voxels per unit time: ``min(beta_d alpha, v_max)`` where ``alpha > sigma_min``, else 0.

    f, s : same shape, lengths in voxels (f / spacing, s / spacing). Returns the same shape, >= 0.
    """
    alpha = voxel_alpha(f, s, 1.0)
    return torch.where(alpha > config.sigma_min, torch.clamp(config.beta_d * alpha, max=config.v_max), 0.0)


def erosion_velocity(f: torch.Tensor, s: torch.Tensor, config: ShellConfig) -> torch.Tensor:
    """Eq. 7 in voxels per unit time, signed as an outward speed: ``-min(v_max, beta_e / alpha)``.

    f, s : same shape, lengths in voxels. Returns the same shape, < 0 (inward).
    """
    alpha = voxel_alpha(f, s, 1.0)
    fast = alpha * config.v_max <= config.beta_e  # also where alpha underflows to 0
    return -torch.where(fast, config.v_max, config.beta_e / torch.where(fast, 1.0, alpha))


def _map_slabs(fn: Callable, f: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """``fn(f, s)`` over a grid one x-slab at a time (bounded temporaries). f, s : (X, Y, Z)."""
    out = torch.empty_like(f)
    slab = max(1, _SLAB_NODES // (f.shape[1] * f.shape[2]))
    for x0 in range(0, f.shape[0], slab):
        out[x0 : x0 + slab] = fn(f[x0 : x0 + slab], s[x0 : x0 + slab])
    return out


def _flow(f, s, spacing, config, velocity_fn, zeta, lambda_curv) -> torch.Tensor:
    h = float(spacing)
    velocity = _map_slabs(lambda fa, sa: velocity_fn(fa / h, sa / h, config) * h, f, s)
    return evolve_level_set(
        f,
        velocity,
        steps=config.steps,
        dt=config.dt,
        zeta=zeta,
        lambda_curv=lambda_curv * h * h,
        spacing=h,
        chunk=config.chunk,
    )


def dilate(f: torch.Tensor, s: torch.Tensor, spacing: float, config: ShellConfig) -> torch.Tensor:
    """SDF+ (Procedure 2 lines 4-7): the dilation flow of Eq. 6, clamped ``min(f0, .)`` for a strict dilation.

    f, s : (X, Y, Z) SDF and kernel size on a grid of ``spacing`` (unit space). Returns (X, Y, Z) <= f.
    """
    _check_fields(f, s, spacing)
    evolved = _flow(f, s, spacing, config, dilation_velocity, config.zeta_dilate, config.lambda_curv_dilate)
    return torch.minimum(evolved, f, out=evolved)


def erode(f: torch.Tensor, s: torch.Tensor, spacing: float, config: ShellConfig) -> torch.Tensor:
    """SDF- (Procedure 2 lines 11-14): the erosion flow of Eq. 7, clamped ``max(f0, .)`` for a strict erosion.

    f, s : (X, Y, Z) SDF and kernel size on a grid of ``spacing`` (unit space). Returns (X, Y, Z) >= f.
    """
    _check_fields(f, s, spacing)
    evolved = _flow(f, s, spacing, config, erosion_velocity, config.zeta_erode, config.lambda_curv_erode)
    return torch.maximum(evolved, f, out=evolved)


def _inside(field: np.ndarray, spacing: float) -> np.ndarray:
    """Nodes :func:`marching_cubes_mesh` treats as inside: ``field <= -1e-3 spacing`` (bool, same shape)."""
    return field <= -_SNAP_REL * float(spacing)


def drop_small_parts(
    f_dilate: np.ndarray, f_erode: np.ndarray, spacing: float, min_fraction: float
) -> tuple[np.ndarray, np.ndarray, int]:
    """Remove the inside regions of SDF+ (26-connected) with fewer nodes than ``min_fraction`` times the
    largest, together with SDF- there (SDF- >= SDF+, so M- never reaches outside its M+ part).

    f_dilate, f_erode : (X, Y, Z) float32 SDF+ and SDF-, spacing : grid spacing. Returns new SDF+ and SDF-
    (``+spacing``, i.e. outside, on the dropped nodes) and the number of parts dropped.
    """
    from skimage.measure import label

    labels = label(_inside(f_dilate, spacing), connectivity=3)
    sizes = np.bincount(labels.ravel())[1:]  # label 0 is the outside
    small = np.flatnonzero(sizes < min_fraction * sizes.max(initial=0)) + 1
    if len(small) == 0:
        return f_dilate, f_erode, 0
    dropped = np.isin(labels, small)
    h = np.float32(spacing)
    return np.where(dropped, h, f_dilate), np.where(dropped, np.maximum(f_erode, h), f_erode), len(small)


def marching_cubes_mesh(field: np.ndarray, origin: Sequence[float], spacing: float) -> trimesh.Trimesh:
    """Watertight mesh of ``field < 0`` with outward normals, vertices at ``origin + index * spacing``.

    The grid is padded with one layer of value ``+spacing`` (outside) so that a surface reaching the border
    closes there, between the last node and the pad.
    Values within ``1e-3 spacing`` of zero are set to ``+1e-3 spacing`` so that no vertex falls on a grid node
    (which would give zero-length edges); this moves the surface by at most ~1e-3 voxel. All components
    are kept. field : (X, Y, Z) float. Returns trimesh.Trimesh (empty when ``field`` has no negative value).
    """
    import trimesh
    from skimage.measure import marching_cubes

    h = float(spacing)
    vol = np.pad(np.asarray(field, dtype=np.float32), 1, constant_values=h)
    vol[~_inside(vol, h) & (vol < _SNAP_REL * h)] = _SNAP_REL * h
    if not (vol < 0).any():
        return trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), process=False)
    verts, faces, _, _ = marching_cubes(vol, level=0.0, spacing=(h, h, h), gradient_direction="descent")
    verts = verts.astype(np.float64) + (np.asarray(origin, dtype=np.float64) - h)
    return trimesh.Trimesh(verts, faces.astype(np.int64), process=False)


def extract_shells(
    f: torch.Tensor,
    s: torch.Tensor,
    origin: Sequence[float],
    spacing: float,
    config: ShellConfig | None = None,
) -> ShellResult:
    """Procedure 2: dilate and erode the ``f = 0`` level set and extract M+ and M- by marching cubes.

    f : (X, Y, Z) signed distance (negative inside) sampled at ``origin + index * spacing``, unit space.
    s : (X, Y, Z) kernel size (> 0) at the same nodes. Any device; the meshes are built on the CPU.
    origin : (3,) position of node (0, 0, 0). spacing : grid spacing (cubic voxels).
    Returns :class:`ShellResult` with SDF- >= f0 >= SDF+ everywhere but on dropped small parts
    (``config.min_part_fraction``, where both are outside), so M- lies inside M+.
    """
    config = config or ShellConfig()
    origin = np.asarray(origin, dtype=np.float64)
    if origin.shape != (3,):
        raise ValueError(f"origin must have shape (3,), got {origin.shape}")
    f = torch.as_tensor(f, dtype=torch.float32)
    s = torch.as_tensor(s, dtype=torch.float32, device=f.device)
    _check_fields(f, s, spacing)
    f_dilate = dilate(f, s, spacing, config).cpu().numpy()
    f_erode = erode(f, s, spacing, config).cpu().numpy()
    f_dilate, f_erode, n_dropped = drop_small_parts(f_dilate, f_erode, spacing, config.min_part_fraction)
    if n_dropped:
        log.info(
            "shells: dropped %d small M+ parts (min_part_fraction %g)", n_dropped, config.min_part_fraction
        )
    outer = marching_cubes_mesh(f_dilate, origin, spacing)
    inner = marching_cubes_mesh(f_erode, origin, spacing)
    log.info("shells: M+ %d faces, M- %d faces", len(outer.faces), len(inner.faces))
    return ShellResult(
        outer=outer,
        inner=inner,
        f_dilate=torch.as_tensor(f_dilate, device=f.device),
        f_erode=torch.as_tensor(f_erode, device=f.device),
    )


def grid_spacing(bbox_min: Sequence[float], bbox_max: Sequence[float], resolution: int) -> float:
    """Spacing of a ``resolution``^3 grid spanning the cube [bbox_min, bbox_max] (corners are nodes)."""
    lo, hi = np.asarray(bbox_min, dtype=np.float64), np.asarray(bbox_max, dtype=np.float64)
    if lo.shape != (3,) or hi.shape != (3,) or not (hi > lo).all():
        raise ValueError(f"bbox_min, bbox_max must be (3,) with max > min, got {lo.tolist()}, {hi.tolist()}")
    side = hi - lo
    if not np.allclose(side, side[0], rtol=1e-6, atol=0):
        raise ValueError(f"the box must be a cube (cubic voxels), got sides {side.tolist()}")
    if resolution < 2:
        raise ValueError(f"resolution must be >= 2, got {resolution}")
    return float(side[0] / (resolution - 1))


def sample_grid(
    fn: Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor]],
    bbox_min: Sequence[float],
    bbox_max: Sequence[float],
    resolution: int,
    chunk: int = 1 << 18,
    device: str | torch.device = "cpu",
) -> tuple[torch.Tensor, torch.Tensor]:
    """Evaluate ``fn`` at the nodes ``bbox_min + index * spacing`` of a ``resolution``^3 grid, in chunks.

    fn : maps (N, 3) float32 points on ``device`` to ``(sdf (N,), s (N,))``; called under ``no_grad``.
    bbox_min, bbox_max : (3,) corners of a cube; spacing = :func:`grid_spacing`.
    Returns f, s : (R, R, R) float32 on ``device``, indexed [x, y, z]. Memory: the two grids plus one chunk.
    """
    from tqdm.auto import tqdm

    h = grid_spacing(bbox_min, bbox_max, resolution)
    if chunk < 1:
        raise ValueError(f"chunk must be >= 1, got {chunk}")
    n = resolution**3
    f = torch.empty(n, dtype=torch.float32, device=device)
    s = torch.empty(n, dtype=torch.float32, device=device)
    lo = torch.as_tensor(np.asarray(bbox_min, dtype=np.float64), dtype=torch.float64, device=device)
    with torch.no_grad(), tqdm(total=n, desc="sampling f, s", unit="pt", unit_scale=True, leave=False) as bar:
        for a in range(0, n, chunk):
            flat = torch.arange(a, min(a + chunk, n), device=device)
            ijk = torch.stack((flat // resolution**2, flat // resolution % resolution, flat % resolution), 1)
            x = (lo + ijk.to(torch.float64) * h).to(torch.float32)
            fa, sa = fn(x)
            if fa.shape != (len(flat),) or sa.shape != (len(flat),):
                raise ValueError(
                    f"fn must return (sdf (N,), s (N,)) for N={len(flat)} points, got {tuple(fa.shape)}, "
                    f"{tuple(sa.shape)}"
                )
            f[a : a + len(flat)] = fa
            s[a : a + len(flat)] = sa
            bar.update(len(flat))
    shape = (resolution,) * 3
    return f.view(shape), s.view(shape)


def shell_width_stats(
    outer, inner, points: np.ndarray | None = None, n_samples: int = 20000, seed: int = 0
) -> dict:
    """Width of the shell: unsigned distance from points on M+ to M- (libigl point-mesh distance).

    outer, inner : trimesh.Trimesh M+ and M-. points : optional (N, 3) query points (e.g. a subset of M+'s
    vertices); by default ``n_samples`` area-uniform samples of M+. Returns ``{"mean", "median", "max"}``
    in mesh units; all NaN when M- or the query set is empty.
    """
    import igl
    import trimesh

    if points is None and len(outer.faces):
        points = trimesh.sample.sample_surface(outer, n_samples, seed=seed)[0]
    elif points is None:
        points = np.zeros((0, 3))
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {points.shape}")
    if len(points) == 0 or len(inner.faces) == 0:
        log.warning("shell width: %s is empty", "the query set" if len(points) == 0 else "M-")
        return {"mean": math.nan, "median": math.nan, "max": math.nan}
    d2, _, _ = igl.point_mesh_squared_distance(
        points, np.asarray(inner.vertices, dtype=np.float64), np.asarray(inner.faces, dtype=np.int64)
    )
    d = np.sqrt(d2)
    return {"mean": float(d.mean()), "median": float(np.median(d)), "max": float(d.max())}
