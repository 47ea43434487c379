"""The simulate job: drop an asset's cage (or a closed mesh, tetrahedralised) as an elastic body.

Everything is in the world of :mod:`shellsim.world`: metres, z up, the ground at z = 0. The body is placed by
:func:`shellsim.world.place_on_ground`: an asset's up axis turned onto +z and its largest extent scaled to
``size`` metres (default :data:`~shellsim.world.BODY_SIZE`); a ``mesh`` is the body itself, in metres (or
``units``), scaled only when ``size`` asks; either way its lowest visible point ``drop_height`` above the
ground and its bounding box centred over the origin. Contact with the ground and the obstacles acts on the
visible surface (the asset's collision surface, a mesh's own; :mod:`shellsim.cage.collision`), by the
incremental potential contact of :mod:`shellsim.physics.ipc`: the one-body case of the scene solver
(:class:`shellsim.physics.multibody.OneBodyDriver`). Obstacles, absolute pin rules and velocities are world
metres; a pin rule in percent is relative to the body's bounding box. An obstacle that overlaps the body at
frame 0 or a pin rule that selects nothing is refused before anything runs. The motion
(:mod:`shellsim.motion.format`) stores world positions and the placement; its settings are
:func:`motion_settings`, its asset and cage identified by content digest. An existing ``out`` made with the
same settings is continued from its last frame and stored velocities; one made with other settings is refused
unless ``overwrite``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from neural.errors import InputError
from shellsim.errors import SettingError
from shellsim.io.outputs import holds_outputs
from shellsim.motion.format import MAX_FPS, MAX_FRAMES
from shellsim.physics.selection import parse_selection, select_vertices, selection_text
from shellsim.render.cameras import OPTIONS, CameraSettings, camera_option
from shellsim.render.result import RenderResult
from shellsim.render.world import OPTIONS as WORLD_OPTIONS
from shellsim.render.world import WorldSettings, world_option
from shellsim.settings import (
    check_range,
    device_setting,
    floats,
    option,
    overwrite_option,
    pixels,
    resume_option,
)
from shellsim.world import BODY_SIZE, UNITS, UP, Placement, describe_placement, place_on_ground

log = logging.getLogger(__name__)

MAX_SUBSTEPS = 1000  # per frame; a retried frame runs up to 4 times as many
#: The settings that do not change the motion (not compared when a file is continued).
NOT_MOTION = (
    "frames",
    "out",
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
    size: float | None = option(
        help="scale the body so that its largest extent measures this many metres",
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
        "in % of the body's bounding box: 'z<0.12', 'x>=0.1', 'z<5%'",
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
    max_stretch: float = option(
        3.0,
        help="largest principal stretch of a tet (deformed over rest length along its most stretched "
        "direction) a frame may reach; a frame past it stops the run",
    )
    allow_stretch: bool = option(False, help="only warn, once, when a frame passes --max-stretch, and go on")
    tets: int | None = option(help="target cage tet count when the cage is built")
    out: str | None = option(help="motion file", shown_default="NAME_sim.npz")
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
        from shellsim.physics.model import SimSettings

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
        max_speed = SimSettings.max_speed  # [m/s]: a faster vertex stops the simulation
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
    of the frames simulated now; video : the render's :class:`shellsim.render.result.RenderResult` (None
    without ``video``)."""

    out: Path
    frames: int
    history: list
    video: RenderResult | None = None


