"""The collision surface of a body: the surface contact acts on, carried by the cage.

The cage is tetrahedralised around the *dilated* outer shell M+, so its boundary lies a margin outside the
asset's visible surface: contact acting on the cage's vertices leaves a body at rest floating that margin
(13 mm for the shipped LEGO) above the ground. Contact must act on the visible surface instead, the
field's zero level set, moved with the cage by barycentric interpolation like the shells are: vertex ``i``
lies in cage tet ``tet[i]`` at coordinates ``bary[i]``, so the collision vertices are a fixed sparse linear
map of the cage's, ``U = W X`` (:meth:`CollisionSurface.weights`, the displacement map of ipctk's
``CollisionMesh``).

How it is made (:func:`surface_of_asset`):

1. sample the field's SDF on a grid of cubic cells over the cage's bounding box, the cell its diagonal /
   ``resolution`` (CPU, no autograd, in chunks), marching cubes at level 0
   (:func:`neural.shell.extract.marching_cubes_mesh`) and keep the connected parts whose area is at least
   :data:`MIN_PART` of the largest's (drops floaters);
2. decimate to about ``max_faces`` triangles (``igl.qslim``, collapses that would make the surface
   intersect itself blocked);
3. embed the vertices in the cage (:func:`shellsim.tetcage.embed.embed_points`); a vertex slightly outside
   it (the cage's boundary may sit inside its input by fTetWild's envelope) has its coordinates clipped
   to its tet, so it lies on the cage and moves with it; one farther than :data:`OUTSIDE_TOL` is an error;
4. check the result is closed, outward oriented and free of self-intersections (ipctk); when it is not,
   decimate less (:data:`GROWTH` times the faces, at most :data:`TRIES` tries), else refuse.

The result is cached (``CACHE/collision/*.npz``, no pickle), keyed by the asset's content digest, the
cage's digest and the settings; an asset may carry its own (:data:`OWN_FILE`, as the shipped ones do),
read first when its key matches. A mesh body (:func:`surface_of_mesh`) uses its closed input mesh, steps 2-4
only.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from neural.errors import InputError
from shellsim.tetcage.build import UNDILATED_EPSILON
from shellsim.tetcage.embed import BARY_TOL, check_embedding, embed_points
from shellsim.tetcage.geometry import check_points, check_tets

logger = logging.getLogger(__name__)

FORMAT = "shellsim-collision-surface"

#: Raise when what the cache holds would change for the same asset, cage and settings.
FORMAT_VERSION = 1

#: Connected parts of the level set with less area than this fraction of the largest's are dropped.
MIN_PART = 0.05

#: A vertex farther outside the cage than this fraction of the cage's bounding-box diagonal is an error
#: (twice fTetWild's envelope around an undilated mesh).
OUTSIDE_TOL = 2 * UNDILATED_EPSILON

#: Each retry decimates to this many times the faces of the previous try, at most ``TRIES`` tries.
GROWTH = 1.5
TRIES = 4

#: Faces of a collision surface (about), and grid cells along the cage's diagonal where its level set is
#: taken.
MAX_FACES = 2000
RESOLUTION = 256

#: The file in an asset directory that holds the collision surface of the asset's own cage.
OWN_FILE = "collision.npz"

#: SDF evaluations per call into the field.
CHUNK = 1 << 18


@dataclass(frozen=True, eq=False)
class CollisionSurface:
    """A closed, outward oriented triangle surface without self-intersections, carried by a cage.

    vertices : (S, 3) float64 rest positions in the cage's frame, ``weights(V) @ cage_vertices``
    faces : (F, 3) int64
    tet : (S,) int64 cage tet holding each vertex
    bary : (S, 4) float64 its barycentric coordinates in that tet (rows sum to 1, none below ``-BARY_TOL``:
        every vertex lies in or on the cage)
    corners : (S, 4) int64 the cage vertices of that tet (``cage_tets[tet]``)
    """

    vertices: np.ndarray
    faces: np.ndarray
    tet: np.ndarray
    bary: np.ndarray
    corners: np.ndarray

    def weights(self, n_cage_vertices: int):
        """(S, V) ``scipy.sparse.csr_matrix`` ``W`` with ``vertices = W @ cage_vertices`` for the rest cage
        (exactly) and any deformed one, ``V = n_cage_vertices``."""
        return embedding_weights(self.corners, self.bary, n_cage_vertices)


def embedding_weights(corners: np.ndarray, bary: np.ndarray, n_cage_vertices: int):
    """(S, V) csr matrix with ``bary[s, k]`` at ``(s, corners[s, k])``; corners, bary (S, 4)."""
    import scipy.sparse as sp

    if len(corners) and corners.max() >= n_cage_vertices:
        raise ValueError(f"the surface uses cage vertex {corners.max()}, beyond {n_cage_vertices} vertices")
    rows = np.repeat(np.arange(len(corners)), 4)
    return sp.csr_matrix((bary.ravel(), (rows, corners.ravel())), shape=(len(corners), n_cage_vertices))


def _carried(cage_vertices, cage_tets, faces, tet, bary) -> CollisionSurface:
    """The :class:`CollisionSurface` of ``faces`` (F, 3) whose vertices lie in tets ``tet`` (S,) at ``bary``
    (S, 4); the vertices are computed. Inconsistent arrays are a ``ValueError``."""
    tet, bary = check_embedding(tet, bary, len(cage_tets))
    faces = np.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"faces: expected (F, 3) integers, got {faces.shape} {faces.dtype}")
    if faces.size and (faces.min() < 0 or faces.max() >= len(tet)):
        raise ValueError(f"faces: vertex indices outside 0..{len(tet) - 1}")
    if not np.isfinite(bary).all() or not np.allclose(bary.sum(axis=1), 1.0, rtol=0, atol=1e-9):
        raise ValueError("bary: rows must be finite and sum to 1")
    corners = cage_tets[tet]
    vertices = embedding_weights(corners, bary, len(cage_vertices)) @ cage_vertices
    return CollisionSurface(vertices, faces.astype(np.int64), tet.astype(np.int64), bary, corners)


def _embedded(cage_vertices, cage_tets, vertices, faces, what: str) -> CollisionSurface:
    """Embed ``vertices`` (S, 3) in the cage, clipping the coordinates of those slightly outside it to their
    tet (they move onto the cage); farther than :data:`OUTSIDE_TOL` is an :class:`InputError`."""
    tet, bary = embed_points(cage_vertices, cage_tets, vertices)
    outside = bary.min(axis=1) < -BARY_TOL
    bary[outside] = np.maximum(bary[outside], 0.0)
    bary[outside] /= bary[outside].sum(axis=1, keepdims=True)
    surface = _carried(cage_vertices, cage_tets, faces, tet, bary)
    moved = np.linalg.norm(surface.vertices[outside] - vertices[outside], axis=1).max(initial=0.0)
    diagonal = float(np.linalg.norm(np.ptp(cage_vertices, axis=0)))
    if moved > OUTSIDE_TOL * diagonal:
        raise InputError(
            f"{what}: the surface reaches {moved:.3g} outside its cage (at most {OUTSIDE_TOL:g} of the "
            f"cage's diagonal, {OUTSIDE_TOL * diagonal:.3g}, is allowed); the cage must enclose the body"
        )
    if outside.any():
        logger.info("%s: %d vertices moved onto the cage (at most %.3g)", what, outside.sum(), moved)
    return surface


def _defect(vertices: np.ndarray, faces: np.ndarray) -> str | None:
    """What keeps the surface (S, 3), (F, 3) from being a collision surface, or None."""
    import ipctk
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    if not (mesh.is_watertight and mesh.is_winding_consistent):
        return "not closed"
    if not mesh.volume > 0:
        return "inside out"
    f32 = np.asfortranarray(faces, dtype=np.int32)
    v64 = np.asfortranarray(vertices, dtype=np.float64)
    if ipctk.has_intersections(ipctk.CollisionMesh(v64, ipctk.edges(f32), f32), v64):
        return "self-intersecting"
    return None


def _decimated(vertices, faces, cage_vertices, cage_tets, max_faces: int, what: str) -> CollisionSurface:
    """The closed, oriented surface (S, 3), (F, 3) decimated to about ``max_faces`` faces (or more, see the
    module docstring, step 4), embedded in the cage (V, 3), (T, 4)."""
    import igl

    target = max_faces
    for _ in range(TRIES):
        if len(faces) > target:
            v, f, _, _ = igl.qslim(
                np.asfortranarray(vertices, dtype=np.float64), np.asfortranarray(faces, dtype=np.int32),
                target, True,
            )  # fmt: skip
        else:
            v, f = vertices, faces
        surface = _embedded(cage_vertices, cage_tets, v, f, what)
        defect = _defect(surface.vertices, surface.faces)
        if defect is None:
            return surface
        logger.info("%s: the collision surface of %d faces is %s; decimating less", what, len(f), defect)
        if len(f) == len(faces):
            break
        target = math.ceil(target * GROWTH)
    raise InputError(
        f"{what}: no collision surface of {max_faces} faces or more is closed, outward oriented and free of "
        f"self-intersections (the last try, {len(f)} faces, is {defect})"
    )


def _check_max_faces(max_faces: int) -> None:
    if max_faces < 4:
        raise ValueError(f"max_faces must be at least 4, got {max_faces}")


def surface_of_mesh(
    vertices, faces, cage_vertices, cage_tets, max_faces: int = MAX_FACES, *, what: str = "mesh"
) -> CollisionSurface:
    """The collision surface of a mesh body: the closed mesh ``vertices`` (N, 3), ``faces`` (F, 3) itself,
    decimated only when it has more than ``max_faces`` faces, embedded in the cage ``cage_vertices`` (V, 3),
    ``cage_tets`` (T, 4). Unreferenced vertices are dropped and an inside-out mesh is turned over; an open
    one is an :class:`InputError` naming ``what``. Returns a :class:`CollisionSurface`."""
    import trimesh

    _check_max_faces(max_faces)
    cage_vertices = check_points("cage_vertices", cage_vertices)
    cage_tets = check_tets(cage_tets, len(cage_vertices))
    mesh = trimesh.Trimesh(check_points("vertices", vertices), np.asarray(faces, np.int64), process=False)
    mesh.remove_unreferenced_vertices()
    if not (mesh.is_watertight and mesh.is_winding_consistent):
        raise InputError(f"{what}: a collision surface needs a closed, consistently oriented mesh")
    faces = mesh.faces if mesh.volume > 0 else mesh.faces[:, ::-1]
    return _decimated(mesh.vertices, faces, cage_vertices, cage_tets, max_faces, what)


def _sample_sdf(field, lo: np.ndarray, spacing: float, shape, cut=None) -> np.ndarray:
    """The field's signed distance at the nodes ``lo + index * spacing`` of a grid of ``shape`` (X, Y, Z)
    (:func:`neural.shell.cutout.region_sdf_and_kernel`: at contracted points for a field in contracted
    space, cut to the region of a ``cut`` asset): (X, Y, Z) float32, on the CPU without autograd, whole
    x-slabs of at most :data:`CHUNK` nodes (or one slab) at a time."""
    import torch

    from neural.shell.cutout import region_sdf_and_kernel

    axes = [lo[k] + spacing * np.arange(shape[k]) for k in range(3)]
    yz = np.stack(np.meshgrid(axes[1], axes[2], indexing="ij"), -1).reshape(-1, 2)
    slab = max(1, CHUNK // len(yz))
    out = np.empty(shape, np.float32)
    with torch.no_grad():
        for x0 in range(0, shape[0], slab):
            xs = axes[0][x0 : x0 + slab]
            points = np.concatenate([np.repeat(xs, len(yz))[:, None], np.tile(yz, (len(xs), 1))], axis=1)
            sdf = region_sdf_and_kernel(field, torch.from_numpy(points.astype(np.float32)), cut)[0]
            out[x0 : x0 + len(xs)] = sdf.cpu().numpy().reshape(len(xs), shape[1], shape[2])
    return out


def _level_set(field, cage_vertices: np.ndarray, resolution: int, what: str, cut=None):
    """Vertices (N, 3), faces (F, 3) of the parts of ``field``'s zero level set (inside ``cut``'s region,
    :func:`_sample_sdf`) over the cage's bounding box with at least :data:`MIN_PART` of the largest part's
    area (step 1 of the module docstring)."""
    import trimesh

    from neural.shell.extract import marching_cubes_mesh

    lo, hi = cage_vertices.min(axis=0), cage_vertices.max(axis=0)
    spacing = float(np.linalg.norm(hi - lo)) / resolution
    shape = tuple(int(n) for n in np.ceil((hi - lo) / spacing) + 1)
    mesh = marching_cubes_mesh(_sample_sdf(field, lo, spacing, shape, cut), lo, spacing)
    if len(mesh.faces) == 0:
        raise InputError(f"{what}: the field's zero level set is empty inside the cage")
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(mesh.faces))
    area = np.bincount(labels, weights=mesh.area_faces)
    small = area < MIN_PART * area.max()
    if small.any():
        logger.info("%s: dropped %d small parts of the level set", what, small.sum())
    kept = trimesh.Trimesh(mesh.vertices, mesh.faces[~small[labels]], process=False)
    kept.remove_unreferenced_vertices()
    logger.info("%s: level set on a %s grid of cell %.3g, %d faces", what, shape, spacing, len(kept.faces))
    return kept.vertices, kept.faces


def cached_surface_path(key: str) -> Path:
    """The cache's file of the collision surface whose :func:`surface_key` is ``key``."""
    from shellsim.tetcage.store import cache_dir

    return cache_dir() / "collision" / f"{key[:32]}.npz"


