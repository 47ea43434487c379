"""shellsim.deform.inverse_map: barycentric transfer and the deformed-to-rest map against closed forms on
a tet grid.

The grid is the unit cube split into n^3 cells of 6 Kuhn tets each; a rest point's containing tet and
barycentric coordinates follow in closed form from the sorted fractional coordinates inside its cell.
"""

import itertools

import numpy as np
import pytest
import torch
from meshes import kuhn_grid

from shellsim.deform.inverse_map import (
    InverseMap,
    deform_points,
    map_directions_reference,
    map_points_reference,
)

N = 4  # cells per side: 384 tets


def embed_in_grid(x: np.ndarray, n: int, flip: np.ndarray):
    """Closed-form containing tet (P,) and barycentrics (P, 4) of rest points in ``kuhn_grid(0, 1, n)``,
    whose tet ``6 * cell + p`` adds the axes in the order of permutation ``p``."""
    cell = np.clip(np.floor(x * n).astype(np.int64), 0, n - 1)
    frac = x * n - cell
    order = np.argsort(-frac, axis=1, kind="stable")  # axes in the order the Kuhn path adds them
    perms = {p: i for i, p in enumerate(itertools.permutations(range(3)))}
    tet = (cell[:, 0] * n * n + cell[:, 1] * n + cell[:, 2]) * 6 + np.array([perms[tuple(o)] for o in order])
    f = np.take_along_axis(frac, order, axis=1)
    bary = np.stack([1 - f[:, 0], f[:, 0] - f[:, 1], f[:, 1] - f[:, 2], f[:, 2]], axis=1)
    bary[flip[tet]] = bary[flip[tet]][:, [1, 0, 2, 3]]
    return tet, bary


def smooth_warp(x: np.ndarray) -> np.ndarray:
    """A smooth non-inverting deformation (displacement gradient well below 1) with a rotation."""
    c, s = np.cos(0.4), np.sin(0.4)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return (x + 0.07 * np.sin(3.0 * x[:, [1, 2, 0]] + 0.5)) @ rot.T + [0.3, -0.2, 0.1]


@pytest.fixture(scope="module")
def grid():
    return kuhn_grid(0.0, 1.0, N)


def test_closed_form_embedding_reproduces_points(grid, rng):
    verts, tets, flip = grid
    x = rng.random((500, 3))
    tet, bary = embed_in_grid(x, N, flip)
    assert bary.min() >= -1e-12
    np.testing.assert_allclose(deform_points(verts, tets, tet, bary), x, atol=1e-12)


def test_deform_points_is_exact_for_an_affine_cage(grid, rng):
    verts, tets, flip = grid
    a = np.eye(3) + 0.3 * rng.normal(size=(3, 3))
    x = rng.random((200, 3))
    tet, bary = embed_in_grid(x, N, flip)
    np.testing.assert_allclose(deform_points(verts @ a.T + 1.5, tets, tet, bary), x @ a.T + 1.5, atol=1e-12)


def test_round_trip_rest_deformed_rest(grid, rng):
    verts, tets, flip = grid
    x = rng.random((3000, 3))
    tet, bary = embed_in_grid(x, N, flip)
    deformed_cage = smooth_warp(verts)
    x_def = deform_points(deformed_cage, tets, tet, bary)
    x_rest, inside = InverseMap(deformed_cage, tets, verts).map_points(x_def)
    assert inside.all()
    np.testing.assert_allclose(x_rest, x, atol=1e-6)
    # cage vertices lie on shared faces and the boundary: the tolerance finds all of them
    v_rest, v_inside = InverseMap(deformed_cage, tets, verts).map_points(deformed_cage)
    assert v_inside.all()
    np.testing.assert_allclose(v_rest, verts, atol=1e-9)