@holds_outputs
def simulate(settings: SimulateSettings, progress: bool = True) -> SimulateResult:
    """Run the simulation ``settings`` describe into ``settings.out_path`` (module docstring)."""
    from shellsim.io.outputs import check_writable_dir, check_writable_file, lock_output
    from shellsim.memory import cage_bytes, check_memory, render_bytes
    from shellsim.motion.changes import describe_changes
    from shellsim.motion.format import cage_digest
    from shellsim.motion.writer import MotionWriter, motion_exists
    from shellsim.physics.control import Control
    from shellsim.physics.driver import SimulationError, restore_state
    from shellsim.physics.driver import simulate as run_frames
    from shellsim.physics.materials import get_material
    from shellsim.physics.model import Model
    from shellsim.physics.multibody import OneBodyDriver, SceneSolver

    s = settings
    out = lock_output(check_writable_file(s.out_path, "out"), "out")
    if s.video:
        video = lock_output(check_writable_file(s.video, "video"), "video")
        frames_dir = check_writable_dir(video.with_name(video.stem + "_frames"), "video")
        lock_output(frames_dir, "video")
    material = get_material(s.material, s.youngs, s.poisson, s.density)
    rules = [parse_selection(text) for text in s.pin]
    device = device_setting(s.device, warp=True)  # the simulator runs in Warp
    if s.tets:
        what = f"a cage of {s.tets:,} tets"
        check_memory("tets", cage_bytes(s.tets), what, "to build and simulate", device)
    if s.video:
        width, height = s.video_size
        frame = f"a frame of {width}x{height} pixels"
        check_memory("video_size", render_bytes(width, height), frame, "to render", device)
    record = motion_settings(s)

    if motion_exists(out) and not s.overwrite:  # same settings: continue the file; other settings: refuse
        replace = "give {overwrite} to start it anew, or another {out}"
        writer = MotionWriter.resume(out)  # not a motion file: refused as it is, never replaced
        if writer.motion.producer != "shellsim simulate":
            raise SettingError("out", f"not a 'shellsim simulate' motion file; {replace}", out)
        if not writer.motion.placement:
            raise SettingError(
                "out", f"was made by an earlier shellsim in the asset's own units, not metres; {replace}", out
            )
        changes = describe_changes(writer.motion.settings, record, _OPTIONS)
        if changes:
            raise SettingError("out", f"made with other settings ({'; '.join(changes)}); {replace}", out)
        contact_surface = _check_source(s, writer.motion)
        rest, tets = writer.motion.rest_vertices, writer.motion.tets
        log.info("resuming %s after frame %d", out, writer.n_frames - 1)
    else:
        writer = None
        vertices, tets, up, surface, asset, contact_surface = _load_cage(s)
        visible = _interpolate(vertices, tets, contact_surface)
        placement = _placement(s, vertices, s.up if s.up is not None else up, visible)
        rest = placement.to_world(vertices)
        log.info("%s", describe_placement(s.name, placement, placement.to_world(visible)))
        _check_obstacles(s, rest, tets)

    pinned = select_vertices(rules, rest, "pin")
    sim_settings = _sim_settings(s)
    model = Model(rest, tets, material, sim_settings, device=device)
    contact = _contact(s, contact_surface, tets, rest)
    driver = OneBodyDriver(SceneSolver([model], contact, sim_settings))
    control = Control(model, pinned=pinned)
    state = model.state(s.velocity, s.spin)
    if writer is None:
        if s.resume:
            log.info("%s does not exist: nothing to resume, starting it", out)
        meta = {
            "fps": s.fps,
            "up": list(UP),
            "material": material.as_dict(),
            "units": "metres: positions and rest_vertices in the world (z up, ground at z = 0), "
            "state velocities in m/s; the header's placement maps the asset's frame to the world",
            "sim_settings": sim_settings.as_dict(),
            "contact": {
                "model": "incremental potential contact (ipctk) on the visible surface",
                "gap": contact.dhat,
                "friction": s.friction,
                "friction_velocity": contact.friction_velocity,
            },
        }
        if out.exists():
            log.info("--overwrite: replacing %s", out)
        writer = MotionWriter(
            out,
            rest,
            tets,
            meta,
            surface=surface,
            producer="shellsim simulate",
            settings=record,
            asset=asset,
            placement=placement.as_dict(),
            cage_digest=cage_digest(vertices, tets),
        )
    else:
        restore_state(state, writer)

    # a new file starts with frame 0, the initial state
    remaining = max(s.frames - max(writer.n_frames, 1), 0)
    log.info(
        "%s: %d cage vertices, %d tets, %s (E=%.3g Pa, nu=%.3g, rho=%.4g kg/m^3), %d frames to go on %s",
        s.name,
        len(rest),
        len(tets),
        material.name,
        material.youngs,
        material.poisson,
        material.density,
        remaining,
        device,
    )
    with writer:
        try:
            history = run_frames(driver, state, control, remaining, writer, progress=progress)
        except SimulationError as err:
            raise _failure(err, out, material) from None
    result = SimulateResult(out, writer.n_frames, history)
    if s.video:
        result.video = _render(s, out, frames_dir, video, s.device)
    return result


def _check_source(s: SimulateSettings, motion) -> None:
    """An :class:`InputError` unless the motion being continued moves the asset's cage
    (:meth:`shellsim.motion.format.Motion.check_against`) or was made from this content of the mesh file;
    returns the surface contact acts on (:func:`_load_cage`)."""
    if s.asset:
        asset, cage = _asset_cage(s)
        motion.check_against(cage)
        return _collision_surface(asset, cage)
    if motion.asset.get("digest") != _file_digest(Path(s.mesh)) or motion.surface is None:
        raise SettingError(
            "out",
            f"made from another content of {s.mesh} (changed since); give {{overwrite}} to start it anew, or "
            "another {out}",
            motion.path,
        )
    return motion.surface


