"""Milliseconds per stage-1 training step on the LEGO scene at 200x200, under settings of torch's OpenMP pool.

Trains stage 1 of ``shellsim train``'s default recipe to step ``--start`` once (kept in ``--base``, reused
by later runs), then for each round and each ``--spin`` setting resumes a copy of that checkpoint in a child
process and times steps ``--start`` to ``--start + --steps`` (the median of the per-step wall times; past
step 256 the occupancy grid is refreshed in part, as in the rest of a run). Settings alternate within a
round, so a slow moment of a shared machine slows them alike. A ``--spin`` value is libgomp's
``GOMP_SPINCOUNT`` for the child (how long an idle thread of torch's pool spins before it sleeps; 300000 is
libgomp's own default, ``shellsim``'s is ``neural.device.OPENMP_SPIN_COUNT``), or ``passive``
(``OMP_WAIT_POLICY=PASSIVE``: no spinning). Run it on a quiet machine.

    python bench/step_bench.py [--spin 300000 30000 10000 passive] [--rounds 2] [--data DIR] [--base DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from neural.device import OPENMP_SPIN_COUNT, configure_process, processor


def train(data_dir: str, out: Path, start: int, steps: int, on_step=None) -> list[float]:
    """Stage 1 of the default lego recipe (downscale 4) in ``out`` up to step ``start + steps``, resuming
    from ``out``'s checkpoint: the wall time (s) of each step run here. ``on_step()`` is called as each
    step ends (before the step's checkpoint and the held-out evaluation after the last step)."""
    import neural.train as training
    from neural.config import PipelineConfig
    from neural.data import load_dataset
    from neural.pipeline import build_field

    config = PipelineConfig(downscale=4)
    data = load_dataset(data_dir, downscale=4, background=config.background, bound=config.bound)
    stamps, make_bar = [], training._progress

    def timed_bar(*args):  # the step loop's progress bar, silent, stamping every step's end
        bar = make_bar(*args)
        bar.disable, update = True, bar.update
        bar.update = lambda n=1: (stamps.append(time.perf_counter()), on_step and on_step(), update(n))[2]
        return bar

    training._progress = timed_bar
    stage1 = dataclasses.replace(
        config.stage1, steps=start + steps, eval_every=10**9, checkpoint_every=start, checkpoint_seconds=1e9
    )
    training.train_stage1(build_field(data, config.field, "cpu", stage1.seed), data, out, stage1, "cpu")
    return np.diff(stamps).tolist()


def kept_checkpoint(data_dir: str, base: Path, start: int) -> Path:
    """``base``, a run holding stage 1's checkpoint at step ``start`` (trained here once if missing)."""
    from safetensors import safe_open

    checkpoint = base / "checkpoints" / "stage1.safetensors"
    if not checkpoint.is_file():
        print(f"training steps 0-{start} into {base} (once)", flush=True)
        train(data_dir, base, start, 0)
    with safe_open(str(checkpoint), framework="pt") as f:
        step = json.loads(f.metadata()["meta"])["step"]
    if step != start:
        sys.exit(f"{checkpoint}: a checkpoint of step {step}, not {start}: pass another --base")
    return base


def child_env(spin: str) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("GOMP_SPINCOUNT", "OMP_WAIT_POLICY")}
    return {**env, **({"OMP_WAIT_POLICY": "PASSIVE"} if spin == "passive" else {"GOMP_SPINCOUNT": spin})}


def main() -> None:
    here = Path(__file__).resolve().parents[1]
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", default=str(here.parent / "shared" / "data" / "lego"))
    parser.add_argument("--base", default=str(here / "runs" / "step_bench"), help="the kept checkpoint's run")
    parser.add_argument("--start", type=int, default=300, help="the checkpoint's step")
    parser.add_argument("--steps", type=int, default=80, help="steps timed from it")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--spin", nargs="+", default=["300000", OPENMP_SPIN_COUNT, "passive"])
    parser.add_argument("--child", help=argparse.SUPPRESS)  # a copy of the base run to time, in a child
    args = parser.parse_args()
    if args.child:
        times = train(args.data, Path(args.child), args.start, args.steps)
        print("step ms:", " ".join(f"{1000 * s:.2f}" for s in times))  # among Warp's lines on stdout
        return
    bad = [s for s in args.spin if s != "passive" and not s.isdigit()]
    if bad:
        parser.error(f"--spin: expected counts or 'passive', got {bad}")
    base = kept_checkpoint(args.data, Path(args.base), args.start)
    print(f"{processor('cpu')}; lego stage 1, steps {args.start}-{args.start + args.steps}, ms per step")
    print(f"{'setting':>16} " + " ".join(f"{'round ' + str(r + 1):>9}" for r in range(args.rounds)))
    medians = {spin: [] for spin in args.spin}
    for r in range(args.rounds):
        for spin in args.spin if r % 2 == 0 else args.spin[::-1]:
            with tempfile.TemporaryDirectory() as tmp:
                shutil.copytree(base, tmp, dirs_exist_ok=True)
                done = subprocess.run(
                    [sys.executable, __file__, *sys.argv[1:], "--child", tmp],
                    env=child_env(spin),
                    capture_output=True,
                    text=True,
                    check=True,
                )
            line = next(x for x in done.stdout.splitlines() if x.startswith("step ms:"))
            medians[spin].append(float(np.median([float(x) for x in line.split()[2:]])))
    for spin, values in medians.items():
        label = "passive" if spin == "passive" else f"spin {spin}"
        print(f"{label:>16} " + " ".join(f"{v:9.1f}" for v in values))


if __name__ == "__main__":
    configure_process()
    main()
