"""Narrow-band sampling between the adaptive shells M+ and M- (paper Sec. 3.4, Procedure 3).

Each ray is cast against the outer mesh M+ (every hit, in order, up to the depth-peeling cap ``dp_max``) and
against the inner mesh M- (first hit only, at ``d_M-``). Consecutive entering/exiting hits of M+ bound the
in-shell intervals; an interval's exit is clipped at ``d_M-`` and the ray stops there, as the inside of M- is
solid. An interval of width ``w`` gets ``N = min(ceil(max(w - w_s, 0) / delta_s) + 1, N_max)`` samples at
``linspace(d_enter, d_exit, N + 2)[1:-1]`` (Procedure 3, line 19-20). All rays are handled at once: one
Embree cast per depth-peeling round for all still-active rays, then pure numpy packing into ``RaySamples``.
Shells that move (deformed rendering, paper Sec. 5) are cast by :class:`RefitShellIntersector` instead: Warp
meshes whose BVHs are refitted to new vertex positions rather than rebuilt.

Rules where Procedure 3 leaves a case open (they only matter for origins inside M+ or for meshes that are
not closed and nested) are followed alike by :func:`narrow_band_samples` and its per-ray twin
:func:`narrow_band_samples_reference`:

- a ray whose first M+ hit exits starts inside M+: its first interval opens at its origin (``near``);
- an exit opens an interval only when the hit before it is an entry (or it is the first hit); an exit that
  follows an exit is skipped instead of re-using a stale ``d_enter``; of two entries in a row the later wins;
- an interval that would open beyond ``d_M-`` ends the ray without samples (Procedure 3 would emit a
  reversed interval there); with nested meshes this coincides with line 21's ``break``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace

import numpy as np
import torch
import trimesh
import warp as wp

from neural.device import run_in_chunks
from neural.render.samples import RaySamples

# Step past a hit before casting again, relative to the scene's bounding-box diagonal: far above float32
# rounding of the centred coordinates (~3e-8), far below any shell width worth sampling.
_STEP_REL = 1e-5
#: Fewest rays per CPU thread of a Warp cast.
_MIN_CAST_CHUNK = 4096


@dataclass(frozen=True)
class NarrowBandConfig:
    """Narrow-band sampling settings (Procedure 3), lengths in world units.

    The paper gives no numbers for ``delta_s`` and ``w_s``; the defaults suit a scene scaled to the unit
    cube ``[-1, 1]^3``: a band thinner than 0.03 (a solid surface, up to ~4 voxels of a 256^3 extraction)
    gets one sample, a fuzzy band 0.1 wide gets eight. Use :meth:`scaled` for scenes of another size.
    ``n_max = 16`` is the paper's cap (Fig. 6). The paper gives no ``dp_max``: 16 M+ hits (8 intervals) are
    needed on lego, whose studs and treads a ray crosses many times; with 8 hits its held-out narrow band
    lost 0.46 dB (28.18 against 28.64 dB at 2.70 samples per pixel), 32 gain nothing more.
    """

    delta_s: float = 0.01  # target spacing between samples
    w_s: float = 0.03  # intervals narrower than this get a single sample at their centre
    n_max: int = 16  # most samples per interval (N_max)
    max_peel: int = 16  # most M+ hits taken per ray (dp_max)

    def __post_init__(self):
        if not self.delta_s > 0:
            raise ValueError(f"delta_s must be > 0, got {self.delta_s}")
        if not self.w_s >= 0:
            raise ValueError(f"w_s must be >= 0, got {self.w_s}")
        if int(self.n_max) != self.n_max or self.n_max < 1:
            raise ValueError(f"n_max must be an integer >= 1, got {self.n_max}")
        if int(self.max_peel) != self.max_peel or self.max_peel < 1:
            raise ValueError(f"max_peel must be an integer >= 1, got {self.max_peel}")

    def scaled(self, scale: float) -> NarrowBandConfig:
        """The same settings for a scene ``scale`` times larger (``delta_s`` and ``w_s`` times ``scale``)."""
        if not scale > 0:
            raise ValueError(f"scale must be > 0, got {scale}")
        return replace(self, delta_s=self.delta_s * scale, w_s=self.w_s * scale)


@dataclass
class NarrowBandStats:
    """What the sampler found, on the CPU; distances in units of the ray directions as given."""

    counts: np.ndarray  # (R,) int64 samples per ray
    interval_rays: np.ndarray  # (I,) int64 ray of each in-shell interval, sorted
    interval_enter: np.ndarray  # (I,) float64 start of each interval
    interval_exit: np.ndarray  # (I,) float64 end of each interval (clipped at t_inner)
    t_inner: np.ndarray  # (R,) float64 first hit of M- (d_M-), inf where the ray misses M-

    @property
    def mean_samples_per_ray(self) -> float:
        """Mean number of samples per ray (per pixel for camera rays)."""
        return float(self.counts.mean()) if self.counts.size else 0.0


def _as_rays(origins, dirs) -> tuple[np.ndarray, np.ndarray]:
    """Validate rays; return float64 numpy ``origins`` and ``dirs`` (R, 3). Accepts numpy or torch."""
    arrays = []
    for name, value in (("origins", origins), ("dirs", dirs)):
        if isinstance(value, torch.Tensor):
            value = value.detach().cpu().numpy()
        value = np.asarray(value, dtype=np.float64)
        if value.ndim != 2 or value.shape[1] != 3:
            raise ValueError(f"{name} must have shape (R, 3), got {value.shape}")
        if not np.isfinite(value).all():
            raise ValueError(f"{name} must be finite")
        arrays.append(value)
    origins, dirs = arrays
    if origins.shape != dirs.shape:
        raise ValueError(f"origins {origins.shape} and dirs {dirs.shape} must have the same shape")
    if (np.linalg.norm(dirs, axis=1) == 0).any():
        raise ValueError("dirs must be non-zero vectors")
    return origins, dirs


def _mesh_arrays(name: str, mesh) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) float64 and faces (F, 3) int64 of a shell; rejects an empty or inward-wound one."""
    if not isinstance(mesh, trimesh.Trimesh):
        raise TypeError(f"{name} must be a trimesh.Trimesh, got {type(mesh).__name__}")
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if len(faces) == 0:
        raise ValueError(f"{name} has no faces")
    if np.einsum("ij,ij->", vertices[faces[:, 0]], _facet_normals(vertices, faces)) < 0:
        raise ValueError(f"{name} encloses a negative volume: its faces are wound inward (see mesh.invert())")
    return vertices, faces