def _file_digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _render(s: SimulateSettings, out: Path, frames_dir: Path, video: Path, device: str) -> RenderResult:
    """Render the motion ``out`` to ``frames_dir`` and ``video``: the asset, or a mesh's surface (pyvista);
    each frame already there is kept only if it records this motion frame and camera."""
    camera = CameraSettings.of(s)
    if s.asset:
        from shellsim.render.frames import render_motion

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


def _sim_settings(s: SimulateSettings):
    """The :class:`shellsim.physics.model.SimSettings` of the run, in world metres (z up): the body's own
    terms; the ground and the obstacles are :func:`_contact`'s."""
    from shellsim.physics.model import SimSettings

    return SimSettings(
        dt=1.0 / s.fps,
        substeps=s.substeps,
        up=UP,
        ground=None,
        friction=s.friction,
        damping=s.damping,
        max_stretch=s.max_stretch,
        allow_stretch=s.allow_stretch,
    )


def _obstacle_distances(s: SimulateSettings, points: np.ndarray):
    """(name, signed distances (N,) of ``points`` (N, 3) to the obstacle, negative inside) of every
    obstacle of ``s``, named as the user gave it."""
    for k, p in enumerate(s.sphere):
        name = f"sphere {k + 1} ({','.join(f'{c:g}' for c in p)})"
        yield name, np.linalg.norm(points - p[:3], axis=1) - p[3]
    for k, b in enumerate(s.box):
        q = np.abs(points - b[:3]) - b[3:]
        name = f"box {k + 1} ({','.join(f'{c:g}' for c in b)})"
        yield name, np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)


def _check_obstacles(s: SimulateSettings, rest: np.ndarray, tets: np.ndarray) -> None:
    """A :class:`SettingError` naming the first obstacle that overlaps the body at frame 0: a cage vertex
    (V, 3, world metres) inside it, or the obstacle's centre inside a cage tet (T, 4)."""
    from shellsim.cage.embed import outside_distance

    centres = np.array([p[:3] for p in (*s.sphere, *s.box)], np.float64).reshape(-1, 3)
    held = outside_distance(rest, tets, centres) == 0
    lo, hi = rest.min(0), rest.max(0)
    span = ", ".join(f"{a} {lo[i]:.3f}..{hi[i]:.3f}" for i, a in enumerate("xyz"))
    for k, (name, distance) in enumerate(_obstacle_distances(s, rest)):
        inside = int((distance < 0).sum())
        if inside or held[k]:
            what = "its centre lies inside the body"
            if inside:
                what = (
                    f"{inside} cage vertices lie inside it" if inside > 1 else "a cage vertex lies inside it"
                )
            field = "sphere" if name.startswith("sphere") else "box"
            raise SettingError(
                field,
                f"{name} overlaps the body at frame 0 ({what}); the body spans {span} m (world metres, "
                "ground at z = 0)",
            )


def _asset_cage(s: SimulateSettings):
    """(asset, cage): the asset's stored cage when it fits ``tets``/``margin``, else one built and cached."""
    from neural.asset import load_asset
    from shellsim.cage.build import CageConfig
    from shellsim.cage.store import load_or_build_cage

    config = {k: v for k, v in (("target_tets", s.tets), ("margin", s.margin)) if v is not None}
    asset = load_asset(s.asset)
    return asset, load_or_build_cage(asset, CageConfig(**config) if config else None)


def _collision_surface(asset, cage):
    """The asset's visible surface embedded in ``cage`` (:func:`shellsim.cage.collision.surface_of_asset`,
    cached) as a :class:`shellsim.motion.format.Surface`."""
    from shellsim.cage.collision import surface_of_asset
    from shellsim.motion.format import Surface

    found = surface_of_asset(asset, cage)
    return Surface(np.asarray(found.tet, np.int64), np.asarray(found.bary), np.asarray(found.faces, np.int64))


def _interpolate(vertices: np.ndarray, tets: np.ndarray, surface) -> np.ndarray:
    """(S, 3) the points of ``surface`` (a :class:`shellsim.motion.format.Surface`) in the cage
    ``vertices``."""
    from shellsim.cage.embed import interpolate

    return interpolate(vertices, tets, surface.tet, surface.bary)


def _contact(s: SimulateSettings, surface, tets: np.ndarray, rest: np.ndarray):
    """The :class:`shellsim.physics.ipc.Contact` of the body's visible ``surface`` (embedded in the cage of
    ``tets``, at rest ``rest`` (V, 3)) with the ground and the obstacles (the triangle meshes of a scene's
    box and sphere colliders), every pair with the Coulomb coefficient ``friction``."""
    from shellsim.cage.collision import embedding_weights
    from shellsim.physics.ipc import CONTACT_GAP, FRICTION_VELOCITY, BodySurface, Contact, StaticSurface
    from shellsim.scene.build import collider_mesh
    from shellsim.scene.spec import ColliderSpec

    obstacles = [ColliderSpec("sphere", "sphere", tuple(p[:3]), radius=p[3]) for p in s.sphere]
    obstacles += [ColliderSpec("box", "box", tuple(b[:3]), half_extents=tuple(b[3:])) for b in s.box]
    statics = [StaticSurface(*collider_mesh(o), s.friction) for o in obstacles]
    weights = embedding_weights(np.asarray(tets, np.int64)[surface.tet], surface.bary, len(rest))
    body = BodySurface(weights, surface.faces, s.friction)
    ground = s.friction if s.ground else None
    return Contact([body], [0], rest, statics, CONTACT_GAP, FRICTION_VELOCITY, ground)


