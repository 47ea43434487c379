"""Where the time goes: a stage-1 training step on LEGO, and a rest frame of an asset, part by part.

``step``: resumes a copy of stage 1 of ``shellsim train``'s default lego recipe (200x200) from its checkpoint
at step ``--start`` (kept in ``--base`` by ``bench/step_bench.py``, trained once if missing) and runs
``--steps`` steps with a wall-clock timer around each part of a step: the occupancy grid's refresh and
march, the visibility pass, the forward pass with gradients, the regularisers (Eq. 10-12), the backward pass
and Adam. The first step is left out (warm-up), and so are the checkpoint and held-out evaluation after the
last one.

``frame``: renders the asset's held-out views ``--rounds`` times with its narrow-band sampler (what
``shellsim eval`` and ``shellsim render`` use), after one warm-up view, with timers around the camera rays
and the sampler (Procedure 3's casts), the geometry network and the radiance network; the rest of a frame is
compositing and bookkeeping.

Both print each part's milliseconds per step or frame and its share, and under a part ("of which") the
time of the hash encoding inside it, summed over its calls (its backward pass: the Warp encoding's). On a
CPU every torch operation is synchronous, so a clock around a call times its work; on CUDA the timers
synchronise first. Run it on a quiet machine.

    python bench/profile_bench.py step [--start 300] [--steps 40] [--data DIR] [--base DIR]
    python bench/profile_bench.py frame [--asset lego] [--data DIR] [--rounds 3] [--device cpu|cuda]
"""

from __future__ import annotations

import argparse
import functools
import shutil
import tempfile
import time
from collections import defaultdict
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from neural.device import configure_process, pick_device, processor


class PartTimers:
    """Wall-clock seconds spent in timed callables, by label. A call made while another timed call runs (the
    encoding inside the geometry network) is filed as ``"OUTER / label"`` under the outermost one."""

    def __init__(self, device: str):
        self.seconds: dict[str, float] = defaultdict(float)
        self.running: list[str] = []
        self._originals: list[tuple[object, str, object]] = []
        self._device = device

    def _sync(self) -> None:
        if self._device == "cuda":
            import torch

            torch.cuda.synchronize()

    def timed(self, function, label: str):
        """``function`` with every call timed under ``label`` (its attributes kept)."""

        @functools.wraps(function)
        def timed(*args, **kwargs):
            outer = self.running[0] if self.running else None
            key = label if outer is None else f"{outer} / {label}"
            self._sync()
            self.running.append(label)
            tick = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                self._sync()
                self.seconds[key] += time.perf_counter() - tick
                self.running.pop()

        return timed

    def patch(self, owner, name: str, label: str) -> None:
        """Time every call of ``owner.name`` (a function of a module or class) under ``label``."""
        raw = owner.__dict__[name] if isinstance(owner, type) else getattr(owner, name)
        if isinstance(raw, staticmethod):
            setattr(owner, name, staticmethod(self.timed(raw.__func__, label)))
        else:
            setattr(owner, name, self.timed(raw, label))
        self._originals.append((owner, name, raw))

    def snapshot(self) -> dict[str, float]:
        """The seconds so far, by label (a copy)."""
        return dict(self.seconds)

    def restore(self) -> None:
        for owner, name, raw in reversed(self._originals):
            setattr(owner, name, raw)
        self._originals.clear()


@contextmanager
def patched(timers: PartTimers):
    try:
        yield timers
    finally:
        timers.restore()


def patch_encoding(timers: PartTimers) -> None:
    """The hash encoding's forward (any backend) and the Warp encoding's backward."""
    from neural.field import hashgrid, hashgrid_warp

    timers.patch(hashgrid.HashGridEncoding, "forward", "hash encoding forward")
    timers.patch(hashgrid_warp._HashEncode, "backward", "hash encoding backward")


def report(title: str, seconds: dict[str, float], count: int, total: float, parts: list[str]) -> None:
    """Print ``parts`` (top-level labels in order) in ms per ``title`` and share of ``total`` seconds, each
    followed by the labels nested in it; 'other' is what no part covers."""
    print(f"{'part':<44} {'ms per ' + title:>14} {'share':>7}")

    def row(label: str, value: float, indent: str = "") -> None:
        print(f"{indent + label:<44} {1000 * value / count:14.1f} {100 * value / total:6.1f}%")

    covered = 0.0
    for part in parts:
        covered += seconds.get(part, 0.0)
        row(part, seconds.get(part, 0.0))
        for key, value in sorted(seconds.items()):
            if key.startswith(part + " / "):
                row("of which " + key.split(" / ", 1)[1], value, "  ")
    row("other", total - covered)
    print(f"{'whole ' + title:<44} {1000 * total / count:14.1f}")