def test_matches_brute_force_twin(grid, rng):
    verts, tets, _ = grid
    deformed_cage = smooth_warp(verts)
    lo, hi = deformed_cage.min(0), deformed_cage.max(0)
    x = lo - 0.1 + (hi - lo + 0.2) * rng.random((2000, 3))  # a good share falls outside the cage
    d = rng.normal(size=x.shape)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    inverse = InverseMap(deformed_cage, tets, verts)
    d_rest, inside = assert_maps_like_the_twin(inverse, deformed_cage, tets, verts, x, d)
    assert 0.2 < inside.mean() < 0.9
    np.testing.assert_allclose(inverse.map_directions(x, d, eps=0.02), d_rest, atol=0, equal_nan=True)


def assert_maps_like_the_twin(inverse, deformed, tets, rest, x, d):
    """``inverse`` maps points x (N, 3) and directions d (N, 3) (step 0.02) like the brute-force twins of the
    cage ``deformed``; returns its d_rest (N, 3) and inside (N,)."""
    x_rest, d_rest, inside = inverse.map_samples(x, d, eps=0.02)
    ref_rest, ref_inside = map_points_reference(deformed, tets, rest, x)
    ref_dirs = map_directions_reference(deformed, tets, rest, x, d, eps=0.02)
    np.testing.assert_array_equal(inside, ref_inside)
    np.testing.assert_allclose(x_rest[inside], ref_rest[inside], atol=1e-9)
    np.testing.assert_allclose(d_rest[inside], ref_dirs[inside], atol=1e-7)
    return d_rest, inside


def test_a_map_updated_to_another_frame_matches_the_brute_force_twin(grid, rng):
    """A map built for one frame and updated to a far larger deformation (its BVH refitted, not rebuilt)
    maps like the brute-force twin of the new frame; a bad frame is refused."""
    verts, tets, _ = grid
    inverse = InverseMap(smooth_warp(verts), tets, verts)
    center = verts.mean(0)
    twisted = center + np.einsum("vij,vj->vi", _rotations_about_z(2.0 * (verts[:, 2] - 0.5)), verts - center)
    inverse.update(twisted)
    lo, hi = twisted.min(0), twisted.max(0)
    x = lo + (hi - lo) * rng.random((2000, 3))
    d = rng.normal(size=x.shape)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    _, inside = assert_maps_like_the_twin(inverse, twisted, tets, verts, x, d)
    assert 0.2 < inside.mean() < 0.95
    with pytest.raises(ValueError, match="deformed_vertices: expected"):
        inverse.update(twisted[:-1])
    with pytest.raises(ValueError, match="NaN"):
        inverse.update(np.full_like(twisted, np.nan))


