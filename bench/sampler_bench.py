"""Full-ray samplers on an analytic sphere: samples per ray, sampler time and rendering error; print a table.

    python bench/sampler_bench.py                      # 4096 rays, cpu (cuda when present)
    python bench/sampler_bench.py --inv-s 64 1024 --rays 4096 --resolution 128

The scene is the unit cube [-1, 1]^3 with a sphere of radius 0.5 (exact SDF, constant kernel 1/inv_s,
colour varying with position and direction); rays come from distance 3 towards random points of the cube.
For each sampler the table gives the mean samples per ray, the field evaluations it needs without gradient
(importance rounds), the sampler's median wall time for all rays, and the max / mean colour error and the
max opacity error against a dense reference (fixed steps of 1e-3). The occupancy grid is updated over all
cells once before timing; its update time is printed separately (training calls it every 16 steps).
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

from neural.device import configure_process, pick_device

if TYPE_CHECKING:  # torch loads in the functions, after configure_process
    import torch

RADIUS = 0.5


@dataclass
class Geometry:
    sdf: torch.Tensor
    inv_s: torch.Tensor
    normal: torch.Tensor


class SphereField:
    """Exact sphere SDF with a constant kernel; a stand-in for the neural field."""

    def __init__(self, inv_s: float) -> None:
        self.inv_s = inv_s

    def sdf(self, x: torch.Tensor) -> torch.Tensor:
        return x.norm(dim=1) - RADIUS

    def sdf_kernel(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.sdf(x), x.new_full((x.shape[0],), self.inv_s)

    def geometry(self, x: torch.Tensor) -> Geometry:
        dist = x.norm(dim=1)
        return Geometry(
            dist - RADIUS, dist.new_full(dist.shape, self.inv_s), x / dist[:, None].clamp(min=1e-9)
        )

    def radiance(self, x: torch.Tensor, d: torch.Tensor, geo: Geometry) -> torch.Tensor:
        import torch

        return torch.sigmoid(torch.stack([3 * x[:, 0] + d[:, 2], 3 * x[:, 1], 2 * x[:, 2] - d[:, 0]], dim=1))


def rays(n: int, device: str) -> tuple[torch.Tensor, torch.Tensor]:
    import torch

    g = torch.Generator().manual_seed(0)
    origins = torch.randn(n, 3, generator=g)
    origins = 3.0 * origins / origins.norm(dim=1, keepdim=True)
    dirs = torch.nn.functional.normalize(torch.rand(n, 3, generator=g) * 1.6 - 0.8 - origins, dim=1)
    return origins.to(device), dirs.to(device)


def timed(fn, repeats: int) -> tuple[object, float]:
    """(result, median ms) of ``fn()`` over ``repeats`` runs after one warm-up run."""
    import torch

    result = fn()
    times = []
    for _ in range(repeats):
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        start = time.perf_counter()
        result = fn()
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        times.append(1000 * (time.perf_counter() - start))
    return result, statistics.median(times)


def render_chunked(field, origins, dirs, sampler, chunk: int) -> dict[str, torch.Tensor]:
    import torch

    from neural.render.fullray import render_rays

    outs = []
    bg = torch.ones(3, device=origins.device)
    for start in range(0, origins.shape[0], chunk):
        o, d = origins[start : start + chunk], dirs[start : start + chunk]
        out = render_rays(field, o, d, sampler(o, d), bg)
        outs.append({k: out[k] for k in ("color", "opacity")})
    return {k: torch.cat([o[k] for o in outs]) for k in outs[0]}


def main() -> None:
    # here, after configure_process (run first): torch loads with them
    import torch
    from fullray_samplers import importance_samples, uniform_samples  # bench/, beside this script

    from neural.render.fullray import ray_aabb, stepped_samples
    from neural.render.occupancy import OccupancyGrid
    from neural.render.samples import RaySamples

    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--rays", type=int, default=4096)
    parser.add_argument("--inv-s", type=float, nargs="+", default=[64.0, 1024.0], help="kernel sharpness 1/s")
    parser.add_argument("--resolution", type=int, default=128, help="occupancy grid resolution")
    parser.add_argument("--step", type=float, default=2 * math.sqrt(3) / 512, help="marching step")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--device", default="auto")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    device = pick_device(args.device)
    lo, hi = -torch.ones(3, device=device), torch.ones(3, device=device)
    origins, dirs = rays(args.rays, device)
    near, far = ray_aabb(origins, dirs, lo, hi)
    threads = torch.get_num_threads()
    print(f"{args.rays} rays, device {device}, {threads} threads, sphere r={RADIUS} in [-1, 1]^3")
    for inv_s in args.inv_s:
        field = SphereField(inv_s)
        grid = OccupancyGrid(lo, hi, args.resolution, device=device)
        _, update_ms = timed(lambda grid=grid, field=field: grid.update(field.sdf_kernel, step=0), 1)
        samplers = {
            "uniform 64": lambda o, d: uniform_samples(*ray_aabb(o, d, lo, hi), 64),
            "uniform 128": lambda o, d: uniform_samples(*ray_aabb(o, d, lo, hi), 128),
            "uniform 256": lambda o, d: uniform_samples(*ray_aabb(o, d, lo, hi), 256),
            "importance 32+32": lambda o, d, f=field: importance_samples(
                f.sdf, o, d, *ray_aabb(o, d, lo, hi), n_coarse=32, n_fine=32
            ),
            "importance 64+64": lambda o, d, f=field: importance_samples(
                f.sdf, o, d, *ray_aabb(o, d, lo, hi)
            ),
            f"stepped {args.step:.4f}": lambda o, d: stepped_samples(
                *ray_aabb(o, d, lo, hi), args.step, 1024
            ),
            f"occupancy {args.resolution}^3": lambda o, d, g=grid: g.sample(o, d, args.step, 1024),
        }
        no_grad_evals = {"importance 32+32": 32 + 24, "importance 64+64": 64 + 48}
        reference = render_chunked(
            field, origins, dirs, lambda o, d: stepped_samples(*ray_aabb(o, d, lo, hi), 1e-3, 4096), 256
        )
        print(
            f"\ninv_s = {inv_s:g} (kernel size {1 / inv_s:.4f}); occupancy: "
            f"{float(grid.occupied.float().mean()):.2%} of cells occupied, full update {update_ms:.0f} ms"
        )
        print(
            f"{'sampler':<22}{'samples/ray':>12}{'no-grad/ray':>12}{'ms':>9}{'max|dc|':>10}{'mean|dc|':>10}{'max|da|':>10}"
        )
        for name, sampler in samplers.items():
            samples, ms = timed(lambda s=sampler: s(origins, dirs), args.repeats)
            assert isinstance(samples, RaySamples)
            out = render_chunked(field, origins, dirs, sampler, args.rays)
            dc = (out["color"] - reference["color"]).abs()
            da = (out["opacity"] - reference["opacity"]).abs()
            spp = samples.t_starts.numel() / args.rays
            print(
                f"{name:<22}{spp:>12.1f}{no_grad_evals.get(name, 0):>12d}{ms:>9.1f}"
                f"{float(dc.max()):>10.4f}{float(dc.mean()):>10.5f}{float(da.max()):>10.4f}"
            )


if __name__ == "__main__":
    configure_process()
    main()
