"""Final frames in about a second (issue 57): what a final 512x512 frame of the README's main shot costs,
where its time goes, and what each of the issue's changes gives.

    python bench/final_frame_bench.py [--work DIR] [--frames 6] [--size 512] [--repeats 3] [--scenes]
                                      [--before TREE]

1. **The main shot**: ``shellsim simulate --asset lego --material rubber --frames 48`` (simulated once into
   ``--work``), its frames rendered as ``shellsim render --asset lego --motion M --out D`` renders them
   (``--size`` square, 4 rays per pixel where a pixel's neighbourhood varies, the orbit camera, the ground
   and the body's shadow), through the job's own renderer: ms per frame over ``--frames`` frames spread over
   the clip, each the least of ``--repeats`` sweeps over them in order (the host's load only adds to a time;
   an orbit's views never repeat, so nothing of the static world is kept), and the split of
   a frame: building it (shells deformed, BVHs refitted, inverse map), casting camera rays against the
   shells, mapping samples to rest space, shading and compositing them, the world's static layer, the
   world behind the body, the shadow rays through it, and the anti-aliasing rays (every pass after the
   first).
2. **Against the slow twins**: the same frames with full supersampling (4 rays through every pixel) and
   with shadow rays that take every sample (``cutoff`` 0): ms, and the adaptive frame's PSNR against the
   full one with the share of pixels refined.
3. ``--scenes``: frames of scenes seen by a fixed camera with the static world kept per view (from the third
   frame on) against drawn anew in every frame (a :class:`~shellsim.film.static.StaticWorld` of budget 0):
   ``examples/scenes/lego_on_bunny.toml`` and a LEGO dropped into the ramp-and-tray colliders of
   ``examples/scenes/ramp_into_tray.toml`` with a box post (the animator's trial: mesh colliders and their
   shadows), their first ``--frames`` frames simulated into ``--work``.
4. ``--before TREE``: the command ``shellsim render --asset lego --motion M --out D --frames a:b --overwrite``
   run by the code in ``TREE`` (e.g. ``git archive b44177d | tar -x -C TREE``) and by this one, alternately,
   ``--repeats`` times each: ms per frame as the command reports it.

A quiet machine: on 2 shared cores a second process can slow torch's threads several times over.
"""

from __future__ import annotations

import argparse
import functools
import os
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples" / "scenes"
MAIN_SHOT = ["simulate", "--asset", "lego", "--material", "rubber", "--frames", "48"]
#: The animator's trial, rebuilt: mesh colliders and a box, a field dropped among them, a fixed camera.
RAMP = """
[world]
duration = 1.0
substeps = 4

[[body]]
name = "lego"
asset = "lego"
material = "rubber"
size = 0.15
position = [0.45, 0, 0.12]
rotation = [0, 0, 30]

[[collider]]
name = "ramp"
shape = "mesh"
mesh = "{meshes}/ramp.obj"
position = [0, 0, 0.225]

[[collider]]
name = "tray"
shape = "mesh"
mesh = "{meshes}/tray.obj"
position = [0.45, 0, 0.045]

[[collider]]
name = "post"
shape = "box"
position = [-0.35, 0.2, 0.1]
half_extents = [0.04, 0.04, 0.1]

[[camera]]
name = "side"
kind = "fixed"
position = [0.2, -1.3, 0.45]
target = [0.15, 0, 0.15]
"""


def shellsim(*args: str, tree: Path = ROOT) -> str:
    """Run ``python -m shellsim.cli.main ARGS`` with the code of ``tree``; its output."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    done = subprocess.run(
        [sys.executable, "-m", "shellsim.cli.main", *args], env=env, capture_output=True, text=True, cwd=tree
    )
    if done.returncode:
        raise RuntimeError(f"shellsim {' '.join(args)}: {done.stderr[-2000:]}")
    return done.stdout + done.stderr


def main_motion(work: Path) -> Path:
    """The README's main shot simulated once into ``work``."""
    motion = work / "lego_drop.npz"
    if not motion.exists():
        print(f"simulating the main shot: shellsim {' '.join(MAIN_SHOT)} --out {motion}", flush=True)
        shellsim(*MAIN_SHOT, "--out", str(motion))
    return motion


class Timed:
    """A tracer (``trace(view, pixels=None)``) that keeps the stats of its first pass and times the others."""

    def __init__(self, trace):
        self.trace, self.first, self.more_ms = trace, None, 0.0

    def __call__(self, view, pixels=None):
        start = time.perf_counter()
        colors, stats = self.trace(view, pixels)
        if self.first is None:
            self.first = stats
        else:
            self.more_ms += 1000.0 * (time.perf_counter() - start)
        return colors, stats