def _rotations_about_z(angles: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations by ``angles`` (N,) radians about the z axis."""
    c, s = np.cos(angles), np.sin(angles)
    rotations = np.zeros((len(angles), 3, 3))
    rotations[:, 0, 0], rotations[:, 0, 1], rotations[:, 1, 0], rotations[:, 1, 1] = c, -s, s, c
    rotations[:, 2, 2] = 1.0
    return rotations


def test_points_along_rays_match_brute_force_twin(grid, rng):
    """Samples along rays, in order (as a renderer queries them: each mostly in its predecessor's tet, some
    leaving the cage and coming back), map like the brute-force twin."""
    verts, tets, _ = grid
    deformed_cage = smooth_warp(verts)
    lo, hi = deformed_cage.min(0), deformed_cage.max(0)
    starts = lo - 0.2 + (hi - lo + 0.4) * rng.random((40, 3))
    ends = lo - 0.2 + (hi - lo + 0.4) * rng.random((40, 3))
    x = (starts[:, None] + np.linspace(0, 1, 100)[None, :, None] * (ends - starts)[:, None]).reshape(-1, 3)
    d = np.repeat((ends - starts) / np.linalg.norm(ends - starts, axis=1, keepdims=True), 100, axis=0)
    x_rest, d_rest, inside = InverseMap(deformed_cage, tets, verts).map_samples(x, d, eps=0.01)
    ref_rest, ref_inside = map_points_reference(deformed_cage, tets, verts, x)
    assert 0.2 < inside.mean() < 0.9
    np.testing.assert_array_equal(inside, ref_inside)
    np.testing.assert_allclose(x_rest[inside], ref_rest[inside], atol=1e-9)
    ref_dirs = map_directions_reference(deformed_cage, tets, verts, x, d, eps=0.01)
    np.testing.assert_allclose(d_rest[inside], ref_dirs[inside], atol=1e-7)


def test_outside_points_are_flagged_nan(grid):
    verts, tets, _ = grid
    inverse = InverseMap(smooth_warp(verts), tets, verts)
    far = np.array([[10.0, 0.0, 0.0], [-3.0, -3.0, -3.0], [0.5, 0.5, 50.0]])
    x_rest, d_rest, inside = inverse.map_samples(far, np.tile([0.0, 0.0, 1.0], (3, 1)))
    assert not inside.any()
    assert np.isnan(x_rest).all() and np.isnan(d_rest).all()


def test_directions_match_affine_jacobian(grid, rng):
    """For x' = A x + c the inverse map's Jacobian is A^-1 everywhere: d_rest = normalize(A^-1 d)."""
    verts, tets, flip = grid
    a = np.eye(3) + 0.3 * rng.normal(size=(3, 3))
    assert np.linalg.det(a) > 0.2
    deformed_cage = verts @ a.T + [0.2, 0.1, -0.4]
    x = rng.uniform(0.001, 0.999, size=(2000, 3))
    x[:500, 0] = 0.9995  # next to the +x face, looking out: the forward step leaves the cage
    d = rng.normal(size=x.shape)
    d[:500] = a @ [1.0, 0.0, 0.0] + 0.1 * d[:500]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    x_def = deform_points(deformed_cage, tets, *embed_in_grid(x, N, flip))
    expected = np.linalg.solve(a, d.T).T
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    inverse = InverseMap(deformed_cage, tets, verts)
    for eps in (None, 0.05):
        d_rest = inverse.map_directions(x_def, d, eps=eps)
        np.testing.assert_allclose(d_rest, expected, atol=1e-5)


def test_cage_thinner_than_eps_uses_the_tet_jacobian(rng):
    """One tet, both finite-difference steps leave it: the containing tet's Jacobian answers."""
    rest = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    tets = np.array([[0, 1, 2, 3]])
    a = np.array([[1.2, 0.3, 0.0], [-0.1, 0.9, 0.2], [0.0, 0.4, 1.1]])
    deformed = rest @ a.T
    x = np.array([[0.25, 0.25, 0.25]]) @ a.T
    d = rng.normal(size=(1, 3))
    expected = np.linalg.solve(a, d[0])
    d_rest = InverseMap(deformed, tets, rest).map_directions(x, d, eps=100.0)
    np.testing.assert_allclose(d_rest[0], expected / np.linalg.norm(expected), atol=1e-12)
    np.testing.assert_allclose(
        map_directions_reference(deformed, tets, rest, x, d, eps=100.0), d_rest, atol=1e-12
    )


def test_degenerate_tets_are_skipped():
    """A flattened tet never claims a point; its neighbour still maps it."""
    rest = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]])
    tets = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
    deformed = rest.copy()
    deformed[4] = [1 / 3, 1 / 3, 1 / 3]  # second tet collapses onto the shared face
    x = np.array([[0.1, 0.2, 0.3]])
    x_rest, inside = InverseMap(deformed, tets, rest).map_points(x)
    assert inside.all()
    np.testing.assert_allclose(x_rest, x, atol=1e-12)