def _load_cage(s: SimulateSettings):
    """(vertices, tets, up, surface, asset, contact) of the rest cage, world frame: an asset's cage
    (:func:`_asset_cage`, surface None), or a mesh tetrahedralised undilated and its surface embedded;
    ``asset`` is the motion's record of what it moves (name or path, and content digest); ``contact`` the
    surface contact acts on, embedded in the cage (:class:`shellsim.motion.format.Surface`): the asset's
    visible surface (:func:`_collision_surface`), the mesh itself."""
    from neural.asset import load_mesh
    from shellsim.cage.build import CageConfig, build_cage
    from shellsim.memory import check_memory, mesh_bytes

    if s.asset:
        asset, cage = _asset_cage(s)
        record = {"name": asset.name, "digest": asset.digest()}
        return cage.vertices, cage.tets, asset.up, None, record, _collision_surface(asset, cage)
    mesh = load_mesh(Path(s.mesh))
    config = CageConfig(margin=0.0, **({"target_tets": s.tets} if s.tets else {}))
    needed, faces = mesh_bytes(len(mesh.faces), config.target_tets), f"a mesh of {len(mesh.faces):,} faces"
    check_memory("mesh", needed, faces, "to tetrahedralise and simulate")
    cage = build_cage(mesh, mesh, config, what=str(s.mesh))
    record = {"mesh": str(Path(s.mesh).resolve()), "digest": _file_digest(Path(s.mesh))}
    surface = _mesh_surface(mesh, cage)
    return cage.vertices, cage.tets, np.array([0.0, 0.0, 1.0]), surface, record, surface


def _mesh_surface(mesh, cage):
    """The surface of the trimesh ``mesh`` embedded in its cage: a :class:`shellsim.motion.format.Surface`."""
    from shellsim.cage.embed import embed_points
    from shellsim.motion.format import Surface

    tet, bary = embed_points(cage.vertices, cage.tets, np.asarray(mesh.vertices, np.float64))
    return Surface(tet, bary, np.asarray(mesh.faces, np.int64))


def _placement(s: SimulateSettings, vertices: np.ndarray, up, visible: np.ndarray):
    """The :class:`shellsim.world.Placement` of the body whose rest cage is ``vertices`` (V, 3, its own
    frame; ``up`` (3,) its up axis) and visible surface ``visible`` (S, 3): an asset scaled to ``size``
    (default :data:`BODY_SIZE`) metres, a mesh by its ``units`` or to ``size``; centred over the origin, its
    lowest visible point at ``drop_height`` (with a ground at least half the contact gap: contact needs
    one)."""
    from shellsim.physics.ipc import CONTACT_GAP

    up = np.asarray(up, np.float64)
    if s.asset or s.size is not None:
        base = place_on_ground(vertices, up, s.scale_size)
    else:
        base = place_on_ground(vertices, up, None, scale=UNITS[s.units or "m"])
    height = max(s.drop_height, 0.5 * CONTACT_GAP) if s.ground else s.drop_height
    lift = height - base.to_world(visible)[:, 2].min()
    return Placement(base.scale, base.rotation, base.translation + np.array([0.0, 0.0, lift]))


def _failure(err, out: Path, material) -> SettingError:
    """The one line for a :class:`shellsim.physics.driver.SimulationError`: the frame, the value, what to
    change (the settings named as placeholders, which the command line shows as its options)."""
    advice = {
        "collapse": f"use a stiffer material ({{material}}, {{youngs}}; now {material.youngs:g} Pa), a "
        "smaller {size} or {drop_height}, or more {damping}",
        "speed": "lower {drop_height}, {velocity} or {spin}",
        "stretch": f"use a stiffer material ({{material}}, {{youngs}}; now {material.youngs:g} Pa), lower "
        "{drop_height}, {velocity} or {spin}, raise {max_stretch}, or give {allow_stretch} to only warn",
        "nonfinite": "use more {substeps} or a lower {drop_height}",
    }[err.kind]
    return SettingError(None, f"{err}; frames 0-{err.frame - 1} are kept in {out}; {advice}")
