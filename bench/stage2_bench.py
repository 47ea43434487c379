"""Stage 2 again from a run's kept stage-1 field, with other stage-2 settings: what a stage-2 recipe reaches
from one and the same stage-1 field and shells, without training stage 1 again.

    shellsim train --data DATA --out RUN --steps N --stage2-steps 1 --keep-checkpoints [...]
    python bench/stage2_bench.py --run RUN [--steps M] [--every K] [--set lr_encoding=4e-3 --set ...]

Loads the run's asset (field settings, normalisation, background, downscale, narrow-band settings and the
shells extracted from its stage-1 field), puts the weights of ``RUN/checkpoints/stage1.safetensors`` into its
field, and trains stage 2 in a scratch directory with the run's stage-2 settings, except ``--steps`` and
each ``--set NAME=VALUE`` (a ``Stage2Config`` field). Prints the held-out PSNR, SSIM and samples per pixel
(narrow band, every held-out view) every ``--every`` steps and at the end. Nothing in RUN is written.

Measured 2026-12-03 (2-core CPU), stage-2 steps from the same stage-1 field:

- furry bunny, ``--steps 3000`` run (stage 1 30.39 dB full ray), 500 steps: 31.22 dB at 2.47 samples per
  pixel with the default rates (3e-2 / 1e-2, 100-step warm-up), 30.91 dB at 2.45 with
  ``--set lr_encoding=4e-3 --set lr_network=5e-4 --set final_lr_factor=0.3 --set warmup_steps=1``, 31.30 dB
  at 2.46 with ``--set lr_encoding=5e-2``;
- lego, ``--steps 3000 --downscale 4`` run (stage 1 26.91 dB), 1000 steps: 27.71 dB at 500, 27.88 at 1000.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
from pathlib import Path

import numpy as np

from neural.asset import load_asset, load_field
from neural.config import Stage2Config
from neural.device import configure_process, pick_device


def stage2_config(recorded: dict, steps: int | None, every: int | None, settings: list[str]) -> Stage2Config:
    """The run's recorded stage-2 settings with ``steps``, ``eval_every`` and ``NAME=VALUE`` overrides."""
    config = Stage2Config(**recorded)
    types = {f.name: f.type for f in dataclasses.fields(Stage2Config)}
    changes = {}
    for setting in settings:
        name, sep, value = setting.partition("=")
        if not sep or name not in types:
            raise SystemExit(f"--set {setting!r}: expected NAME=VALUE with NAME one of {sorted(types)}")
        kind = str(types[name])
        try:
            parse = {"int": int, "bool": lambda text: text.lower() == "true"}.get(kind, float)
            changes[name] = parse(value)
        except ValueError:
            raise SystemExit(f"--set {setting!r}: {value!r} is not a valid {kind}") from None
    steps = steps or changes.get("steps", config.steps)
    changes.update(steps=steps, eval_every=every or changes.get("eval_every", steps), eval_views=0)
    return dataclasses.replace(config, **changes)


def main() -> None:
    # here, after configure_process (run first): torch loads with them
    from neural.checkpoint import load_checkpoint
    from neural.data import load_dataset
    from neural.train import train_stage2

    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--run", required=True, help="asset directory trained with --keep-checkpoints")
    parser.add_argument("--data", default=None, help="its dataset (default: the one recorded in the run)")
    parser.add_argument("--steps", type=int, default=None, help="stage-2 steps (default: the run's)")
    parser.add_argument("--every", type=int, default=None, help="steps between held-out evaluations")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    parser.add_argument("--device", default="auto")
    args = parser.parse_args()
    device = pick_device(args.device)
    asset = load_asset(args.run)
    training = asset.meta["training"]
    stage1 = asset.root / "checkpoints" / "stage1.safetensors"
    if not stage1.is_file():
        raise SystemExit(f"{stage1}: missing; train the run with --keep-checkpoints")
    config = stage2_config(training["stage2"], args.steps, args.every, args.set)
    data_dir = args.data or training["data"]
    data = load_dataset(data_dir, downscale=asset.training_downscale, background=asset.background)
    if not np.allclose(data.normalisation.center, asset.center) or not np.isclose(
        data.normalisation.scale, asset.scale
    ):
        raise SystemExit(f"{data_dir}: its normalisation differs from the run's (another dataset or --bound)")
    field = load_field(asset, device)
    load_checkpoint(stage1, field)
    with tempfile.TemporaryDirectory() as scratch:
        result = train_stage2(
            field,
            data,
            asset.outer_mesh(),
            asset.inner_mesh(),
            Path(scratch),
            config,
            asset.narrowband_config(),
            device,
        )
    keys = ("step", "psnr", "ssim", "samples_per_pixel", "train_seconds")
    print(
        json.dumps(
            {
                "run": str(asset.root),
                "stage2": dataclasses.asdict(config),
                "curve": [{k: m[k] for k in keys} for m in result["history"]],
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    configure_process()
    main()
