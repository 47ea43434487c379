"""The viewer's neural picture (shellsim.view.picture.NeuralPicture) on a shipped scene's bodies at rest:
seconds to the first picture, pictures per second while the camera moves (low resolution), while the bodies
move too (every request new cage positions), and when it rests (refined), and what each picture costs.

    python bench/view_bench.py [--scene examples/scenes/lego_on_bunny.toml] [--device cpu] [--seconds 5]

Cages and collision surfaces come from the cache (~/.cache/shellsim) after their first build.
"""

from __future__ import annotations

import argparse
import math
import threading
import time

import numpy as np


def orbit(eye, target, angle: float) -> np.ndarray:
    """``eye`` (3,) turned by ``angle`` radians about the vertical through ``target``."""
    c, s = math.cos(angle), math.sin(angle)
    d = np.asarray(eye, np.float64) - target
    return target + np.array([c * d[0] - s * d[1], s * d[0] + c * d[1], d[2]])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="examples/scenes/lego_on_bunny.toml")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--seconds", type=float, default=5.0, help="of camera motion")
    parser.add_argument("--rate", type=float, default=30.0, help="camera requests per second while moving")
    parser.add_argument("--low-side", type=int, default=80)
    parser.add_argument("--max-side", type=int, default=512)
    parser.add_argument("--antialias", type=int, default=4)
    parser.add_argument("--no-moving-shadows", action="store_true")
    args = parser.parse_args()

    from neural.device import configure_process
    from shellsim.shot.bodies import build_body
    from shellsim.shot.file import read_scene
    from shellsim.view.picture import FINAL, FULL, NeuralPicture, PictureSettings, Pinhole

    configure_process()
    spec = read_scene(args.scene)
    tick = time.perf_counter()
    lift = 0.5 * spec.world.contact_gap if spec.world.ground else -np.inf
    bodies = [build_body(b, lift) for b in spec.bodies]
    built = time.perf_counter() - tick
    settings = PictureSettings(
        low_side=args.low_side,
        max_side=args.max_side,
        antialias=args.antialias,
        moving_shadows=not args.no_moving_shadows,
    )
    tick = time.perf_counter()
    picture = NeuralPicture.from_bodies(spec, bodies, args.device, settings=settings)
    made = time.perf_counter() - tick
    rest = np.concatenate([b.rest for b in bodies])
    camera = spec.cameras[0] if spec.cameras else None
    eye = np.array(camera.position if camera else (0.6, -0.65, 0.55), np.float64)
    target = np.array(camera.target if camera else (0.0, 0.0, 0.2), np.float64)
    fov, aspect, size = math.radians(50.0), 16 / 9, (1280, 720)

    def view(angle: float) -> Pinhole:
        return Pinhole.looking_at(orbit(eye, target, angle), target, fov, aspect, size=size)

    got = []
    arrived = threading.Event()

    def on_picture(rgb, depth):
        got.append((time.perf_counter(), rgb.shape))
        arrived.set()

    print(f"scene {args.scene}: {len(bodies)} bodies, {len(rest)} cage vertices, device {args.device}")
    print(f"bodies built (cached cages) {built:.2f} s; picture made (fields loaded) {made:.2f} s")
    low, full = view(0.0).pixels(args.low_side), view(0.0).pixels(args.max_side)
    print(f"low {low[0]}x{low[1]}, refined {full[0]}x{full[1]} with {args.antialias} rays per pixel")

    print("here and now (this thread, before the picture's thread starts):")
    for name, (w, h), rays in (("low", low, 1), ("refined", full, 1), ("anti-aliased", full, args.antialias)):
        times = []
        for k in range(3 if name == "low" else 1):
            tick = time.perf_counter()
            picture.render(view(0.01 * k), rest, w, h, rays)
            times.append(time.perf_counter() - tick)
        best = min(times)
        print(f"  {name} {w}x{h} x{rays}: {best:.3f} s ({1 / best:.1f} pictures/s)")

    start = time.perf_counter()
    picture.request(view(0.0), rest, on_picture)
    arrived.wait()
    print(f"first picture (low, frame built): {got[0][0] - start:.3f} s")
    while not any(s == FINAL for _, s, _ in picture.stages):
        time.sleep(0.05)
    by_stage = {s: t for g, s, t in picture.stages if g == picture.generation}
    print(
        f"still, first request: full {by_stage.get(FULL, math.nan):.2f} s, "
        f"final {by_stage.get(FINAL, math.nan):.2f} s after the request"
    )

    def moving(positions_of) -> tuple[int, float]:
        """(requests made, pictures delivered a second) while the camera turns ``args.rate`` times a second,
        the cages at ``positions_of(n)`` for the n-th request."""
        got.clear()
        start = time.perf_counter()
        n = 0
        while time.perf_counter() - start < args.seconds:
            picture.request(view(0.02 * n), positions_of(n), on_picture)
            n += 1
            time.sleep(max(0.0, start + n / args.rate - time.perf_counter()))
        return n, len([t for t, _ in got if t <= start + args.seconds]) / args.seconds

    n, rate = moving(lambda n: rest)
    lows = sum(1 for _, shape in got if max(shape[:2]) == max(low))
    print(
        f"moving ({n} requests over {args.seconds:g} s): {rate:.1f} pictures/s, "
        f"{lows} of {len(got)} low resolution"
    )
    # the cages moved a little each time
    n, rate = moving(lambda n: rest + np.array([0.0, 0.0, 0.002 * math.sin(0.5 * n)]))
    print(f"moving with the bodies ({n} requests, new positions each): {rate:.1f} pictures/s")
    last = picture.generation
    while not any(g == last and s == FINAL for g, s, _ in picture.stages):
        time.sleep(0.05)
    by_stage = {s: t for g, s, t in picture.stages if g == last}
    print(
        f"stopped: refined (1 ray) {by_stage.get(FULL, math.nan):.2f} s, anti-aliased "
        f"{by_stage.get(FINAL, math.nan):.2f} s after the last request"
    )
    picture.close()


if __name__ == "__main__":
    main()
