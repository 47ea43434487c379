"""Embedding points in a tetrahedral mesh: containing tet + barycentric coordinates (paper Sec. 5).

The cage's deformation reaches the shells ``M+`` / ``M-`` by barycentric interpolation with coordinates
precomputed once in the rest cage:

- :func:`embed_points` finds the tet containing each point (libigl AABB tree + ``in_element``) and its
  barycentric coordinates. fTetWild's cage surface may sit slightly inside its input, so a point outside
  every tet falls back to the tet of the nearest boundary facet, with *extrapolated* coordinates (one or
  more negative, still summing to 1, still reproducing the point exactly in the rest cage). How many points
  took the fallback and how far outside they were is logged; :func:`outside_distance` measures it.
- :func:`barycentric` is the float64 closed form (Cramer's rule on signed sub-volumes).
- :func:`interpolate` maps embedded points through a (deformed) cage, one frame or many.
"""

from __future__ import annotations

import logging

import numpy as np

from shellsim.tetcage.geometry import boundary_facets, check_points, check_tets

logger = logging.getLogger(__name__)

#: A point whose smallest barycentric coordinate in its tet is below ``-BARY_TOL`` lies outside it
#: (by more than rounding).
BARY_TOL = 1e-9


def check_embedding(
    tet_index, bary, n_tets: int, names=("tet_index", "bary")
) -> tuple[np.ndarray, np.ndarray]:
    """``tet_index`` (P,) int indices into ``n_tets`` tets and ``bary`` (P, 4) as float64; anything else is a
    ``ValueError`` naming them as ``names``."""
    tet_index = np.asarray(tet_index)
    bary = np.asarray(bary, dtype=np.float64)
    if (
        tet_index.ndim != 1
        or not np.issubdtype(tet_index.dtype, np.integer)
        or bary.shape != (len(tet_index), 4)
    ):
        raise ValueError(
            f"{names[0]} (P,) int and {names[1]} (P, 4) expected, got {tet_index.shape} {tet_index.dtype} "
            f"and {bary.shape}"
        )
    if tet_index.size and (tet_index.min() < 0 or tet_index.max() >= n_tets):
        raise ValueError(f"{names[0]}: tet indices outside 0..{n_tets - 1}")
    return tet_index, bary


def barycentric(points: np.ndarray, tet_vertices: np.ndarray) -> np.ndarray:
    """Barycentric coordinates of each point in its own tet, float64 closed form.

    points : (P, 3) float
    tet_vertices : (P, 4, 3) float, the corners ``v0..v3`` of each point's tet
    returns : (P, 4) float64 ``w`` with ``sum_k w[p, k] = 1`` and ``sum_k w[p, k] v_k = points[p]``;
        ``w_k = vol(v_0..p..v_3) / vol(v_0..v_3)`` (``p`` in place of ``v_k``), negative outside the tet.

    Raises ``ValueError`` for a degenerate (zero-volume) tet, where the coordinates are undefined.
    """
    points = check_points("points", points)
    tet_vertices = np.asarray(tet_vertices, dtype=np.float64)
    if tet_vertices.shape != (len(points), 4, 3):
        raise ValueError(f"tet_vertices: expected shape ({len(points)}, 4, 3), got {tet_vertices.shape}")
    # Work relative to v0 so the triple products do not lose digits to a far-away origin.
    e = tet_vertices[:, 1:] - tet_vertices[:, :1]  # (P, 3, 3): rows v1-v0, v2-v0, v3-v0
    q = points - tet_vertices[:, 0]
    det = np.einsum("pi,pi->p", e[:, 0], np.cross(e[:, 1], e[:, 2]))
    scale = np.max(np.abs(e), axis=(1, 2)) ** 3
    bad = ~(np.abs(det) > 1e-14 * scale)
    if bad.any():
        raise ValueError(f"tet_vertices: {int(bad.sum())} degenerate (zero-volume) tets")
    w1 = np.einsum("pi,pi->p", q, np.cross(e[:, 1], e[:, 2])) / det
    w2 = np.einsum("pi,pi->p", e[:, 0], np.cross(q, e[:, 2])) / det
    w3 = np.einsum("pi,pi->p", e[:, 0], np.cross(e[:, 1], q)) / det
    return np.stack([1.0 - (w1 + w2 + w3), w1, w2, w3], axis=1)


