"""``shellsim simulate``: drop an asset's cage (or a closed mesh, tetrahedralised) as an elastic body.

Thin: parse, build the cage and the :class:`shellsim.fem.Simulator`, drive :func:`shellsim.fem.simulate`
into a motion file, report. The world frame is kept: an asset's cage is scaled so that its largest extent
measures ``--size`` metres (default 0.3); a ``--mesh`` is the body itself, in metres (or ``--units``), not
dilated, and scaled only when ``--size`` asks. It is simulated in SI units and written back in world
coordinates (``meta['world']`` holds the scale and why). An existing ``--out`` made with the same settings
is continued from its last frame with the velocities stored in its meta; one made with other settings is
refused unless ``--overwrite``.
"""

from __future__ import annotations

import argparse
import logging
import math
from pathlib import Path

import numpy as np

from neural.errors import InputError
from shellsim.commands.args import (
    MAX_FPS,
    MAX_FRAMES,
    add_resume_options,
    check_range,
    device_option,
    parse_floats,
    parse_size,
)
from shellsim.outputs import check_writable_dir, check_writable_file
from shellsim.selection import parse_selection, select_vertices

log = logging.getLogger(__name__)

#: Metres per unit of a --mesh file's coordinates (--units).
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "ft": 0.3048}
#: Size in metres of an asset's largest extent when --size is not given.
ASSET_SIZE = 0.3


