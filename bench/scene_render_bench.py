"""Frames of scenes: the cost of several bodies with a lit ground and shadows, how dark their shadows are, how
close a resting body's visible bottom is drawn to the ground, and the wall time of every example's video.

    python bench/scene_render_bench.py [--frames N] [--size 512] [--videos DIR]

1. **Cost.** The LEGO-on-bunny scene (``examples/scenes/lego_on_bunny.toml``, its first ``--frames`` frames
   simulated here) rendered at ``--size`` x ``--size`` by its own camera, with the ground and shadows,
   against each body alone without them (no ground, no sky, no shadow rays), one ray per pixel, median ms per
   frame over the frames. Goal (issue "Frames worth watching"): at most 2.5x the one body alone.
2. **Shadows.** The light that ground points receive, as a share of open ground's ``ambient + diffuse l_z``:
   under the bunny's body and the LEGO (the least of the points' visibility through the fields, the
   :func:`~neural.render.view.bodies_transmittance` of shadow rays, on a 1 mm grid around each body), and the
   share of the shadow that is partial (0.05 < V < 0.95): a translucent fur fringe against a hard solid edge.
3. **No gap.** The LEGO resting on the ground (a scene of it alone, settled for ``--frames`` frames), seen
   from the side at ground level at ``--size`` pixels: in every column where its visible bottom meets the
   horizon, the rows of sky between its lowest pixel and the ground. Goal: at most 1.
4. ``--videos DIR``: the wall time of ``shellsim scene EXAMPLE --out DIR/EXAMPLE --video DIR/EXAMPLE.mp4``
   for every example scene (the whole shot simulated and filmed at 512x512 with 4 rays per pixel; run again,
   only what is missing is done), and three stills of each to ``docs/scenes/EXAMPLE.png``
   (:data:`STILL_FRAMES`).

A quiet machine, one job at a time.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples" / "scenes"
STILLS = ROOT / "docs" / "scenes"
#: The three frames of each example shown in the README: its start, the moment that shows what it is about,
#: and where it ends up (the shaken bunny at its first three swings).
STILL_FRAMES = {
    "lego_on_bunny": (0, 12, 44),
    "bunny_shaken": (5, 11, 17),
    "ramp_into_tray": (0, 22, 44),
    "head_on": (0, 5, 17),
}


def simulate(scene: Path, out: Path, frames: int | None) -> Path:
    from shellsim.jobs.scene import SceneSettings
    from shellsim.jobs.scene import scene as run_scene

    run_scene(SceneSettings(scene=str(scene), out=str(out), frames=frames), progress=False)
    return out


def renderer_of(scene, bodies, look):
    """A :class:`SceneRenderer` of the neural bodies named ``bodies`` of ``scene`` (``look`` None: no
    world)."""
    from neural.asset import load_field
    from shellsim.film.renderer import DeformedRenderer, SceneRenderer
    from shellsim.film.shot_frames import scene_world

    renderers = [
        DeformedRenderer(b.asset, load_field(b.asset, "cpu"), b.cage, "cpu", placement=b.placement)
        for b in scene.bodies
        if b.name in bodies
    ]
    if look is None:
        return SceneRenderer(renderers)
    return SceneRenderer(renderers, *scene_world(scene, look))


def frame_cages(scene, positions, bodies):
    return [b.placement.to_asset(positions[b.vertices]) for b in scene.bodies if b.name in bodies]


def cost(out: Path, size: int) -> dict:
    """Median ms per frame of the scene with its world, and of each body alone without one."""
    from shellsim.film.cameras import scene_shot
    from shellsim.film.shot_frames import scene_camera, scene_tracks
    from shellsim.motion.read import read_frames
    from shellsim.shot.recorded import read_scene_motion
    from shellsim.world import WorldLook

    scene = read_scene_motion(out)
    placements = {b.name: b.placement for b in scene.bodies}
    shot = scene_shot(scene_camera(scene, None), scene_tracks(scene), size, size, placements)
    names = [b.name for b in scene.bodies]
    runs = {"scene, ground and shadows": (names, WorldLook())}
    runs.update({f"{name} alone, no world": ([name], None) for name in names})
    figures = {}
    for label, (bodies, look) in runs.items():
        renderer = renderer_of(scene, bodies, look)
        warm = read_frames(scene.path, [0])[0]  # the first frame builds what the next ones refit
        renderer.render(shot.camera_for_frame(0), 0, frame_cages(scene, warm, bodies))
        times, spp = [], []
        for k in range(scene.info.n_frames):
            positions = read_frames(scene.path, [k])[0]
            _, stats = renderer.render(shot.camera_for_frame(k), 0, frame_cages(scene, positions, bodies))
            times.append(stats["ms"])
            spp.append(stats["samples_per_pixel"])
        figures[label] = (statistics.median(times), float(np.mean(spp)))
        print(
            f"  {label}: {figures[label][0]:.0f} ms/frame, {figures[label][1]:.2f} samples/pixel", flush=True
        )
    scene_ms = figures["scene, ground and shadows"][0]
    for name in names:
        print(
            f"  ratio to {name} alone: {scene_ms / figures[f'{name} alone, no world'][0]:.2f}x (goal <= 2.5)"
        )
    return figures


REST = """
[world]
fps = 30
frames = {frames}
substeps = 4

