"""Animated meshes out to the formats animation tools open: USD (Blender, Omniverse), VTU + PVD (ParaView),
PLY sequences.

Each writer takes the frames to write as a list of frame numbers and a function giving the points of a
frame, so a long motion is never held in memory whole; a static mesh (a scene's collider) is written once.
Files are written under a temporary name and renamed when complete: an interrupted export leaves no
half-written file under the final name.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from neural.errors import InputError
from neural.files import write_atomically

#: The install line for USD export, printed when ``pxr`` is missing.
USD_HINT = "USD export needs the usd-core package: pip install 'shellsim[usd]'"


#: USD purposes a mesh may have: "default" is rendered, "guide" (a cage) only shown when asked for.
PURPOSES = ("default", "guide")


@dataclass
class AnimatedMesh:
    """A triangle mesh whose points move: ``faces`` (F, 3) int, ``points(frame)`` -> (V, 3) float;
    ``colors`` float in [0, 1], (V, 3) per vertex or (3,) one for the whole mesh, or None; ``purpose`` one of
    :data:`PURPOSES`; ``static``: its points do not depend on the frame (a collider), written once."""

    name: str
    faces: np.ndarray
    points: Callable[[int], np.ndarray]
    colors: np.ndarray | None = None
    purpose: str = "default"
    static: bool = False

    def __post_init__(self):
        if self.purpose not in PURPOSES:
            raise ValueError(f"purpose: expected one of {', '.join(PURPOSES)}, got {self.purpose!r}")
        if self.colors is not None:
            colors = np.asarray(self.colors, np.float32)
            if colors.shape[-1:] != (3,) or colors.ndim > 2 or not np.all((colors >= 0) & (colors <= 1)):
                raise ValueError(
                    f"colors: expected (V, 3) or (3,) numbers in [0, 1], got shape {colors.shape}"
                )
            self.colors = colors


def require_usd() -> None:
    """An :class:`InputError` with the install line unless ``pxr`` (usd-core) can be imported."""
    try:
        import pxr  # noqa: F401
    except ImportError:
        raise InputError(USD_HINT) from None


def up_rotation(up: Sequence[float]) -> tuple[np.ndarray, str]:
    """(R (3, 3), axis): USD knows only a Y or Z up axis. An up of +Y or +Z is kept (R = I); any other is
    turned onto +Z by the smallest rotation R (R @ up = +Z)."""
    from shellsim.world import up_rotation as onto_z

    u = np.asarray(up, np.float64)
    u = u / np.linalg.norm(u)
    for axis, target in (("Y", (0.0, 1.0, 0.0)), ("Z", (0.0, 0.0, 1.0))):
        if np.allclose(u, target, atol=1e-9):
            return np.eye(3), axis
    return onto_z(u), "Z"


def safe_name(name: str) -> str:
    """A mesh's name as a USD prim and in file names: letters, digits and underscores, not starting with a
    digit."""
    clean = "".join(ch if ch.isalnum() or ch == "_" else "_" for ch in name) or "mesh"
    return clean if not clean[0].isdigit() else "_" + clean


def write_usd(
    path,
    meshes: Sequence[AnimatedMesh],
    frames: Sequence[int],
    fps: float,
    up: Sequence[float] = (0.0, 0.0, 1.0),
    metres_per_unit: float = 1.0,
    progress: Callable[[], None] | None = None,
) -> Path:
    """A USD stage (``.usd``/``.usda``/``.usdc``) with each mesh under ``/Root`` (:func:`safe_name`) and its
    points sampled at time codes ``0 .. len(frames) - 1`` (the motion's frames ``frames``), a static mesh's
    points set once (no time samples), ``fps`` time codes per second, the up axis and metres per unit set so
    that Blender and Omniverse play it at its size; a mesh's ``colors`` become its ``primvars:displayColor``
    (per vertex, or constant) and its ``purpose`` its USD purpose."""
    require_usd()
    from pxr import Gf, Sdf, Usd, UsdGeom, Vt

    rotation, axis = up_rotation(up)
    path = Path(path)

    def put(mesh: AnimatedMesh, attrs, frame: int, code) -> None:
        points = np.asarray(mesh.points(frame), np.float64) @ rotation.T
        attrs[0].Set(Vt.Vec3fArray.FromNumpy(points.astype(np.float32)), code)
        lo, hi = points.min(0), points.max(0)
        attrs[1].Set(Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))]), code)

    def write(tmp: Path) -> None:
        stage = Usd.Stage.CreateNew(str(tmp))
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if axis == "Y" else UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(stage, float(metres_per_unit))
        stage.SetTimeCodesPerSecond(float(fps))
        stage.SetFramesPerSecond(float(fps))
        stage.SetStartTimeCode(0)
        stage.SetEndTimeCode(max(len(frames) - 1, 0))
        root = UsdGeom.Xform.Define(stage, "/Root")
        stage.SetDefaultPrim(root.GetPrim())
        moving = []
        for mesh in meshes:
            prim = UsdGeom.Mesh.Define(stage, Sdf.Path("/Root").AppendChild(safe_name(mesh.name)))
            faces = np.asarray(mesh.faces, np.int64)
            prim.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(faces)))
            prim.CreateFaceVertexIndicesAttr(Vt.IntArray(faces.reshape(-1).tolist()))
            prim.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
            prim.CreatePurposeAttr(mesh.purpose)
            if mesh.colors is not None:
                one = mesh.colors.ndim == 1
                color = prim.CreateDisplayColorPrimvar(
                    UsdGeom.Tokens.constant if one else UsdGeom.Tokens.vertex
                )
                color.Set(Vt.Vec3fArray.FromNumpy(mesh.colors.reshape(-1, 3)))
            attrs = (prim.CreatePointsAttr(), prim.CreateExtentAttr())
            if mesh.static:
                put(mesh, attrs, 0, Usd.TimeCode.Default())
            else:
                moving.append((mesh, attrs))
        for code, frame in enumerate(frames):
            for mesh, attrs in moving:
                put(mesh, attrs, frame, code)
            if progress:
                progress()
        stage.GetRootLayer().Save()

    return write_atomically(path, write)


def write_vtu_series(
    path,
    rest_vertices: np.ndarray,
    tets: np.ndarray,
    positions: Callable[[int], np.ndarray],
    frames: Sequence[int],
    times: Sequence[float],
    progress: Callable[[], None] | None = None,
    cell_data: Callable[[np.ndarray], dict[str, np.ndarray]] | None = None,
) -> list[Path]:
    """A ParaView series: ``path`` (``.pvd``) indexing one ``.vtu`` per frame in ``<stem>_vtu/``; each holds
    the tet mesh ``tets`` (T, 4) at ``positions(frame)`` (V, 3) with point data ``displacement`` (V, 3) from
    ``rest_vertices`` (V, 3) and the cell data ``cell_data(points)`` gives (name -> (T,) or (T, k); e.g.
    ``volume_ratio``, det F, from :mod:`shellsim.jobs.export`). Returns the files written, the ``.pvd``
    last."""
    import pyvista as pv

    path = Path(path)
    tets = np.asarray(tets, np.int64)
    rest = np.asarray(rest_vertices, np.float64)
    folder = path.with_name(path.stem + "_vtu")
    written = []
    collection = ET.Element("Collection")
    for frame, time in zip(frames, times, strict=True):
        x = np.asarray(positions(frame), np.float64)
        grid = pv.UnstructuredGrid({pv.CellType.TETRA: tets}, x)
        grid.point_data["displacement"] = x - rest
        for name, values in (cell_data(x) if cell_data else {}).items():
            grid.cell_data[name] = values
        name = f"frame_{frame:05d}.vtu"
        written.append(write_atomically(folder / name, lambda tmp, g=grid: g.save(str(tmp), binary=True)))
        ET.SubElement(
            collection,
            "DataSet",
            timestep=repr(float(time)),
            group="",
            part="0",
            file=f"{folder.name}/{name}",
        )
        if progress:
            progress()
    document = ET.Element("VTKFile", type="Collection", version="0.1", byte_order="LittleEndian")
    document.append(collection)
    ET.indent(document)
    written.append(write_atomically(path, lambda tmp: ET.ElementTree(document).write(tmp, "utf-8", True)))
    return written


def write_ply_sequence(
    directory,
    meshes: Sequence[AnimatedMesh],
    frames: Sequence[int],
    progress: Callable[[], None] | None = None,
) -> list[Path]:
    """Binary PLY files in ``directory``: per frame one of each moving mesh at that frame,
    ``<name>_NNNNN.ply``, and one of each static mesh, ``<name>.ply`` (:func:`safe_name`); a mesh's
    ``colors`` become its per-vertex colours in every file (uint8 RGBA, opaque). Returns the files written."""
    import trimesh

    directory = Path(directory)

    def save(mesh: AnimatedMesh, frame: int, stem: str) -> Path:
        points = np.asarray(mesh.points(frame), np.float64)
        rgba = None
        if mesh.colors is not None:
            rgba = np.full((len(points), 4), 255, np.uint8)
            rgba[:, :3] = np.round(np.broadcast_to(mesh.colors, (len(points), 3)) * 255)
        surface = trimesh.Trimesh(points, mesh.faces, vertex_colors=rgba, process=False)
        return write_atomically(
            directory / f"{stem}.ply", lambda tmp: surface.export(str(tmp), file_type="ply")
        )

    written = [save(m, 0, safe_name(m.name)) for m in meshes if m.static]
    for frame in frames:
        written += [save(m, frame, f"{safe_name(m.name)}_{frame:05d}") for m in meshes if not m.static]
        if progress:
            progress()
    return written
