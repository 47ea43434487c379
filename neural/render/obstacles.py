"""Static obstacles of the world drawn behind and in front of a body (issue 41): axis-aligned boxes and
spheres in world metres, met by rays in closed form (float64).

A world ray ``o + t d`` (``d`` need not be unit; ``t`` is the renderer's ray parameter,
:class:`~neural.render.ground.WorldFrame`) crosses

- a **box** of centre ``c`` and half extents ``h`` over ``[t_near, t_far]``, the intersection of its three
  slabs (Kay and Kajiya 1986): ``t_near = max_k min(t1_k, t2_k)``, ``t_far = min_k max(t1_k, t2_k)`` with
  ``t1_k = (c_k - h_k - o_k) / d_k``, ``t2_k = (c_k + h_k - o_k) / d_k`` (a ray parallel to slab ``k`` is in
  it for every ``t`` or none); the outward normal at ``t_near`` is ``-sign(d_k) e_k`` of the slab ``k``
  that gives ``t_near``;
- a **sphere** of centre ``c`` and radius ``r`` over the roots of ``|o + t d - c|^2 = r^2``:
  ``t = (-b -+ sqrt(b^2 - a q)) / a`` with ``a = d.d``, ``b = d.(o - c)``, ``q = |o - c|^2 - r^2``; the
  normal ``(o + t d - c) / r``.

A ray from outside sees an obstacle at ``t_near > 0`` when ``t_near <= t_far``; a shadow ray is blocked when
the interval reaches ``t > 0`` (the obstacles are opaque).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # torch is imported where the images are made: the settings stay light for the jobs
    import torch


def _rows(name: str, value, width: int, what: str) -> tuple[tuple[float, ...], ...]:
    """``value`` as rows of ``width`` finite floats whose last ``width - 3`` (the sizes) are > 0."""
    rows = np.asarray(value if len(value) else np.zeros((0, width)), np.float64)
    if rows.ndim != 2 or rows.shape[1] != width or not np.isfinite(rows).all() or not (rows[:, 3:] > 0).all():
        raise ValueError(f"{name}: expected rows of {what} (sizes > 0, metres), got {value!r}")
    return tuple(tuple(float(v) for v in row) for row in rows)


@dataclass(frozen=True)
class Obstacles:
    """Static obstacles in world metres (z up, ground z = 0).

    boxes : rows ``(x, y, z, hx, hy, hz)``: axis-aligned boxes by centre and half extents
    spheres : rows ``(x, y, z, r)``: spheres by centre and radius
    """

    boxes: tuple = ()
    spheres: tuple = ()

    def __post_init__(self):
        object.__setattr__(self, "boxes", _rows("boxes", self.boxes, 6, "x, y, z, hx, hy, hz"))
        object.__setattr__(self, "spheres", _rows("spheres", self.spheres, 4, "x, y, z, r"))

    def __bool__(self) -> bool:
        return bool(self.boxes or self.spheres)


def _intervals(obstacles: Obstacles, origins: torch.Tensor, dirs: torch.Tensor):
    """Where world rays ``origins``, ``dirs`` (R, 3) float64 cross each obstacle (boxes, then spheres):
    ``near``, ``far`` (R, N) (``near > far``: no crossing) and the outward normals ``normals`` (R, N, 3) at
    ``near``."""
    import torch

    parts = []
    if obstacles.boxes:
        boxes = torch.tensor(obstacles.boxes, dtype=torch.float64, device=origins.device)
        lo, hi = (boxes[:, :3] - boxes[:, 3:])[None], (boxes[:, :3] + boxes[:, 3:])[None]  # (1, B, 3)
        o, d = origins[:, None], dirs[:, None].expand(-1, len(boxes), 3)  # (R, 1, 3), (R, B, 3)
        parallel = d == 0
        safe = torch.where(parallel, 1.0, d)
        t1, t2 = (lo - o) / safe, (hi - o) / safe
        within = (lo <= o) & (o <= hi)  # a parallel ray is in the slab for every t, or for none
        t_lo = torch.where(parallel, torch.where(within, -math.inf, math.inf), torch.minimum(t1, t2))
        t_hi = torch.where(parallel, torch.where(within, math.inf, -math.inf), torch.maximum(t1, t2))
        near, axis = t_lo.max(dim=2)
        normals = torch.zeros_like(d)
        sign = -torch.sign(d.gather(2, axis[..., None]))
        normals.scatter_(2, axis[..., None], sign)
        parts.append((near, t_hi.min(dim=2).values, normals))
    if obstacles.spheres:
        spheres = torch.tensor(obstacles.spheres, dtype=torch.float64, device=origins.device)
        oc = origins[:, None] - spheres[None, :, :3]  # (R, S, 3)
        a = (dirs * dirs).sum(dim=1, keepdim=True)  # (R, 1)
        b = (oc * dirs[:, None]).sum(dim=2)
        q = (oc * oc).sum(dim=2) - spheres[None, :, 3] ** 2
        disc = b * b - a * q
        root = disc.clamp_min(0.0).sqrt()
        near = torch.where(disc >= 0, (-b - root) / a, math.inf)
        far = torch.where(disc >= 0, (-b + root) / a, -math.inf)
        normals = (oc + torch.where(disc >= 0, near, 0.0)[..., None] * dirs[:, None]) / spheres[None, :, 3:]
        parts.append((near, far, normals))
    return tuple(torch.cat(p, dim=1) for p in zip(*parts, strict=True))


def obstacle_hits(obstacles: Obstacles, origins: torch.Tensor, dirs: torch.Tensor):
    """The nearest obstacle in front of world rays ``origins``, ``dirs`` (R, 3) float64 (module docstring):
    ``t`` (R,) its ray parameter (inf where a ray meets none, or starts inside one) and the outward unit
    normal ``normals`` (R, 3) there (zeros without a hit)."""
    import torch

    if not obstacles:
        t = torch.full((len(origins),), math.inf, dtype=torch.float64, device=origins.device)
        return t, torch.zeros_like(origins)
    near, far, normals = _intervals(obstacles, origins, dirs)
    t = torch.where((near > 0) & (near <= far), near, math.inf)
    t, nearest = t.min(dim=1)
    normal = normals.gather(1, nearest[:, None, None].expand(-1, 1, 3))[:, 0]
    return t, torch.where(torch.isfinite(t)[:, None], normal, 0.0)


def blocked(obstacles: Obstacles, origins: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """(R,) bool: world rays ``origins``, ``dirs`` (R, 3) float64 cross an obstacle at some ``t > 0`` (a
    shadow ray toward the light; obstacles are opaque)."""
    import torch

    if not obstacles:
        return torch.zeros(len(origins), dtype=torch.bool, device=origins.device)
    near, far, _ = _intervals(obstacles, origins, dirs)
    return ((near <= far) & (far > 0)).any(dim=1)
