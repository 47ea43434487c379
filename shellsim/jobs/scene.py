"""The scene job: a shot of several bodies, static colliders and timed actions, read from a scene file.

The file (:mod:`shellsim.scene.file`, schema in the README) is read and checked before anything
heavy runs; then every body's cage and collision surface are loaded or built (cached), the bodies placed
(:mod:`shellsim.scene.build`) and the first instant checked (bodies overlapping each other, a collider or the
ground; a region that selects nothing). One implicit solve moves every body per substep
(:class:`shellsim.physics.multibody.SceneSolver`), with incremental potential contact between the bodies'
visible surfaces, the colliders and the ground (:mod:`shellsim.physics.ipc`), and the actions' pins, grabs,
pushes and wind (:mod:`shellsim.scene.actions`).

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
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from neural.errors import InputError
from shellsim.errors import SettingError
from shellsim.io.outputs import check_writable_file, holds_outputs
from shellsim.motion.format import MAX_FRAMES
from shellsim.settings import check_range, device_setting, option, overwrite_option, resume_option

log = logging.getLogger(__name__)

PRODUCER = "shellsim scene"
#: Largest principal stretch of a tet a frame may reach (a scene file sets none yet); a frame past it is
#: redone with more substeps, then stops the run.
MAX_STRETCH = 5.0
#: Prefix of the actions' state arrays in the motion (after the velocities).
ACTION_STATE = "action_"


@dataclass(frozen=True)
class SceneSettings:
    """What :func:`scene` does."""

    scene: str = option(help="the scene file (TOML; its schema is in the README)", required=True)
    out: str | None = option(
        help="output directory: motion.npz (the shot's motion)", shown_default="the scene file without .toml"
    )
    frames: int | None = option(
        help="simulate only the shot's first N frames (frame 0 the initial state), for a quick look",
        shown_default="the scene's",
    )
    video: str | None = option(
        help="also render the shot to this MP4 (frames in OUT/frames, 512x512, anti-aliased), seen by the "
        "scene's --camera; 'shellsim render --scene OUT' renders other cameras and sizes"
    )
    camera: str | None = option(
        help="with --video: the scene file's [[camera]] of this name",
        shown_default="its first, or a three-quarter orbit framed to the bodies",
        metavar="NAME",
    )
    resume: bool = resume_option()
    overwrite: bool = overwrite_option()
    device: str = option("auto", help="auto, cpu or cuda")

    def __post_init__(self):
        if self.frames is not None:
            check_range("frames", self.frames, 1, MAX_FRAMES, "an integer")
        if self.camera is not None and self.video is None:
            raise SettingError("camera", "chooses the camera of {video}")

    @property
    def out_dir(self) -> Path:
        scene = Path(self.scene)
        return Path(self.out) if self.out else scene.with_suffix("")


@dataclass
class SceneResult:
    """out : the motion file; frames : its frame count; history : the
    :class:`shellsim.physics.driver.FrameStats` of the frames simulated now; bodies : their names; video :
    the :class:`shellsim.render.result.RenderResult` of its frames and video (None without one)."""

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


def _simulated(record: dict) -> dict:
    """What of a :func:`scene_record` the motion depends on: all but the cameras and the look."""
    return {k: v for k, v in record.items() if k not in ("cameras", "look")}


class _Schedule:
    """:class:`shellsim.physics.multibody.Schedule` of the scene's actions, bodies in order."""

    def __init__(self, actions, names: list[str]):
        self.actions, self.names = actions, names

    def inputs(self, t, h, positions, velocities):
        by_name = (
            dict(zip(self.names, positions, strict=True)),
            dict(zip(self.names, velocities, strict=True)),
        )
        got = self.actions.inputs(t, h, *by_name)
        return [(got[n].pinned, got[n].targets, got[n].forces) for n in self.names]

    def state(self) -> dict:
        return self.actions.state()

    def restore(self, state: dict) -> None:
        self.actions.restore(state)


