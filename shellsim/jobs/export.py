"""Export a motion (of an asset's cage, of a simulated mesh, or a scene's) to USD, a VTU series or a PLY
sequence. A scene's export holds every body (a neural one's M+ through its cage, a mesh's surface) and every
collider, in world metres, z up."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shellsim.errors import SettingError
from shellsim.io.outputs import holds_outputs
from shellsim.settings import check_required, option

FORMATS = ("usd", "vtu", "ply")


@dataclass(frozen=True)
class ExportSettings:
    """What :func:`export` writes: ``motion`` (a motion file) as ``format`` to ``out``."""

    motion: str = option(
        help="motion file written by 'shellsim simulate' or 'shellsim wind', or the output directory (or its "
        "motion.npz) of 'shellsim scene'",
        required=True,
    )
    out: str = option(
        help="file to write: a .usd/.usda/.usdc stage, a .pvd index (its .vtu files go in OUT_STEM_vtu/) or "
        "a directory of .ply files",
        required=True,
    )
    format: str = option("usd", help="usd, vtu or ply", choices=FORMATS)
    asset: str | None = option(
        help="asset directory or shipped asset name whose outer shell M+ the motion deforms (a motion of "
        "'simulate --mesh' carries its own surface and needs none, a scene's bodies name their own)"
    )
    frames: str | None = option(
        help="START:END[:STEP] (END exclusive; every STEP-th frame) or one frame number", shown_default="all"
    )
    overwrite: bool = option(help="replace OUT if it exists")

    def __post_init__(self):
        check_required(self)
        if self.format not in FORMATS:
            raise SettingError("format", f"expected one of {', '.join(FORMATS)}, got {self.format!r}")
        suffix = Path(self.out).suffix.lower()
        wanted = {"usd": (".usd", ".usda", ".usdc"), "vtu": (".pvd",), "ply": ("",)}[self.format]
        if suffix not in wanted:
            expected = " or ".join(w or "a directory name without suffix" for w in wanted)
            raise SettingError("out", f"a {self.format} export is written to {expected}, got {self.out!r}")


@dataclass(frozen=True)
class ExportResult:
    """What :func:`export` wrote: ``out`` (the USD stage, the .pvd index or the PLY directory) in ``format``,
    ``files`` every file written (the index or stage last), ``frames`` the motion frames exported."""

    out: Path
    format: str
    files: list[Path]
    frames: int


def _compact(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(used vertex indices (U,), faces (F, 3) renumbered into them) of faces indexing a larger vertex set."""
    used, renumbered = np.unique(faces, return_inverse=True)
    return used, renumbered.reshape(faces.shape)


def _meshes(settings: ExportSettings, motion):
    """The moving meshes of ``motion`` (list of AnimatedMesh): the asset's M+ (through its cage, with the
    field's colour at each vertex, :func:`shellsim.film.shell_colors.shell_colors`), the surface a
    'simulate --mesh' motion carries, and the cage's boundary last, a guide (not rendered)."""
    from shellsim.deform.inverse_map import deform_points
    from shellsim.io.export import AnimatedMesh
    from shellsim.tetcage.geometry import boundary_faces
    from shellsim.tetcage.store import cage_for_motion

    meshes = []
    if settings.asset is not None:
        from neural.asset import load_asset, load_field
        from shellsim.film.shell_colors import shell_colors

        asset = load_asset(settings.asset)
        cage = cage_for_motion(asset, motion, settings.motion)
        outer = np.asarray(asset.outer_mesh().faces, np.int64)
        colors = shell_colors(asset, load_field(asset, "cpu"))
        meshes.append(
            AnimatedMesh(
                "outer_shell",
                outer,
                lambda k: deform_points(motion.positions[k], cage.tets, cage.outer_tet, cage.outer_bary),
                colors,
            )
        )
    if motion.surface is not None:
        meshes.append(AnimatedMesh("surface", motion.surface.faces, motion.surface_points))
    if not meshes:
        raise SettingError(
            "motion", "the motion of an asset's cage needs {asset} to export its shell", value=settings.motion
        )
    used, faces = _compact(boundary_faces(motion.tets))
    return [*meshes, AnimatedMesh("cage", faces, lambda k: motion.positions[k][used], purpose="guide")]


def _scene_meshes(path: Path, motion) -> list:
    """The meshes of the scene motion ``motion`` (its file ``path``; list of AnimatedMesh), in world metres:
    each body's visible surface (:func:`_body_meshes`) under its name, each collider (static, in its
    ``color``, else the scene's ``[look] collider_color``) under its name, then each body's cage boundary
    ``<body>_cage`` (a guide). An :class:`InputError` naming ``path`` when two names would clash."""
    from collections import Counter

    from neural.errors import InputError
    from shellsim.io.export import AnimatedMesh, safe_name
    from shellsim.shot.bodies import collider_mesh
    from shellsim.shot.recorded import read_scene_motion
    from shellsim.tetcage.geometry import boundary_faces

    scene = read_scene_motion(path)
    boundary, colors = boundary_faces(motion.tets), {}
    surfaces, guides = zip(*(_body_meshes(b, motion, boundary, colors) for b in scene.bodies), strict=True)
    colliders = []
    for spec in scene.colliders:
        vertices, faces = collider_mesh(spec)
        color = scene.look.collider_color if spec.color is None else spec.color
        colliders.append(AnimatedMesh(spec.name, faces, lambda k, v=vertices: v, color, static=True))
    meshes = [*surfaces, *colliders, *guides]
    clashes = [n for n, count in Counter(safe_name(m.name) for m in meshes).items() if count > 1]
    if clashes:
        raise InputError(
            f"{path}: two of its bodies, colliders and cages would be exported as {clashes[0]!r}; rename "
            "one in the scene file and make the scene again"
        )
    return meshes