def surface_key(asset_digest: str, cage_digest: str, max_faces: int, resolution: int) -> str:
    """sha256 (hex) of what a cached collision surface depends on: the asset's content
    (:meth:`neural.asset.Asset.digest`), the cage (:func:`shellsim.tetcage.geometry.cage_digest`), the
    settings and :data:`FORMAT_VERSION`."""
    parts = [FORMAT, FORMAT_VERSION, asset_digest, cage_digest, int(max_faces), int(resolution)]
    return hashlib.sha256(json.dumps(parts).encode()).hexdigest()


def _read_cached(
    path: Path, key: str, cage_vertices, cage_tets, own: bool = False
) -> CollisionSurface | None:
    """The surface stored at ``path`` for ``key``, or None when there is none or it is unusable (logged; an
    asset's ``own`` file made for another cage or settings is passed over quietly)."""
    from shellsim.io.npz import load_npz

    if not path.is_file():
        return None
    try:
        arrays = load_npz(path, ("key", "faces", "tet", "bary"), "collision surface")
        if arrays["key"].shape != () or str(arrays["key"]) != key:
            if own:
                return None
            raise ValueError("made for another asset, cage or settings")
        return _carried(cage_vertices, cage_tets, arrays["faces"], arrays["tet"], arrays["bary"])
    except (InputError, ValueError) as err:
        logger.warning("building the collision surface again, %s is unusable: %s", path, err)
        return None


