"""Tetrahedral-mesh geometry shared by the cage, the simulator, the wind and the renderer: array checks,
signed tet volumes and volume ratios, shape quality, boundary faces and connected parts, and the digest that
names a rest cage (:func:`cage_digest`: what a motion and a collision surface record). Plain numpy.

A tet ``(a, b, c, d)`` is positively oriented when ``det[b - a, c - a, d - a] > 0``. A deformed tet's volume
ratio is ``det F`` = deformed volume / rest volume: at or below 0 the tet is inverted and the shells
embedded in it fold through each other; close to 0 it is a sliver that smears whatever it holds. Both are
refused below :data:`MIN_VOLUME_RATIO` (a tet squeezed to a fifth of its volume) before a frame is written
(:mod:`shellsim.physics.driver`, :mod:`shellsim.physics.wind`). Normal motion stays far above it (a 0.3 m
jelly cube dropped 0.1 m onto the ground: 0.75 at worst; rubber, foam, plastic: above 0.99).
"""

from __future__ import annotations

import hashlib
import math

import numpy as np

MIN_VOLUME_RATIO = 0.2  # smallest det F a written frame may have

#: Outward-oriented faces of a positively oriented tet ``(a, b, c, d)``: face ``k`` is opposite vertex ``k``.
TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], dtype=np.int64)


def cage_digest(vertices: np.ndarray, tets: np.ndarray) -> str:
    """sha256 (hex) of a rest cage: its vertices (V, 3) as float64 and tets (T, 4) as int64, with shapes."""
    h = hashlib.sha256()
    for array in (np.asarray(vertices, np.float64), np.asarray(tets, np.int64)):
        h.update(str(array.shape).encode())
        h.update(np.ascontiguousarray(array).tobytes())
    return h.hexdigest()


def check_points(name: str, x) -> np.ndarray:
    """``x`` as (N, 3) float64; another shape is a ``ValueError`` naming ``name``."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"{name}: expected shape (N, 3), got {x.shape}")
    return x


def check_tets(tets, n_vertices: int, allow_empty: bool = False) -> np.ndarray:
    """``tets`` as (T, 4) int64 indices into ``n_vertices`` vertices; anything else (no tets at all unless
    ``allow_empty``) is a ``ValueError`` naming ``tets``."""
    tets = np.asarray(tets)
    if tets.ndim != 2 or tets.shape[1] != 4 or not np.issubdtype(tets.dtype, np.integer):
        raise ValueError(f"tets: expected (T, 4) integers, got {tets.shape} {tets.dtype}")
    if len(tets) == 0 and not allow_empty:
        raise ValueError("tets: the mesh has no tetrahedra")
    if tets.size and (tets.min() < 0 or tets.max() >= n_vertices):
        raise ValueError(f"tets: vertex indices outside 0..{n_vertices - 1}")
    return tets.astype(np.int64)


def tet_volumes(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volumes ``det[v1 - v0, v2 - v0, v3 - v0] / 6``: vertices (V, 3), tets (T, 4) -> (T,) float64,
    positive for positively oriented tets."""
    p = np.asarray(vertices, dtype=np.float64)[np.asarray(tets)]  # (T, 4, 3)
    e = p[:, 1:] - p[:, :1]
    return np.einsum("ti,ti->t", e[:, 0], np.cross(e[:, 1], e[:, 2])) / 6.0


def volume_ratios(rest_vertices: np.ndarray, positions: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(T,) deformed / rest volume of each tet (``det F``); rest_vertices, positions (V, 3), tets (T, 4)
    positively oriented at rest."""
    tets = np.asarray(tets, np.int64)
    return tet_volumes(positions, tets) / tet_volumes(rest_vertices, tets)


def tet_quality(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Shape quality ``6 sqrt(2) volume / rms_edge**3``: 1 for a regular tet, 0 for a flat one, negative
    for an inverted one. vertices (V, 3), tets (T, 4) -> (T,) float64."""
    p = np.asarray(vertices, dtype=np.float64)[np.asarray(tets)]
    pairs = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    rms = np.sqrt(np.mean([np.sum((p[:, i] - p[:, j]) ** 2, axis=1) for i, j in pairs], axis=0))
    return 6.0 * math.sqrt(2.0) * tet_volumes(vertices, tets) / rms**3


def _face_ids(tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which face each tet face slot is: tets (T, 4) int64 -> ``face_id`` (4T,) of slot ``4 t + k`` (the face
    opposite vertex ``k``, ``TET_FACES[k]``; slots with the same three vertices share an id) and ``counts``
    (n_faces,), the slots of each face."""
    faces = np.sort(tets[:, TET_FACES].reshape(-1, 3), axis=1)
    order = np.lexsort(faces.T[::-1])  # rows in lexicographic order (what np.unique(axis=0) numbers by)
    new_face = np.r_[True, (faces[order[1:]] != faces[order[:-1]]).any(axis=1)]
    face_id = np.empty(len(faces), dtype=np.int64)
    face_id[order] = np.cumsum(new_face) - 1
    return face_id, np.bincount(face_id)


def boundary_facets(tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Faces of a tet mesh that belong to exactly one tet, with the tet each belongs to.

    tets : (T, 4) int, positively oriented
    returns : faces (F, 3) int64, oriented outward (counter-clockwise seen from outside),
        and owner (F,) int64, the tet each face belongs to
    """
    tets = np.asarray(tets, dtype=np.int64)
    if tets.ndim != 2 or tets.shape[1] != 4:
        raise ValueError(f"tets: expected shape (T, 4), got {tets.shape}")
    face_id, counts = _face_ids(tets)
    once = counts[face_id] == 1
    return tets[:, TET_FACES].reshape(-1, 3)[once], np.nonzero(once)[0] // 4


def boundary_faces(tets: np.ndarray) -> np.ndarray:
    """Faces of exactly one tet: tets (T, 4) positively oriented -> (F, 3) int64, oriented outward."""
    return boundary_facets(tets)[0]


def tet_neighbors(tets: np.ndarray) -> np.ndarray:
    """The tet across each face: tets (T, 4) -> (T, 4) int64 whose entry ``[t, k]`` is the other tet sharing
    tet ``t``'s face opposite its vertex ``k`` (``TET_FACES[k]``), -1 where that face is on the boundary (or
    shared by more than two tets)."""
    face_id, counts = _face_ids(np.asarray(tets, dtype=np.int64))
    order = np.argsort(face_id, kind="stable")  # the slots of one face side by side
    sorted_id = face_id[order]
    pair = np.flatnonzero((sorted_id[:-1] == sorted_id[1:]) & (counts[sorted_id[:-1]] == 2))
    first, second = order[pair], order[pair + 1]
    neighbors = np.full(len(face_id), -1, dtype=np.int64)
    neighbors[first], neighbors[second] = second // 4, first // 4
    return neighbors.reshape(-1, 4)


def connected_parts(tets: np.ndarray) -> np.ndarray:
    """Label of the solid each tet belongs to, tets connecting through shared faces: (T, 4) -> (T,) int64."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    tets = np.asarray(tets, dtype=np.int64)
    face_id, _ = _face_ids(tets)
    n = len(tets)
    rows = np.repeat(np.arange(n), 4)
    graph = coo_matrix((np.ones(4 * n), (rows, n + face_id)), shape=(n + face_id.max() + 1,) * 2)
    _, labels = connected_components(graph, directed=False)
    return np.unique(labels[:n], return_inverse=True)[1].ravel().astype(np.int64)