def _body_meshes(body, motion, boundary: np.ndarray, colors: dict) -> tuple:
    """(surface, cage guide) AnimatedMeshes of the scene body ``body``
    (:class:`shellsim.shot.recorded.MotionBody`) of ``motion``, in world metres. A neural body's surface is
    its asset's M+ deformed by its cage (barycentric in the cage's world positions: the same as in the
    asset's frame mapped to the world, a placement being affine) with its field's colours (kept in
    ``colors`` by asset directory for the next body of that asset) times its tint; a mesh body's is its own
    surface in its colour. The guide is its share of ``boundary`` (F, 3), the boundary faces of the
    motion's tets."""
    from neural.asset import load_field
    from shellsim.deform.inverse_map import deform_points
    from shellsim.film.shell_colors import shell_colors
    from shellsim.io.export import AnimatedMesh

    def share(k: int) -> np.ndarray:
        return motion.positions[k][body.vertices]

    if body.asset is None:
        surface = AnimatedMesh(
            body.name, body.surface_faces, lambda k: body.surface_points(share(k)), body.color
        )
    else:
        cage = body.cage

        def shell(k: int) -> np.ndarray:
            return deform_points(share(k), cage.tets, cage.outer_tet, cage.outer_bary)

        root = body.asset.root.resolve()
        if root not in colors:
            colors[root] = shell_colors(body.asset, load_field(body.asset, "cpu"))
        outer = np.asarray(body.asset.outer_mesh().faces, np.int64)
        tint = np.ones(3) if body.color is None else np.asarray(body.color)
        surface = AnimatedMesh(body.name, outer, shell, colors[root] * tint)
    lo, hi = body.vertices.start, body.vertices.stop
    used, faces = _compact(boundary[(boundary[:, 0] >= lo) & (boundary[:, 0] < hi)])
    guide = AnimatedMesh(f"{body.name}_cage", faces, lambda k: motion.positions[k][used], purpose="guide")
    return surface, guide


@holds_outputs
def export(settings: ExportSettings, progress: bool = True) -> ExportResult:
    """Write the export ``settings`` describe; a scene motion (:func:`shellsim.shot.recorded.is_scene_motion`)
    is exported whole (:func:`_scene_meshes`), in world metres, z up."""
    from tqdm import tqdm

    from shellsim.film.motion_frames import motion_fps
    from shellsim.io.export import require_usd, write_ply_sequence, write_usd, write_vtu_series
    from shellsim.io.outputs import check_writable_dir, check_writable_file, lock_output
    from shellsim.motion.read import load_motion, read_motion_info
    from shellsim.settings import parse_frames
    from shellsim.shot.recorded import is_scene_motion, motion_path
    from shellsim.tetcage.geometry import volume_ratios

    if settings.format == "usd":
        require_usd()
    out = Path(settings.out)
    (check_writable_dir if settings.format == "ply" else check_writable_file)(out, "out")
    lock_output(out, "out")
    taken = out.is_dir() and any(out.iterdir()) if settings.format == "ply" else out.exists()
    if taken and not settings.overwrite:
        raise SettingError("out", "exists; give {overwrite} to replace it, or another {out}", out)
    path = motion_path(settings.motion)
    info = read_motion_info(path)
    frames = parse_frames(settings.frames, info.n_frames, str(path))
    scene = is_scene_motion(info)
    if scene and settings.asset is not None:
        raise SettingError(
            "asset",
            f"{path} is a scene motion, whose bodies name their own assets; leave {{asset}} out",
            settings.asset,
        )
    motion = load_motion(path)
    meshes = None
    if settings.format != "vtu":
        meshes = _scene_meshes(path, motion) if scene else _meshes(settings, motion)
    bar = tqdm(total=len(frames), desc=f"export {settings.format}", unit="frame", disable=not progress)
    with bar:
        if settings.format == "vtu":
            files = write_vtu_series(
                out,
                motion.rest_vertices,
                motion.tets,
                lambda k: motion.positions[k],
                frames,
                [float(motion.times[k]) for k in frames],
                bar.update,
                lambda x: {"volume_ratio": volume_ratios(motion.rest_vertices, x, motion.tets)},
            )
        elif settings.format == "ply":
            surfaces = [m for m in meshes if m.purpose == "default"] if scene else meshes[:1]
            files = write_ply_sequence(out, surfaces, frames, bar.update)
        else:
            up = (0.0, 0.0, 1.0) if scene else motion.meta.get("up") or _asset_up(settings)
            metres = 1.0 if scene else float(motion.meta.get("world", {}).get("scale", 1.0))
            files = [write_usd(out, meshes, frames, motion_fps(motion), up, metres, bar.update)]
    return ExportResult(out, settings.format, files, len(frames))


def _asset_up(settings: ExportSettings) -> list[float]:
    """The up axis of the asset (+Z without one)."""
    if settings.asset is None:
        return [0.0, 0.0, 1.0]
    from neural.asset import load_asset

    return [float(c) for c in load_asset(settings.asset).up]
