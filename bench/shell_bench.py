"""Time and peak memory of a full adaptive-shell extraction (grid sampling + Procedure 2) on an analytic
field: a sphere of radius 0.6 whose upper cap is bumpy and fuzzy (large kernel size s), sharp elsewhere.

    python bench/shell_bench.py                          # resolutions 128 and 256, torch's thread count
    python bench/shell_bench.py --resolution 256 --threads 1 --device cuda

Each resolution runs in its own subprocess so that its peak memory is its own (CPU: peak resident set size,
and its growth over the size after imports; CUDA: torch's peak allocation).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

from neural.device import configure_process

S_SHARP, S_FUZZY = 0.001, 0.03  # kernel sizes in unit space (the sphere spans [-0.6, 0.6])


def bumpy_fuzzy_sphere(x):
    """(N, 3) points -> (sdf (N,), s (N,)): sphere r = 0.6, bumps of 0.03 and s -> S_FUZZY for z > 0.2."""
    import torch

    cap = torch.clamp((x[:, 2] - 0.2) / 0.3, 0.0, 1.0)
    cap = cap * cap * (3 - 2 * cap)  # smoothstep
    bumps = 0.03 * torch.sin(14 * x[:, 0]) * torch.sin(14 * x[:, 1]) * torch.sin(14 * x[:, 2])
    sdf = x.norm(dim=1) - 0.6 - cap * bumps
    return sdf, S_SHARP + (S_FUZZY - S_SHARP) * cap


def _peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_one(resolution: int, device: str, threads: int | None) -> dict:
    import igl  # noqa: F401  (imported here so that the memory growth excludes the imports)
    import numpy as np
    import skimage.measure  # noqa: F401
    import torch
    import trimesh  # noqa: F401

    from neural.device import pick_device
    from neural.shell import ShellConfig, extract_shells, grid_spacing, sample_grid, shell_width_stats

    device = pick_device(device)
    if threads:
        torch.set_num_threads(threads)
    config = ShellConfig(resolution=resolution)
    lo, hi = [-1.0] * 3, [1.0] * 3
    h = grid_spacing(lo, hi, resolution)
    rss0 = _peak_rss_mib()
    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
    if device == "cuda":
        torch.cuda.reset_peak_memory_stats()
    t0 = time.perf_counter()
    f, s = sample_grid(bumpy_fuzzy_sphere, lo, hi, resolution, device=device)
    sync()
    t1 = time.perf_counter()
    result = extract_shells(f, s, lo, h, config)
    sync()
    t2 = time.perf_counter()
    verts = np.asarray(result.outer.vertices)
    widths = {
        name: shell_width_stats(result.outer, result.inner, points=verts[sel])
        for name, sel in (("sharp (z < 0)", verts[:, 2] < 0.0), ("fuzzy (z > 0.45)", verts[:, 2] > 0.45))
    }
    return {
        "resolution": resolution,
        "device": device,
        "threads": torch.get_num_threads(),
        "sample_s": t1 - t0,
        "extract_s": t2 - t1,
        "peak_rss_mib": _peak_rss_mib(),
        "rss_growth_mib": _peak_rss_mib() - rss0,
        "cuda_peak_mib": torch.cuda.max_memory_allocated() / 2**20 if device == "cuda" else None,
        "outer_faces": len(result.outer.faces),
        "inner_faces": len(result.inner.faces),
        "watertight": bool(result.outer.is_watertight and result.inner.is_watertight),
        "width_voxels": {k: {m: round(v / h, 2) for m, v in w.items()} for k, w in widths.items()},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, nargs="+", default=[128, 256])
    parser.add_argument("--device", default="auto", help="cpu, cuda or auto")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's)")
    parser.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(run_one(args.resolution[0], args.device, args.threads)))
        return
    for res in args.resolution:
        cmd = [sys.executable, __file__, "--one", "--resolution", str(res), "--device", args.device]
        if args.threads:
            cmd += ["--threads", str(args.threads)]
        out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
        r = json.loads(out.strip().splitlines()[-1])
        cuda = f", CUDA peak {r['cuda_peak_mib']:.0f} MiB" if r["cuda_peak_mib"] is not None else ""
        print(
            f"{res}^3 on {r['device']} ({r['threads']} threads): sampling {r['sample_s']:.1f} s, "
            f"extraction {r['extract_s']:.1f} s; peak RSS {r['peak_rss_mib']:.0f} MiB "
            f"(+{r['rss_growth_mib']:.0f} MiB over imports){cuda}; M+ {r['outer_faces']} / "
            f"M- {r['inner_faces']} faces, watertight {r['watertight']}"
        )
        for name, w in r["width_voxels"].items():
            print(f"    shell width, {name}: mean {w['mean']}, median {w['median']}, max {w['max']} voxels")


if __name__ == "__main__":
    configure_process()
    main()
