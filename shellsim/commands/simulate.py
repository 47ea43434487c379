"""``shellsim simulate``: drop an asset's cage (or a closed mesh, tetrahedralised) as an elastic body.

Thin: parse, build the cage and the :class:`shellsim.fem.Simulator`, drive :func:`shellsim.fem.simulate`
into a motion file, report. The world frame is kept: the cage is scaled so that its largest extent measures
``--size`` metres, simulated in SI units, and written back in world coordinates (``meta['world']`` holds the
scale). ``--resume`` continues ``--out`` from its last frame with the velocities stored in its meta.
"""

from __future__ import annotations

import argparse
import logging
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from neural.errors import InputError
from shellsim.commands.args import parse_floats, parse_size
from shellsim.commands.outputs import check_writable_dir, check_writable_file

log = logging.getLogger(__name__)

_NUMBER = r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?"
_PIN = re.compile(rf"\s*([xyzXYZ])\s*(<=|>=|<|>)\s*({_NUMBER})\s*(%?)\s*")


@dataclass(frozen=True)
class PinRule:
    """``AXIS OP VALUE[%]``: select vertices whose world coordinate ``axis`` (0, 1, 2) compares with
    ``value`` (world units, or percent of the bounding box along the axis, measured from its minimum)."""

    axis: int
    op: str
    value: float
    percent: bool

    def select(self, vertices: np.ndarray) -> np.ndarray:
        """(V,) bool mask of the vertices (V, 3) the rule selects."""
        coord = vertices[:, self.axis]
        threshold = self.value
        if self.percent:
            threshold = coord.min() + self.value / 100.0 * (coord.max() - coord.min())
        compare = {"<": np.less, "<=": np.less_equal, ">": np.greater, ">=": np.greater_equal}[self.op]
        return compare(coord, threshold)


def parse_pin(text: str) -> PinRule:
    """Parse ``"z<0.1"``, ``"x >= -2"``, ``"y>95%"`` with a strict grammar (never evaluated)."""
    match = _PIN.fullmatch(text)
    value = float(match.group(3)) if match else math.nan
    if not match or not math.isfinite(value):
        raise InputError(
            f"--pin {text!r}: expected AXIS OP VALUE, e.g. 'z<0.1', 'x>=-2' or 'z<5%' "
            "(AXIS x, y or z; OP <, <=, > or >=; VALUE a number in world units or a percentage)"
        )
    return PinRule("xyz".index(match.group(1).lower()), match.group(2), value, bool(match.group(4)))