def interpolate(
    vertices: np.ndarray, tets: np.ndarray, tet_index: np.ndarray, bary: np.ndarray
) -> np.ndarray:
    """Embedded points moved with the cage: ``x_p = sum_k bary[p, k] * vertices[tets[tet_index[p], k]]``.

    vertices : (V, 3) or (F, V, 3) float, cage vertices (rest, or deformed; one frame or F frames)
    tets : (T, 4) int
    tet_index : (P,) int, the tet of each point (from :func:`embed_points`)
    bary : (P, 4) float, its barycentric coordinates
    returns : (P, 3) or (F, P, 3) float64
    """
    vertices = np.asarray(vertices)
    if vertices.ndim not in (2, 3) or vertices.shape[-1] != 3:
        raise ValueError(f"vertices: expected shape (V, 3) or (F, V, 3), got {vertices.shape}")
    tets = check_tets(tets, vertices.shape[-2])
    tet_index, bary = check_embedding(tet_index, bary, len(tets))
    corners = tets[tet_index]  # (P, 4)
    out = np.zeros(vertices.shape[:-2] + (len(tet_index), 3), dtype=np.float64)
    for k in range(4):  # one corner at a time keeps the (F, P, 4, 3) gather out of memory
        out += bary[:, k, None] * vertices[..., corners[:, k], :]
    return out


def _nearest_boundary(
    vertices: np.ndarray, tets: np.ndarray, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(P,) tet owning the nearest boundary facet of each point, and (P,) the distance to that facet."""
    import igl

    faces, owner = boundary_facets(tets)
    sq_dist, face, _ = igl.point_mesh_squared_distance(points, vertices, faces)
    return owner[face], np.sqrt(sq_dist)


def embed_points(vertices: np.ndarray, tets: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Containing tet and barycentric coordinates of every point.

    vertices : (V, 3) float, rest cage vertices
    tets : (T, 4) int, positively oriented tets
    points : (P, 3) float
    returns : tet_index (P,) int64 and bary (P, 4) float64 with ``interpolate(vertices, tets, tet_index, bary)
        == points`` up to rounding. Points inside no tet use the tet of the nearest boundary facet with
        extrapolated coordinates (see the module docstring); their number and largest distance are logged.
    """
    import igl

    vertices = check_points("vertices", vertices)
    tets = check_tets(tets, len(vertices))
    points = check_points("points", points)
    if len(points) == 0:
        return np.zeros(0, np.int64), np.zeros((0, 4))
    tree = igl.AABB()
    tree.init(vertices, tets)
    tet_index = igl.in_element(vertices, tets, points, tree).astype(np.int64)
    outside = np.nonzero(tet_index < 0)[0]
    if outside.size:
        nearest, dist = _nearest_boundary(vertices, tets, points[outside])
        tet_index[outside] = nearest
        logger.info(
            "%d of %d points lie outside the cage (max distance %.3g); they use the nearest boundary "
            "tet with extrapolated coordinates",
            outside.size,
            len(points),
            dist.max(),
        )
    return tet_index, barycentric(points, vertices[tets[tet_index]])


def outside_distance(vertices: np.ndarray, tets: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Distance of each point outside the tet mesh: 0 inside (or on) it, else the distance to its boundary.

    vertices : (V, 3) float, tets : (T, 4) int, points : (P, 3) float -> (P,) float64
    """
    import igl

    vertices = check_points("vertices", vertices)
    tets = check_tets(tets, len(vertices))
    points = check_points("points", points)
    dist = np.zeros(len(points))
    if len(points) == 0:
        return dist
    tree = igl.AABB()
    tree.init(vertices, tets)
    outside = np.nonzero(igl.in_element(vertices, tets, points, tree) < 0)[0]
    if outside.size:
        dist[outside] = _nearest_boundary(vertices, tets, points[outside])[1]
    return dist
