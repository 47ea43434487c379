"""A scene motion read back for drawing and export: its bodies (each a neural asset with its cage, or a mesh's
surface), its colliders, its world and its cameras, from what ``shellsim scene`` wrote (``DIR/motion.npz``:
the concatenated cages, their collision surfaces, ``asset.bodies`` and the scene as ``settings``).

A neural body is drawn by its asset's field through the cage its record names (found by digest among the
asset's own and cached cages); a mesh body by its collision surface, which is the mesh itself, carried by its
cage. Colliders are rebuilt from the scene's record as the solver saw them
(:func:`shellsim.shot.bodies.collider_mesh`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from neural.errors import InputError

#: Albedo of the mesh bodies of a scene that set no ``color``, in the order of its bodies (cycled).
MESH_BODY_COLORS = ((0.25, 0.50, 0.80), (0.85, 0.40, 0.30), (0.40, 0.68, 0.38), (0.82, 0.70, 0.25))


def body_color(color, k: int, mesh: bool) -> tuple | None:
    """How the ``k``-th body of a scene is coloured: a mesh body's albedo (its ``color``, else the ``k``-th
    of :data:`MESH_BODY_COLORS`), an asset body's tint (its ``color``; None: none)."""
    if color is not None:
        return tuple(float(c) for c in color)
    return MESH_BODY_COLORS[k % len(MESH_BODY_COLORS)] if mesh else None


@dataclass
class MotionBody:
    """One body of a scene motion: ``name``; ``vertices`` (slice) of its cage's vertices in the motion's;
    ``placement`` (:class:`shellsim.world.Placement`, asset frame -> world); ``asset`` and ``cage`` (asset
    frame) of a neural body, else None; ``surface_tet`` (S,), ``surface_bary`` (S, 4), ``surface_faces``
    (F, 3) its visible surface carried by its own cage's tets, whose cage vertices are ``surface_corners``
    (S, 4); ``mesh`` whether it is a mesh body; ``color`` (3,) a mesh body's albedo or a neural body's tint
    (None: none), :func:`body_color`."""

    name: str
    vertices: slice
    placement: object
    asset: object
    cage: object
    surface_tet: np.ndarray
    surface_bary: np.ndarray
    surface_faces: np.ndarray
    surface_corners: np.ndarray
    mesh: bool
    color: tuple | None

    def surface_points(self, positions: np.ndarray) -> np.ndarray:
        """(S, 3) its surface's vertices where its cage vertices are ``positions`` (V_b, 3)."""
        corners = np.asarray(positions, np.float64)[self.surface_corners]
        return np.einsum("sk,ski->si", self.surface_bary, corners)


@dataclass
class SceneMotion:
    """``path`` of the motion file, ``info`` its :class:`~shellsim.motion.format.MotionInfo`, ``bodies``
    (:class:`MotionBody`), ``colliders`` (:class:`~shellsim.shot.spec.ColliderSpec`), ``ground`` (the world
    has one), ``cameras`` (:class:`~shellsim.shot.spec.CameraSpec`) and ``look``
    (:class:`~shellsim.shot.spec.LookSpec`) of the scene."""

    path: Path
    info: object
    bodies: list
    colliders: list
    ground: bool
    cameras: list
    look: object

    def body_positions(self, positions: np.ndarray) -> list[np.ndarray]:
        """Each body's share (V_b, 3) of a frame's world ``positions`` (V, 3)."""
        return [positions[b.vertices] for b in self.bodies]

    def as_file_says(self, spec) -> SceneMotion:
        """This scene with the cameras, the look and the colours (of bodies and colliders) of ``spec``, the
        :class:`~shellsim.shot.spec.SceneSpec` of its scene file as it is now: none of them changes the
        motion."""
        colors = {b.name: b.color for b in spec.bodies}
        bodies = [
            dataclasses.replace(b, color=body_color(colors.get(b.name), k, b.mesh))
            for k, b in enumerate(self.bodies)
        ]
        return dataclasses.replace(
            self, bodies=bodies, colliders=list(spec.colliders), cameras=list(spec.cameras), look=spec.look
        )