def register(sub: argparse._SubParsersAction) -> None:
    # numpy only; shellsim.fem (warp) is imported when the command runs
    from shellsim.materials import PRESETS

    p = sub.add_parser(
        "simulate",
        help="simulate an asset's cage (or a closed mesh) as an elastic body; writes a motion file",
        description="Implicit hyperelastic FEM (stable Neo-Hookean, backward Euler) of the cage under "
        "gravity, with ground and obstacle contact and friction. Writes a motion file (render it with "
        "'shellsim render'). Interrupt at any time; --resume continues it.",
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
        default=0.3,
        help="physical size in metres of the cage's largest extent (default 0.3)",
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
    p.add_argument("--resume", action="store_true", help="continue OUT after its last frame")
    p.add_argument(
        "--video",
        help="then render the motion (orbiting camera) to this MP4 and its frames to VIDEO_frames/; needs "
        "--asset; frames already there are kept with --resume, rendered anew otherwise",
    )
    p.add_argument("--video-size", default="200x200", help="WxH of the rendered frames (default 200x200)")
    p.add_argument("--device", default="auto", help="auto, cpu or cuda (default auto)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    if args.video and not args.asset:
        raise InputError("--video renders the neural asset: it needs --asset, not --mesh")
    size = parse_size("--video-size", args.video_size) if args.video else None
    if args.video:
        video = check_writable_file(args.video, "--video")
        check_writable_dir(video.with_name(video.stem + "_frames"), "--video")
    out = simulate_to_file(args)
    log.info("motion written to %s", out)
    if args.video:
        from shellsim.render import render_motion

        video = Path(args.video)
        frames_dir = video.with_name(video.stem + "_frames")
        summary = render_motion(  # a new motion's frames replace any earlier ones; --resume keeps them
            args.asset,
            out,
            frames_dir,
            orbit=True,
            size=size,
            video=video,
            overwrite=not args.resume,
            device=args.device,
        )
        log.info(
            "rendered %d frames (%d already there) to %s and the video %s",
            summary["rendered"],
            summary["skipped"],
            frames_dir,
            video,
        )


def _device(name: str) -> str:
    import warp as wp

    has_cuda = wp.get_cuda_device_count() > 0
    if name == "auto":
        return "cuda:0" if has_cuda else "cpu"
    if name not in ("cpu", "cuda"):
        raise InputError(f"--device: expected auto, cpu or cuda, got {name!r}")
    if name == "cuda" and not has_cuda:
        raise InputError("--device cuda: no CUDA device is available on this machine")
    return "cuda:0" if name == "cuda" else "cpu"


def _parameters(args: argparse.Namespace, material, up) -> dict:
    """Everything that defines the simulation, as stored in ``meta['params']`` and checked on --resume."""
    return {
        "source": {"asset": args.asset} if args.asset else {"mesh": str(Path(args.mesh).resolve())},
        "material": material.as_dict(),
        "fps": args.fps,
        "substeps": args.substeps,
        "size": args.size,
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


def _load_cage(args: argparse.Namespace):
    """(vertices, tets, up) of the rest cage, world frame."""
    from neural.asset import load_asset, load_mesh
    from shellsim import cage as cages

    config = cages.CageConfig(target_tets=args.tets) if args.tets else None
    if args.asset:
        asset = load_asset(args.asset)
        cage = cages.load_or_build_cage(asset, config)
        up = asset.up
    else:
        mesh = load_mesh(Path(args.mesh))
        cage = cages.build_cage(mesh, mesh, config, what=str(args.mesh))
        up = np.array([0.0, 0.0, 1.0])
    return cage.vertices, cage.tets, up


def simulate_to_file(args: argparse.Namespace) -> Path:
    """Run the simulation the arguments describe; returns the motion file written."""
    from shellsim.contact import Box, Sphere
    from shellsim.fem import SimSettings, Simulator, WorldMap, restore_state, simulate
    from shellsim.materials import get_material
    from shellsim.motion import MotionWriter

    for flag, value in (("--frames", args.frames), ("--substeps", args.substeps)):
        if value < 1:
            raise InputError(f"{flag}: expected a positive integer, got {value}")
    if args.tets is not None and args.tets < 10:
        raise InputError(f"--tets: expected at least 10, got {args.tets}")
    for flag, value in (("--fps", args.fps), ("--size", args.size)):
        if not (math.isfinite(value) and value > 0):
            raise InputError(f"{flag}: expected a positive number, got {value}")
    for flag, value in (
        ("--drop-height", args.drop_height),
        ("--friction", args.friction),
        ("--damping", args.damping),
    ):
        if not (math.isfinite(value) and value >= 0):
            raise InputError(f"{flag}: expected a number >= 0, got {value}")
    material = get_material(args.material, args.youngs, args.poisson, args.density)
    rules = [parse_pin(text) for text in args.pin]
    device = _device(args.device)
    name = Path(args.mesh).stem if args.mesh else Path(args.asset).name
    out = check_writable_file(Path(args.out) if args.out else Path(f"{name}_sim.npz"), "--out")

    writer = None
    if args.resume and out.is_file():
        writer = MotionWriter.resume(out)
        meta = writer.motion.meta
        if not {"params", "world", "state"} <= set(meta):
            raise InputError(f"{out}: not a 'shellsim simulate' motion file; cannot --resume it")
        up = np.asarray(meta["params"]["up"]) if args.up is None else parse_floats("--up", args.up, 3)
        params = _parameters(args, material, up)
        changed = [k for k, v in params.items() if meta["params"].get(k) != v]
        if changed:
            raise InputError(f"--resume {out}: these settings differ from the file's: {', '.join(changed)}")
        vertices, tets = writer.motion.rest_vertices, writer.motion.tets
        world = WorldMap(tuple(meta["world"]["origin"]), float(meta["world"]["scale"]))
        log.info("resuming %s after frame %d", out, writer.n_frames - 1)
    else:
        vertices, tets, up = _load_cage(args)
        if args.up is not None:
            up = parse_floats("--up", args.up, 3)
        params = _parameters(args, material, up)
        world = WorldMap.fit(vertices, args.size)
    if np.linalg.norm(up) == 0:
        raise InputError("--up: the up axis must be a non-zero vector")
    up = np.asarray(up, np.float64) / np.linalg.norm(up)

    pinned = np.zeros(len(vertices), bool)
    for text, rule in zip(args.pin, rules, strict=True):
        chosen = rule.select(vertices)
        if not chosen.any():
            lo, hi = vertices[:, rule.axis].min(), vertices[:, rule.axis].max()
            raise InputError(
                f"--pin {text!r} selects no cage vertex ({'xyz'[rule.axis]} spans {lo:.4g}..{hi:.4g})"
            )
        pinned |= chosen
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
        sim.set_rigid_velocity(params["velocity"], params["spin"])
        meta = {
            "producer": "shellsim simulate",
            "params": params,
            "world": {"origin": list(world.origin), "scale": world.scale},
            "units": "positions in world units; meta.world.scale is metres per world unit; "
            "state.velocities in world units per second",
            "settings": settings.as_dict(),
            "cage": {"vertices": len(vertices), "tets": len(tets)},
        }
        if out.exists():
            log.info("overwriting %s", out)
        writer = MotionWriter(out, vertices, tets, meta)
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
        history = simulate(sim, max(remaining, 0), writer, world)
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
