"""From a real capture to a shot of its object wobbling in its own room (paper Sec. 4.7 and 5, issue 43).

1. ``shellsim train`` on photos without alpha: the field lives in contracted space, so the room around the
   object is learnt with it (OUT/capture);
2. ``shellsim cut``: the object cut out, by the supporting plane found in the field (a table, else a wall)
   and the surface the cameras look at: a body with its own shells, the rest of the field its backdrop
   (OUT/body);
3. a scene file (OUT/shot.toml): the body as jelly, its base pinned to its table (or its back to the wall
   it hangs on), its top (or front) pulled aside and let go, seen along the capture's own camera path (a
   ``capture`` camera, smoothed);
4. ``shellsim scene`` simulates it and ``shellsim render --scene`` draws the frames and an MP4
   (OUT/shot.mp4) at the capture's aspect.

Each step is skipped when its output is there, so a run that stopped goes on. Nothing trained on a capture
you may not redistribute (the shared fox) should be shipped: OUT is yours.

    python examples/real_capture.py --data ../shared/data/fox --out /tmp/fox_shot
    python examples/real_capture.py --data DATA --steps 3000 --downscale 8 --frames 48 --width 270
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np

from neural.asset import load_asset
from neural.device import configure_process
from neural.errors import ShellsimError
from neural.shell.cutout import is_table
from shellsim.cli.main import main as shellsim
from shellsim.world import up_rotation

SHOT = """# {name} cut out of its capture: jelly where it rests, seen along the capture's cameras.
[world]
duration = {duration}
substeps = 4

[[body]]
name = "object"
asset = "body"
material = "jelly"
size = {size}
position = [0, 0, 0]
damping = 0.01

[[action]]
kind = "pin"
body = "object"
region = ["{pin}"]

[[action]]
kind = "grab"
body = "object"
region = ["{grab}"]
start = 0.0
end = {release}
keyframes = [{{ time = {release}, position = {pull} }}]

[[camera]]
name = "capture"
kind = "capture"
path = "{cameras}"
smooth = 2
"""


def main(argv: list[str] | None = None) -> Path:
    """Run the example; returns the MP4's path."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", required=True, help="the capture: transforms.json or COLMAP, photos")
    parser.add_argument("--out", default="real_capture", help="output directory (default real_capture)")
    parser.add_argument("--steps", type=int, default=3000, help="stage-1 training steps (default 3000)")
    parser.add_argument("--downscale", type=int, default=8, help="photo downscale (default 8)")
    parser.add_argument("--frames", type=int, default=48, help="frames of the shot (default 48, 2 s)")
    parser.add_argument("--width", type=int, default=270, help="frame width; height by the photos' aspect")
    parser.add_argument("--size", type=float, default=0.2, help="the object's size in metres (default 0.2)")
    parser.add_argument("--device", default="auto", help="cpu, cuda or auto (default)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    out = Path(args.out).resolve()
    data = Path(args.data).resolve()
    device = ["--device", args.device]
    capture, body, scene, video = out / "capture", out / "body", out / "shot", out / "shot.mp4"
    if not (capture / "asset.json").is_file() or (capture / "checkpoints").is_dir():
        train = ["train", "--data", str(data), "--out", str(capture), "--downscale", str(args.downscale)]
        _run([*train, "--steps", str(args.steps), *device])
    if not (body / "asset.json").is_file():
        _run(["cut", "--asset", str(capture), "--out", str(body), *device])
    cameras = data / "transforms.json" if (data / "transforms.json").is_file() else data
    duration = (args.frames - 1) / 24.0
    pin, grab, aside = holds(load_asset(body))
    text = SHOT.format(
        name=data.name,
        duration=round(duration, 4),
        size=args.size,
        pin=pin,
        grab=grab,
        release=round(duration / 4, 4),
        pull=[round(0.15 * args.size * float(a), 4) for a in aside],
        cameras=cameras.as_posix(),
    )
    (out / "shot.toml").write_text(text)
    _run(["scene", str(out / "shot.toml"), "--out", str(scene), *device])
    from neural.data import load_camera_file

    photos = load_camera_file(cameras)
    height = round(args.width * float(photos.height[0]) / float(photos.width[0]) / 2) * 2
    render = ["render", "--scene", str(scene), "--scene-camera", "capture", "--out", str(out / "frames")]
    _run([*render, "--width", str(args.width), "--height", str(height), "--video", str(video), *device])
    return video


def holds(body) -> tuple[str, str, np.ndarray]:
    """Where the cut ``body`` (an :class:`neural.asset.Asset`) is pinned, where it is grabbed (regions of
    the scene file) and the world direction (3,) it is pulled along: an object on its table (or with no
    plane) by its base and its top, pulled along x; one hanging on its wall by its back part against the wall
    and the side away from it, pulled sideways along the wall."""
    cut = body.cut
    if cut.normal is None or is_table(cut.normal, body.up):
        return "z<10%", "z>75%", np.array([1.0, 0.0, 0.0])
    away = up_rotation(body.up) @ cut.normal  # the wall's normal in the world (the body is placed up)
    axis = int(np.argmax(np.abs(away[:2])))
    name, aside = "xy"[axis], np.eye(3)[1 - axis]  # pulled along the other horizontal axis
    if away[axis] > 0:  # the back 40%: the plaque and the neck, a jelly cantilever sags from less
        return f"{name}<40%", f"{name}>75%", aside
    return f"{name}>60%", f"{name}<25%", aside


def _run(argv: list[str]) -> None:
    """``shellsim ARGV``; a non-zero exit ends the example with it."""
    code = shellsim(argv)
    if code:
        raise SystemExit(code)


if __name__ == "__main__":
    configure_process()
    try:
        main()
    except ShellsimError as err:
        raise SystemExit(f"real_capture: error: {err}") from None
