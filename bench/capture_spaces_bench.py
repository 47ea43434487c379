"""The background of a synthetic capture: the contracted field against the bounded one with its environment
map (docs/measurements.md, "The background of a synthetic capture against the environment map").

Both spaces are trained on the synthetic capture of ``tests/scenes.py`` (a sphere on a checkered table inside
a textured room sphere; 24 photos of 40x30 without alpha) with the settings of
``tests/test_capture_contraction.py``; printed per stage-1 step count, seed and space: the narrow band's mean
PSNR on the held-out views outside the object (pixels off the sphere padded by 0.05) and over the whole frame,
and the training time. The test checks the ranking at 1500 steps, seed 0, with a margin.

    python bench/capture_spaces_bench.py                            # 1500 steps, seed 0: 2 min on 2 cores
    python bench/capture_spaces_bench.py --steps 500 1000 1500 --seeds 0 1
    python bench/capture_spaces_bench.py --period 0.5               # the cut tests' finer checker
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from scenes import unbounded_object_mask, write_unbounded_scene  # noqa: E402

from neural.config import (  # noqa: E402
    HashGridConfig,
    PipelineConfig,
    ShellConfig,
    Stage1Config,
    Stage2Config,
)
from neural.device import configure_process  # noqa: E402

#: tests/test_capture_contraction.py's box half-size about the cameras' focus and its hash grid
BOUND = 0.35
GRID = HashGridConfig(n_levels=8, log2_table_size=14, max_resolution=256)


def pipeline_config(space: str, steps: int, seed: int) -> PipelineConfig:
    """The test's settings for ``space`` ("contracted" or "bounded"), ``steps`` stage-1 steps, ``seed``."""
    config = PipelineConfig(bound=BOUND, space=space)
    config.field = dataclasses.replace(config.field, hashgrid=GRID, kernel_grid=16)
    config.stage1 = Stage1Config(
        steps=steps, target_samples=8192, max_rays=2048, occupancy_resolution=48, eval_every=steps, seed=seed
    )
    config.stage2 = Stage2Config(steps=60, rays=2048, eval_every=60)
    config.shell = ShellConfig(resolution=96)
    return config


def scores(asset, data) -> tuple[float, float]:
    """Mean PSNR (dB) of ``asset``'s narrow-band renders on ``data``'s held-out views: outside the object,
    and over the whole frame."""
    import numpy as np
    import torch

    from neural.asset import load_field
    from neural.metrics import psnr
    from neural.render.view import asset_sampler, render_camera

    field = load_field(asset)
    background = torch.as_tensor(asset.background, dtype=torch.float32)
    outside, whole = [], []
    for v in data.test_idx:
        image = render_camera(field, data.cameras, int(v), asset_sampler(asset), background)[0]
        photo = data.images[v]
        mask = ~unbounded_object_mask(data.cameras, int(v), pad=0.05)
        outside.append(psnr(image[mask], photo[mask]))
        whole.append(psnr(image, photo))
    return float(np.mean(outside)), float(np.mean(whole))


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--steps", type=int, nargs="+", default=[1500], help="stage-1 step counts")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0], help="stage-1 seeds")
    parser.add_argument(
        "--period",
        type=float,
        default=2.0,
        help="the table's checker period (the test's: 2; the cut tests': 0.5)",
    )
    parser.add_argument(
        "--spaces", nargs="+", default=["contracted", "bounded"], choices=["contracted", "bounded"]
    )
    args = parser.parse_args()
    configure_process()

    from neural.asset import load_asset
    from neural.data import load_dataset
    from neural.pipeline import train_asset

    print(f"{'steps':>6} {'seed':>5}  {'space':<11} {'outside dB':>11} {'whole dB':>9} {'train s':>8}")
    with tempfile.TemporaryDirectory(prefix="shellsim-capture-") as tmp:
        root = Path(tmp)
        data_dir = write_unbounded_scene(
            root / "data", n_views=24, width=40, height=30, table_period=args.period
        )
        data = load_dataset(data_dir, bound=BOUND)
        for steps in args.steps:
            for seed in args.seeds:
                for space in args.spaces:
                    start = time.perf_counter()
                    out = root / f"{space}-{steps}-{seed}"
                    asset = load_asset(train_asset(data_dir, out, pipeline_config(space, steps, seed), "cpu"))
                    seconds = time.perf_counter() - start
                    outside, whole = scores(asset, data)
                    print(
                        f"{steps:>6} {seed:>5}  {space:<11} {outside:>11.2f} {whole:>9.2f} {seconds:>8.0f}",
                        flush=True,
                    )


if __name__ == "__main__":
    main()