def register(sub: argparse._SubParsersAction) -> None:
    # numpy only; shellsim.fem (warp) is imported when the command runs
    from shellsim.materials import PRESETS

    p = sub.add_parser(
        "simulate",
        help="simulate an asset's cage (or a closed mesh) as an elastic body; writes a motion file",
        description="Implicit hyperelastic FEM (stable Neo-Hookean, backward Euler) of the cage under "
        "gravity, with ground and obstacle contact and friction. Writes a motion file (render it with "
        "'shellsim render'). Interrupt at any time: run again, and an OUT made with the same settings is "
        "continued; one made with other settings is refused unless --overwrite.",
    )
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--asset", help="asset directory or shipped asset name (its cage is used)")
    src.add_argument("--mesh", help="a closed triangle mesh file to tetrahedralise and simulate")
    p.add_argument("--material", default="rubber", help=f"preset: {', '.join(PRESETS)} (default rubber)")
    p.add_argument("--youngs", type=float, help="Young's modulus in Pa, overriding the preset")
    p.add_argument("--poisson", type=float, help="Poisson ratio in (-1, 0.5), overriding the preset")
    p.add_argument("--density", type=float, help="density in kg/m^3, overriding the preset")
    p.add_argument(
        "--frames", type=int, default=90, help="number of frames, the first the initial state (90)"
    )
    p.add_argument("--fps", type=float, default=30.0, help="frames per second (default 30)")
    p.add_argument("--substeps", type=int, default=8, help="implicit steps per frame (default 8)")
    p.add_argument(
        "--size",
        type=float,
        help=f"scale the body so that its largest extent measures this many metres (default {ASSET_SIZE} "
        "for --asset; a --mesh keeps its own size, see --units)",
    )
    p.add_argument(
        "--units",
        choices=list(UNITS),
        help="length unit of the --mesh file's coordinates (default m); not with --size",
    )
    p.add_argument(
        "--margin",
        type=float,
        help="dilation of the asset's outer shell when its cage is built, relative to its bounding-box "
        "diagonal (default 0.02); a --mesh is tetrahedralised as it is",
    )
    p.add_argument(
        "--drop-height",
        type=float,
        default=0.1,
        help="gap in metres between the lowest cage vertex and the ground (default 0.1)",
    )
    p.add_argument("--no-ground", action="store_true", help="no ground plane")
    p.add_argument("--up", help="up axis x,y,z: gravity points against it (default: the asset's, or 0,0,1)")
    p.add_argument(
        "--pin",
        action="append",
        default=[],
        metavar="RULE",
        help="hold the cage vertices selected by AXIS OP VALUE in world units, or in %% of the "
        "bounding box: 'z<0.1', 'x>=-2', 'z<5%%'; repeat for several",
    )
    p.add_argument("--velocity", help="initial velocity vx,vy,vz in m/s")
    p.add_argument("--spin", help="initial angular velocity wx,wy,wz in rad/s about the centre of mass")
    p.add_argument(
        "--sphere",
        action="append",
        default=[],
        metavar="X,Y,Z,R",
        help="a static sphere obstacle, world units; repeat for several",
    )
    p.add_argument(
        "--box",
        action="append",
        default=[],
        metavar="X,Y,Z,HX,HY,HZ",
        help="a static axis-aligned box obstacle (centre, half extents), world units",
    )
    p.add_argument("--friction", type=float, default=0.5, help="Coulomb coefficient (default 0.5)")
    p.add_argument("--damping", type=float, default=0.0, help="Kelvin-Voigt damping in seconds (default 0)")
    p.add_argument("--tets", type=int, help="target cage tet count when the cage is built")
    p.add_argument("--out", help="motion file (default NAME_sim.npz)")
    add_resume_options(p)
    p.add_argument(
        "--video",
        help="then render the motion (orbiting camera) to this MP4 and its frames to VIDEO_frames/ (with "
        "--mesh: the mesh's surface, drawn with pyvista); frames already there are kept only when they show "
        "the same motion frame, camera and size",
    )
    p.add_argument("--video-size", default="200x200", help="WxH of the rendered frames (default 200x200)")
    p.add_argument("--device", default="auto", help="auto, cpu or cuda (default auto)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    size = parse_size("--video-size", args.video_size) if args.video else None
    if args.video:
        video = check_writable_file(args.video, "--video")
        frames_dir = check_writable_dir(video.with_name(video.stem + "_frames"), "--video")
    out = simulate_to_file(args)
    log.info("motion written to %s", out)
    if args.video:
        # each frame is kept only if it records this motion frame and camera
        if args.asset:
            from shellsim.render import render_motion

            summary = render_motion(
                args.asset, out, frames_dir, orbit=True, size=size, video=video, device=args.device
            )
        else:  # a mesh: its surface moved by the cage, drawn with pyvista
            from shellsim.inspect import quiet_vtk
            from shellsim.surface import render_surface_motion

            if not args.verbose:
                quiet_vtk()
            summary = render_surface_motion(out, frames_dir, size=size, video=video)
        log.info(
            "rendered %d frames (%d already there) to %s and the video %s",
            summary["rendered"],
            summary["skipped"],
            frames_dir,
            video,
        )


def _parameters(args: argparse.Namespace, material, up) -> dict:
    """Everything that defines the simulation, as stored in ``meta['params']`` and checked on --resume."""
    return {
        "source": {"asset": args.asset} if args.asset else {"mesh": str(Path(args.mesh).resolve())},
        "material": material.as_dict(),
        "fps": args.fps,
        "substeps": args.substeps,
        "size": args.size,
        "units": args.units,
        "margin": args.margin,
        "drop_height": None if args.no_ground else args.drop_height,
        "up": [float(c) for c in up],
        "pins": list(args.pin),
        "velocity": list(parse_floats("--velocity", args.velocity, 3)) if args.velocity else [0.0, 0.0, 0.0],
        "spin": list(parse_floats("--spin", args.spin, 3)) if args.spin else [0.0, 0.0, 0.0],
        "spheres": [list(parse_floats("--sphere", s, 4)) for s in args.sphere],
        "boxes": [list(parse_floats("--box", b, 6)) for b in args.box],
        "friction": args.friction,
        "damping": args.damping,
        "tets": args.tets,
    }


#: The option behind each key of :func:`_parameters` whose name is not ``--key-with-dashes``.
_OPTIONS = {
    "source.asset": "--asset",
    "source.mesh": "--mesh",
    "material.name": "--material",
    "material.youngs": "Young's modulus (--youngs)",
    "material.poisson": "Poisson ratio (--poisson)",
    "material.density": "density (--density)",
    "pins": "--pin",
    "spheres": "--sphere",
    "boxes": "--box",
    "drop_height": "--drop-height (none: --no-ground)",
}


def _check_scale_options(args: argparse.Namespace) -> None:
    """Refuse --size/--units/--margin that do not fit the source; an asset's --size defaults to ASSET_SIZE."""
    if args.units is not None and (args.asset or args.size is not None):
        raise InputError(
            "--units: gives the unit of a --mesh file's coordinates; "
            + ("an asset is scaled by --size" if args.asset else "not with --size, which sets the size")
        )
    if args.margin is not None:
        if args.mesh:
            raise InputError("--margin: dilates an asset's shell into its cage; a --mesh is the body itself")
        check_range("--margin", args.margin, 0, 1, "a fraction of the shell's diagonal", "(]")
    if args.asset and args.size is None:
        args.size = ASSET_SIZE


def _load_cage(args: argparse.Namespace):
    """(vertices, tets, up, surface) of the rest cage, world frame. An asset's cage is its stored one when it
    fits --tets/--margin (surface None); a --mesh is tetrahedralised undilated (margin 0) and its surface
    embedded in the cage (:func:`_mesh_surface`)."""
    from neural.asset import load_asset, load_mesh
    from shellsim import cage as cages

    if args.asset:
        settings = {"target_tets": args.tets, "margin": args.margin}
        settings = {k: v for k, v in settings.items() if v is not None}
        asset = load_asset(args.asset)
        cage = cages.load_or_build_cage(asset, cages.CageConfig(**settings) if settings else None)
        return cage.vertices, cage.tets, asset.up, None
    mesh = load_mesh(Path(args.mesh))
    config = cages.CageConfig(margin=0.0, **({"target_tets": args.tets} if args.tets else {}))
    cage = cages.build_cage(mesh, mesh, config, what=str(args.mesh))
    return cage.vertices, cage.tets, np.array([0.0, 0.0, 1.0]), _mesh_surface(mesh, cage.vertices, cage.tets)


MAX_SUBSTEPS = 1000  # per frame; a retried frame runs up to 4 times as many


def _check_numbers(args: argparse.Namespace) -> None:
    """Every numeric option in its valid range, or an InputError naming it and the range."""
    from shellsim.fem import SimSettings
    from shellsim.materials import RANGES

    check_range("--frames", args.frames, 1, MAX_FRAMES, "an integer")
    check_range("--substeps", args.substeps, 1, MAX_SUBSTEPS, "an integer")
    if args.tets is not None:
        check_range("--tets", args.tets, 10, 1_000_000, "an integer")
    check_range("--fps", args.fps, 0, MAX_FPS, "a number of frames per second", "(]")
    if args.size is not None:
        check_range("--size", args.size, 1e-3, 1e3, "a length in metres")
    check_range("--drop-height", args.drop_height, 0, 100, "a height in metres")  # lands below 45 m/s
    check_range("--friction", args.friction, 0, 10, "a Coulomb coefficient")
    check_range("--damping", args.damping, 0, 10, "a time in seconds")
    for flag, value, what in (
        ("--youngs", args.youngs, "a Young's modulus in Pa"),
        ("--poisson", args.poisson, "a Poisson ratio"),
        ("--density", args.density, "a density in kg/m^3"),
    ):
        if value is not None:
            low, high, ends = RANGES[flag[2:]]
            check_range(flag, value, low, high, what, ends)
    max_speed = SimSettings.max_speed  # [m/s]: a faster vertex stops the simulation
    if args.velocity:
        speed = float(np.linalg.norm(parse_floats("--velocity", args.velocity, 3)))
        check_range("--velocity", speed, 0, max_speed, "a speed in m/s (the simulator's limit)", "[)")
    if args.spin and args.size is not None:  # a --mesh in its own units: the simulator checks speeds
        rate = float(np.linalg.norm(parse_floats("--spin", args.spin, 3)))
        what = f"an angular speed in rad/s at --size {args.size:g}"  # the rim below max_speed
        check_range("--spin", rate, 0, max_speed / args.size, what, "[)")
    for text in args.sphere:
        check_range("--sphere", parse_floats("--sphere", text, 4)[3], 0, math.inf, "a radius", "()")
    for text in args.box:
        check_range("--box", min(parse_floats("--box", text, 6)[3:]), 0, math.inf, "half extents", "()")


def _failure_line(err, out: Path, args: argparse.Namespace, material) -> str:
    """The one line for a :class:`shellsim.fem.SimulationError`: the frame, the value, what to change."""
    advice = {
        "collapse": f"use a stiffer material (--material, --youngs; now {material.youngs:g} Pa), a smaller "
        "--size or --drop-height, or more --damping",
        "speed": "lower --drop-height, --velocity or --spin",
        "nonfinite": "use more --substeps or a lower --drop-height",
    }[err.kind]
    return f"{err}; frames 0-{err.frame - 1} are kept in {out}; {advice}"


def _mesh_surface(mesh, vertices: np.ndarray, tets: np.ndarray):
    """The surface of the trimesh ``mesh`` embedded in its cage (vertices (V, 3), tets (T, 4)), so the
    motion file can show it: a :class:`shellsim.motion.Surface`."""
    from shellsim.embed import embed_points
    from shellsim.motion import Surface

    tet, bary = embed_points(vertices, tets, np.asarray(mesh.vertices, np.float64))
    return Surface(tet, bary, np.asarray(mesh.faces, np.int64))


def _world_map(args: argparse.Namespace, vertices: np.ndarray):
    """The :class:`shellsim.fem.WorldMap` of the body (vertices (V, 3), world units) and one line saying
    how it is scaled, logged and kept in the motion's meta."""
    from shellsim.fem import WorldMap

    extent = float(np.ptp(vertices, axis=0).max())
    if args.size is not None:
        world = WorldMap.fit(vertices, args.size)
        return world, (
            f"scaled by {world.scale:.6g} m per unit (largest extent {extent:.6g} units -> "
            f"--size {args.size:g} m)"
        )
    units = args.units or "m"
    lo, hi = vertices.min(0), vertices.max(0)
    world = WorldMap(tuple(float(c) for c in (lo + hi) / 2), UNITS[units])
    return world, (
        f"not rescaled: coordinates in {units} ({world.scale:g} m per unit), "
        f"largest extent {extent * world.scale:.6g} m"
    )


def simulate_to_file(args: argparse.Namespace) -> Path:
    """Run the simulation the arguments describe; returns the motion file written."""
    from shellsim.contact import Box, Sphere
    from shellsim.fem import SimSettings, SimulationError, Simulator, WorldMap, restore_state, simulate
    from shellsim.materials import get_material
    from shellsim.motion import MotionWriter, describe_changes

    _check_scale_options(args)
    _check_numbers(args)
    material = get_material(args.material, args.youngs, args.poisson, args.density)
    rules = [parse_selection(text, "--pin") for text in args.pin]
    device = device_option(args.device, warp=True)
    name = Path(args.mesh).stem if args.mesh else Path(args.asset).name
    out = check_writable_file(Path(args.out) if args.out else Path(f"{name}_sim.npz"), "--out")

    writer = None
    if out.is_file() and not args.overwrite:  # same settings: continue the file; other settings: refuse
        replace = "give --overwrite to start it anew, or another --out"
        writer = MotionWriter.resume(out)  # not a motion file: refused as it is, never replaced
        meta = writer.motion.meta
        if not {"params", "world", "state"} <= set(meta):
            raise InputError(f"{out}: not a 'shellsim simulate' motion file; {replace}")
        up = np.asarray(meta["params"]["up"]) if args.up is None else parse_floats("--up", args.up, 3)
        params = _parameters(args, material, up)
        changes = describe_changes(meta["params"], params, _OPTIONS)
        if changes:
            raise InputError(f"{out}: made with other settings ({'; '.join(changes)}); {replace}")
        vertices, tets = writer.motion.rest_vertices, writer.motion.tets
        world = WorldMap(tuple(meta["world"]["origin"]), float(meta["world"]["scale"]))
        log.info("resuming %s after frame %d", out, writer.n_frames - 1)
    else:
        vertices, tets, up, surface = _load_cage(args)
        if args.up is not None:
            up = parse_floats("--up", args.up, 3)
        params = _parameters(args, material, up)
        world, how = _world_map(args, vertices)
        log.info("%s: %s", name, how)
    if np.linalg.norm(up) == 0:
        raise InputError("--up: the up axis must be a non-zero vector")
    up = np.asarray(up, np.float64) / np.linalg.norm(up)

    pinned = select_vertices(rules, vertices, "--pin")
    rest_sim = world.to_sim(vertices)
    settings = SimSettings(
        dt=1.0 / args.fps,
        substeps=args.substeps,
        up=tuple(up),
        ground=None if args.no_ground else float((rest_sim @ up).min() - args.drop_height),
        spheres=tuple(Sphere(tuple(world.to_sim(s[:3])), s[3] * world.scale) for s in params["spheres"]),
        boxes=tuple(
            Box(tuple(world.to_sim(b[:3])), tuple(np.multiply(b[3:], world.scale))) for b in params["boxes"]
        ),
        friction=args.friction,
        damping=args.damping,
    )
    sim = Simulator(rest_sim, tets, material, settings, pinned=pinned, device=device)
    if writer is None:
        if args.resume:
            log.info("%s does not exist: nothing to resume, starting it", out)
        sim.set_rigid_velocity(params["velocity"], params["spin"])
        meta = {
            "producer": "shellsim simulate",
            "params": params,
            "world": {"origin": list(world.origin), "scale": world.scale, "scaling": how},
            "units": "positions in world units; meta.world.scale is metres per world unit; "
            "state.velocities in world units per second",
            "settings": settings.as_dict(),
            "cage": {"vertices": len(vertices), "tets": len(tets)},
        }
        if out.exists():
            log.info("--overwrite: replacing %s", out)
        writer = MotionWriter(out, vertices, tets, meta, surface=surface)
    else:
        restore_state(sim, writer, world)

    remaining = args.frames - max(writer.n_frames, 1)  # a new file starts with frame 0, the initial state
    log.info(
        "%s: %d cage vertices, %d tets, %s (E=%.3g Pa, nu=%.3g, rho=%.4g kg/m^3), %d frames to go on %s",
        name,
        len(vertices),
        len(tets),
        material.name,
        material.youngs,
        material.poisson,
        material.density,
        max(remaining, 0),
        device,
    )
    with writer:
        try:
            history = simulate(sim, max(remaining, 0), writer, world)
        except SimulationError as err:
            raise InputError(_failure_line(err, out, args, material)) from None
    if history:
        substeps = sum(h.substeps for h in history)
        log.info(
            "%d frames: %.1f ms per substep, %.2f Newton iterations per substep, %d retried frames",
            len(history),
            1e3 * sum(h.seconds for h in history) / substeps,
            sum(h.newton_iterations for h in history) / substeps,
            sum(h.retries > 0 for h in history),
        )
    return out