[[body]]
name = "{name}"
asset = "{asset}"
material = "rubber"
size = 0.3
"""


def shadows(out: Path) -> None:
    """Light received by ground points around a one-body scene's body at its last frame (module docstring)."""
    import torch

    from neural.render.view import bodies_transmittance
    from shellsim.motion.read import read_frames
    from shellsim.shot.recorded import read_scene_motion
    from shellsim.world import WorldLook

    scene = read_scene_motion(out)
    (body,) = scene.bodies
    look = WorldLook()
    light = look.light_unit()
    open_light = look.ambient + look.diffuse * light[2]
    positions = read_frames(scene.path, [scene.info.n_frames - 1])[0]
    (renderer,) = renderer_of(scene, [body.name], None).bodies
    field_body = renderer.field_body(body.placement.to_asset(positions[body.vertices]))
    cage = positions[body.vertices]
    lo, hi = cage.min(0), cage.max(0)
    reach = hi[2] * np.hypot(light[0], light[1]) / light[2]  # how far the shadow falls
    xs = np.arange(lo[0] - reach, hi[0] + reach, 1e-3)
    ys = np.arange(lo[1] - reach, hi[1] + reach, 1e-3)
    grid = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1).reshape(-1, 2)
    origins = torch.tensor(np.concatenate([grid, np.full((len(grid), 1), 1e-6)], 1), dtype=torch.float32)
    dirs = torch.tensor(light, dtype=torch.float32).expand(len(grid), 3).contiguous()
    visible = bodies_transmittance([field_body], origins, dirs).numpy()
    received = (look.ambient + look.diffuse * light[2] * visible) / open_light
    shadow = visible < 0.95
    soft = (visible > 0.05) & shadow
    print(
        f"  {body.name}: darkest ground {received.min():.1%} of open ground's light; {shadow.sum()} mm^2 of "
        f"shadow, {soft.sum() / max(shadow.sum(), 1):.1%} of it partial (0.05 < V < 0.95; mean light there "
        f"{received[soft].mean() if soft.any() else float('nan'):.1%})",
        flush=True,
    )


