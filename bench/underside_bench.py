"""What no training camera saw, as a user meets it (the issue on assets that hold up from every side):

- **from below**: the asset seen from three cameras 30 degrees below its middle, over a plain sky, at 256x256;
  prints the share of the object's pixels (opacity above 0.5) that are near-white (every channel above 0.85),
  and writes the pictures (with one from the side at ground level) to ``--out``;
- **at rest**: the asset set down on the ground as wood and simulated for ``--frames`` frames; prints the
  largest tilt of the body (the rotation that best maps its cage's first frame onto each frame, Kabsch) and
  the tilt at the last frame;
- the share of the surface no camera saw, from the asset's record.

    python bench/underside_bench.py --asset lego /work/runs/lego_seen --out /tmp/underside
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
from PIL import Image

from neural.device import configure_process

SKY = (0.35, 0.55, 0.85)
SIDE = 256
SCENE = """
[world]
fps = 30
frames = {frames}
substeps = 4

[[body]]
name = "body"
asset = "{asset}"
size = {size}
material = "wood"
"""


def cameras_around(asset, elevation_deg: float, n: int, distance: float):
    """n cameras at ``elevation_deg`` (about the asset's up) around its centre, looking at it, 40 degrees."""
    from neural.data import Cameras, look_at

    up = asset.up / np.linalg.norm(asset.up)
    side = np.cross(up, [1.0, 0, 0] if abs(up[0]) < 0.9 else [0, 1.0, 0])
    side /= np.linalg.norm(side)
    other = np.cross(up, side)
    center = asset.center
    c2w = []
    for k in range(n):
        azimuth = 2 * math.pi * (k + 0.125) / n
        e = math.radians(elevation_deg)
        direction = math.cos(e) * (math.cos(azimuth) * side + math.sin(azimuth) * other) + math.sin(e) * up
        c2w.append(look_at(center + distance * direction, center, up))
    focal = 0.5 * SIDE / math.tan(math.radians(20))
    ones = np.ones(n)
    return Cameras(
        np.stack(c2w),
        focal * ones,
        focal * ones,
        SIDE / 2 * ones,
        SIDE / 2 * ones,
        np.full(n, SIDE),
        np.full(n, SIDE),
        np.zeros((n, 4)),
        [f"cam{k}" for k in range(n)],
    )


def pictures(asset, cameras) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Each camera's picture over the sky (H, W, 3) and its opacity (H, W)."""
    import torch

    from neural.asset import load_field
    from neural.render.view import asset_sampler, render_camera

    field, sampler = load_field(asset), asset_sampler(asset)
    images, alphas = [], []
    for i in range(len(cameras)):
        with torch.no_grad():
            black, _ = render_camera(field, cameras, i, sampler, torch.zeros(3))
            sky, _ = render_camera(field, cameras, i, sampler, torch.tensor(SKY))
        images.append(sky)
        alphas.append(1.0 - (sky - black).mean(-1) / np.mean(SKY))
    return images, alphas


def tilt_degrees(motion) -> np.ndarray:
    """(F,) angle [deg] between up and up turned by the rotation best mapping frame 0 onto each frame."""
    first = motion.positions[0].astype(np.float64)
    a = first - first.mean(0)
    angles = []
    for frame in motion.positions.astype(np.float64):
        b = frame - frame.mean(0)
        u, _, vt = np.linalg.svd(a.T @ b)
        d = np.sign(np.linalg.det(u @ vt))
        rotation = (u @ np.diag([1, 1, d]) @ vt).T
        angles.append(math.degrees(math.acos(np.clip(rotation[2, 2], -1, 1))))
    return np.asarray(angles)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--asset", nargs="+", default=["lego"])
    parser.add_argument("--size", type=float, default=0.3, help="[m] of the body at rest")
    parser.add_argument("--frames", type=int, default=45)
    parser.add_argument("--out", default="underside_bench")
    args = parser.parse_args()
    configure_process()
    from neural.asset import load_asset
    from shellsim.jobs.scene import SceneSettings, scene
    from shellsim.motion.read import load_motion

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print("asset  near-white from below  tilt max / last [deg]  unseen surface")
    for spec in args.asset:
        asset = load_asset(spec)
        name = Path(spec).name
        radius = 1.0 / asset.scale
        below = cameras_around(asset, -30.0, 3, 3.2 * radius)
        images, alphas = pictures(asset, below)
        shown = np.concatenate([a > 0.5 for a in alphas])
        white = np.concatenate([(im > 0.85).all(-1) for im in images])[shown]
        side_image, _ = pictures(asset, cameras_around(asset, 0.0, 1, 3.2 * radius))
        strip = np.concatenate([*images, side_image[0]], 1)
        Image.fromarray((strip * 255 + 0.5).astype(np.uint8)).save(out / f"{name}_below_and_side.png")
        path = out / f"{name}_rest.toml"
        path.write_text(
            SCENE.format(
                frames=args.frames,
                asset=Path(spec).resolve() if Path(spec).is_dir() else spec,
                size=args.size,
            )
        )
        result = scene(SceneSettings(scene=str(path), out=str(path.with_suffix(""))), progress=False)
        tilts = tilt_degrees(load_motion(result.out))
        record = asset.meta.get("visibility", {}).get("unseen_surface_share")
        unseen = "not recorded" if record is None else f"{100 * record:.1f}%"
        print(
            f"{name}  {100 * white.mean():.1f}% of {shown.sum()} pixels  "
            f"{tilts.max():.2f} / {tilts[-1]:.2f}  {unseen}"
        )


if __name__ == "__main__":
    main()
