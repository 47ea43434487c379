"""The scene job: a shot of several bodies, static colliders and timed actions, read from a scene file.

The file (:mod:`shellsim.shot.file`, schema in docs/scene-file.md) is read and checked before anything
heavy runs; then the shot is made to move (:class:`shellsim.shot.simulation.SceneSimulation`: every body's
cage and collision surface loaded or built and placed, the first instant checked, one implicit solve over
every body per substep with incremental potential contact and the timed actions) and its frames recorded
(:mod:`shellsim.jobs.recording`). ``shellsim simulate`` is the one-body case (:mod:`shellsim.jobs.simulate`).

The motion (``OUT/motion.npz``, format 3, :mod:`shellsim.motion.format`) holds the cages of all bodies one
after the other, and their collision surfaces as its surface; its header's ``asset`` lists the ``bodies``
(name, source, cage digest in the asset's frame, placement, vertex and tet ranges) and its ``settings`` are
the whole scene as read (world, bodies, colliders, actions, cameras). ``frames`` shortens the shot; a later
run with more frames, or after an interruption, continues the motion when the scene is unchanged, and refuses
a changed one unless ``overwrite``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from pathlib import Path

from shellsim.errors import SettingError
from shellsim.film.cameras import MOTION_ANTIALIAS, VIDEO_SIZE, check_antialias
from shellsim.film.motion_frames import QUALITIES
from shellsim.io.outputs import check_writable_file, holds_outputs
from shellsim.motion.format import MAX_FRAMES
from shellsim.settings import (
    allow_stretch_option,
    check_choice,
    check_range,
    device_setting,
    max_stretch_option,
    option,
    overwrite_option,
    resume_option,
)

log = logging.getLogger(__name__)

PRODUCER = "shellsim scene"
#: What a run that leaves the valid regime is told to try.
ADVICE = "try more substeps, stiffer materials or slower bodies"
#: [m/s] A body whose fastest vertex is faster at the end of the shot is said to be still moving.
STILL_MOVING = 0.01


@dataclass(frozen=True)
class SceneSettings:
    """What :func:`scene` does."""

    scene: str = option(help="the scene file (TOML; its schema is in docs/scene-file.md)", required=True)
    out: str | None = option(
        help="output directory: motion.npz (the shot's motion)", shown_default="the scene file without .toml"
    )
    frames: int | None = option(
        help="simulate only the shot's first N frames (frame 0 the initial state), for a quick look",
        shown_default="the scene's",
    )
    video: str | None = option(
        help="also render the shot to this MP4 (frames in OUT/frames, --width x --height, anti-aliased), "
        "seen by the scene's --camera; 'shellsim render --scene OUT' renders other cameras"
    )
    camera: str | None = option(
        help="with --video: the scene file's [[camera]] of this name",
        shown_default="its first, or a three-quarter orbit framed to the bodies",
        metavar="NAME",
    )
    width: int | None = option(help="with --video: image width", shown_default=f"{VIDEO_SIZE[0]}")
    height: int | None = option(help="with --video: image height", shown_default="as --width")
    antialias: int | None = option(
        help="with --video: jittered rays per pixel, averaged (1: one ray through each pixel's centre)",
        shown_default=f"{MOTION_ANTIALIAS}",
    )
    quality: str = option(
        "final",
        help="with --video: final (the size asked for, anti-aliased, with shadows), or preview: half the "
        "size, one ray per pixel, no shadows (a look at the whole shot in seconds)",
        choices=QUALITIES,
    )
    max_stretch: float = max_stretch_option()
    allow_stretch: bool = allow_stretch_option()
    resume: bool = resume_option()
    overwrite: bool = overwrite_option()
    device: str = option("auto", help="auto, cpu or cuda")

    def __post_init__(self):
        if self.frames is not None:
            check_range("frames", self.frames, 1, MAX_FRAMES, "an integer")
        check_range("max_stretch", self.max_stretch, 1, math.inf, "a principal stretch", "(]")
        if self.camera is not None and self.video is None:
            raise SettingError("camera", "chooses the camera of {video}")
        check_choice("quality", self.quality, QUALITIES)
        for name in ("quality", "width", "height", "antialias"):
            if getattr(self, name) not in (None, "final") and self.video is None:
                raise SettingError(name, "sets how {video} is rendered")
        for name in ("width", "height"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise SettingError(name, f"expected a positive size, got {value}")
        if self.antialias is not None:
            check_antialias(self.antialias)
            if self.quality == "preview":
                raise SettingError("antialias", "not with {quality} preview (one ray per pixel)")

    def size(self) -> tuple[int, int]:
        """(W, H) of the video's frames: a side not given is the other's, both default 512."""
        side = self.width or self.height or VIDEO_SIZE[0]
        return (self.width or side, self.height or side)

    @property
    def out_dir(self) -> Path:
        scene = Path(self.scene)
        return Path(self.out) if self.out else scene.with_suffix("")


@dataclass
class SceneResult:
    """out : the motion file; frames : its frame count; history : the
    :class:`shellsim.physics.driver.FrameStats` of the frames simulated now; bodies : their names; video :
    the :class:`shellsim.film.result.RenderResult` of its frames and video (None without one)."""

    out: Path
    frames: int
    history: list
    bodies: list[str]
    video: object = None


def scene_record(spec) -> dict:
    """The scene as the motion records it: every table, the file's path left out."""
    record = dataclasses.asdict(spec)
    record.pop("path")
    return record


