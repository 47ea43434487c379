"""Cost of the deformed-to-rest map (:class:`~shellsim.deform.inverse_map.InverseMap`): build and queries.

Cages: the unit cube split into n^3 cells of 6 tets (n = 12: 10,368 tets; n = 19: 41,154 tets), deformed
by a smooth non-inverting warp. Queries: random points in the deformed cage's bounding box (most inside)
with random unit directions. Prints the median of ``--repeats`` runs in ms.

    python bench/inverse_map_bench.py                       # Warp's preferred device, all CPU cores
    python bench/inverse_map_bench.py --device cpu --threads 1
    python bench/inverse_map_bench.py --points 120000 1000000 5000000
"""

from __future__ import annotations

import argparse
import itertools
import time

import numpy as np

from neural.device import configure_process
from shellsim.deform.inverse_map import InverseMap


def cube_grid(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices ((n+1)^3, 3) of the unit cube and its 6 n^3 Kuhn tets, positively oriented."""
    verts = np.stack(np.meshgrid(*[np.linspace(0.0, 1.0, n + 1)] * 3, indexing="ij"), -1).reshape(-1, 3)
    corners = np.array(list(itertools.product((0, 1), repeat=3)))  # corner k = (i, j, l) bits
    paths = []
    for perm in itertools.permutations(range(3)):
        step, path = np.zeros(3, np.int64), [0]
        for axis in perm:
            step[axis] = 1
            path.append(int(np.flatnonzero((corners == step).all(1))[0]))
        paths.append(path)
    cells = np.array(list(itertools.product(range(n), repeat=3)))
    corner_ids = ((cells[:, None, :] + corners[None]) * [(n + 1) ** 2, n + 1, 1]).sum(-1)  # (C, 8)
    tets = corner_ids[:, paths].reshape(-1, 4)
    e = verts[tets[:, 1:]] - verts[tets[:, :1]]
    flip = np.einsum("ti,ti->t", e[:, 0], np.cross(e[:, 1], e[:, 2])) < 0
    tets[flip] = tets[flip][:, [1, 0, 2, 3]]
    return verts, tets


def warp_smooth(x: np.ndarray) -> np.ndarray:
    return x + 0.07 * np.sin(3.0 * x[:, [1, 2, 0]] + 0.5)


def median_ms(repeats: int, fn, *fn_args, **fn_kwargs) -> tuple[str, object]:
    """Median wall and CPU (all threads) time of ``fn(*fn_args, **fn_kwargs)`` as text, and its last result.

    On a shared machine the CPU time is the steadier figure."""
    wall, cpu, out = [], [], None
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        out = fn(*fn_args, **fn_kwargs)
        wall.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return f"{1e3 * np.median(wall):8.1f} ms (cpu {1e3 * np.median(cpu):8.1f} ms)", out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="Warp device: cpu, cuda:0 (default: Warp's preferred)")
    parser.add_argument(
        "--threads", type=int, default=None, help="CPU threads per query (default: all cores)"
    )
    parser.add_argument("--cells", type=int, nargs="+", default=[12, 19], help="grid cells per side")
    parser.add_argument("--points", type=int, nargs="+", default=[120_000, 1_000_000])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    rng = np.random.default_rng(0)
    for n in args.cells:
        rest, tets = cube_grid(n)
        deformed = warp_smooth(rest)
        InverseMap(deformed, tets, rest, device=args.device)  # compile / load the kernels
        build, inverse = median_ms(
            args.repeats, InverseMap, deformed, tets, rest, device=args.device, cpu_threads=args.threads
        )
        print(f"{len(tets):>7,} tets on {inverse.device}: build (tet matrices + BVH) {build}")
        lo, hi = deformed.min(0), deformed.max(0)
        for n_points in args.points:
            x = lo + (hi - lo) * rng.random((n_points, 3))
            d = rng.normal(size=x.shape)
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            points_time, (_, inside) = median_ms(args.repeats, inverse.map_points, x)
            samples_time, _ = median_ms(args.repeats, inverse.map_samples, x, d)
            print(
                f"{'':>7}  {n_points:>10,} points ({inside.mean():.0%} inside): "
                f"map_points {points_time}, map_samples (points + directions) {samples_time}"
            )


if __name__ == "__main__":
    configure_process()
    main()
