"""Warp kernel that marches rays through an occupancy grid (for :meth:`~neural.render.occupancy.OccupancyGrid.
sample`).

Not re-exported. One kernel thread marches one ray over its candidate steps ``k`` in ``[first, end)``
(section ``t_start = near + (k + u) step``, valid while ``t_start < far``) and keeps those whose centre lies
in an occupied cell: a counting pass, a prefix sum in torch, then a writing pass into the packed layout. The
dense (rays x steps) tensors of a torch formulation are never built. Tensors are shared with Warp without
copies and the kernels run on their device (cpu or cuda, on the current torch stream); on the CPU the rays
are split over threads by :func:`neural.device.run_in_chunks` (Warp releases the GIL during a CPU launch).
"""

# no ``from __future__ import annotations``: Warp reads the kernels' annotations
import functools

import torch

from ..device import cpu_threads as default_cpu_threads
from ..device import initialised_warp, run_in_chunks
from .samples import RaySamples

_MIN_RAYS_PER_THREAD = 64  # a ray marches hundreds of steps: small chunks still pay for their thread


@functools.cache
def _kernels():
    wp = initialised_warp()

    @wp.func
    def occupied_at(
        o: wp.vec3,
        d: wp.vec3,
        t: float,
        step: float,
        lo: wp.vec3,
        cell: wp.vec3,
        res: int,
        occ: wp.array(dtype=wp.uint8),
    ) -> bool:
        t_end = t + step
        mid = 0.5 * (t + t_end)
        p = o + mid * d
        i = int(wp.floor((p[0] - lo[0]) / cell[0]))
        j = int(wp.floor((p[1] - lo[1]) / cell[1]))
        k = int(wp.floor((p[2] - lo[2]) / cell[2]))
        if i < 0 or j < 0 or k < 0 or i >= res or j >= res or k >= res:
            return False
        return occ[(i * res + j) * res + k] != wp.uint8(0)

    @wp.kernel(enable_backward=False, module="unique")
    def march(
        origins: wp.array(dtype=wp.vec3),
        dirs: wp.array(dtype=wp.vec3),
        near: wp.array(dtype=float),
        far: wp.array(dtype=float),
        shift: wp.array(dtype=float),
        first: wp.array(dtype=int),
        end: wp.array(dtype=int),
        step: float,
        lo: wp.vec3,
        cell: wp.vec3,
        res: int,
        occ: wp.array(dtype=wp.uint8),
        ray_offset: int,
        write: int,
        offsets: wp.array(dtype=int),
        counts: wp.array(dtype=int),
        out_rays: wp.array(dtype=wp.int64),
        out_starts: wp.array(dtype=float),
    ):
        r = wp.tid() + ray_offset
        o = origins[r]
        d = dirs[r]
        n = int(0)  # noqa: UP018 (a mutable Warp variable, not a constant)
        base = offsets[r]  # 0 in the counting pass
        for k in range(first[r], end[r]):
            t = near[r] + (float(k) + shift[r]) * step
            if t >= far[r]:
                break
            if occupied_at(o, d, t, step, lo, cell, res, occ):
                if write != 0:
                    out_rays[base + n] = wp.int64(r)
                    out_starts[base + n] = t
                n += 1
        if write == 0:
            counts[r] = n

    return march


def march_occupied(
    origins: torch.Tensor,
    dirs: torch.Tensor,
    near: torch.Tensor,
    far: torch.Tensor,
    shift: torch.Tensor,
    first: torch.Tensor,
    end: torch.Tensor,
    step: float,
    aabb_min: torch.Tensor,
    cell_size: torch.Tensor,
    occupied: torch.Tensor,
    resolution: int,
    cpu_threads: int | None = None,
) -> RaySamples:
    """Packed sections ``[t, t + step]``, ``t = near + (k + shift) step`` for ``first <= k < end`` and
    ``t < far``, whose centre lies in an occupied cell of the grid at ``aabb_min`` (3,) with cells of
    ``cell_size`` (3,) and flat mask ``occupied`` (resolution^3,) bool.

    origins, dirs : (R, 3) float32 ; near, far, shift : (R,) float32 ; first, end : (R,) int.
    cpu_threads : threads sharing the rays of a CPU launch (None: :func:`neural.device.cpu_threads`).
    """
    wp = initialised_warp()
    march = _kernels()
    device = origins.device
    n_rays = origins.shape[0]
    if n_rays == 0:
        empty = origins.new_zeros(0)
        return RaySamples(torch.zeros(0, dtype=torch.int64, device=device), empty, empty, 0)
    f32 = [t.detach().to(torch.float32).contiguous() for t in (origins, dirs, near, far, shift)]
    i32 = [t.to(torch.int32).contiguous() for t in (first, end)]
    occ = occupied.contiguous().view(torch.uint8)
    counts = torch.zeros(n_rays, dtype=torch.int32, device=device)
    offsets = torch.zeros_like(counts)
    lo = wp.vec3(*(float(v) for v in aabb_min.tolist()))
    cell = wp.vec3(*(float(v) for v in cell_size.tolist()))
    stream = wp.stream_from_torch(wp.device_to_torch(device)) if device.type == "cuda" else None
    arrays = [
        wp.from_torch(f32[0], dtype=wp.vec3),
        wp.from_torch(f32[1], dtype=wp.vec3),
        *(wp.from_torch(t) for t in f32[2:]),
        *(wp.from_torch(t) for t in i32),
    ]
    grid_args = [float(step), lo, cell, int(resolution), wp.from_torch(occ)]
    offsets_wp, counts_wp = wp.from_torch(offsets), wp.from_torch(counts)
    threads = 1 if device.type == "cuda" else (cpu_threads or default_cpu_threads())
    if threads > 1:
        wp.load_module(march.module, device="cpu")  # compile once, before the threads race to do it

    def launch(write: int, rays_out, starts_out) -> None:
        def part(a: int, b: int) -> None:
            inputs = [*arrays, *grid_args, a, write, offsets_wp, counts_wp, rays_out, starts_out]
            wp.launch(march, dim=b - a, inputs=inputs, device=str(device), stream=stream)

        run_in_chunks(n_rays, part, threads, _MIN_RAYS_PER_THREAD)

    none_rays = wp.empty(0, dtype=wp.int64, device=str(device))
    none_starts = wp.empty(0, dtype=float, device=str(device))
    launch(0, none_rays, none_starts)
    offsets.copy_(torch.cumsum(counts, 0, dtype=torch.int32) - counts)
    total = int(counts.sum())
    ray_indices = torch.empty(total, dtype=torch.int64, device=device)
    t_starts = torch.empty(total, dtype=torch.float32, device=device)
    if total > 0:
        launch(1, wp.from_torch(ray_indices), wp.from_torch(t_starts))
    return RaySamples(ray_indices, t_starts, t_starts + step, n_rays)
