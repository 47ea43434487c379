"""Casting rays against the two shells M+ ("outer") and M- ("inner"): the "CastRay" of Procedure 3.

One interface, :class:`ShellCaster` (:meth:`~ShellCaster.first_hit`, :meth:`~ShellCaster.all_hits` by depth
peeling, :meth:`~ShellCaster.band_hits` the casts of Procedure 3), over interchangeable backends that only
cast one batch of rays against one mesh:

- :class:`EmbreeCaster`: Embree scenes (embreex), built once; the faster cast on a CPU, for shells that stay
  put (rest rendering, training): Procedure 3 for a 200x200 view of lego took 35 ms against 45 ms with
  Warp on two cores (Embree's build 0.45 s, Warp's 0.25 s);
- :class:`WarpCaster`: Warp meshes whose BVHs are refitted to moved vertices (:meth:`WarpCaster.refit`),
  for shells that move (deformed rendering, paper Sec. 5); casts on the CPU or a GPU, each ray's depth
  peeling (and all of Procedure 3's casts) in one kernel thread.

:func:`ray_triangle_hits` is the brute-force float64 truth they are tested against.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np
import torch
import trimesh
import warp as wp

from neural.device import cpu_threads as default_cpu_threads
from neural.device import run_in_chunks

# Step past a hit before casting again, relative to the scene's bounding-box diagonal: far above float32
# rounding of the centred coordinates (~3e-8), far below any shell width worth sampling.
_STEP_REL = 1e-5
#: Fewest rays per CPU thread of a cast.
_MIN_CAST_CHUNK = 2048
#: Consecutive rays a CPU thread of :meth:`WarpCaster.band_hits` casts before the next thread's turn (0.89x
#: the time of two contiguous halves on lego views, whose halves differ in work).
_CAST_BLOCK = 1024


def ray_lengths(dirs: np.ndarray) -> np.ndarray:
    """Lengths (R,) of float64 vectors (R, 3); a third of ``np.linalg.norm``'s time."""
    return np.sqrt(np.einsum("ij,ij->i", dirs, dirs))


def as_rays(origins, dirs) -> tuple[np.ndarray, np.ndarray]:
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
    if (ray_lengths(dirs) == 0).any():
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