def motion_frames(motion: Path, size: int, count: int):
    """The renderer of ``shellsim render --motion`` for the main shot's asset and ``count`` jobs ``(view,
    k)`` spread over the clip."""
    from neural.asset import load_asset, load_field
    from shellsim.film import motion_frames as mf
    from shellsim.film.cameras import CameraSettings, mass_weights, motion_track
    from shellsim.film.renderer import DeformedRenderer
    from shellsim.motion.read import iter_frames, read_motion_info
    from shellsim.tetcage.store import cage_for_motion
    from shellsim.world import UP

    info = read_motion_info(motion)
    track = motion_track(
        iter_frames(motion, range(info.n_frames)), mass_weights(info.rest_vertices, info.tets), info.times
    )
    shot = CameraSettings().shot(track, size, size, up=UP)
    asset = load_asset("lego")
    renderer = DeformedRenderer(
        asset,
        load_field(asset, "cpu"),
        cage_for_motion(asset, info, motion),
        "cpu",
        None,
        *mf.motion_world(info, None),
    )
    positions = mf.motion_frames(info, motion)
    ks = np.linspace(0, info.n_frames - 1, count).round().astype(int)
    return renderer, [(mf.asset_camera(info, shot.camera_for_frame(k)), positions(k)) for k in ks]


def best_of(repeats: int, render):
    """(the least wall ms of ``repeats`` calls of ``render()``, its last result)."""
    times, out = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        out = render()
        times.append(1000.0 * (time.perf_counter() - start))
    return min(times), out


def sweeps(repeats: int, jobs, render) -> list:
    """Per job, (the least wall ms of ``render(job)`` over ``repeats`` sweeps over every job, the result of
    that render): the frames in order, as a shot renders them (an orbit's views never repeat)."""
    best = [(np.inf, None)] * len(jobs)
    for _ in range(repeats):
        for j, job in enumerate(jobs):
            start = time.perf_counter()
            out = render(*job)
            ms = 1000.0 * (time.perf_counter() - start)
            best[j] = min(best[j], (ms, out), key=lambda pair: pair[0])
    return best


def main_shot(motion: Path, size: int, count: int, repeats: int) -> None:
    """Sections 1 and 2 of the module docstring."""
    import neural.render.view as view_module
    from neural.metrics import psnr
    from shellsim.film.antialias import adaptive, antialiased
    from shellsim.film.cameras import MOTION_ANTIALIAS

    renderer, jobs = motion_frames(motion, size, count)
    renderer.tracer(jobs[0][1])(jobs[0][0])  # builds the Warp meshes and the inverse map, compiles kernels

    def final(view, positions):
        timed = Timed(renderer.tracer(positions))
        image, stats = adaptive(timed, MOTION_ANTIALIAS)(view)
        return image, stats, timed

    def full(view, positions):
        trace = renderer.tracer(positions)

        def render(v):
            colors, stats = trace(v)
            return colors.numpy().reshape(size, size, 3), stats

        return antialiased(render, MOTION_ANTIALIAS)(view)[0]

    adaptive_runs, full_runs = sweeps(repeats, jobs, final), sweeps(repeats, jobs, full)
    uncut = functools.partial(view_module.bodies_transmittance, cutoff=0.0)
    kept, view_module.bodies_transmittance = view_module.bodies_transmittance, uncut
    try:
        uncut_runs = sweeps(repeats, jobs, full)
    finally:
        view_module.bodies_transmittance = kept
    stages = ("build", "sample", "map", "shade", "static", "world", "shadow")
    split = {s: [timed.first[f"{s}_ms"] for _, (_, _, timed) in adaptive_runs] for s in stages}
    split["antialias"] = [timed.more_ms for _, (_, _, timed) in adaptive_runs]
    print(f"the main shot, {size}x{size}, {MOTION_ANTIALIAS} rays per pixel, {len(jobs)} frames:")
    rows = {"adaptive": adaptive_runs, "full": full_runs, "full, shadows uncut": uncut_runs}
    for label, runs in rows.items():
        times = [ms for ms, _ in runs]
        spread = f"{min(times):.0f}-{max(times):.0f}"
        print(f"  {label}: {statistics.median(times):.0f} ms a frame (median; {spread})")
    total = sum(statistics.median(v) for v in split.values())
    print("  where an adaptive frame's time goes (medians; the first pass's stages, then the other passes):")
    for s, v in split.items():
        print(f"    {s}: {statistics.median(v):.0f} ms ({statistics.median(v) / total:.0%})")
    quality = [
        (psnr(image, whole), stats["refined"], stats["rays_per_pixel"])
        for (_, (image, stats, _)), (_, whole) in zip(adaptive_runs, full_runs, strict=True)
    ]
    psnrs, refined, rays = (np.array(q) for q in zip(*quality, strict=True))
    print(
        f"  adaptive against full supersampling: {psnrs.min():.1f}-{psnrs.max():.1f} dB, "
        f"{refined.mean():.1%} of the pixels refined, {rays.mean():.2f} rays per pixel",
        flush=True,
    )


