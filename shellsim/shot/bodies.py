"""A scene's bodies and colliders made real: cages, collision surfaces, materials and placements in the world,
and the checks of the shot's first instant that need them (bodies overlapping, below the ground).

A body is placed by its **visible** surface (its collision surface, :mod:`shellsim.tetcage.collision`): its
largest extent is ``size``, and the bottom centre of its bounding box, after the rotation, is at
``position``. A body set on the ground (``position`` z below half the barrier's reach ``contact_gap``) starts
half that reach above it: incremental potential contact needs a positive gap at every instant.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shellsim.shot.file import problem
from shellsim.shot.spec import BodySpec, ColliderSpec, SceneSpec
from shellsim.world import UNITS, Placement, place_on_ground

#: Subdivisions of the icosphere that stands for a sphere collider (642 vertices).
SPHERE_SUBDIVISIONS = 3


@dataclass
class SceneBody:
    """One body, ready to simulate: ``spec``; the rest cage in the world, ``rest`` (V, 3) [m] and ``tets``
    (T, 4); ``placement`` (asset frame -> world); ``cage_digest`` of the cage in the asset's frame;
    ``source`` (the motion's record: asset name and digest, or the mesh path and digest); ``cage`` the cage
    in the asset's frame (``vertices``, ``tets``); ``material``;
    ``surface`` the :class:`shellsim.tetcage.collision.CollisionSurface` (asset frame) and
    ``surface_world`` (S, 3) its vertices in the world."""

    spec: BodySpec
    rest: np.ndarray
    tets: np.ndarray
    placement: Placement
    cage_digest: str
    source: dict
    cage: object
    material: object
    surface: object
    surface_world: np.ndarray

    @property
    def name(self) -> str:
        return self.spec.name


def body_placement(points: np.ndarray, up, spec: BodySpec, is_mesh: bool, lift: float) -> Placement:
    """The :class:`Placement` of a body whose visible surface has asset-frame ``points`` (S, 3): ``up`` turned
    onto +z; scaled to ``spec.size`` (an asset without one: :data:`shellsim.world.BODY_SIZE`; a mesh without
    one: by its units); turned by ``spec.rotation`` (degrees about world x, y, z) about its bounding-box
    centre; the bottom centre of its bounding box at ``spec.position``, raised to at least ``lift``."""
    from scipy.spatial.transform import Rotation

    if is_mesh and spec.size is None:
        base = place_on_ground(points, up, None, 0.0, scale=UNITS[spec.units])
    else:
        base = (
            place_on_ground(points, up, spec.size) if spec.size is not None else place_on_ground(points, up)
        )
    placed = base.to_world(points)
    turn = Rotation.from_euler("xyz", spec.rotation, degrees=True).as_matrix()
    centre = 0.5 * (placed.min(0) + placed.max(0))
    turned = (placed - centre) @ turn.T
    lo, hi = turned.min(0), turned.max(0)
    bottom = np.array([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), lo[2]])
    target = np.array(spec.position, np.float64)
    target[2] = max(target[2], lift)
    translation = turn @ (base.translation - centre) + target - bottom
    return Placement(base.scale, turn @ base.rotation, translation)


def lowest_start(world) -> float:
    """The least height [m] of a body's lowest visible point at t = 0 in the world ``world``
    (:class:`~shellsim.shot.spec.WorldSpec`): half the barrier's reach above a ground, any without one."""
    return 0.5 * world.contact_gap if world.ground else -np.inf


def file_digest(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def build_body(spec: BodySpec, lift: float) -> SceneBody:
    """Load or build ``spec``'s cage and collision surface (cached) and place it (:func:`body_placement`); a
    mesh too large to tetrahedralise in the memory the machine has is refused before it is."""
    from neural.asset import load_asset, load_mesh
    from shellsim.memory import check_memory, mesh_bytes
    from shellsim.physics.materials import get_material
    from shellsim.tetcage.build import CageConfig, build_cage
    from shellsim.tetcage.collision import surface_of_asset, surface_of_mesh
    from shellsim.tetcage.geometry import cage_digest
    from shellsim.tetcage.store import load_or_build_cage

    overrides = {k: v for k, v in (("target_tets", spec.cage.target_tets), ("margin", spec.cage.margin)) if v}
    if spec.asset is not None:
        asset = load_asset(spec.asset)
        cage = load_or_build_cage(asset, CageConfig(**overrides) if overrides else None)
        surface = surface_of_asset(asset, cage)
        up, source = spec.up or asset.up, {"name": asset.name, "digest": asset.digest()}
    else:
        mesh = load_mesh(Path(spec.mesh))
        config = CageConfig(**{**overrides, "margin": 0.0})
        faces = f"a mesh of {len(mesh.faces):,} faces"
        needed = mesh_bytes(len(mesh.faces), config.target_tets)
        check_memory("mesh", needed, faces, "to tetrahedralise and simulate")
        cage = build_cage(mesh, mesh, config, what=str(spec.mesh))
        surface = surface_of_mesh(mesh.vertices, mesh.faces, cage.vertices, cage.tets)
        up, source = (
            (0.0, 0.0, 1.0),
            {"mesh": str(Path(spec.mesh).resolve()), "digest": file_digest(spec.mesh)},
        )
    placement = body_placement(
        surface.vertices, np.asarray(up, np.float64), spec, spec.mesh is not None, lift
    )
    try:
        material = get_material(spec.material, spec.youngs, spec.poisson, spec.density)
    except ValueError as err:
        raise problem(spec.where, "material", str(err)) from None
    return SceneBody(
        spec=spec,
        rest=placement.to_world(cage.vertices),
        tets=np.asarray(cage.tets, np.int64),
        placement=placement,
        cage_digest=cage_digest(cage.vertices, cage.tets),
        source=source,
        cage=cage,
        material=material,
        surface=surface,
        surface_world=placement.to_world(surface.vertices),
    )


def collider_mesh(spec: ColliderSpec):
    """(vertices (S, 3) world metres, faces (F, 3) outward) of a static collider."""
    import trimesh
    from scipy.spatial.transform import Rotation

    from neural.asset import load_mesh

    if spec.shape == "box":
        mesh = trimesh.creation.box(extents=2.0 * np.asarray(spec.half_extents, np.float64))
    elif spec.shape == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=SPHERE_SUBDIVISIONS, radius=spec.radius)
    else:
        mesh = load_mesh(Path(spec.mesh))
        mesh = trimesh.Trimesh(mesh.vertices * UNITS[spec.units] * spec.scale, mesh.faces, process=False)
        mesh.apply_translation(-0.5 * (mesh.bounds[0] + mesh.bounds[1]))
    turn = Rotation.from_euler("xyz", spec.rotation, degrees=True).as_matrix()
    vertices = np.asarray(mesh.vertices, np.float64) @ turn.T + np.asarray(spec.position, np.float64)
    return vertices, np.asarray(mesh.faces, np.int64)


def _intersect(a, b) -> bool:
    """Whether the closed surfaces ``a`` and ``b`` ((vertices, faces) each) overlap: their triangles cross,
    or one lies inside the other."""
    import igl
    import ipctk

    (va, fa), (vb, fb) = a, b
    lo, hi = np.maximum(va.min(0), vb.min(0)), np.minimum(va.max(0), vb.max(0))
    if (lo > hi).any():
        return False
    vertices = np.concatenate([va, vb])
    faces = np.concatenate([fa, fb + len(va)]).astype(np.int32)
    mesh = ipctk.CollisionMesh(vertices, ipctk.edges(faces), faces)
    if ipctk.has_intersections(mesh, vertices):
        return True
    inside_b = igl.winding_number(vb, fb.astype(np.int64), va[:1])
    inside_a = igl.winding_number(va, fa.astype(np.int64), vb[:1])
    return bool(abs(inside_b[0]) > 0.5 or abs(inside_a[0]) > 0.5)


def check_start(scene: SceneSpec, bodies: list[SceneBody], colliders: list) -> None:
    """A :class:`shellsim.shot.spec.SceneError` for the first problem of the shot's first instant: a body
    below the ground, two bodies overlapping (naming both), or a body overlapping a collider."""
    surfaces = [(b.surface_world, np.asarray(b.surface.faces)) for b in bodies]
    for body, (vertices, _) in zip(bodies, surfaces, strict=True):
        if scene.world.ground and vertices[:, 2].min() < 0:
            low = vertices[:, 2].min()
            raise problem(
                body.spec.where, "position", f"the body reaches {low:.4f} m, below the ground (z = 0)"
            )
    for i, a in enumerate(bodies):
        for j in range(i + 1, len(bodies)):
            if _intersect(surfaces[i], surfaces[j]):
                raise problem(
                    a.spec.where,
                    "position",
                    f"bodies '{a.name}' and '{bodies[j].name}' overlap at t = 0; move one of them",
                )
        for spec, surface in zip(scene.colliders, colliders, strict=True):
            if _intersect(surfaces[i], surface):
                raise problem(
                    a.spec.where, "position", f"the body overlaps the collider '{spec.name}' at t = 0"
                )
