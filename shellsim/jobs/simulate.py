"""The simulate job: drop an asset's cage (or a closed mesh, tetrahedralised) as an elastic body.

:func:`simulate` builds the cage and the :class:`shellsim.physics.fem.Simulator`, drives :func:`shellsim.physics.fem.simulate`
into a motion file (:mod:`shellsim.motion.format`, format 2: its settings are :func:`motion_settings`, its asset
and cage identified by content digest) and optionally renders it. The world frame is kept: an asset's cage
is scaled so that its largest extent measures ``size`` metres (default :data:`ASSET_SIZE`); a ``mesh`` is
the body itself, in metres (or ``units``), not dilated, and scaled only when ``size`` asks. It is simulated
in SI units and written back in world coordinates (``meta['world']`` holds the scale and why). An existing
``out`` made with the same settings is continued from its last frame and stored velocities; one made with
other settings is refused unless ``overwrite``.
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
from shellsim.motion.format import MAX_FPS, MAX_FRAMES
from shellsim.physics.selection import parse_selection, select_vertices, selection_text
from shellsim.settings import (
    check_range,
    device_setting,
    floats,
    option,
    overwrite_option,
    pixels,
    resume_option,
)

log = logging.getLogger(__name__)

#: Metres per unit of a mesh file's coordinates (``units``).
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "ft": 0.3048}
#: Size in metres of an asset's largest extent when ``size`` is not given.
ASSET_SIZE = 0.3
MAX_SUBSTEPS = 1000  # per frame; a retried frame runs up to 4 times as many
#: The settings that do not change the motion (not compared when a file is continued).
NOT_MOTION = ("frames", "out", "resume", "overwrite", "video", "video_size", "device")


def _presets() -> str:
    from shellsim.physics.materials import PRESETS

    return ", ".join(PRESETS)


@dataclass(frozen=True)
class SimulateSettings:
    """What :func:`simulate` does; lengths in world units unless said otherwise."""

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
        shown_default=f"{ASSET_SIZE} for --asset; a --mesh keeps its own size, see --units",
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
    drop_height: float = option(0.1, help="gap in metres between the lowest cage vertex and the ground")
    ground: bool = option(True, help="no ground plane", flag="--no-ground", negate=True)
    up: tuple[float, ...] | None = option(
        help="up axis x,y,z: gravity points against it",
        parse=floats(3),
        shown_default="the asset's, or 0,0,1",
    )
    pin: tuple[str, ...] = option(
        help="hold the cage vertices selected by AXIS OP VALUE in world units, or in % of the bounding box: "
        "'z<0.1', 'x>=-2', 'z<5%'; repeat for several",
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
        help="a static sphere obstacle, world units; repeat for several",
        repeat=True,
        metavar="X,Y,Z,R",
        parse=floats(4),
    )
    box: tuple[tuple[float, ...], ...] = option(
        help="a static axis-aligned box obstacle (centre, half extents), world units; repeat for several",
        repeat=True,
        metavar="X,Y,Z,HX,HY,HZ",
        parse=floats(6),
    )
    friction: float = option(0.5, help="Coulomb coefficient")
    damping: float = option(0.0, help="Kelvin-Voigt damping in seconds")
    tets: int | None = option(help="target cage tet count when the cage is built")
    out: str | None = option(help="motion file", shown_default="NAME_sim.npz")
    resume: bool = resume_option()
    overwrite: bool = overwrite_option()
    video: str | None = option(
        help="then render the motion (orbiting camera) to this MP4 and its frames to VIDEO_frames/ (with "
        "--mesh: the mesh's surface, drawn with pyvista); frames already there are kept only when they show "
        "the same motion frame, camera and size"
    )
    video_size: tuple[int, int] = option(
        (200, 200), help="WxH of the rendered frames", parse=pixels, shown_default="200x200"
    )
    device: str = option("auto", help="auto, cpu or cuda")

    def __post_init__(self):
        from shellsim.physics.fem import SimSettings
        from shellsim.physics.materials import RANGES, get_material

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
            check_range("tets", self.tets, 10, 1_000_000, "an integer")
        check_range("fps", self.fps, 0, MAX_FPS, "a number of frames per second", "(]")
        if self.size is not None:
            check_range("size", self.size, 1e-3, 1e3, "a length in metres")
        check_range("drop_height", self.drop_height, 0, 100, "a height in metres")  # lands below 45 m/s
        check_range("friction", self.friction, 0, 10, "a Coulomb coefficient")
        check_range("damping", self.damping, 0, 10, "a time in seconds")
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
            what = f"an angular speed in rad/s at --size {size:g}"  # the rim below max_speed
            check_range("spin", float(np.linalg.norm(self.spin)), 0, max_speed / size, what, "[)")
        for s in self.sphere:
            check_range("sphere", s[3], 0, math.inf, "a radius", "()")
        for b in self.box:
            check_range("box", min(b[3:]), 0, math.inf, "half extents", "()")
        if self.up is not None and not np.linalg.norm(self.up) > 0:
            raise SettingError("up", "the up axis must be a non-zero vector")

    @property
    def scale_size(self) -> float | None:
        """The body's largest extent in metres: ``size``, :data:`ASSET_SIZE` for an asset, None for a mesh
        kept in its own units."""
        return self.size if self.size is not None or self.mesh else ASSET_SIZE

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
    """out : the motion file; frames : its frame count; history : :class:`shellsim.physics.fem.StepStats` of the
    frames simulated now; video : the render's summary (None without ``video``)."""

    out: Path
    frames: int
    history: list
    video: dict | None = None