def save_surface(path, key: str, surface: CollisionSurface) -> None:
    """Store ``surface`` for :func:`surface_key` ``key`` at ``path`` (an asset's :data:`OWN_FILE` or the
    cache's): its faces and embedding, no vertices (they follow from the cage)."""
    from shellsim.io.npz import save_npz

    save_npz(path, key=np.array(key), faces=surface.faces, tet=surface.tet, bary=surface.bary)


def surface_of_asset(
    asset, cage, max_faces: int = MAX_FACES, resolution: int = RESOLUTION
) -> CollisionSurface:
    """The collision surface of ``asset`` (:class:`neural.asset.Asset`) in ``cage`` (``.vertices`` (V, 3),
    ``.tets`` (T, 4) in the asset's frame, e.g. :func:`shellsim.tetcage.store.load_or_build_cage`): its
    field's zero level set on a grid whose cell is the cage's bounding-box diagonal / ``resolution``,
    decimated to about ``max_faces`` faces (module docstring). Read from the cache when it holds it, else
    built and cached; an :class:`InputError` naming the asset when no usable surface comes out."""
    from neural.asset import load_field
    from shellsim.tetcage.geometry import cage_digest

    _check_max_faces(max_faces)
    if resolution < 8:
        raise ValueError(f"resolution must be at least 8, got {resolution}")
    cage_vertices = check_points("cage vertices", cage.vertices)
    cage_tets = check_tets(cage.tets, len(cage_vertices))
    key = surface_key(asset.digest(), cage_digest(cage_vertices, cage_tets), max_faces, resolution)
    surface = _read_cached(Path(asset.root) / OWN_FILE, key, cage_vertices, cage_tets, own=True)
    path = cached_surface_path(key)
    surface = surface or _read_cached(path, key, cage_vertices, cage_tets)
    if surface is not None:
        return surface
    start, what = time.perf_counter(), f"asset {asset.name!r}"
    vertices, faces = _level_set(load_field(asset, "cpu"), cage_vertices, resolution, what, asset.cut)
    surface = _decimated(vertices, faces, cage_vertices, cage_tets, max_faces, what)
    save_surface(path, key, surface)
    logger.info(
        "%s: collision surface of %d vertices, %d faces in %.1f s, cached in %s",
        what,
        len(surface.vertices),
        len(surface.faces),
        time.perf_counter() - start,
        path,
    )
    return surface