class ShellCaster(ABC):
    """Rays against the outer shell M+ and inner shell M- (world coordinates); a backend builds one scene
    per mesh (:meth:`_build`) and casts one batch of rays against it (:meth:`_cast`), the rest is shared.

    Meshes must be closed (not checked: it costs more than the build) with outward facet normals
    (counter-clockwise winding seen from outside; an inward-wound mesh is rejected): a hit enters a mesh
    where ``dot(dir, normal) < 0`` and exits otherwise. Geometry is centred on the scene's bounding box
    before conversion to float32, keeping rounding small in world units.
    """

    def __init__(self, outer: trimesh.Trimesh, inner: trimesh.Trimesh):
        arrays = {"outer": _mesh_arrays("outer", outer), "inner": _mesh_arrays("inner", inner)}
        points = np.concatenate([vertices for vertices, _ in arrays.values()])
        lo, hi = points.min(axis=0), points.max(axis=0)
        self.center = 0.5 * (lo + hi)  # (3,) float64
        self.step = _STEP_REL * max(float(np.linalg.norm(hi - lo)), 1e-12)  # world units
        # (V, 3) float64 as given here (a WarpCaster's refits move its meshes' points, not these)
        self._vertices = {which: vertices for which, (vertices, _) in arrays.items()}
        self._faces = {which: faces for which, (_, faces) in arrays.items()}  # (F, 3) int64
        self._scenes = {
            which: self._build(
                np.ascontiguousarray(vertices - self.center, dtype=np.float32),
                np.ascontiguousarray(faces, dtype=np.int32),
            )
            for which, (vertices, faces) in arrays.items()
        }

    @abstractmethod
    def _build(self, vertices: np.ndarray, faces: np.ndarray):
        """The scene of one mesh: centred ``vertices`` (V, 3) float32, ``faces`` (F, 3) int32."""

    @abstractmethod
    def _cast(
        self, scene, starts: np.ndarray, units: np.ndarray, reach: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """One cast from world ``starts`` along unit ``units`` (K, 3), up to world distances ``reach`` (K,)
        when given: primitive (K,) int64, -1 on a miss, and world distance (K,) float64."""

    def _scene(self, mesh_which: str):
        if mesh_which not in self._scenes:
            raise ValueError(f"mesh_which must be 'outer' or 'inner', got {mesh_which!r}")
        return self._scenes[mesh_which]

    def first_hit(self, mesh_which: str, origins, dirs) -> tuple[np.ndarray, np.ndarray]:
        """First hit of each ray on one mesh.

        Returns ``t`` (R,) float64 (``inf`` on a miss) in units of ``dirs`` (hit = origin + t * dir), and
        ``primitive`` (R,) int64 face index (-1 on a miss).
        """
        scene = self._scene(mesh_which)
        origins, dirs = as_rays(origins, dirs)
        norms = ray_lengths(dirs)
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
        origins, dirs = as_rays(origins, dirs)
        if int(max_hits) != max_hits or max_hits < 1:
            raise ValueError(f"max_hits must be an integer >= 1, got {max_hits}")
        n_rays = len(origins)
        norms = ray_lengths(dirs)
        units = dirs / norms[:, None]
        stop = np.full(n_rays, np.inf)
        if t_stop is not None:
            t_stop = np.asarray(t_stop, dtype=np.float64)
            if t_stop.shape != (n_rays,):
                raise ValueError(f"t_stop must have shape ({n_rays},), got {t_stop.shape}")
            stop = t_stop * norms  # world units
        ray_idx, t, prim = self._peel(scene, origins, units, stop, int(max_hits))
        return ray_idx, t / norms[ray_idx], self._entering(mesh_which, units[ray_idx], prim)

    def band_hits(
        self, starts: np.ndarray, units: np.ndarray, max_hits: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The casts of Procedure 3 for rays from world ``starts`` along unit ``units`` (R, 3) float64: which
        rays meet M+, ``meets`` (M,) int64 sorted; their first M- hit ``t_inner`` (M,) (world distance,
        ``inf`` on a miss); and their M+ hits as :meth:`all_hits` with ``t_stop = t_inner`` finds them:
        ``ray_idx`` (H,) int64 into the R rays, sorted, world ``t`` (H,) and ``entering`` (H,) bool."""
        outer = self._scenes["outer"]
        prim, dist = self._cast(outer, starts, units)
        meets = np.flatnonzero(prim >= 0)
        starts, units = starts[meets], units[meets]
        inner_prim, inner_dist = self._cast(self._scenes["inner"], starts, units)
        t_inner = np.where(inner_prim >= 0, inner_dist, np.inf)
        first = prim[meets], dist[meets]  # the first peeling round's casts, already made
        ray_idx, t, faces = self._rounds(outer, starts, units, t_inner, max_hits, first)
        return meets, t_inner, meets[ray_idx], t, self._entering("outer", units[ray_idx], faces)

    @abstractmethod
    def _entering(self, mesh_which: str, units: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """(K,) bool: rays along unit ``units`` (K, 3) enter the mesh at their hits of ``faces`` (K,),
        ``dot(unit, facet normal) < 0``."""

    def _peel(
        self, scene, origins: np.ndarray, units: np.ndarray, stop: np.ndarray, max_hits: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The rounds of :meth:`all_hits` from world ``origins`` along ``units`` (R, 3), ``stop`` (R,) world:
        ``ray_idx`` (H,) sorted, world ``t`` (H,) increasing per ray and faces ``prim`` (H,) of the hits."""
        return self._rounds(scene, origins, units, stop, max_hits)

    def _rounds(
        self,
        scene,
        origins: np.ndarray,
        units: np.ndarray,
        stop: np.ndarray,
        max_hits: int,
        first: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`_peel` one cast of the active rays per round; ``first``: the faces and world distances (R,)
        of the first round's casts (from the origins, without a reach) when already made, every ray a hit."""
        n_rays = len(origins)
        t_next = np.zeros(n_rays)  # where each ray's next cast starts (world)
        step = np.full(n_rays, self.step)
        last = np.full(n_rays, -1, dtype=np.int64)
        n_found = np.zeros(n_rays, dtype=np.int64)
        active = np.arange(n_rays)
        found_rays, found_t, found_prim = [], [], []
        # A ray takes one round per hit plus the rounds spent stepping off a triangle it grazes; the bound
        # only guarantees termination (a ray still stuck then keeps the hits it has).
        rounds = 2 * max_hits + 8
        if first is not None:  # the first round's bookkeeping
            last[:], t_hit = first
            found_rays.append(active)
            found_t.append(t_hit)
            found_prim.append(last.copy())
            n_found[:] = 1
            t_next = t_hit + self.step
            active = active[(max_hits > 1) & (t_hit <= stop)]
            rounds -= 1
        for _ in range(rounds):
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
        return ray_idx[order], t[order], prim[order]


class EmbreeCaster(ShellCaster):
    """:class:`ShellCaster` on Embree scenes, built once. Building costs 1-3 us of CPU per face (embreex
    copies buffers element by element) plus Embree's BVH build, a third of that; the binding has no vertex
    update: for shells that move, :class:`WarpCaster` refits. A cast is split over ``cpu_threads`` threads
    (None: :func:`neural.device.cpu_threads`; embreex releases the GIL while it casts)."""

    def __init__(self, outer: trimesh.Trimesh, inner: trimesh.Trimesh, cpu_threads: int | None = None):
        self.cpu_threads = cpu_threads or default_cpu_threads()
        super().__init__(outer, inner)
        # the shells never move: every facet normal once, instead of those of the hits at every cast
        self._facet_normals = {w: _facet_normals(self._vertices[w], self._faces[w]) for w in self._scenes}

    def _entering(self, mesh_which: str, units: np.ndarray, faces: np.ndarray) -> np.ndarray:
        normals = self._facet_normals[mesh_which].take(faces, axis=0)  # take: 0.4x the time of [faces]
        return np.einsum("ij,ij->i", units, normals) < 0

    def _build(self, vertices: np.ndarray, faces: np.ndarray):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        scene = rtcore_scene.EmbreeScene(robust=True)
        TriangleMesh(scene=scene, vertices=vertices, indices=faces)
        one = np.zeros((1, 3), dtype=np.float32)
        scene.run(one, one + np.float32([0, 0, 1]), output=1)  # commits (builds the BVH) before threads cast
        return scene

    def _cast(
        self, scene, starts: np.ndarray, units: np.ndarray, reach: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        starts = np.ascontiguousarray(starts - self.center, dtype=np.float32)
        units = np.ascontiguousarray(units, dtype=np.float32)
        reach = None if reach is None else np.ascontiguousarray(reach, dtype=np.float32)
        prim = np.empty(len(starts), dtype=np.int64)
        dist = np.empty(len(starts), dtype=np.float64)

        def cast(lo: int, hi: int) -> None:
            out = scene.run(
                starts[lo:hi], units[lo:hi], dists=None if reach is None else reach[lo:hi], output=1
            )
            prim[lo:hi], dist[lo:hi] = out["primID"], out["tfar"]

        run_in_chunks(len(starts), cast, self.cpu_threads, _MIN_CAST_CHUNK)
        return prim, dist


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


@wp.func
def _peel_from(
    mesh: wp.uint64,
    i: int,
    o: wp.vec3d,
    u: wp.vec3d,
    stop: wp.float64,
    center: wp.vec3d,
    step0: wp.float64,
    max_hits: int,
    rounds: int,
    t_next: wp.float64,
    last: wp.int64,
    n: int,
    t_out: wp.array2d(dtype=wp.float64),
    prim_out: wp.array2d(dtype=wp.int64),
):
    """:meth:`ShellCaster._peel`'s rounds for ray ``i`` (world origin ``o``, unit ``u``) from the state after
    ``n`` hits (the next cast at ``t_next``, the last face ``last``), in one thread: the same casts in the
    same order. Writes hits ``n, n + 1, ...`` of row ``i``; returns the ray's number of hits."""
    unit = wp.vec3(wp.float32(u[0]), wp.float32(u[1]), wp.float32(u[2]))
    step = step0
    for _ in range(rounds):
        if n >= max_hits:
            break
        reach = wp.float64(wp.inf)
        if n > 0:
            reach = stop - t_next
        if reach <= wp.float64(0.0):
            break
        s = (o + t_next * u) - center
        start = wp.vec3(wp.float32(s[0]), wp.float32(s[1]), wp.float32(s[2]))
        query = wp.mesh_query_ray(mesh, start, unit, wp.float32(reach))
        if not query.result:
            break
        t_hit = t_next + wp.float64(query.t)
        face = wp.int64(query.face)
        fresh = face != last
        if fresh:
            t_out[i, n] = t_hit
            prim_out[i, n] = face
            n += 1
            step = step0
        else:
            step = wp.float64(2.0) * step
        last = face
        t_next = t_hit + step
        if fresh and t_hit > stop:
            break
    return n


@wp.kernel
def _peel_kernel(
    mesh: wp.uint64,
    origins: wp.array(dtype=wp.vec3d),
    units: wp.array(dtype=wp.vec3d),
    stop: wp.array(dtype=wp.float64),
    center: wp.vec3d,
    step0: wp.float64,
    max_hits: int,
    rounds: int,
    t_out: wp.array2d(dtype=wp.float64),
    prim_out: wp.array2d(dtype=wp.int64),
    count: wp.array(dtype=wp.int32),
):
    """:meth:`ShellCaster._peel` for one ray per thread."""
    i = wp.tid()
    count[i] = _peel_from(
        mesh,
        i,
        origins[i],
        units[i],
        stop[i],
        center,
        step0,
        max_hits,
        rounds,
        wp.float64(0.0),
        wp.int64(-1),
        0,
        t_out,
        prim_out,
    )


@wp.kernel
def _band_kernel(
    outer: wp.uint64,
    inner: wp.uint64,
    origins: wp.array(dtype=wp.vec3d),
    units: wp.array(dtype=wp.vec3d),
    center: wp.vec3d,
    step0: wp.float64,
    max_hits: int,
    rounds: int,
    block: int,
    blocks_step: int,
    first_block: int,
    t_inner: wp.array(dtype=wp.float64),
    t_out: wp.array2d(dtype=wp.float64),
    prim_out: wp.array2d(dtype=wp.int64),
    count: wp.array(dtype=wp.int32),
):
    """:meth:`ShellCaster.band_hits` for one ray per thread: its first M+ hit, on a hit its first M- hit,
    then the peeling rounds of M+ from the first hit on (the generic path's casts, the first one shared).
    The launch covers the blocks of ``block`` consecutive rays ``first_block``, ``first_block + blocks_step``,
    ...: CPU threads take turns over an image's rows (an object covers some more than others) while each
    casts neighbouring rays one after the other."""
    tid = wp.tid()
    i = ((tid // block) * blocks_step + first_block) * block + tid % block
    if i >= origins.shape[0]:
        return
    o = origins[i]
    u = units[i]
    s = o - center
    start = wp.vec3(wp.float32(s[0]), wp.float32(s[1]), wp.float32(s[2]))
    unit = wp.vec3(wp.float32(u[0]), wp.float32(u[1]), wp.float32(u[2]))
    first = wp.mesh_query_ray(outer, start, unit, wp.float32(wp.inf))
    n = int(0)  # noqa: UP018 (a Warp dynamic variable, not a constant)
    stop = wp.float64(wp.inf)
    if first.result:
        behind = wp.mesh_query_ray(inner, start, unit, wp.float32(wp.inf))
        if behind.result:
            stop = wp.float64(behind.t)
        t_hit = wp.float64(first.t)
        t_out[i, 0] = t_hit
        prim_out[i, 0] = wp.int64(first.face)
        n = 1
        if t_hit <= stop:
            n = _peel_from(
                outer,
                i,
                o,
                u,
                stop,
                center,
                step0,
                max_hits,
                rounds - 1,
                t_hit + step0,
                wp.int64(first.face),
                1,
                t_out,
                prim_out,
            )
    t_inner[i] = stop
    count[i] = n


def _listed_hits(t: np.ndarray, prim: np.ndarray, count: np.ndarray) -> tuple[np.ndarray, ...]:
    """The hits a kernel wrote per row, ``t`` and ``prim`` (R, max_hits) with ``count`` (R,) of them in each
    row, as lists: row (H,) sorted, ``t`` (H,) and ``prim`` (H,), in t order within a row."""
    found = np.arange(t.shape[1])[None, :] < count[:, None]  # row-major: by row, then t
    return np.nonzero(found)[0], t[found], prim[found]


@wp.kernel
def _blend_points(
    control: wp.array(dtype=wp.vec3d),
    corners: wp.array2d(dtype=wp.int32),
    weights: wp.array2d(dtype=wp.float64),
    center: wp.vec3d,
    points: wp.array(dtype=wp.vec3),
):
    """points[i] = sum_k weights[i, k] control[corners[i, k]] - center, in float64, stored as float32."""
    i = wp.tid()
    x = weights[i, 0] * control[corners[i, 0]] + weights[i, 1] * control[corners[i, 1]]
    x += weights[i, 2] * control[corners[i, 2]]
    x += weights[i, 3] * control[corners[i, 3]]
    x -= center
    points[i] = wp.vec3(wp.float32(x[0]), wp.float32(x[1]), wp.float32(x[2]))


@wp.func
def _corner(mesh: wp.uint64, index: int):
    """Corner ``index`` (3 face + k) of a Warp mesh's faces, in float64."""
    p = wp.mesh_get_point(mesh, index)
    return wp.vec3d(wp.float64(p[0]), wp.float64(p[1]), wp.float64(p[2]))


@wp.kernel
def _entering_kernel(
    mesh: wp.uint64,
    faces: wp.array(dtype=wp.int64),
    units: wp.array(dtype=wp.vec3d),
    entering: wp.array(dtype=wp.bool),
):
    """Whether each ray enters the mesh at its hit face: the sign of ``dot(unit, (b - a) x (c - a))`` in
    float64 of the face's (centred, float32) corners."""
    h = wp.tid()
    f = wp.int32(faces[h]) * 3
    a = _corner(mesh, f)
    normal = wp.cross(_corner(mesh, f + 1) - a, _corner(mesh, f + 2) - a)
    entering[h] = wp.dot(units[h], normal) < wp.float64(0.0)


class WarpCaster(ShellCaster):
    """:class:`ShellCaster` on Warp meshes whose vertices can move: :meth:`refit` takes new vertex
    positions (same faces) and refits the BVHs in linear time, so deformed shells (paper Sec. 5) are cast
    without a rebuild per frame (refitting 440k faces takes ~12 ms on a CPU core, building them into Embree
    ~600 ms). Casts run on ``device`` ("cpu", "cuda:0"; None: Warp's preferred), on the CPU split over
    ``cpu_threads`` threads (None: :func:`neural.device.cpu_threads`). Centre and peeling step stay those
    of the shells given here.
    """

    def __init__(
        self,
        outer: trimesh.Trimesh,
        inner: trimesh.Trimesh,
        device: str | None = None,
        cpu_threads: int | None = None,
    ):
        self.device = wp.get_device(device)
        self.cpu_threads = 1 if self.device.is_cuda else (cpu_threads or default_cpu_threads())
        self._blends = None  # per shell (corners, weights) as Warp arrays (set_blend)
        self._blend_controls = 0  # control points a blend reads
        super().__init__(outer, inner)

    def _build(self, vertices: np.ndarray, faces: np.ndarray) -> wp.Mesh:
        return wp.Mesh(
            points=wp.array(vertices, dtype=wp.vec3, device=self.device),
            indices=wp.array(faces.ravel(), dtype=wp.int32, device=self.device),
        )

    def refit(self, outer_vertices, inner_vertices) -> None:
        """Move the shells' vertices to ``outer_vertices`` (V+, 3) and ``inner_vertices`` (V-, 3) (world, in
        the order of the meshes given at construction) and refit both BVHs."""
        moved = {"outer": outer_vertices, "inner": inner_vertices}
        for which, vertices in moved.items():
            vertices = np.asarray(vertices, dtype=np.float64)
            expected = (self._scenes[which].points.shape[0], 3)
            if vertices.shape != expected:
                raise ValueError(f"{which}_vertices: expected shape {expected}, got {vertices.shape}")
            if not np.isfinite(vertices).all():
                raise ValueError(f"{which}_vertices: contain NaN or infinity")
            moved[which] = wp.array(vertices - self.center, dtype=wp.vec3, device=self.device)
        self._refit_each(lambda which, points: points.assign(moved[which]))

    def outer_points(self) -> np.ndarray:
        """(V+, 3) float64 the outer shell's vertices as last refitted (as cast: float32 about the centre)."""
        return self._scenes["outer"].points.numpy().astype(np.float64) + self.center

    def set_blend(self, outer: tuple, inner: tuple) -> None:
        """Make every shell vertex a weighted sum of control points, for :meth:`refit_blended`: per shell
        ``(corners (V, 4) int, weights (V, 4) float)``, vertex ``i`` = ``sum_k weights[i, k] *
        control[corners[i, k]]`` (a cage's barycentric embedding of the shells)."""
        blends = {}
        for which, (corners, weights) in {"outer": outer, "inner": inner}.items():
            corners, weights = np.asarray(corners), np.asarray(weights, dtype=np.float64)
            expected = (self._scenes[which].points.shape[0], 4)
            if corners.shape != expected or weights.shape != expected:
                raise ValueError(
                    f"{which}: expected corners and weights of shape {expected}, got {corners.shape} and "
                    f"{weights.shape}"
                )
            if corners.size and corners.min() < 0 or not np.isfinite(weights).all():
                raise ValueError(f"{which}: corners must be >= 0 and weights finite")
            blends[which] = (
                wp.array(corners.astype(np.int32), dtype=wp.int32, device=self.device),
                wp.array(weights, dtype=wp.float64, device=self.device),
            )
        self._blends = blends
        self._blend_controls = 1 + max((int(c.max()) for c in (outer[0], inner[0]) if np.size(c)), default=-1)

    def refit_blended(self, control) -> None:
        """Move the shells' vertices to their blends (:meth:`set_blend`) of world ``control`` points (C, 3),
        in a Warp kernel straight into the meshes' float32 points, and refit both BVHs: the vertices of
        :meth:`refit` with the blends computed in float64 (lego's shells: 0.69x the time of blending them
        in numpy first)."""
        if self._blends is None:
            raise ValueError("refit_blended: no blend of the shells (set_blend)")
        control = np.asarray(control, dtype=np.float64)
        if control.ndim != 2 or control.shape[1] != 3 or len(control) < self._blend_controls:
            raise ValueError(
                f"control: expected shape (C, 3) with C >= {self._blend_controls}, got {control.shape}"
            )
        if not np.isfinite(control).all():
            raise ValueError("control: contain NaN or infinity")
        control = wp.array(control, dtype=wp.vec3d, device=self.device)
        center = wp.vec3d(*self.center)

        def blend(which: str, points: wp.array) -> None:
            inputs = [control, *self._blends[which], center]
            wp.launch(_blend_points, dim=len(points), inputs=inputs, outputs=[points], device=self.device)

        wp.load_module(_blend_points.module, device=self.device)
        self._refit_each(blend)

    def _refit_each(self, move) -> None:
        """``move(which, points)`` writes a shell's centred float32 points; then its BVH is refitted; both
        shells at once on the CPU (Warp releases the GIL)."""

        def refit(lo: int, hi: int) -> None:
            for which in ("outer", "inner")[lo:hi]:
                mesh = self._scenes[which]
                move(which, mesh.points)
                mesh.refit()

        run_in_chunks(2, refit, self.cpu_threads, 1)

    def _peel(
        self, scene: wp.Mesh, origins: np.ndarray, units: np.ndarray, stop: np.ndarray, max_hits: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All rounds of every ray in one kernel launch (per thread chunk) instead of a cast per round."""
        n, dev = len(origins), self.device
        arrays = [
            wp.array(np.ascontiguousarray(origins), dtype=wp.vec3d, device=dev),
            wp.array(np.ascontiguousarray(units), dtype=wp.vec3d, device=dev),
            wp.array(np.ascontiguousarray(stop, dtype=np.float64), dtype=wp.float64, device=dev),
        ]
        outputs = [
            wp.empty((n, max_hits), dtype=wp.float64, device=dev),
            wp.empty((n, max_hits), dtype=wp.int64, device=dev),
            wp.empty(n, dtype=wp.int32, device=dev),
        ]
        center, rounds = wp.vec3d(*self.center), 2 * max_hits + 8

        def launch(lo: int, hi: int) -> None:
            wp.launch(
                _peel_kernel,
                dim=hi - lo,
                inputs=[scene.id, *(a[lo:hi] for a in arrays), center, self.step, max_hits, rounds],
                outputs=[a[lo:hi] for a in outputs],
                device=dev,
            )

        wp.load_module(_peel_kernel.module, device=dev)
        run_in_chunks(n, launch, self.cpu_threads, _MIN_CAST_CHUNK)
        t, prim, count = (a.numpy() for a in outputs)
        return _listed_hits(t, prim, count)

    def band_hits(
        self, starts: np.ndarray, units: np.ndarray, max_hits: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Every cast of every ray in one kernel launch (per thread chunk): the generic path's casts, its
        first M+ cast shared with the peeling."""
        n, dev = len(starts), self.device
        arrays = [wp.array(np.ascontiguousarray(x), dtype=wp.vec3d, device=dev) for x in (starts, units)]
        outputs = [
            wp.empty(n, dtype=wp.float64, device=dev),
            wp.empty((n, max_hits), dtype=wp.float64, device=dev),
            wp.empty((n, max_hits), dtype=wp.int64, device=dev),
            wp.empty(n, dtype=wp.int32, device=dev),
        ]
        center, rounds = wp.vec3d(*self.center), 2 * max_hits + 8
        outer, inner = self._scenes["outer"].id, self._scenes["inner"].id
        threads = max(1, min(self.cpu_threads, n // _MIN_CAST_CHUNK))
        blocks = -(-n // _CAST_BLOCK)

        def launch(lo: int, hi: int) -> None:
            for first_block in range(lo, hi):  # this CPU thread's blocks: first_block, + threads, ...
                wp.launch(
                    _band_kernel,
                    dim=len(range(first_block, blocks, threads)) * _CAST_BLOCK,
                    inputs=[
                        *(outer, inner, *arrays, center, self.step, max_hits, rounds),
                        *(_CAST_BLOCK, threads, first_block),
                    ],
                    outputs=outputs,
                    device=dev,
                )

        wp.load_module(_band_kernel.module, device=dev)
        run_in_chunks(threads, launch, threads, 1)
        t_inner, t, prim, count = (a.numpy() for a in outputs)
        meets = np.flatnonzero(count > 0)
        rows, t, prim = _listed_hits(t[meets], prim[meets], count[meets])
        ray_idx = meets[rows]
        return meets, t_inner[meets], ray_idx, t, self._entering("outer", units[ray_idx], prim)

    def _entering(self, mesh_which: str, units: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """In a Warp kernel from the mesh's own corners (a third of the time of gathering the corners in
        numpy; the moving shells keep no facet normals)."""
        n, dev = len(faces), self.device
        arrays = [
            wp.array(np.ascontiguousarray(faces, dtype=np.int64), dtype=wp.int64, device=dev),
            wp.array(np.ascontiguousarray(units), dtype=wp.vec3d, device=dev),
        ]
        entering = wp.empty(n, dtype=wp.bool, device=dev)
        mesh = self._scenes[mesh_which].id

        def launch(lo: int, hi: int) -> None:
            inputs = [mesh, *(a[lo:hi] for a in arrays)]
            wp.launch(_entering_kernel, dim=hi - lo, inputs=inputs, outputs=[entering[lo:hi]], device=dev)

        wp.load_module(_entering_kernel.module, device=dev)
        run_in_chunks(n, launch, self.cpu_threads, _MIN_CAST_CHUNK)
        return entering.numpy()

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


def ray_triangle_hits(triangles: np.ndarray, origin: np.ndarray, unit: np.ndarray):
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