def film(renderer, cages, view):
    """A final frame of a scene: (image, stats)."""
    from shellsim.film.antialias import adaptive
    from shellsim.film.cameras import MOTION_ANTIALIAS

    return adaptive(renderer.tracer(cages), MOTION_ANTIALIAS)(view)


def scene_frames(work: Path, size: int, count: int, repeats: int) -> None:
    """Section 3 of the module docstring."""
    from shellsim.film.cameras import scene_shot
    from shellsim.film.shot_frames import scene_camera, scene_renderer, scene_tracks
    from shellsim.film.world import look_of
    from shellsim.jobs.scene import SceneSettings, scene
    from shellsim.motion.read import read_frames
    from shellsim.shot.recorded import read_scene_motion

    ramp = work / "lego_ramp.toml"
    ramp.write_text(RAMP.format(meshes=EXAMPLES / "meshes"))
    for path in (EXAMPLES / "lego_on_bunny.toml", ramp):
        out = work / path.stem
        scene(SceneSettings(scene=str(path), out=str(out), frames=count), progress=False)
        motion = read_scene_motion(out)
        look = look_of(motion.look, True)
        placements = {b.name: b.placement for b in motion.bodies}
        shot = scene_shot(scene_camera(motion, None), scene_tracks(motion), size, size, placements)
        neural = [b for b in motion.bodies if b.asset is not None]
        figures = {}
        for label, budget in (("kept", None), ("drawn every frame", 0)):
            renderer = scene_renderer(motion, "cpu", look)
            if budget is not None:
                renderer.static.budget = budget
            times, static_ms = [], []
            for k in range(motion.info.n_frames):
                positions = read_frames(motion.path, [k])[0]
                cages = [b.placement.to_asset(positions[b.vertices]) for b in neural]
                render = functools.partial(film, renderer, cages, shot.camera_for_frame(k))
                ms, (_, stats) = best_of(repeats if k >= 2 else 1, render)
                if k >= 2:  # the first frame draws its rays' layer, the second the whole view's
                    times.append(ms)
                    static_ms.append(stats["static_ms"])
            figures[label] = statistics.median(times)
            frames = f"frames 2-{motion.info.n_frames - 1}"
            print(
                f"  {path.stem}, static world {label}: {figures[label]:.0f} ms a frame, of which "
                f"{statistics.median(static_ms):.0f} ms its static layer ({frames})",
                flush=True,
            )
        print(f"  {path.stem}: {figures['kept'] / figures['drawn every frame']:.2f}x the time", flush=True)


def before_after(motion: Path, before: Path, work: Path, size: int, count: int, repeats: int) -> None:
    """Section 4 of the module docstring."""
    frames = f"{24 - count // 2}:{24 + (count + 1) // 2}"
    command = ["render", "--asset", "lego", "--motion", str(motion), "--frames", frames]
    command += ["--width", str(size), "--height", str(size), "--overwrite", "--device", "cpu"]
    figures = {"before": [], "after": []}
    for _ in range(repeats):
        for label, tree in (("before", before), ("after", ROOT)):
            said = shellsim(*command, "--out", str(work / f"frames_{label}"), tree=tree)
            figures[label].append(float(re.search(r"(\d+) ms/frame", said).group(1)))
    print(f"shellsim {' '.join(command)} --out DIR:")
    for label, ms in figures.items():
        tree = before if label == "before" else ROOT
        print(f"  {label} ({tree}): {', '.join(f'{m:.0f}' for m in ms)} ms a frame")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", type=Path, default=Path("final_frame_bench"), help="where motions are kept")
    parser.add_argument("--frames", type=int, default=6, help="frames rendered of each shot (default 6)")
    parser.add_argument("--size", type=int, default=512, help="square frame size in pixels (default 512)")
    parser.add_argument("--repeats", type=int, default=3, help="renders of each frame, the least kept")
    parser.add_argument("--scenes", action="store_true", help="also the static world of fixed-camera scenes")
    parser.add_argument("--before", type=Path, metavar="TREE", help="also time the command with this code")
    args = parser.parse_args()
    from neural.device import configure_process

    configure_process()
    args.work.mkdir(parents=True, exist_ok=True)
    motion = main_motion(args.work)
    main_shot(motion, args.size, args.frames, args.repeats)
    if args.scenes:
        print(f"scenes by a fixed camera, {args.size}x{args.size}:")
        scene_frames(args.work, args.size, args.frames, args.repeats)
    if args.before:
        before_after(motion, args.before, args.work, args.size, args.frames, args.repeats)


if __name__ == "__main__":
    main()
