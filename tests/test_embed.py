"""shellsim.tetcage.embed on a procedural tet mesh of a box (Kuhn subdivision), where containment and the
distance outside have closed forms."""

import igl
import numpy as np
import pytest
from meshes import kuhn_grid

from shellsim.tetcage.embed import barycentric, embed_points, interpolate, outside_distance
from shellsim.tetcage.geometry import boundary_facets

LO, HI = np.array([-1.0, -0.5, 0.0]), np.array([1.0, 0.5, 0.75])


def box_distance(points):
    """Closed-form distance of points outside the box (0 inside)."""
    return np.linalg.norm(np.maximum(np.maximum(LO - points, points - HI), 0.0), axis=1)


@pytest.fixture(scope="module")
def box():
    """(V, 3), (T, 4): the box ``[LO, HI]`` cut into 4 x 3 x 2 cells, each cell into 6 positive tets."""
    return kuhn_grid(LO, HI, (4, 3, 2))[:2]


def test_barycentric_closed_form(rng):
    tet_vertices = rng.normal(size=(500, 4, 3)) + rng.normal(scale=100.0, size=(500, 1, 3))
    points = rng.normal(size=(500, 3)) + tet_vertices.mean(axis=1)
    w = barycentric(points, tet_vertices)
    assert np.allclose(w.sum(axis=1), 1.0, rtol=0, atol=1e-12)
    assert np.allclose(np.einsum("pk,pkc->pc", w, tet_vertices), points, rtol=0, atol=1e-9)
    corners = [np.ascontiguousarray(tet_vertices[:, k]) for k in range(4)]
    assert np.allclose(w, igl.barycentric_coordinates(points, *corners), rtol=0, atol=1e-8)
    corners = barycentric(tet_vertices.reshape(-1, 3), np.repeat(tet_vertices, 4, axis=0))
    assert np.allclose(corners, np.tile(np.eye(4), (500, 1)), rtol=0, atol=1e-9)


def test_barycentric_rejects_bad_input():
    flat = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]], dtype=float)
    with pytest.raises(ValueError, match="degenerate"):
        barycentric(np.zeros((1, 3)), flat)
    with pytest.raises(ValueError, match="tet_vertices"):
        barycentric(np.zeros((2, 3)), flat)
    with pytest.raises(ValueError, match="points"):
        barycentric(np.zeros((1, 2)), flat)


def test_boundary_facets_enclose_the_box(box):
    vertices, tets = box
    faces, owner = boundary_facets(tets)
    assert len(faces) == 2 * 2 * (4 * 3 + 3 * 2 + 4 * 2)  # two triangles per boundary square
    assert all(set(f) < set(t) for f, t in zip(faces, tets[owner], strict=True))
    v = vertices[faces]
    on_side = (np.isclose(v, LO) | np.isclose(v, HI)).all(axis=1)  # (F, 3): all three corners on one side
    assert on_side.any(axis=1).all()
    enclosed = np.einsum("fi,fi->f", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0
    assert enclosed == pytest.approx(np.prod(HI - LO), rel=1e-12)  # outward orientation: positive volume


def test_embed_inside_round_trips(box, rng):
    vertices, tets = box
    points = rng.uniform(LO, HI, size=(2000, 3))
    points = np.vstack([points, vertices])  # vertices lie on shared faces and on the boundary
    tet_index, bary = embed_points(vertices, tets, points)
    assert tet_index.dtype == np.int64 and bary.shape == (len(points), 4)
    assert (bary >= -1e-12).all()
    assert np.allclose(bary.sum(axis=1), 1.0, rtol=0, atol=1e-12)
    assert np.abs(interpolate(vertices, tets, tet_index, bary) - points).max() < 1e-12
    assert (outside_distance(vertices, tets, points) == 0).all()


def test_embed_outside_falls_back_to_nearest_boundary_tet(box, rng):
    vertices, tets = box
    points = rng.uniform(LO - 0.2, HI + 0.2, size=(3000, 3))
    outside = box_distance(points) > 0
    tet_index, bary = embed_points(vertices, tets, points)
    assert np.allclose(bary.sum(axis=1), 1.0, rtol=0, atol=1e-12)
    assert np.abs(interpolate(vertices, tets, tet_index, bary) - points).max() < 1e-12
    assert (bary[outside].min(axis=1) < 0).all()  # extrapolated
    dist = outside_distance(vertices, tets, points)
    assert np.allclose(dist, box_distance(points), rtol=0, atol=1e-12)
    # the fallback tet touches the boundary point nearest to the point
    nearest = np.clip(points[outside], LO, HI)
    own = barycentric(nearest, vertices[tets[tet_index[outside]]])
    assert (own >= -1e-9).all()


def test_affine_map_of_cage_maps_points_exactly(box, rng):
    vertices, tets = box
    points = rng.uniform(LO - 0.1, HI + 0.1, size=(1000, 3))
    tet_index, bary = embed_points(vertices, tets, points)
    a, b = rng.normal(size=(3, 3)) + 2 * np.eye(3), rng.normal(size=3)
    moved = interpolate(vertices @ a.T + b, tets, tet_index, bary)
    assert np.abs(moved - (points @ a.T + b)).max() < 1e-9


def test_interpolate_many_frames(box, rng):
    vertices, tets = box
    points = rng.uniform(LO, HI, size=(100, 3))
    tet_index, bary = embed_points(vertices, tets, points)
    frames = vertices + rng.normal(scale=0.05, size=(5,) + vertices.shape)
    many = interpolate(frames.astype(np.float32), tets, tet_index, bary)
    assert many.shape == (5, 100, 3) and many.dtype == np.float64
    for f in range(5):
        assert np.allclose(many[f], interpolate(frames[f], tets, tet_index, bary), rtol=0, atol=1e-6)


def test_api_misuse_is_value_error(box):
    vertices, tets = box
    with pytest.raises(ValueError, match="tets"):
        embed_points(vertices, tets[:, :3], np.zeros((1, 3)))
    with pytest.raises(ValueError, match="tets"):
        embed_points(vertices, tets + len(vertices), np.zeros((1, 3)))
    with pytest.raises(ValueError, match="points"):
        embed_points(vertices, tets, np.zeros(3))
    with pytest.raises(ValueError, match="tet_index"):
        interpolate(vertices, tets, np.array([len(tets)]), np.full((1, 4), 0.25))
    with pytest.raises(ValueError, match="vertices"):
        interpolate(vertices[None, None], tets, np.array([0]), np.full((1, 4), 0.25))
    empty_index, empty_bary = embed_points(vertices, tets, np.zeros((0, 3)))
    assert empty_index.shape == (0,) and empty_bary.shape == (0, 4)
