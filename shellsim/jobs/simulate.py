"""The simulate job: drop an asset's cage (or a closed mesh, tetrahedralised) as an elastic body: the
one-body shot of :mod:`shellsim.jobs.scene`.

:func:`scene_of` translates the settings into a :class:`~shellsim.shot.spec.SceneSpec`: one body, the
ground, its obstacles as box and sphere colliders, each ``pin`` rule a pin action for the whole shot, every
friction the one ``friction``; :class:`shellsim.shot.simulation.SceneSimulation` moves it and
:mod:`shellsim.jobs.recording` records it. ``save_scene`` writes that spec as a scene file, which
``shellsim scene`` runs to the same positions.

Everything is in the world of :mod:`shellsim.world`: metres, z up, the ground at z = 0. An asset's up axis is
turned onto +z and its visible surface's largest extent scaled to ``size`` metres (default
:data:`~shellsim.world.BODY_SIZE`); a ``mesh`` is the body itself, in metres (or ``units``), scaled only when
``size`` asks; either way its lowest visible point ``drop_height`` above the ground and its bounding box
centred over the origin. Contact with the ground and the obstacles acts on the visible surface, by
incremental potential contact (:mod:`shellsim.physics.ipc`). The motion (:mod:`shellsim.motion.format`)
stores world positions and the placement; its settings are :func:`motion_settings`, its asset and cage
identified by content digest. An existing ``out`` made with the same settings is continued from its last
frame and stored velocities; one made with other settings is refused unless ``overwrite``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from neural.errors import InputError
from shellsim.errors import SettingError
from shellsim.film.cameras import OPTIONS, CameraSettings, camera_option
from shellsim.film.result import RenderResult
from shellsim.film.world import OPTIONS as WORLD_OPTIONS
from shellsim.film.world import WorldSettings, world_option
from shellsim.io.outputs import holds_outputs
from shellsim.jobs.recording import REPLACE
from shellsim.motion.format import MAX_FPS, MAX_FRAMES
from shellsim.physics.selection import selection_text
from shellsim.settings import (
    allow_stretch_option,
    check_choice,
    check_range,
    device_setting,
    floats,
    max_stretch_option,
    option,
    overwrite_option,
    pixels,
    resume_option,
)
from shellsim.world import BODY_SIZE, INTEGRATORS, UNITS, UP, describe_placement

if TYPE_CHECKING:
    from shellsim.shot.spec import SceneSpec

log = logging.getLogger(__name__)

PRODUCER = "shellsim simulate"
MAX_SUBSTEPS = 1000  # per frame; a retried frame runs up to 4 times as many
#: The settings that do not change the motion (not compared when a file is continued).
NOT_MOTION = (
    "frames",
    "out",
    "save_scene",
    "resume",
    "overwrite",
    "video",
    "video_size",
    *OPTIONS,
    *WORLD_OPTIONS,
    "device",
    "max_stretch",
    "allow_stretch",
)


def _presets() -> str:
    from shellsim.physics.materials import PRESETS

    return ", ".join(PRESETS)


@dataclass(frozen=True)
class SimulateSettings:
    """What :func:`simulate` does; lengths in world metres (z up, ground at z = 0)."""

    asset: str | None = option(
        help="asset directory or shipped asset name (its cage is used)", group="source", required=True
    )
    mesh: str | None = option(
        help="a closed triangle mesh file to tetrahedralise and simulate", group="source"
    )
    material: str = option("rubber", help=f"preset: {_presets()}")
    youngs: float | None = option(help="Young's modulus in Pa, overriding the preset")
    poisson: float | None = option(help="Poisson ratio in (-1, 0.5), overriding the preset")
    density: float | None = option(help="density in kg/m^3, overriding the preset")
    frames: int = option(90, help="number of frames, the first the initial state")
    fps: float = option(30.0, help="frames per second")
    substeps: int = option(8, help="implicit steps per frame")
    integrator: str = option(
        "euler",
        help="time integration: euler (backward Euler, first order: motion loses energy to it) or bdf2 "
        "(second order: a rubber ball bounces)",
        choices=INTEGRATORS,
    )
    size: float | None = option(
        help="scale the body so that its visible surface's largest extent measures this many metres",
        shown_default=f"{BODY_SIZE} for --asset; a --mesh keeps its own size, see --units",
    )
    units: str | None = option(
        help="length unit of the --mesh file's coordinates; not with --size",
        choices=tuple(UNITS),
        shown_default="m",
    )
    margin: float | None = option(
        help="dilation of the asset's outer shell when its cage is built, relative to its bounding-box "
        "diagonal; a --mesh is tetrahedralised as it is",
        shown_default="0.02",
    )
    drop_height: float = option(
        0.1,
        help="height in metres of the body's lowest visible point above the ground (z = 0) at frame 0 (at "
        "least half the contact gap, 0.5 mm)",
    )
    ground: bool = option(True, help="no ground plane", flag="--no-ground", negate=True)
    up: tuple[float, ...] | None = option(
        help="the asset's up axis x,y,z (in its own frame), turned onto the world's +z",
        parse=floats(3),
        shown_default="the asset's, or 0,0,1",
    )
    pin: tuple[str, ...] = option(
        help="hold the cage vertices selected by AXIS OP VALUE, in world metres (z up, ground at z = 0) or "
        "in % of the body's bounding box: 'z<0.12', 'x>=0.1', 'z<5%'; each is a pin of the shot, so several "
        "hold every vertex one of them selects",
        repeat=True,
        metavar="RULE",
        parse=selection_text,
    )
    velocity: tuple[float, ...] = option(
        (0.0, 0.0, 0.0), help="initial velocity vx,vy,vz in m/s", parse=floats(3)
    )
    spin: tuple[float, ...] = option(
        (0.0, 0.0, 0.0),
        help="initial angular velocity wx,wy,wz in rad/s about the centre of mass",
        parse=floats(3),
    )
    sphere: tuple[tuple[float, ...], ...] = option(
        help="a static sphere obstacle: centre and radius in world metres",
        repeat=True,
        metavar="X,Y,Z,R",
        parse=floats(4),
    )
    box: tuple[tuple[float, ...], ...] = option(
        help="a static axis-aligned box obstacle: centre and half extents in world metres (the ground is "
        "z = 0)",
        repeat=True,
        metavar="X,Y,Z,HX,HY,HZ",
        parse=floats(6),
    )
    friction: float = option(0.5, help="Coulomb coefficient")
    damping: float = option(0.0, help="Kelvin-Voigt damping in seconds")
    max_stretch: float = max_stretch_option()
    allow_stretch: bool = allow_stretch_option()
    tets: int | None = option(help="target cage tet count when the cage is built")
    out: str | None = option(help="motion file", shown_default="NAME_sim.npz")
    save_scene: str | None = option(
        help="also write this run as a scene file (one body, the ground, the obstacles, the pins): "
        "'shellsim scene FILE' makes the same motion, and a shot grows from it",
        metavar="FILE",
    )
    resume: bool = resume_option()
    overwrite: bool = overwrite_option()
    video: str | None = option(
        help="then render the motion (seen by --camera) to this MP4 and its frames to VIDEO_frames/ (with "
        "--mesh: the mesh's surface, drawn with pyvista); frames already there are kept only when they show "
        "the same motion frame, camera and size"
    )
    video_size: tuple[int, int] = option(
        (512, 512), help="WxH of the rendered frames", parse=pixels, shown_default="512x512"
    )
    camera: str | None = camera_option("camera")
    orbit_degrees: float | None = camera_option("orbit_degrees")
    camera_position: tuple[float, float, float] | None = camera_option("camera_position")
    look_at: tuple[float, float, float] | None = camera_option("look_at")
    ground_colors: tuple[float, ...] = world_option("ground_colors")
    light: tuple[float, ...] = world_option("light")
    sky: tuple[float, ...] = world_option("sky")
    device: str = option("auto", help="auto, cpu or cuda")

    def __post_init__(self):
        from shellsim.physics.materials import RANGES, get_material
        from shellsim.physics.model import SolverSettings

        if (self.asset is None) == (self.mesh is None):
            raise SettingError("asset", "give exactly one of an asset and a mesh")
        if self.units is not None and (self.asset or self.size is not None):
            raise SettingError(
                "units",
                "gives the unit of a mesh file's coordinates; "
                + ("an asset is scaled by size" if self.asset else "not with size, which sets the size"),
            )
        if self.margin is not None:
            if self.mesh:
                raise SettingError(
                    "margin", "dilates an asset's shell into its cage; a mesh is the body itself"
                )
            check_range("margin", self.margin, 0, 1, "a fraction of the shell's diagonal", "(]")
        check_range("frames", self.frames, 1, MAX_FRAMES, "an integer")
        check_range("substeps", self.substeps, 1, MAX_SUBSTEPS, "an integer")
        check_choice("integrator", self.integrator, INTEGRATORS)
        if self.tets is not None:
            check_range("tets", self.tets, 10, 1_000_000_000, "an integer")
        check_range("fps", self.fps, 0, MAX_FPS, "a number of frames per second", "(]")
        if self.size is not None:
            check_range("size", self.size, 1e-3, 1e3, "a length in metres")
        check_range("drop_height", self.drop_height, 0, 100, "a height in metres")  # lands below 45 m/s
        check_range("friction", self.friction, 0, 10, "a Coulomb coefficient")
        check_range("damping", self.damping, 0, 10, "a time in seconds")
        check_range("max_stretch", self.max_stretch, 1, math.inf, "a principal stretch", "(]")
        for name, what in (
            ("youngs", "a Young's modulus in Pa"),
            ("poisson", "a Poisson ratio"),
            ("density", "a density in kg/m^3"),
        ):
            if getattr(self, name) is not None:
                low, high, ends = RANGES[name]
                check_range(name, getattr(self, name), low, high, what, ends)
        try:
            get_material(self.material)
        except InputError as err:
            raise SettingError("material", str(err)) from None
        max_speed = SolverSettings.max_speed  # [m/s]: a faster vertex stops the simulation
        speed = float(np.linalg.norm(self.velocity))
        check_range("velocity", speed, 0, max_speed, "a speed in m/s (the simulator's limit)", "[)")
        size = self.scale_size
        if size is not None:  # a --mesh in its own units: the simulator checks speeds
            what = f"an angular speed in rad/s at {{size}} {size:g} m"  # the rim below max_speed
            check_range("spin", float(np.linalg.norm(self.spin)), 0, max_speed / size, what, "[)")
        for s in self.sphere:
            check_range("sphere", s[3], 0, math.inf, "a radius", "()")
        for b in self.box:
            check_range("box", min(b[3:]), 0, math.inf, "half extents", "()")
        if self.up is not None and not np.linalg.norm(self.up) > 0:
            raise SettingError("up", "the up axis must be a non-zero vector")
        for name in OPTIONS:
            if self.video is None and getattr(self, name) is not None:
                raise SettingError(name, "sets the camera of the {video}")
        CameraSettings.of(self)
        for name in WorldSettings.of(self).changed():
            if self.asset is None or self.video is None:
                raise SettingError(name, "sets the world behind the {video} of an {asset}")

    @property
    def scale_size(self) -> float | None:
        """The body's largest extent in metres: ``size``, :data:`~shellsim.world.BODY_SIZE` for an asset,
        None for a mesh kept in its own units."""
        return self.size if self.size is not None or self.mesh else BODY_SIZE

    @property
    def name(self) -> str:
        return Path(self.mesh).stem if self.mesh else Path(self.asset).name

    @property
    def out_path(self) -> Path:
        return Path(self.out) if self.out else Path(f"{self.name}_sim.npz")


def motion_settings(settings: SimulateSettings) -> dict:
    """The settings recorded in the motion and compared when it is continued: those of :data:`NOT_MOTION`
    left out, the mesh as an absolute path, ``drop_height`` None without a ground."""
    record = {k: v for k, v in dataclasses.asdict(settings).items() if k not in NOT_MOTION}
    if settings.mesh:
        record["mesh"] = str(Path(settings.mesh).resolve())
    record["drop_height"] = settings.drop_height if record.pop("ground") else None
    return record


def _as_recorded(record: dict) -> dict:
    """``record`` as it compares: one made before ``integrator`` existed integrated by backward Euler."""
    return {"integrator": "euler", **record}


#: How a changed setting is named when it is not the field itself (placeholders of SettingError).
_OPTIONS = {
    "youngs": "Young's modulus ({youngs})",
    "poisson": "Poisson ratio ({poisson})",
    "density": "density ({density})",
    "drop_height": "{drop_height} (none: {ground})",
}


@dataclass
class SimulateResult:
    """out : the motion file; frames : its frame count; history : :class:`shellsim.physics.driver.FrameStats`
    of the frames simulated now; video : the render's :class:`shellsim.film.result.RenderResult` (None
    without ``video``)."""

    out: Path
    frames: int
    history: list
    video: RenderResult | None = None


@holds_outputs
def simulate(settings: SimulateSettings, progress: bool = True) -> SimulateResult:
    """Run the simulation ``settings`` describe into ``settings.out_path`` (module docstring)."""
    from neural.files import write_atomically
    from shellsim.io.outputs import check_writable_dir, check_writable_file, lock_output
    from shellsim.jobs.recording import record_frames, resume_or_refuse
    from shellsim.memory import cage_bytes, check_memory, render_bytes
    from shellsim.motion.writer import MotionWriter
    from shellsim.shot.bodies import file_digest
    from shellsim.shot.save import scene_toml
    from shellsim.shot.simulation import SceneSimulation

    s = settings
    out = lock_output(check_writable_file(s.out_path, "out"), "out")
    if s.video:
        video = lock_output(check_writable_file(s.video, "video"), "video")
        frames_dir = check_writable_dir(video.with_name(video.stem + "_frames"), "video")
        lock_output(frames_dir, "video")
    device = device_setting(s.device, warp=True)  # the simulator runs in Warp
    if s.tets:
        what = f"a cage of {s.tets:,} tets"
        check_memory("tets", cage_bytes(s.tets), what, "to build and simulate", device)
    if s.video:
        width, height = s.video_size
        frame = f"a frame of {width}x{height} pixels"
        check_memory("video_size", render_bytes(width, height), frame, "to render", device)
    spec = scene_of(s)
    if s.save_scene:
        path = lock_output(check_writable_file(s.save_scene, "save_scene"), "save_scene")
        text = scene_toml(spec)
        write_atomically(path, lambda tmp: Path(tmp).write_text(text))
        log.info("the scene file of this run: %s ('shellsim scene %s' makes the same motion)", path, path)

    record = motion_settings(s)
    writer = resume_or_refuse(out, PRODUCER, record, s.overwrite, s.resume, _OPTIONS, compared=_as_recorded)
    if writer is not None and not writer.motion.placement:
        raise SettingError(
            "out", f"was made by an earlier shellsim in the asset's own units, not metres; {REPLACE}", out
        )
    if writer is not None and s.mesh and writer.motion.asset.get("digest") != file_digest(s.mesh):
        raise SettingError("out", f"made from another content of {s.mesh} (changed since); {REPLACE}", out)
    sim = SceneSimulation(spec, device, s.max_stretch, s.allow_stretch)
    body = sim.bodies[0]
    material = body.material
    if writer is None:
        log.info("%s", describe_placement(s.name, body.placement, body.surface_world))
        meta = {
            "fps": s.fps,
            "up": list(UP),
            "material": material.as_dict(),
            "units": "metres: positions and rest_vertices in the world (z up, ground at z = 0), "
            "state velocities in m/s; the header's placement maps the asset's frame to the world",
            "solver_settings": sim.settings.as_dict(),
            "contact": {
                "model": "incremental potential contact (ipctk) on the visible surface",
                "gap": sim.contact.dhat,
                "friction": s.friction,
                "friction_velocity": sim.contact.friction_velocity,
            },
        }
        writer = MotionWriter(
            out,
            body.rest,
            body.tets,
            meta,
            surface=sim.surface() if s.mesh else None,
            producer=PRODUCER,
            settings=record,
            asset=body.source,
            placement=body.placement.as_dict(),
            cage_digest=body.cage_digest,
        )
    else:
        _check_source(writer.motion, sim)
        sim.restore(writer.last_positions, writer.last_time, writer.motion.state, str(out))
    log.info(
        "%s: %d cage vertices, %d tets, %s (E=%.3g Pa, nu=%.3g, rho=%.4g kg/m^3), %d frames to go on %s",
        s.name,
        len(body.rest),
        len(body.tets),
        material.name,
        material.youngs,
        material.poisson,
        material.density,
        max(s.frames - max(writer.n_frames, 1), 0),
        device,
    )
    with writer:
        history = record_frames(
            writer,
            s.frames,
            sim.advance,
            sim.snapshot,
            advice=lambda err: _advice(err, material),
            desc="simulate",
            progress=progress,
        )
    result = SimulateResult(out, writer.n_frames, history)
    if s.video:
        result.video = _render(s, out, frames_dir, video, s.device)
    return result


def scene_of(settings: SimulateSettings) -> SceneSpec:
    """The one-body shot the settings describe (module docstring): what :func:`simulate` runs and
    ``save_scene`` writes."""
    from shellsim.shot import spec as specs
    from shellsim.shot.spec import ActionSpec, BodySpec, CageSpec, ColliderSpec, WorldSpec

    def point(values) -> tuple[float, float, float]:
        return tuple(float(c) for c in values)

    s = settings
    name = s.name
    world = WorldSpec(
        fps=float(s.fps),
        frames=s.frames,
        substeps=s.substeps,
        integrator=s.integrator,
        ground=s.ground,
        ground_friction=s.friction,
        damping=s.damping,
    )
    if s.asset is not None:
        asset = str(Path(s.asset).resolve()) if Path(s.asset).is_dir() else s.asset
        source = {"asset": asset, "up": None if s.up is None else point(s.up)}
    else:
        source = {"mesh": str(Path(s.mesh).resolve()), "units": s.units or "m"}
    body = BodySpec(
        name=name,
        **source,
        size=s.size,
        position=(0.0, 0.0, float(s.drop_height)),
        material=s.material,
        youngs=s.youngs,
        poisson=s.poisson,
        density=s.density,
        friction=s.friction,
        velocity=point(s.velocity),
        spin=point(s.spin),
        cage=CageSpec(target_tets=s.tets, margin=s.margin),
        where=name,
    )

    def named(kind: str, k: int, values) -> str:  # as the user gave it: "box 1 (0,0,0.05,0.2,0.2,0.06)"
        return f"{kind} {k} ({','.join(f'{c:g}' for c in values)})"

    colliders = [
        ColliderSpec(named("sphere", k, p), "sphere", point(p[:3]), radius=float(p[3]), friction=s.friction)
        for k, p in enumerate(s.sphere, 1)
    ]
    colliders += [
        ColliderSpec(named("box", k, b), "box", point(b[:3]), half_extents=point(b[3:]), friction=s.friction)
        for k, b in enumerate(s.box, 1)
    ]
    colliders = [dataclasses.replace(c, where=c.name) for c in colliders]
    pins = [ActionSpec("pin", 0.0, world.duration, body=name, region=(rule,), where="pin") for rule in s.pin]
    return specs.SceneSpec(name, world, (body,), tuple(colliders), tuple(pins))


def _check_source(motion, sim) -> None:
    """A :class:`SettingError` unless the motion being continued moves this cage, placed as now."""
    body = sim.bodies[0]
    motion.check_against(body.cage)
    rest = motion.rest_vertices
    if rest.shape != sim.rest.shape or not np.allclose(
        rest, sim.rest, rtol=0, atol=1e-9 * body.placement.scale
    ):
        raise SettingError(
            "out",
            f"was made by an earlier shellsim that placed the body otherwise (by its cage); {REPLACE}",
            motion.path,
        )


def _render(s: SimulateSettings, out: Path, frames_dir: Path, video: Path, device: str) -> RenderResult:
    """Render the motion ``out`` to ``frames_dir`` and ``video``: the asset, or a mesh's surface (pyvista);
    each frame already there is kept only if it records this motion frame and camera."""
    camera = CameraSettings.of(s)
    if s.asset:
        from shellsim.film.motion_frames import render_motion

        return render_motion(
            s.asset,
            out,
            frames_dir,
            camera=camera,
            size=s.video_size,
            video=video,
            device=device,
            look=WorldSettings.of(s).look(),
        )
    from shellsim.viz.surface import render_surface_motion

    return render_surface_motion(out, frames_dir, size=s.video_size, video=video, camera=camera)


def _advice(err, material) -> str:
    """What to change when a frame leaves the valid regime (a
    :class:`shellsim.physics.driver.SimulationError`), the settings named as placeholders, which the
    command line shows as its options."""
    return {
        "collapse": f"use a stiffer material ({{material}}, {{youngs}}; now {material.youngs:g} Pa), a "
        "smaller {size} or {drop_height}, or more {damping}",
        "speed": "lower {drop_height}, {velocity} or {spin}",
        "stretch": f"use a stiffer material ({{material}}, {{youngs}}; now {material.youngs:g} Pa), lower "
        "{drop_height}, {velocity} or {spin}, raise {max_stretch}, or give {allow_stretch} to only warn",
        "nonfinite": "use more {substeps} or a lower {drop_height}",
    }[err.kind]