def no_gap(out: Path, size: int) -> None:
    """Rows of sky between a resting body's visible bottom and the ground, seen from the side at ground
    level (module docstring), at its last frame."""
    from neural.data import camera_rays, look_at
    from shellsim.film.cameras import Shot
    from shellsim.film.ground import sky
    from shellsim.motion.read import read_frames
    from shellsim.shot.recorded import read_scene_motion
    from shellsim.world import WorldLook

    scene = read_scene_motion(out)
    (body,) = scene.bodies
    positions = read_frames(scene.path, [scene.info.n_frames - 1])[0]
    cage = positions[body.vertices]
    centre = 0.5 * (cage.min(0) + cage.max(0))
    width = float(np.max(cage.max(0) - cage.min(0)))
    eye = np.array([centre[0], centre[1] - 2.0 * width, 0.002])  # 2 mm above the ground, level
    target = np.array([centre[0], centre[1], 0.002])
    focal = 0.5 * size / np.tan(np.radians(20.0))
    view = Shot(
        look_at(eye, target, np.array([0.0, 0.0, 1.0]))[None], focal, size, size, "side"
    ).camera_for_frame(0)
    look = WorldLook()
    cages = frame_cages(scene, positions, [body.name])
    image, _ = renderer_of(scene, [body.name], look).render(view, 0, cages)
    empty, _ = renderer_of(scene, [], look).render(view, 0, [])
    _, dirs = camera_rays(view, 0)
    sky_colour = sky(look, dirs.double()).reshape(size, size, 3).numpy()
    is_body = np.abs(image - empty).max(2) > 0.05
    is_sky = np.abs(image - sky_colour).max(2) < 0.01
    # the columns of the visible surface's points within 1 mm of the ground: where the body rests
    surface = body.surface_points(positions[body.vertices])
    low = surface[surface[:, 2] < 1e-3 + surface[:, 2].min()]
    local = (low - eye) @ view.c2w[0, :3, :3]  # camera axes: x right, z back
    columns = np.unique(np.floor(view.cx[0] + view.fx[0] * local[:, 0] / -local[:, 2]).astype(int))
    pixel_mm = 1e3 * float(np.linalg.norm(eye - target)) / view.fx[0]
    gaps = []
    for column in columns[(columns >= 0) & (columns < size)]:
        rows = np.nonzero(is_body[:, column])[0]
        if not len(rows):
            continue
        below = np.nonzero(~is_sky[rows.max() + 1 :, column])[0]
        gaps.append(int(below[0]) if len(below) else size)
    print(
        f"  {body.name}: lowest visible point {1e3 * surface[:, 2].min():.2f} mm above the ground; "
        f"{len(gaps)} columns where it rests: sky rows between its visible bottom and the ground max "
        f"{max(gaps)}, mean {np.mean(gaps):.2f} ({pixel_mm:.2f} mm per pixel there; goal <= 1)",
        flush=True,
    )


def videos(root: Path) -> None:
    """Wall time of ``shellsim scene EXAMPLE --out ROOT/EXAMPLE --video ROOT/EXAMPLE.mp4`` for every example
    scene, and three stills of each (:data:`STILL_FRAMES`) to ``docs/scenes/EXAMPLE.png``."""
    from PIL import Image

    from shellsim.jobs.scene import SceneSettings
    from shellsim.jobs.scene import scene as run_scene

    STILLS.mkdir(parents=True, exist_ok=True)
    for path in sorted(EXAMPLES.glob("*.toml")):
        out = root / path.stem
        start = time.perf_counter()
        video = str(root / f"{path.stem}.mp4")
        result = run_scene(SceneSettings(scene=str(path), out=str(out), video=video), progress=False)
        wall = time.perf_counter() - start
        render = result.video
        print(
            f"  {path.stem}: {result.frames} frames simulated and filmed in {wall:.0f} s "
            f"({f'{render.ms / 1000:.1f} s per 512x512 frame, ' if render.rendered else ''}{render.rendered} "
            f"rendered, {render.skipped} already there)",
            flush=True,
        )
        picks = [out / "frames" / f"{k:05d}.png" for k in STILL_FRAMES[path.stem]]
        strip = np.concatenate([np.asarray(Image.open(f))[..., :3] for f in picks], axis=1)
        half = (strip.shape[1] // 2, strip.shape[0] // 2)
        Image.fromarray(strip).resize(half, Image.LANCZOS).save(STILLS / f"{path.stem}.png")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=6, help="frames of the simulated shots (default 6)")
    parser.add_argument("--size", type=int, default=512, help="square frame size in pixels (default 512)")
    parser.add_argument(
        "--videos", type=Path, metavar="DIR", help="also film every example scene, whole, into DIR"
    )
    args = parser.parse_args()
    from neural.device import configure_process

    configure_process()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        print(
            f"cost of a {args.size}x{args.size} frame, one ray per pixel (lego_on_bunny, {args.frames} "
            "frames):"
        )
        cost(simulate(EXAMPLES / "lego_on_bunny.toml", tmp / "lob", args.frames), args.size)
        print("shadows and contact of one body resting on the ground:")
        for name, asset in (("lego", "lego"), ("bunny", "furry_bunny")):
            scene = tmp / f"{name}.toml"
            scene.write_text(REST.format(frames=args.frames, name=name, asset=asset))
            out = simulate(scene, tmp / name, None)
            shadows(out)
            no_gap(out, args.size)
    if args.videos:
        print("example scenes filmed (shellsim scene EXAMPLE --video):")
        videos(args.videos)


if __name__ == "__main__":
    main()
