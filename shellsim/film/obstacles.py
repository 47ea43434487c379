"""Static obstacles of the world drawn behind and in front of a body (issue 41): axis-aligned boxes and
spheres in world metres, met by rays in closed form (float64).

A world ray ``o + t d`` (``d`` need not be unit; ``t`` is the renderer's ray parameter,
:func:`shellsim.film.ground.to_world`) crosses

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


#: Faces meeting at a vertex at less than this angle (degrees) share a normal there (smooth shading); sharper
#: edges (a box's) stay sharp.
CREASE_DEGREES = 30.0


def corner_normals(vertices: np.ndarray, faces: np.ndarray, crease: float = CREASE_DEGREES) -> np.ndarray:
    """(F, 3, 3) unit normal at each corner of each face (F, 3) of a mesh with ``vertices`` (N, 3): the mean
    of the unit normals of the faces around that corner's vertex within ``crease`` degrees of the face's
    own (its own always included)."""
    normals = np.cross(
        vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]]
    )
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
    corner_vertex = faces.reshape(-1)
    order = np.argsort(corner_vertex, kind="stable")  # corners grouped by vertex
    vertex = corner_vertex[order]
    face = np.repeat(np.arange(len(faces)), 3)[order]
    counts = np.bincount(vertex, minlength=len(vertices))
    first = np.cumsum(counts) - counts
    valence = counts[vertex]  # (3F,) corners sharing each corner's vertex
    mine = np.repeat(np.arange(len(vertex)), valence)  # every pair of corners of one vertex
    other = first[vertex[mine]] + np.arange(len(mine)) - np.repeat(np.cumsum(valence) - valence, valence)
    near = np.einsum("ij,ij->i", normals[face[mine]], normals[face[other]]) >= math.cos(math.radians(crease))
    total = np.zeros((len(vertex), 3))
    np.add.at(total, mine[near], normals[face[other[near]]])
    out = np.empty_like(total)
    out[order] = total / np.linalg.norm(total, axis=1, keepdims=True)
    return out.reshape(-1, 3, 3)


class Meshes:
    """Opaque triangle meshes in world metres, each with its albedo: mesh colliders, turned boxes and the
    surfaces of mesh bodies of a scene. Rays meet them through one Embree scene (float32, about the meshes'
    centre); they are shaded on both sides (the normal faces the ray), smoothly within
    :data:`CREASE_DEGREES` (:func:`corner_normals`, interpolated at the hit).

    meshes : sequence of ``(vertices (N, 3), faces (F, 3), albedo (3,))``
    """

    def __init__(self, meshes=()):
        parts = [
            (np.asarray(v, np.float64), np.asarray(f, np.int64), np.asarray(c, np.float64))
            for v, f, c in meshes
        ]
        self.count = len(parts)
        if not parts:
            return
        offsets = np.cumsum([0] + [len(v) for v, _, _ in parts])
        vertices = np.concatenate([v for v, _, _ in parts])
        faces = np.concatenate([f + o for (_, f, _), o in zip(parts, offsets, strict=False)])
        self.albedo = np.concatenate([np.broadcast_to(c, (len(f), 3)) for _, f, c in parts])
        self.corners = corner_normals(vertices, faces)
        normals = self.corners.sum(axis=1)  # only its sign matters: which side a ray meets
        self.normals = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
        self.center = 0.5 * (vertices.min(0) + vertices.max(0))
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self._scene = rtcore_scene.EmbreeScene(robust=True)
        TriangleMesh(scene=self._scene, vertices=(vertices - self.center).astype(np.float32), indices=faces)

    def __bool__(self) -> bool:
        return self.count > 0

    def _cast(self, origins, dirs):
        """(faces (R,) int64, -1 on a miss; t (R,) float64 ray parameter; uv (R, 2) barycentrics of the hit
        on its face's second and third corners) of the first hits of world rays ``origins``, ``dirs`` (R, 3)
        at t > 0."""
        norm = np.linalg.norm(dirs, axis=1)
        starts = np.ascontiguousarray(origins - self.center, dtype=np.float32)
        units = np.ascontiguousarray(dirs / np.maximum(norm, 1e-30)[:, None], dtype=np.float32)
        out = self._scene.run(starts, units, output=1)
        uv = np.stack([out["u"], out["v"]], axis=1).astype(np.float64)
        return np.asarray(out["primID"], np.int64), np.asarray(out["tfar"], np.float64) / norm, uv

    def hits(self, origins: torch.Tensor, dirs: torch.Tensor):
        """The first mesh in front of world rays ``origins``, ``dirs`` (R, 3) float64: ``t`` (R,) (inf where
        none), the unit normal facing the ray ``normals`` (R, 3) and the ``albedo`` (R, 3) there (zeros
        without a hit)."""
        import torch

        n = len(origins)
        t = np.full(n, math.inf)
        normals, albedo = np.zeros((n, 3)), np.zeros((n, 3))
        if self and n:
            d = dirs.cpu().numpy()
            faces, dist, uv = self._cast(origins.cpu().numpy(), d)
            hit = faces >= 0
            t[hit] = dist[hit]
            f, (u, v) = faces[hit], uv[hit].T
            smooth = (1 - u - v)[:, None] * self.corners[f, 0] + u[:, None] * self.corners[f, 1]
            smooth = smooth + v[:, None] * self.corners[f, 2]
            smooth /= np.maximum(np.linalg.norm(smooth, axis=1, keepdims=True), 1e-30)
            normals[hit] = smooth * -np.sign(np.einsum("ij,ij->i", self.normals[f], d[hit]))[:, None]
            albedo[hit] = self.albedo[f]
        return tuple(torch.as_tensor(a, device=origins.device) for a in (t, normals, albedo))

    def blocked(self, origins: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
        """(R,) bool: world rays ``origins``, ``dirs`` (R, 3) meet a mesh at some ``t > 0``."""
        import torch

        if not self or not len(origins):
            return torch.zeros(len(origins), dtype=torch.bool, device=origins.device)
        faces = self._cast(origins.cpu().numpy(), dirs.cpu().numpy())[0]
        return torch.as_tensor(faces >= 0, device=origins.device)