@holds_outputs
def scene(settings: SceneSettings, progress: bool = True) -> SceneResult:
    """Simulate the shot of ``settings.scene`` into ``settings.out_dir`` (module docstring)."""
    from tqdm.auto import tqdm

    from shellsim.cage.geometry import boundary_faces
    from shellsim.io.outputs import check_writable_dir, lock_output
    from shellsim.motion.changes import describe_changes
    from shellsim.motion.writer import MotionWriter, motion_exists
    from shellsim.physics.driver import SimulationError
    from shellsim.physics.ipc import BodySurface, Contact, StaticSurface
    from shellsim.physics.model import Model, SimSettings
    from shellsim.physics.multibody import SceneDriver, SceneSolver
    from shellsim.scene.actions import Actions, BodyInfo
    from shellsim.scene.build import build_body, check_start, collider_mesh
    from shellsim.scene.file import read_scene

    s = settings
    spec = read_scene(s.scene)  # every error of the file, before anything heavy or written
    world = spec.world
    frames = s.frames or world.frames
    device = device_setting(s.device, warp=True)
    if s.camera is not None and s.camera not in {c.name for c in spec.cameras}:
        known = ", ".join(c.name for c in spec.cameras) or "none"
        raise SettingError("camera", f"{spec.path}: no [[camera]] named {s.camera!r} (it has: {known})")
    out_dir = lock_output(check_writable_dir(s.out_dir, "out"), "out")
    if s.video is not None:
        lock_output(check_writable_file(s.video, "video"), "video")
    out = out_dir / "motion.npz"
    record = scene_record(spec)
    writer = None
    if motion_exists(out) and not s.overwrite:
        replace = "give {overwrite} to start it anew, or another {out}"
        writer = MotionWriter.resume(out)
        if writer.motion.producer != PRODUCER:
            raise SettingError("out", f"holds a motion not made by '{PRODUCER}'; {replace}", out)
        changes = describe_changes(_simulated(writer.motion.settings), _simulated(record), {})
        if changes:
            raise SettingError("out", f"made from another scene ({'; '.join(changes)}); {replace}", out)
        if writer.n_frames >= frames:
            log.info("%s already holds %d frames", out, writer.n_frames)
            writer.close()
            names = [b.name for b in spec.bodies]
            return SceneResult(out, writer.n_frames, [], names, _video(s, spec, out_dir, frames, progress))

    lift = 0.5 * world.contact_gap if world.ground else -np.inf
    bodies = [build_body(b, lift) for b in spec.bodies]
    colliders = [collider_mesh(c) for c in spec.colliders]
    check_start(spec, bodies, colliders)
    if writer is not None:
        _check_bodies(writer.motion, bodies, out)

    solver_settings = SimSettings(
        gravity=world.gravity,
        ground=None,
        damping=world.damping,
        drag=world.drag,
        dt=1.0 / world.fps,
        substeps=world.substeps,
        max_stretch=MAX_STRETCH,
    )
    models = [
        Model(
            b.rest,
            b.tets,
            b.material,
            solver_settings
            if b.spec.damping is None
            else dataclasses.replace(solver_settings, damping=b.spec.damping),
            device=device,
        )
        for b in bodies
    ]
    starts = np.concatenate([[0], np.cumsum([m.n_vertices for m in models])])
    statics = [StaticSurface(v, f, c.friction) for (v, f), c in zip(colliders, spec.colliders, strict=True)]
    contact = Contact(
        [
            BodySurface(body.surface.weights(len(body.rest)), body.surface.faces, body.spec.friction)
            for body in bodies
        ],
        starts[:-1],
        np.concatenate([b.rest for b in bodies]),
        statics,
        world.contact_gap,
        world.friction_velocity,
        world.ground_friction if world.ground else None,
    )
    names = [b.name for b in bodies]
    actions = Actions(
        spec.actions,
        [
            BodyInfo(b.name, b.rest, m.masses, boundary_faces(b.tets))
            for b, m in zip(bodies, models, strict=True)
        ],
    )
    driver = SceneDriver(SceneSolver(models, contact, solver_settings), _Schedule(actions, names))
    states = [m.state(b.spec.velocity, b.spec.spin) for m, b in zip(models, bodies, strict=True)]

    if writer is None:
        writer = MotionWriter(
            out,
            np.concatenate([b.rest for b in bodies]),
            np.concatenate([b.tets + start for b, start in zip(bodies, starts, strict=False)]),
            surface=_surfaces(bodies),
            producer=PRODUCER,
            settings=record,
            asset={"bodies": _body_records(bodies, starts)},
        )
    else:
        positions = writer.last_positions
        velocities = writer.motion.state.get("velocities")
        if velocities is None or velocities.shape != positions.shape:
            raise InputError(f"{out}: no simulation state after its last frame; cannot resume it")
        for k, state in enumerate(states):
            a, b = starts[k], starts[k + 1]
            state.set(positions[a:b], velocities[a:b], writer.last_time)
        actions.restore(
            {k[len(ACTION_STATE) :]: v for k, v in writer.motion.state.items() if k.startswith(ACTION_STATE)}
        )
        log.info("resuming %s after frame %d", out, writer.n_frames - 1)

    def append() -> None:
        x = np.concatenate([st.positions.numpy() for st in states])
        v = np.concatenate([st.velocities.numpy() for st in states])
        state = {"velocities": v, **{ACTION_STATE + k: a for k, a in actions.state().items()}}
        writer.append(x, states[0].time, state)

    history = []
    try:
        if writer.n_frames == 0:
            append()
        todo = frames - writer.n_frames
        with tqdm(total=todo, disable=not progress, unit="frame", desc="scene") as bar:
            for _ in range(todo):
                try:
                    stats = driver.step(states)
                except SimulationError as err:
                    err.frame = writer.n_frames
                    raise InputError(
                        f"{spec.path}: {err}; frames 0-{err.frame - 1} are kept in {out}; try more substeps, "
                        "stiffer materials or slower bodies"
                    ) from None
                history.append(stats)
                append()
                bar.set_postfix(newton=stats.newton_iterations, retries=stats.retries)
                bar.update()
    finally:
        writer.flush()
    writer.close()
    return SceneResult(out, writer.n_frames, history, names, _video(s, spec, out_dir, frames, progress))