def simulated_part(record: dict) -> dict:
    """What of a :func:`scene_record` the motion depends on: all but the cameras, the look and the colours
    of bodies and colliders; a record made before ``[world] settle`` and ``integrator`` existed settled for
    0 s and integrated by backward Euler."""
    part = {k: v for k, v in record.items() if k not in ("cameras", "look")}
    part["world"] = {"settle": 0.0, "integrator": "euler", **part.get("world", {})}
    for table in ("bodies", "colliders"):
        part[table] = [{k: v for k, v in e.items() if k != "color"} for e in part.get(table, [])]
    return part


@holds_outputs
def scene(settings: SceneSettings, progress: bool = True) -> SceneResult:
    """Simulate the shot of ``settings.scene`` into ``settings.out_dir`` (module docstring)."""
    from shellsim.io.outputs import check_writable_dir, lock_output
    from shellsim.jobs.recording import record_frames, resume_or_refuse
    from shellsim.memory import check_memory, render_bytes
    from shellsim.motion.writer import MotionWriter
    from shellsim.shot.file import read_scene
    from shellsim.shot.simulation import SceneSimulation

    s = settings
    spec = read_scene(s.scene)  # every error of the file, before anything heavy or written
    frames = s.frames or spec.world.frames
    device = device_setting(s.device, warp=True)
    if s.camera is not None and s.camera not in {c.name for c in spec.cameras}:
        known = ", ".join(c.name for c in spec.cameras) or "none"
        raise SettingError("camera", f"{spec.path}: no [[camera]] named {s.camera!r} (it has: {known})")
    out_dir = lock_output(check_writable_dir(s.out_dir, "out"), "out")
    if s.video is not None:
        lock_output(check_writable_file(s.video, "video"), "video")
        width, height = s.size()
        frame = f"a frame of {width}x{height} pixels"
        check_memory("width", render_bytes(width, height), frame, "to render", device)
    out = out_dir / "motion.npz"
    record = scene_record(spec)
    names = [b.name for b in spec.bodies]
    writer = resume_or_refuse(
        out,
        PRODUCER,
        record,
        s.overwrite,
        s.resume,
        compared=simulated_part,
        changed="made from another scene",
    )
    if writer is not None and writer.n_frames >= frames:
        log.info("%s already holds %d frames", out, writer.n_frames)
        writer.close()
        return SceneResult(out, writer.n_frames, [], names, _video(s, spec, out_dir, frames, progress))

    sim = SceneSimulation(spec, device, s.max_stretch, s.allow_stretch)
    if writer is None:
        writer = MotionWriter(
            out,
            sim.rest,
            sim.tets,
            surface=sim.surface(),
            producer=PRODUCER,
            settings=record,
            asset={"bodies": sim.body_records()},
        )
        settled = _settle(sim, progress)
        if settled:
            writer.motion.meta["settle"] = settled
    else:
        _check_bodies(writer.motion, sim.bodies, out)
        sim.restore(writer.last_positions, writer.last_time, writer.motion.state, str(out))
    with writer:
        history = record_frames(
            writer,
            frames,
            sim.advance,
            sim.snapshot,
            advice=lambda err: f"{spec.path}: {ADVICE}",
            desc="scene",
            progress=progress,
        )
    speeds = sim.speeds()
    fastest = max(speeds, key=speeds.get)
    if speeds[fastest] > STILL_MOVING:
        log.info("still moving at the end: body %s at %.3g m/s", fastest, speeds[fastest])
    return SceneResult(out, writer.n_frames, history, names, _video(s, spec, out_dir, frames, progress))


def _settle(sim, progress: bool) -> dict:
    """Settle ``sim`` (:meth:`shellsim.shot.simulation.SceneSimulation.settle`) with a progress bar; a frame
    that leaves the valid regime is one :class:`SettingError` line (nothing is written yet)."""
    from tqdm.auto import tqdm

    from shellsim.physics.driver import SimulationError

    if not sim.settle_frames:
        return {}
    with tqdm(total=sim.settle_frames, disable=not progress, unit="frame", desc="settle") as bar:
        try:
            settled = sim.settle(lambda stats: bar.update())
        except SimulationError as err:
            raise SettingError(
                None, f"{sim.spec.path}: settling: {err}; nothing was written; {ADVICE}"
            ) from None
    log.info(
        "settled for %g s before frame 0 (%d frames); fastest vertex then %.3g m/s",
        settled["seconds"],
        settled["frames"],
        settled["max_speed"],
    )
    return settled


def _video(settings: SceneSettings, spec, out_dir: Path, frames: int, progress: bool):
    """The frames of the shot's first ``frames`` frames in ``out_dir/frames`` and ``settings.video``, seen by
    the scene file's camera ``settings.camera`` in its look, as the file says them now; None without a
    video."""
    if settings.video is None:
        return None
    from shellsim.film.shot_frames import render_scene

    return render_scene(
        out_dir,
        out_dir / "frames",
        settings.camera,
        frames=f"0:{frames}",
        size=settings.size(),
        antialias=settings.antialias or MOTION_ANTIALIAS,
        video=settings.video,
        device=settings.device,
        overwrite=settings.overwrite,
        progress=progress,
        spec=spec,
        quality=settings.quality,
    )


def _check_bodies(motion, bodies, out: Path) -> None:
    """Refuse to continue ``motion`` when a body's source or cage changed since it was made."""
    for old, body in zip(motion.asset.get("bodies", []), bodies, strict=False):
        if (
            old.get("source", {}).get("digest") != body.source["digest"]
            or old.get("cage") != body.cage_digest
        ):
            raise SettingError(
                "out",
                f"made with another content or cage of body '{body.name}' (changed since); give "
                "{overwrite} to start it anew, or another {out}",
                out,
            )