def test_torch_in_torch_out(grid, rng):
    verts, tets, flip = grid
    deformed_cage = smooth_warp(verts)
    x = deform_points(deformed_cage, tets, *embed_in_grid(rng.random((100, 3)), N, flip))
    d = rng.normal(size=x.shape)
    inverse = InverseMap(deformed_cage, tets, verts)
    x_np, d_np, in_np = inverse.map_samples(x, d)
    x_t, d_t, in_t = inverse.map_samples(
        torch.tensor(x, dtype=torch.float32), torch.tensor(d, dtype=torch.float32)
    )
    assert x_t.dtype == d_t.dtype == torch.float32 and in_t.dtype == torch.bool
    assert x_t.shape == (100, 3)
    np.testing.assert_array_equal(in_t.numpy(), in_np)
    np.testing.assert_allclose(x_t.numpy(), x_np, atol=1e-5)
    np.testing.assert_allclose(d_t.numpy(), d_np, atol=1e-4)
    x64, in64 = inverse.map_points(torch.tensor(x))
    assert x64.dtype == torch.float64
    np.testing.assert_array_equal(x64.numpy(), x_np)


def test_empty_query_and_bad_input(grid):
    verts, tets, _ = grid
    inverse = InverseMap(verts, tets, verts)
    x_rest, inside = inverse.map_points(np.zeros((0, 3)))
    assert x_rest.shape == (0, 3) and inside.shape == (0,)
    with pytest.raises(ValueError, match="x: expected shape"):
        inverse.map_points(np.zeros((5, 2)))
    with pytest.raises(ValueError, match="d: expected shape"):
        inverse.map_directions(np.zeros((5, 3)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match="eps"):
        inverse.map_directions(np.zeros((5, 3)), np.zeros((5, 3)), eps=0.0)
    with pytest.raises(ValueError, match="tets"):
        InverseMap(verts, tets + len(verts), verts)
    with pytest.raises(ValueError, match="rest_vertices"):
        InverseMap(verts, tets, verts[:-1])
    with pytest.raises(ValueError, match="neighbors"):
        InverseMap(verts, tets, verts, neighbors=np.full_like(tets, len(tets)))
    with pytest.raises(ValueError, match="tet_index"):
        deform_points(verts, tets, np.array([len(tets)]), np.full((1, 4), 0.25))


def test_cpu_threads_split_the_query(grid, rng, monkeypatch):
    import shellsim.deform.inverse_map

    verts, tets, _ = grid
    deformed_cage = smooth_warp(verts)
    x = deformed_cage.min(0) + np.ptp(deformed_cage, axis=0) * rng.random((1001, 3))
    d = rng.normal(size=x.shape)
    one = InverseMap(deformed_cage, tets, verts, cpu_threads=1).map_samples(x, d)
    monkeypatch.setattr(shellsim.deform.inverse_map, "_MIN_CHUNK", 100)
    three = InverseMap(deformed_cage, tets, verts, cpu_threads=3).map_samples(x, d)
    for a, b in zip(one, three, strict=True):
        np.testing.assert_array_equal(a, b)


def test_walking_from_the_previous_tet_maps_like_the_search(grid, rng):
    """Samples along rays (consecutive points a step apart, as a renderer maps them) map alike when each
    search walks across faces from the previous point's tet and when every search queries the BVH (no
    neighbours: the walk ends at once)."""
    verts, tets, _ = grid
    deformed_cage = smooth_warp(verts)
    lo, hi = deformed_cage.min(0), deformed_cage.max(0)
    starts = lo + (hi - lo) * rng.random((300, 1, 3))
    steps = rng.normal(size=(300, 1, 3)) * 0.01
    x = (starts + steps * np.arange(40)[None, :, None]).reshape(-1, 3)
    d = np.repeat(steps[:, 0] / np.linalg.norm(steps[:, 0], axis=1, keepdims=True), 40, axis=0)
    walked = InverseMap(deformed_cage, tets, verts).map_rays(x, d)
    searched = InverseMap(deformed_cage, tets, verts, neighbors=-np.ones_like(tets)).map_rays(x, d)
    np.testing.assert_array_equal(walked[3], searched[3])
    assert 0.3 < walked[3].mean() < 0.95
    for a, b in zip(walked[:3], searched[:3], strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