def motion_path(path) -> Path:
    """The motion file of a scene output ``path``: ``path/motion.npz`` for a directory, else ``path``."""
    path = Path(path)
    return path / "motion.npz" if path.is_dir() else path


def is_scene_motion(info) -> bool:
    """Whether a :class:`~shellsim.motion.format.MotionInfo` was made by ``shellsim scene``."""
    return bool(info.asset.get("bodies"))


def read_scene_motion(path, load_assets: bool = True) -> SceneMotion:
    """The :class:`SceneMotion` of ``path`` (a scene output directory or its ``motion.npz``); an
    :class:`InputError` naming the file when it is not a scene motion or a body's asset or cage is gone.
    ``load_assets`` False leaves neural bodies' ``asset`` and ``cage`` None (cameras, framing)."""
    from neural.asset import load_asset
    from shellsim.motion.read import read_motion_info
    from shellsim.shot.spec import CameraKeyframe, CameraSpec, ColliderSpec, LookSpec
    from shellsim.tetcage.store import find_cage
    from shellsim.world import Placement

    path = motion_path(path)
    info = read_motion_info(path)
    if not is_scene_motion(info):
        raise InputError(f"{path}: not a scene motion (made by '{info.producer}'), a motion of one body")
    settings, records = info.settings, info.asset["bodies"]
    specs = {b["name"]: b for b in settings.get("bodies", [])}
    surface = info.surface
    bodies = []
    for k, record in enumerate(records):
        name = record["name"]
        lo, hi = record["vertices"]
        t_lo, t_hi = record["tets"]
        mine = (surface.tet >= t_lo) & (surface.tet < t_hi)
        first = int(np.argmax(mine)) if mine.any() else 0
        faces = surface.faces[np.all(mine[surface.faces], axis=1)] - first
        tet = surface.tet[mine] - t_lo
        placement = Placement.from_dict(record["placement"], f"{path}: body '{name}'")
        asset = cage = None
        source = record.get("source", {})
        if "name" in source and load_assets:
            where = specs.get(name, {}).get("asset") or source["name"]
            try:
                asset = load_asset(where)
            except (InputError, OSError) as err:
                raise InputError(
                    f"{path}: body '{name}': its asset {where} cannot be loaded ({err})"
                ) from None
            cage, _ = find_cage(asset, record["cage"])
            if cage is None:
                raise InputError(
                    f"{path}: body '{name}': no cage of the asset {where} has the digest the motion records "
                    f"({record['cage'][:12]}; rebuilt since?); make the scene again"
                )
        corners = (info.tets[t_lo:t_hi] - lo)[tet]
        mesh = "name" not in source
        color = body_color(specs.get(name, {}).get("color"), k, mesh)
        bodies.append(
            MotionBody(
                name,
                slice(lo, hi),
                placement,
                asset,
                cage,
                tet,
                surface.bary[mine],
                faces,
                corners,
                mesh,
                color,
            )
        )
    colliders = [ColliderSpec(**_tuples(c)) for c in settings.get("colliders", [])]
    cameras = []
    for c in settings.get("cameras", []):
        c = _tuples(c)
        c["keyframes"] = tuple(CameraKeyframe(**_tuples(f)) for f in c.get("keyframes", ()))
        cameras.append(CameraSpec(**c))
    ground = bool(settings.get("world", {}).get("ground", True))
    look = settings.get("look")
    look = LookSpec() if look is None else LookSpec(**_tuples(look))
    return SceneMotion(path, info, bodies, colliders, ground, cameras, look)


def _tuples(record: dict) -> dict:
    """A dataclass record read back from JSON, its lists (nested too) as tuples (the specs' vectors)."""

    def frozen(value):
        return tuple(frozen(v) for v in value) if isinstance(value, list) else value

    return {k: frozen(v) if k != "keyframes" else v for k, v in record.items()}