def _facet_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unnormalised facet normals (F, 3) of ``faces`` (F, 3) into ``vertices`` (V, 3); summed against the
    first corners they give 6 x the signed volume (cheaper than ``mesh.volume``)."""
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    return np.cross(b - a, c - a)


class ShellIntersector:
    """Embree scenes of the outer shell M+ and inner shell M-, built once (the "CastRay" of Procedure 3).

    Meshes must be closed (not checked: it costs more than the build) with outward facet normals
    (counter-clockwise winding seen from outside; an inward-wound mesh is rejected): a hit enters a mesh
    where ``dot(dir, normal) < 0`` and exits otherwise. Geometry is centred on the scene's bounding box
    before conversion to float32, keeping rounding small in world units. Building costs 1-3 us of CPU per
    face (embreex copies buffers element by element), Embree's BVH build a third of that on the first
    cast; the binding has no vertex update: for shells that move, :class:`RefitShellIntersector` refits.
    """

    def __init__(self, outer: trimesh.Trimesh, inner: trimesh.Trimesh):
        arrays = {"outer": _mesh_arrays("outer", outer), "inner": _mesh_arrays("inner", inner)}
        points = np.concatenate([vertices for vertices, _ in arrays.values()])
        lo, hi = points.min(axis=0), points.max(axis=0)
        self.center = 0.5 * (lo + hi)  # (3,) float64
        self.step = _STEP_REL * max(float(np.linalg.norm(hi - lo)), 1e-12)  # world units
        self._vertices = {which: vertices for which, (vertices, _) in arrays.items()}  # (V, 3) float64
        self._faces = {which: faces for which, (_, faces) in arrays.items()}  # (F, 3) int64
        self._scenes = {
            which: self._build(
                np.ascontiguousarray(vertices - self.center, dtype=np.float32),
                np.ascontiguousarray(faces, dtype=np.int32),
            )
            for which, (vertices, faces) in arrays.items()
        }

    def _build(self, vertices: np.ndarray, faces: np.ndarray):
        """The scene of one mesh: centred ``vertices`` (V, 3) float32, ``faces`` (F, 3) int32."""
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        scene = rtcore_scene.EmbreeScene(robust=True)
        TriangleMesh(scene=scene, vertices=vertices, indices=faces)
        return scene

    def _scene(self, mesh_which: str):
        if mesh_which not in self._scenes:
            raise ValueError(f"mesh_which must be 'outer' or 'inner', got {mesh_which!r}")
        return self._scenes[mesh_which]

    def _cast(
        self, scene, starts: np.ndarray, units: np.ndarray, reach: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """One Embree cast from world ``starts`` along unit ``units`` (K, 3), up to world distances ``reach``
        (K,) when given: primitive (K,) int64, -1 on a miss, and world distance (K,) float64."""
        out = scene.run(
            np.ascontiguousarray(starts - self.center, dtype=np.float32),
            np.ascontiguousarray(units, dtype=np.float32),
            dists=None if reach is None else np.ascontiguousarray(reach, dtype=np.float32),
            output=1,
        )
        return out["primID"].astype(np.int64), out["tfar"].astype(np.float64)

    def first_hit(self, mesh_which: str, origins, dirs) -> tuple[np.ndarray, np.ndarray]:
        """First hit of each ray on one mesh.

        Returns ``t`` (R,) float64 (``inf`` on a miss) in units of ``dirs`` (hit = origin + t * dir), and
        ``primitive`` (R,) int64 face index (-1 on a miss).
        """
        scene = self._scene(mesh_which)
        origins, dirs = _as_rays(origins, dirs)
        norms = np.linalg.norm(dirs, axis=1)
        prim, dist = self._cast(scene, origins, dirs / norms[:, None])
        return np.where(prim >= 0, dist / norms, np.inf), prim

    def all_hits(
        self, mesh_which: str, origins, dirs, max_hits: int, t_stop=None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every hit of every ray on one mesh, in order along each ray, at most ``max_hits`` per ray.

        Depth peeling for all rays at once: each round casts every still-active ray from just past its last
        hit (a step of ``1e-5`` scene diagonals) and skips a repeated hit of the triangle it starts on
        (grazing rays), doubling the step until it gets clear. A ray stops at ``max_hits`` hits or on a miss.
        With ``t_stop`` (R,), only a ray's first hit is searched for beyond ``t_stop``: the ray stops after
        a hit beyond it, and later casts end at ``t_stop``, so a ray stops when no hit is left before it
        (this keeps rays that have entered a solid from being traced through it).

        Returns ``ray_idx`` (H,) int64 sorted, ``t`` (H,) float64 in units of ``dirs`` and increasing per ray,
        and ``entering`` (H,) bool (``dot(dir, facet normal) < 0``).
        """
        scene = self._scene(mesh_which)
        origins, dirs = _as_rays(origins, dirs)
        if int(max_hits) != max_hits or max_hits < 1:
            raise ValueError(f"max_hits must be an integer >= 1, got {max_hits}")
        n_rays = len(origins)
        norms = np.linalg.norm(dirs, axis=1)
        units = dirs / norms[:, None]
        stop = np.full(n_rays, np.inf)
        if t_stop is not None:
            t_stop = np.asarray(t_stop, dtype=np.float64)
            if t_stop.shape != (n_rays,):
                raise ValueError(f"t_stop must have shape ({n_rays},), got {t_stop.shape}")
            stop = t_stop * norms  # world units

        t_next = np.zeros(n_rays)  # where each ray's next cast starts (world)
        step = np.full(n_rays, self.step)
        last = np.full(n_rays, -1, dtype=np.int64)
        n_found = np.zeros(n_rays, dtype=np.int64)
        active = np.arange(n_rays)
        found_rays, found_t, found_prim = [], [], []
        # A ray takes one round per hit plus the rounds spent stepping off a triangle it grazes; the bound
        # only guarantees termination (a ray still stuck then keeps the hits it has).
        for _ in range(2 * max_hits + 8):
            reach = np.where(n_found[active] > 0, stop[active] - t_next[active], np.inf)
            active, reach = active[reach > 0], reach[reach > 0]
            if active.size == 0:
                break
            prim, dist = self._cast(
                scene, origins[active] + t_next[active, None] * units[active], units[active], reach
            )
            hit = prim >= 0
            active, prim = active[hit], prim[hit]
            t_hit = t_next[active] + dist[hit]
            fresh = prim != last[active]
            found_rays.append(active[fresh])
            found_t.append(t_hit[fresh])
            found_prim.append(prim[fresh])
            n_found[active[fresh]] += 1
            last[active] = prim
            step[active] = np.where(fresh, self.step, 2.0 * step[active])
            t_next[active] = t_hit + step[active]
            done = (n_found[active] >= max_hits) | (fresh & (t_hit > stop[active]))
            active = active[~done]

        ray_idx = np.concatenate(found_rays) if found_rays else np.zeros(0, dtype=np.int64)
        t = np.concatenate(found_t) if found_t else np.zeros(0)
        prim = np.concatenate(found_prim) if found_prim else np.zeros(0, dtype=np.int64)
        order = np.argsort(ray_idx, kind="stable")  # rounds are in t order along each ray
        ray_idx, t, prim = ray_idx[order], t[order], prim[order]
        normals = _facet_normals(self._vertices[mesh_which], self._faces[mesh_which][prim])
        entering = np.einsum("ij,ij->i", units[ray_idx], normals) < 0
        return ray_idx, t / norms[ray_idx], entering


