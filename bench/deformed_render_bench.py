"""Cost of deformed rendering (paper Sec. 5) against rest rendering of the same asset, views and size.

For each view (a camera orbiting the asset, evenly spaced in azimuth) it renders the asset at rest
(narrow-band rendering of the rest shells, Sec. 3.4) and with its cage deformed (shells deformed by
barycentric interpolation, cast in deformed space, every sample mapped back to rest space), and prints the
median milliseconds per frame of each and their split (build: shell deformation and BVH refits, the inverse
map's update; sample: casting; map: the inverse map; shade: the field), and the ratio deformed / rest as the
median over back-to-back pairs (rest and deformed renders alternate, so a slow moment of a shared machine
slows both alike; target: at most 1.5).
The deformation is a frame of the analytic wind (``--motion wind``, :mod:`~shellsim.physics.wind`) or a
twist of the cage about the up axis growing with height (``--motion twist``). Wall times: run on a quiet
machine.

    python bench/deformed_render_bench.py                          # assets/lego, 200x200, 4 views
    python bench/deformed_render_bench.py --asset PATH --size 100 --views 2 --motion twist
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from neural.asset import load_asset, load_field
from neural.device import configure_process, pick_device, processor
from shellsim.film.cameras import orbit_camera, orbit_framing
from shellsim.physics.wind import WindField, wind_displacement
from shellsim.tetcage.store import load_or_build_cage


def twist(vertices: np.ndarray, up: np.ndarray, turns: float = 0.15) -> np.ndarray:
    """(V, 3) ``vertices`` twisted about the vertical axis through their centre, by ``turns`` revolutions
    at the top, linearly in height from none at the bottom."""
    up = up / np.linalg.norm(up)
    center = 0.5 * (vertices.min(0) + vertices.max(0))
    h = (vertices - center) @ up
    angle = 2 * math.pi * turns * (h - h.min()) / max(np.ptp(h), 1e-12)
    radial = (vertices - center) - np.outer(h, up)
    rotated = radial * np.cos(angle)[:, None] + np.cross(up, radial) * np.sin(angle)[:, None]
    return center + np.outer(h, up) + rotated


def main() -> None:
    from shellsim.film.renderer import STAGES, DeformedRenderer  # loads torch, after configure_process

    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--asset", default="lego", help="asset directory or shipped name (default lego)")
    parser.add_argument("--size", type=int, default=200, help="images are SIZE x SIZE (default 200)")
    parser.add_argument("--views", type=int, default=4, help="orbit views (default 4)")
    parser.add_argument("--motion", choices=("wind", "twist"), default="wind")
    parser.add_argument("--repeats", type=int, default=3, help="renders per view and mode; median kept")
    parser.add_argument("--device", default="auto", help="cpu, cuda or auto (default)")
    args = parser.parse_args()

    asset = load_asset(args.asset)
    device = pick_device(args.device)
    field = load_field(asset, device)
    cage = load_or_build_cage(asset)
    renderer = DeformedRenderer(asset, field, cage, device)
    rest = cage.vertices
    if args.motion == "wind":
        settings = WindField(up=tuple(asset.up), strength=0.1)
        positions = rest + wind_displacement(rest, 1.5, settings)
    else:
        positions = twist(rest, asset.up)
    center, distance = orbit_framing(np.concatenate([rest, positions]))
    print(
        f"asset {asset.name}: {len(renderer.outer.faces)} + {len(renderer.inner.faces)} shell faces, cage "
        f"{len(cage.vertices)} vertices / {len(cage.tets)} tets; {args.size}x{args.size}, {args.motion}, "
        f"{device} ({processor(device)}), median of {args.repeats}"
    )
    warm = orbit_camera(center, distance, asset.up, 0.0, args.size, args.size)
    for _ in range(2):  # warm-up: kernel loading, first allocations (the first two frames are slow)
        renderer.render(warm, 0)
        renderer.render(warm, 0, positions)
    header = f"{'view':>4} {'frame':>8} {'spp':>5} {'ms':>11} " + " ".join(f"{s + ' ms':>9}" for s in STAGES)
    print(header + f" {'ratio':>6}")
    ratios, totals = [], {"rest": [], "deformed": []}
    for v in range(args.views):
        view = orbit_camera(center, distance, asset.up, 2 * math.pi * v / args.views, args.size, args.size)
        runs = {"rest": [], "deformed": []}
        for _ in range(args.repeats):  # interleaved: a slow moment of the machine slows both alike
            runs["rest"].append(renderer.render(view, 0)[1])
            runs["deformed"].append(renderer.render(view, 0, positions)[1])
        pairs = [d["ms"] / r["ms"] for r, d in zip(runs["rest"], runs["deformed"], strict=True)]
        ratios.extend(pairs)
        med = {
            mode: {
                k: float(np.median([r[k] for r in rs]))
                for k in ("ms", "samples_per_pixel", *(f"{s}_ms" for s in STAGES))
            }
            for mode, rs in runs.items()
        }
        for mode in totals:
            totals[mode].append(med[mode]["ms"])
        for mode in ("rest", "deformed"):
            m = med[mode]
            print(
                f"{v if mode == 'rest' else '':>4} {mode:>8} {m['samples_per_pixel']:>5.2f} {m['ms']:>11.0f} "
                + " ".join(f"{m.get(s + '_ms', 0.0):>9.0f}" for s in STAGES)
                + (f" {np.median(pairs):>6.2f}" if mode == "deformed" else "")
            )
    rest_ms, deformed_ms = np.mean(totals["rest"]), np.mean(totals["deformed"])
    print(
        f"mean: rest {rest_ms:.0f} ms/frame, deformed {deformed_ms:.0f} ms/frame; deformed / rest, the "
        f"median of {len(ratios)} back-to-back pairs: {np.median(ratios):.2f} (target <= 1.5)"
    )


if __name__ == "__main__":
    configure_process()
    main()
