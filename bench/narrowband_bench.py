"""Throughput of narrow-band sampling (Procedure 3) on the CPU: rays per second for one camera view.

Shells: marching cubes of a bumpy sphere in the unit cube, offset outward (M+) and inward (M-) by a
half-width of 0.003 (a surface-like band: one sample) that grows to 0.023 on the top cap (a fuzzy band).

    python bench/narrowband_bench.py                # 200x200 view, ~200k triangles per shell
    python bench/narrowband_bench.py --grid 128     # smaller meshes
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import trimesh
from skimage.measure import marching_cubes

from neural.config import NarrowBandConfig
from neural.device import configure_process


def bumpy_shells(grid: int) -> tuple[trimesh.Trimesh, trimesh.Trimesh]:
    """M+ and M- of a bumpy sphere (radius 0.3 around (0.5, 0.5, 0.5)) on a ``grid``^3 lattice."""
    x = (np.arange(grid) + 0.5) / grid
    p = np.stack(np.meshgrid(x, x, x, indexing="ij"), axis=-1) - 0.5
    f = np.linalg.norm(p, axis=-1) - 0.3 - 0.03 * np.prod(np.sin(14 * p), axis=-1)
    band = 0.003 + 0.02 * np.clip((p[..., 1] - 0.15) / 0.15, 0, 1)  # half-width 0.003, 0.023 at the top
    meshes = []
    for level in (f - band, f + band):  # M+ = {f < band}, M- = {f < -band}
        verts, faces, _, _ = marching_cubes(level.astype(np.float32), 0.0, spacing=(1 / grid,) * 3)
        # skimage winds faces with normals towards increasing values: outward for the region {level < 0}.
        meshes.append(trimesh.Trimesh(verts + 0.5 / grid, faces, process=False))
    return meshes[0], meshes[1]


def camera_rays(resolution: int, distance: float = 1.3, fov_deg: float = 40.0):
    """Pinhole rays (resolution^2, 3) looking at the scene centre from the front-right-up."""
    center = np.array([0.5, 0.5, 0.5])
    eye = center + distance * np.array([0.6, 0.5, 0.62]) / np.linalg.norm([0.6, 0.5, 0.62])
    forward = (center - eye) / np.linalg.norm(center - eye)
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    s = np.tan(np.radians(fov_deg) / 2) * ((np.arange(resolution) + 0.5) / resolution * 2 - 1)
    u, v = np.meshgrid(s, -s, indexing="xy")
    dirs = forward + u.reshape(-1, 1) * right + v.reshape(-1, 1) * up
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    return np.broadcast_to(eye, dirs.shape).copy(), dirs


def best_of(repeats: int, fn):
    """Smallest CPU time of this thread over ``repeats`` calls (s), and the last result. Everything timed runs
    on one thread, so CPU time is what a quiet machine would show as wall time (the benchmark machine may be
    shared)."""
    times = []
    for _ in range(repeats):
        start = time.thread_time()
        result = fn()
        times.append(time.thread_time() - start)
    return min(times), result


def main():
    # here, after configure_process (run first): torch loads with them
    import torch

    from neural.render.narrowband import (
        intervals_from_hits,
        narrow_band_samples,
        samples_from_intervals,
        samples_per_interval,
    )
    from neural.render.raycast import EmbreeCaster

    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--resolution", type=int, default=200, help="view is resolution x resolution rays")
    parser.add_argument("--grid", type=int, default=224, help="marching-cubes lattice size")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    torch.set_num_threads(1)

    start = time.perf_counter()
    outer, inner = bumpy_shells(args.grid)
    t_mesh = time.perf_counter() - start
    start = time.thread_time()
    intersector = EmbreeCaster(outer, inner)
    t_init = time.thread_time() - start
    start = time.process_time()
    for which in ("outer", "inner"):  # Embree builds its BVH (possibly multi-threaded) on the first cast
        intersector.first_hit(which, [[0.0, 0.0, 0.0]], [[1.0, 0.0, 0.0]])
    t_commit = time.process_time() - start
    origins, dirs = camera_rays(args.resolution)
    config = NarrowBandConfig()
    n_rays = len(origins)

    t_total, (samples, stats) = best_of(
        args.repeats, lambda: narrow_band_samples(intersector, origins, dirs, config)
    )
    units = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    t_casts, (meets, t_meets, *hits) = best_of(
        args.repeats, lambda: intersector.band_hits(origins, units, config.max_peel)
    )
    t_inner = np.full(n_rays, np.inf)
    t_inner[meets] = t_meets
    t_pair, intervals = best_of(args.repeats, lambda: intervals_from_hits(*hits, t_inner, config.max_peel))
    rays, d_enter, d_exit = intervals
    t_count, n = best_of(args.repeats, lambda: samples_per_interval(d_exit - d_enter, config))
    t_pack, _ = best_of(args.repeats, lambda: samples_from_intervals(rays, d_enter, d_exit, n))

    counts = stats.counts
    print(f"shells: M+ {len(outer.faces):,} / M- {len(inner.faces):,} triangles (grid {args.grid}^3)")
    print(
        f"marching cubes {t_mesh:.2f} s wall; CPU: EmbreeCaster() {t_init * 1e3:.0f} ms, "
        f"Embree BVH builds {t_commit * 1e3:.0f} ms (all threads)"
    )
    print(f"rays: {n_rays:,} ({args.resolution}x{args.resolution}), {config}")
    print(
        f"hits of M+: {len(hits[0]):,}, intervals: {len(rays):,}, samples: {len(samples.ray_indices):,}, "
        f"mean samples/ray {stats.mean_samples_per_ray:.2f} "
        f"({counts[counts > 0].mean():.2f} over rays with any), max {counts.max()}"
    )
    print(f"CPU time, end to end: {t_total * 1e3:7.1f} ms  -> {n_rays / t_total / 1e6:.2f} M rays/s")
    parts = [
        (f"casts ({len(meets):,} meet M+)", t_casts),
        ("pair hits -> intervals", t_pair),
        ("N per interval", t_count),
        ("place samples", t_pack),
        ("to torch + checks", t_total - t_casts - t_pair - t_count - t_pack),
    ]
    for name, seconds in parts:
        print(f"  {name:24s} {seconds * 1e3:7.1f} ms  ({100 * seconds / t_total:4.1f} %)")


if __name__ == "__main__":
    configure_process()
    main()