def _video(settings: SceneSettings, spec, out_dir: Path, frames: int, progress: bool):
    """The frames of the shot's first ``frames`` frames in ``out_dir/frames`` and ``settings.video``, seen by
    the scene file's camera ``settings.camera`` in its look, as the file says them now; None without a
    video."""
    if settings.video is None:
        return None
    from shellsim.render.scene_frames import render_scene

    return render_scene(
        out_dir,
        out_dir / "frames",
        settings.camera,
        frames=f"0:{frames}",
        video=settings.video,
        device=settings.device,
        overwrite=settings.overwrite,
        progress=progress,
        spec=spec,
    )


def _body_records(bodies, starts) -> list[dict]:
    """The motion's record of each body: name, source (the asset's name and digest, or the mesh's path and
    digest), cage digest (asset frame), placement, vertex and tet ranges in the concatenated cage."""
    records, tet_start = [], 0
    for body, start, end in zip(bodies, starts[:-1], starts[1:], strict=True):
        records.append(
            {
                "name": body.name,
                "source": body.source,
                "cage": body.cage_digest,
                "placement": body.placement.as_dict(),
                "vertices": [int(start), int(end)],
                "tets": [tet_start, tet_start + len(body.tets)],
            }
        )
        tet_start += len(body.tets)
    return records


def _surfaces(bodies):
    """Every body's collision surface (its visible surface) as one
    :class:`shellsim.motion.format.Surface` of the concatenated cage."""
    from shellsim.motion.format import Surface

    tets, bary, faces, tet_start, vertex_start = [], [], [], 0, 0
    for body in bodies:
        tets.append(np.asarray(body.surface.tet, np.int64) + tet_start)
        bary.append(np.asarray(body.surface.bary, np.float64))
        faces.append(np.asarray(body.surface.faces, np.int64) + vertex_start)
        tet_start += len(body.tets)
        vertex_start += len(body.surface.tet)
    return Surface(np.concatenate(tets), np.concatenate(bary), np.concatenate(faces))


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