def simulate(settings: SimulateSettings, progress: bool = True) -> SimulateResult:
    """Run the simulation ``settings`` describe into ``settings.out_path`` (module docstring)."""
    from shellsim.io.outputs import check_writable_dir, check_writable_file
    from shellsim.motion.changes import describe_changes
    from shellsim.motion.format import MotionWriter
    from shellsim.physics.fem import SimulationError, Simulator, WorldMap, restore_state
    from shellsim.physics.fem import simulate as run_frames
    from shellsim.physics.materials import get_material

    s = settings
    out = check_writable_file(s.out_path, "out")
    if s.video:
        video = check_writable_file(s.video, "video")
        frames_dir = check_writable_dir(video.with_name(video.stem + "_frames"), "video")
    material = get_material(s.material, s.youngs, s.poisson, s.density)
    rules = [parse_selection(text) for text in s.pin]
    device = device_setting(s.device, warp=True)  # the simulator runs in Warp
    record = motion_settings(s)

    if out.is_file() and not s.overwrite:  # same settings: continue the file; other settings: refuse
        replace = "give {overwrite} to start it anew, or another {out}"
        writer = MotionWriter.resume(out)  # not a motion file: refused as it is, never replaced
        meta = writer.motion.meta
        if writer.motion.producer != "shellsim simulate" or not {"world", "up"} <= set(meta):
            raise SettingError("out", f"not a 'shellsim simulate' motion file; {replace}", out)
        changes = describe_changes(writer.motion.settings, record, _OPTIONS)
        if changes:
            raise SettingError("out", f"made with other settings ({'; '.join(changes)}); {replace}", out)
        _check_source(s, writer.motion)
        vertices, tets, up = writer.motion.rest_vertices, writer.motion.tets, np.asarray(meta["up"])
        world = WorldMap(tuple(meta["world"]["origin"]), float(meta["world"]["scale"]))
        log.info("resuming %s after frame %d", out, writer.n_frames - 1)
    else:
        writer = None
        vertices, tets, up, surface, asset = _load_cage(s)
        up = np.asarray(s.up if s.up is not None else up, np.float64)
        world, how = _world_map(s, vertices)
        log.info("%s: %s", s.name, how)
    up = up / np.linalg.norm(up)

    pinned = select_vertices(rules, vertices, "pin")
    sim_settings = _sim_settings(s, world, world.to_sim(vertices), up)
    sim = Simulator(world.to_sim(vertices), tets, material, sim_settings, pinned=pinned, device=device)
    if writer is None:
        if s.resume:
            log.info("%s does not exist: nothing to resume, starting it", out)
        sim.set_rigid_velocity(s.velocity, s.spin)
        meta = {
            "fps": s.fps,
            "up": [float(c) for c in up],
            "material": material.as_dict(),
            "world": {"origin": list(world.origin), "scale": world.scale, "scaling": how},
            "units": "positions in world units; meta.world.scale is metres per world unit; "
            "state.velocities in world units per second",
            "sim_settings": sim_settings.as_dict(),
        }
        if out.exists():
            log.info("--overwrite: replacing %s", out)
        writer = MotionWriter(
            out,
            vertices,
            tets,
            meta,
            surface=surface,
            producer="shellsim simulate",
            settings=record,
            asset=asset,
        )
    else:
        restore_state(sim, writer, world)

    # a new file starts with frame 0, the initial state
    remaining = max(s.frames - max(writer.n_frames, 1), 0)
    log.info(
        "%s: %d cage vertices, %d tets, %s (E=%.3g Pa, nu=%.3g, rho=%.4g kg/m^3), %d frames to go on %s",
        s.name,
        len(vertices),
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
            history = run_frames(sim, remaining, writer, world, progress=progress)
        except SimulationError as err:
            raise _failure(err, out, material) from None
    result = SimulateResult(out, writer.n_frames, history)
    if s.video:
        result.video = _render(s, out, frames_dir, video, s.device)
    return result


def _check_source(s: SimulateSettings, motion) -> None:
    """An :class:`InputError` unless the motion being continued moves the asset's cage
    (:meth:`shellsim.motion.format.Motion.check_against`) or was made from this content of the mesh file."""
    if s.asset:
        motion.check_against(_asset_cage(s)[1])
    elif motion.asset.get("digest") != _file_digest(Path(s.mesh)):
        raise InputError(
            f"{motion.path}: made from another content of {s.mesh} (changed since); give --overwrite to "
            "start it anew, or another --out"
        )


def _file_digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _render(s: SimulateSettings, out: Path, frames_dir: Path, video: Path, device: str) -> dict:
    """Render the motion ``out`` to ``frames_dir`` and ``video``: the asset, or a mesh's surface (pyvista);
    each frame already there is kept only if it records this motion frame and camera."""
    if s.asset:
        from shellsim.render.frames import render_motion

        return render_motion(
            s.asset, out, frames_dir, orbit=True, size=s.video_size, video=video, device=device
        )
    from shellsim.viz.surface import render_surface_motion

    return render_surface_motion(out, frames_dir, size=s.video_size, video=video)


def _sim_settings(s: SimulateSettings, world, rest_sim: np.ndarray, up: np.ndarray):
    """The :class:`shellsim.physics.fem.SimSettings` of the run: obstacles and the ground in simulation metres."""
    from shellsim.physics.contact import Box, Sphere
    from shellsim.physics.fem import SimSettings

    return SimSettings(
        dt=1.0 / s.fps,
        substeps=s.substeps,
        up=tuple(up),
        ground=float((rest_sim @ up).min() - s.drop_height) if s.ground else None,
        spheres=tuple(Sphere(tuple(world.to_sim(p[:3])), p[3] * world.scale) for p in s.sphere),
        boxes=tuple(Box(tuple(world.to_sim(b[:3])), tuple(np.multiply(b[3:], world.scale))) for b in s.box),
        friction=s.friction,
        damping=s.damping,
    )


def _asset_cage(s: SimulateSettings):
    """(asset, cage): the asset's stored cage when it fits ``tets``/``margin``, else one built and cached."""
    from neural.asset import load_asset
    from shellsim.cage.build import CageConfig
    from shellsim.cage.store import load_or_build_cage

    config = {k: v for k, v in (("target_tets", s.tets), ("margin", s.margin)) if v is not None}
    asset = load_asset(s.asset)
    return asset, load_or_build_cage(asset, CageConfig(**config) if config else None)


def _load_cage(s: SimulateSettings):
    """(vertices, tets, up, surface, asset) of the rest cage, world frame: an asset's cage
    (:func:`_asset_cage`, surface None), or a mesh tetrahedralised undilated and its surface embedded;
    ``asset`` is the motion's record of what it moves (name or path, and content digest)."""
    from neural.asset import load_mesh
    from shellsim.cage.build import CageConfig, build_cage

    if s.asset:
        asset, cage = _asset_cage(s)
        return cage.vertices, cage.tets, asset.up, None, {"name": asset.name, "digest": asset.digest()}
    mesh = load_mesh(Path(s.mesh))
    config = CageConfig(margin=0.0, **({"target_tets": s.tets} if s.tets else {}))
    cage = build_cage(mesh, mesh, config, what=str(s.mesh))
    record = {"mesh": str(Path(s.mesh).resolve()), "digest": _file_digest(Path(s.mesh))}
    return cage.vertices, cage.tets, np.array([0.0, 0.0, 1.0]), _mesh_surface(mesh, cage), record


def _mesh_surface(mesh, cage):
    """The surface of the trimesh ``mesh`` embedded in its cage: a :class:`shellsim.motion.format.Surface`."""
    from shellsim.cage.embed import embed_points
    from shellsim.motion.format import Surface

    tet, bary = embed_points(cage.vertices, cage.tets, np.asarray(mesh.vertices, np.float64))
    return Surface(tet, bary, np.asarray(mesh.faces, np.int64))


def _world_map(s: SimulateSettings, vertices: np.ndarray):
    """The :class:`shellsim.physics.fem.WorldMap` of the body (vertices (V, 3), world units) and one line saying how
    it is scaled, logged and kept in the motion's meta."""
    from shellsim.physics.fem import WorldMap

    extent = float(np.ptp(vertices, axis=0).max())
    size = s.scale_size
    if size is not None:
        world = WorldMap.fit(vertices, size)
        return world, (
            f"scaled by {world.scale:.6g} m per unit (largest extent {extent:.6g} units -> --size {size:g} m)"
        )
    units = s.units or "m"
    lo, hi = vertices.min(0), vertices.max(0)
    world = WorldMap(tuple(float(c) for c in (lo + hi) / 2), UNITS[units])
    return world, (
        f"not rescaled: coordinates in {units} ({world.scale:g} m per unit), "
        f"largest extent {extent * world.scale:.6g} m"
    )


def _failure(err, out: Path, material) -> SettingError:
    """The one line for a :class:`shellsim.physics.fem.SimulationError`: the frame, the value, what to change (the
    settings named as placeholders, which the command line shows as its options)."""
    advice = {
        "collapse": f"use a stiffer material ({{material}}, {{youngs}}; now {material.youngs:g} Pa), a "
        "smaller {size} or {drop_height}, or more {damping}",
        "speed": "lower {drop_height}, {velocity} or {spin}",
        "nonfinite": "use more {substeps} or a lower {drop_height}",
    }[err.kind]
    return SettingError(None, f"{err}; frames 0-{err.frame - 1} are kept in {out}; {advice}")