@wp.kernel
def _cast_kernel(
    mesh: wp.uint64,
    starts: wp.array(dtype=wp.vec3),
    units: wp.array(dtype=wp.vec3),
    reach: wp.array(dtype=wp.float32),
    prim: wp.array(dtype=wp.int64),
    dist: wp.array(dtype=wp.float32),
):
    """First hit of each ray on a Warp mesh within ``reach``: face (-1 on a miss) and distance."""
    i = wp.tid()
    query = wp.mesh_query_ray(mesh, starts[i], units[i], reach[i])
    if query.result:
        prim[i] = wp.int64(query.face)
        dist[i] = query.t
    else:
        prim[i] = wp.int64(-1)
        dist[i] = wp.inf


class RefitShellIntersector(ShellIntersector):
    """:class:`ShellIntersector` on Warp meshes whose vertices can move: :meth:`refit` takes new vertex
    positions (same faces) and refits the BVHs in linear time, so deformed shells (paper Sec. 5) are cast
    without a rebuild per frame (refitting 440k faces takes ~12 ms on a CPU core, building them into Embree
    ~600 ms). Casts run on ``device`` ("cpu", "cuda:0"; None: Warp's preferred), on the CPU split over
    ``cpu_threads`` threads (None: all cores). Centre and peeling step stay those of the shells given here.
    """

    def __init__(
        self,
        outer: trimesh.Trimesh,
        inner: trimesh.Trimesh,
        device: str | None = None,
        cpu_threads: int | None = None,
    ):
        self.device = wp.get_device(device)
        self.cpu_threads = 1 if self.device.is_cuda else (cpu_threads or os.cpu_count() or 1)
        super().__init__(outer, inner)

    def _build(self, vertices: np.ndarray, faces: np.ndarray) -> wp.Mesh:
        return wp.Mesh(
            points=wp.array(vertices, dtype=wp.vec3, device=self.device),
            indices=wp.array(faces.ravel(), dtype=wp.int32, device=self.device),
        )

    def refit(self, outer_vertices, inner_vertices) -> None:
        """Move the shells' vertices to ``outer_vertices`` (V+, 3) and ``inner_vertices`` (V-, 3) (world, in
        the order of the meshes given at construction) and refit both BVHs."""
        for which, vertices in (("outer", outer_vertices), ("inner", inner_vertices)):
            vertices = np.asarray(vertices, dtype=np.float64)
            if vertices.shape != self._vertices[which].shape:
                raise ValueError(
                    f"{which}_vertices: expected shape {self._vertices[which].shape}, got {vertices.shape}"
                )
            if not np.isfinite(vertices).all():
                raise ValueError(f"{which}_vertices: contain NaN or infinity")
            self._vertices[which] = vertices
            mesh = self._scenes[which]
            mesh.points.assign(wp.array(vertices - self.center, dtype=wp.vec3, device=self.device))
            mesh.refit()

    def _cast(
        self, scene: wp.Mesh, starts: np.ndarray, units: np.ndarray, reach: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        n = len(starts)
        dev = self.device
        arrays = [
            wp.array(np.ascontiguousarray(starts - self.center, dtype=np.float32), dtype=wp.vec3, device=dev),
            wp.array(np.ascontiguousarray(units, dtype=np.float32), dtype=wp.vec3, device=dev),
            wp.array(
                np.full(n, np.inf, np.float32) if reach is None else np.asarray(reach, dtype=np.float32),
                dtype=wp.float32,
                device=dev,
            ),
            wp.empty(n, dtype=wp.int64, device=dev),
            wp.empty(n, dtype=wp.float32, device=dev),
        ]

        def launch(lo: int, hi: int) -> None:
            wp.launch(_cast_kernel, dim=hi - lo, inputs=[scene.id, *(a[lo:hi] for a in arrays)], device=dev)

        wp.load_module(_cast_kernel.module, device=dev)
        run_in_chunks(n, launch, self.cpu_threads, _MIN_CAST_CHUNK)
        return arrays[3].numpy(), arrays[4].numpy().astype(np.float64)


def intervals_from_hits(
    ray_idx: np.ndarray, t: np.ndarray, entering: np.ndarray, t_inner: np.ndarray, max_peel: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """In-shell intervals from the ordered M+ hits of all rays (Procedure 3, lines 10-22, vectorised).

    Args:
        ray_idx, t, entering: (H,) M+ hits sorted by ray then distance (``ShellIntersector.all_hits``),
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
    k = np.arange(len(owner)) - np.repeat(np.cumsum(n) - n, n)
    n_s, enter, exit_ = n[owner], d_enter[owner], d_exit[owner]
    gap = (exit_ - enter) / (n_s + 1)
    positions = enter + (k + 1) * gap
    starts = np.where(k == 0, enter, positions - 0.5 * gap)
    ends = np.where(k == n_s - 1, exit_, positions + 0.5 * gap)
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
    intersector: ShellIntersector,
    origins,
    dirs,
    config: NarrowBandConfig | None = None,
    near: float = 0.0,
    device: torch.device | str = "cpu",
) -> tuple[RaySamples, NarrowBandStats]:
    """Samples of all rays in the narrow band between M+ and M- (Procedure 3, vectorised over rays).

    Args:
        intersector: the shells' Embree scenes.
        origins, dirs: (R, 3) rays (numpy or torch); ``dirs`` need not be unit length: distances are in
            units of ``dirs`` (sample = origin + t * dir) while widths, ``delta_s`` and ``w_s`` are in world
            units.
        config: sampling settings; ``NarrowBandConfig()`` when omitted.
        near: rays start at ``t = near``; a ray starting inside M+ has an interval opening there.
        device: where the returned tensors live.

    Returns ``RaySamples`` (with ``t_positions``: samples at the ends of an interval are not at their
    section midpoints) and ``NarrowBandStats``.
    """
    config = NarrowBandConfig() if config is None else config
    origins, dirs = _as_rays(origins, dirs)
    if not (np.isfinite(near) and near >= 0):
        raise ValueError(f"near must be finite and >= 0, got {near}")
    n_rays = len(origins)
    norms = np.linalg.norm(dirs, axis=1)
    units = dirs / norms[:, None]
    starts = origins + near * dirs
    # World distances from the near point along unit directions from here on.
    t_inner, _ = intersector.first_hit("inner", starts, units)
    ray_idx, t, entering = intersector.all_hits("outer", starts, units, config.max_peel, t_stop=t_inner)
    rays, d_enter, d_exit = intervals_from_hits(ray_idx, t, entering, t_inner, config.max_peel)
    n = samples_per_interval(d_exit - d_enter, config)
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


def _ray_triangle_hits(triangles: np.ndarray, origin: np.ndarray, unit: np.ndarray):
    """Brute-force Möller–Trumbore of one ray against all ``triangles`` (F, 3, 3) in float64: world distances
    (K,) of the hits with t > 0, sorted, and their faces (K,)."""
    v0, e1, e2 = triangles[:, 0], triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]
    p = np.cross(unit, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-14
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = origin - v0
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = (q @ unit) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    faces = np.flatnonzero(ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0))
    order = np.argsort(t[faces])
    return t[faces][order], faces[order]


def narrow_band_samples_reference(
    outer: trimesh.Trimesh,
    inner: trimesh.Trimesh,
    origins,
    dirs,
    config: NarrowBandConfig | None = None,
    near: float = 0.0,
    device: torch.device | str = "cpu",
) -> tuple[RaySamples, NarrowBandStats]:
    """Slow twin of :func:`narrow_band_samples`: Procedure 3 line by line, one ray at a time, with a
    brute-force float64 ray-triangle test against every face. Same arguments and results (for tests)."""
    config = NarrowBandConfig() if config is None else config
    origins, dirs = _as_rays(origins, dirs)
    tri_outer = np.asarray(outer.triangles, dtype=np.float64)
    tri_inner = np.asarray(inner.triangles, dtype=np.float64)
    normals_outer = np.asarray(outer.face_normals, dtype=np.float64)
    samples, intervals, t_inner = [], [], []
    for ray, (origin, direction) in enumerate(zip(origins, dirs, strict=True)):
        norm = np.linalg.norm(direction)
        unit = direction / norm
        start = origin + near * direction
        # Lines 3-7: first hit of M-.
        t_minus, _ = _ray_triangle_hits(tri_inner, start, unit)
        d_minus = t_minus[0] if len(t_minus) else np.inf
        t_inner.append(near + d_minus / norm)
        # Lines 9-23: walk the hits of M+.
        t_plus, faces = _ray_triangle_hits(tri_outer, start, unit)
        d_enter, pending = 0.0, True  # a first hit that exits: the ray starts inside M+
        for n_hits, (hit_distance, face) in enumerate(zip(t_plus, faces, strict=True)):
            if n_hits >= config.max_peel:
                break
            if np.dot(unit, normals_outer[face]) < 0:  # ENTERING
                d_enter, pending = hit_distance, True
            elif pending:  # EXITING
                pending = False
                if d_enter > d_minus:
                    break
                d_exit = min(hit_distance, d_minus)
                w = d_exit - d_enter
                n = min(int(np.ceil(max(w - config.w_s, 0.0) / config.delta_s)) + 1, config.n_max)
                tau = np.linspace(d_enter, d_exit, n + 2)
                bounds = np.concatenate([[d_enter], 0.5 * (tau[1:-2] + tau[2:-1]), [d_exit]])
                for k in range(n):
                    samples.append((ray, bounds[k], bounds[k + 1], tau[k + 1], norm))
                intervals.append((ray, d_enter, d_exit, norm))
                if hit_distance > d_minus:
                    break

    def columns(rows, width):
        return np.array(rows, dtype=np.float64).reshape(-1, width).T

    s_ray, s_start, s_end, s_pos, s_norm = columns(samples, 5)
    i_ray, i_enter, i_exit, i_norm = columns(intervals, 4)
    s_ray, i_ray = s_ray.astype(np.int64), i_ray.astype(np.int64)
    return (
        _pack(
            s_ray, near + s_start / s_norm, near + s_end / s_norm, near + s_pos / s_norm, len(origins), device
        ),
        NarrowBandStats(
            counts=np.bincount(s_ray, minlength=len(origins)).astype(np.int64),
            interval_rays=i_ray,
            interval_enter=near + i_enter / i_norm,
            interval_exit=near + i_exit / i_norm,
            t_inner=np.array(t_inner, dtype=np.float64),
        ),
    )