STEP_PARTS = [
    "occupancy refresh",
    "occupancy march",
    "visibility pass",
    "forward with gradients",
    "regularisers",
    "backward",
    "optimizer",
]


def profile_step(args) -> None:
    import torch
    from step_bench import kept_checkpoint, train

    import neural.train as training
    from neural.render.occupancy import OccupancyGrid

    base = kept_checkpoint(args.data, Path(args.base), args.start)
    timers, snapshots = PartTimers("cpu"), []
    with patched(timers), tempfile.TemporaryDirectory() as tmp:
        for owner, name, label in [
            (OccupancyGrid, "update", "occupancy refresh"),
            (OccupancyGrid, "sample", "occupancy march"),
            (training, "visible_samples", "visibility pass"),
            (training, "render_rays", "forward with gradients"),
            (training, "regularisers", "regularisers"),
            (torch.Tensor, "backward", "backward"),
            (torch.optim.Adam, "step", "optimizer"),
        ]:
            timers.patch(owner, name, label)
        patch_encoding(timers)
        shutil.copytree(base, tmp, dirs_exist_ok=True)
        times = train(
            args.data, Path(tmp), args.start, args.steps, lambda: snapshots.append(timers.snapshot())
        )
    first, last = snapshots[0], snapshots[-1]
    seconds = {k: v - first.get(k, 0.0) for k, v in last.items()}
    steps = len(times)  # the steps between the first step's end and the last's
    print(f"{processor('cpu')}; lego stage 1, steps {args.start + 2}-{args.start + args.steps}")
    print(f"ms per step: median {1000 * np.median(times):.1f}, mean {1000 * np.mean(times):.1f}")
    report("step", seconds, steps, float(np.sum(times)), STEP_PARTS)


FRAME_PARTS = ["camera rays and sampler", "geometry network", "radiance network"]


def profile_frame(args) -> None:
    import torch

    from neural.asset import load_asset, load_field
    from neural.data import load_dataset
    from neural.field.network import ShellField
    from neural.render import view
    from neural.render.view import asset_sampler, render_camera

    device = pick_device(args.device)
    asset = load_asset(args.asset)
    field = load_field(asset, device)
    data = load_dataset(args.data, downscale=asset.training_downscale, background=asset.background)
    background = torch.as_tensor(asset.background, dtype=torch.float32, device=device)
    views = [int(v) for v in data.test_idx]
    sampler = asset_sampler(asset)
    render_camera(field, data.cameras, views[0], sampler, background)  # warm-up: first casts and kernels
    timers = PartTimers(device)
    sampler = timers.timed(sampler, "camera rays and sampler")
    with patched(timers):
        timers.patch(view, "camera_rays", "camera rays and sampler")
        timers.patch(ShellField, "geometry", "geometry network")
        timers.patch(ShellField, "radiance", "radiance network")
        patch_encoding(timers)
        frames = []
        for _ in range(args.rounds):
            for v in views:
                frames.append(render_camera(field, data.cameras, v, sampler, background)[1])
    seconds = timers.snapshot()
    total = sum(s["ms"] for s in frames) / 1000.0
    best = np.min(np.reshape([s["ms"] for s in frames], (args.rounds, len(views))), axis=0)
    print(f"{processor(device)}; {asset.root.name}, {len(views)} held-out views x {args.rounds} rounds")
    print(f"ms per frame: mean {1000 * total / len(frames):.1f}, each view's best {best.mean():.1f}")
    report("frame", seconds, len(frames), total, FRAME_PARTS)


def main() -> None:
    here = Path(__file__).resolve().parents[1]
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("what", choices=("step", "frame"))
    parser.add_argument("--data", default=str(here.parent / "shared" / "data" / "lego"))
    parser.add_argument(
        "--base", default=str(here / "runs" / "step_bench"), help="step: the kept checkpoint's run"
    )
    parser.add_argument("--start", type=int, default=300, help="step: the checkpoint's step")
    parser.add_argument("--steps", type=int, default=40, help="step: steps run from it")
    parser.add_argument("--asset", default="lego", help="frame: asset directory or shipped name")
    parser.add_argument("--rounds", type=int, default=3, help="frame: renders of every held-out view")
    parser.add_argument("--device", default="auto", help="frame: cpu, cuda or auto (default)")
    args = parser.parse_args()
    (profile_step if args.what == "step" else profile_frame)(args)


if __name__ == "__main__":
    configure_process()
    main()
