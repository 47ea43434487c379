"""shellsim.tetcage.geometry against closed forms: the unit tet, a cube cut into tets, two tets sharing a
face."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from shellsim.tetcage.geometry import (
    boundary_faces,
    check_points,
    check_tets,
    connected_parts,
    tet_neighbors,
    tet_quality,
    tet_volumes,
    volume_ratios,
)

UNIT_TET = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
#: Two tets sharing the face (1, 2, 3), both positively oriented.
TWO_TETS = np.vstack([UNIT_TET, [[1.0, 1, 1]]]), np.array([[0, 1, 2, 3], [4, 1, 3, 2]])


def cube_tets() -> tuple[np.ndarray, np.ndarray]:
    """The unit cube cut into the 6 Kuhn tets along the diagonal 0 -> 7 (corner k at its bits x, y, z)."""
    vertices = np.array([[k & 1, k >> 1 & 1, k >> 2 & 1] for k in range(8)], dtype=np.float64)
    tets = []
    for perm in itertools.permutations(range(3)):  # the path 0 -> 7 adding one axis at a time
        path, k = [0], 0
        for axis in perm:
            k |= 1 << axis
            path.append(k)
        tets.append(path)
    tets = np.array(tets)
    flip = tet_volumes(vertices, tets) < 0  # orient them all positively (swap two corners)
    tets[flip] = tets[flip][:, [1, 0, 2, 3]]
    return vertices, tets


def test_unit_tet_volume_is_one_sixth_and_its_mirror_negative():
    assert tet_volumes(UNIT_TET, [[0, 1, 2, 3]]) == pytest.approx([1 / 6], rel=1e-15)
    assert tet_volumes(UNIT_TET, [[1, 0, 2, 3]]) == pytest.approx([-1 / 6], rel=1e-15)
    scaled = UNIT_TET * [2.0, 3.0, 0.5] + [10.0, -4.0, 7.0]  # volume scales by det, ignores translation
    assert tet_volumes(scaled, [[0, 1, 2, 3]]) == pytest.approx([3.0 / 6], rel=1e-12)


def test_a_cube_cut_into_six_tets():
    vertices, tets = cube_tets()
    volumes = tet_volumes(vertices, tets)
    np.testing.assert_allclose(volumes, 1 / 6, rtol=1e-15)  # the Kuhn tets are congruent
    faces = boundary_faces(tets)
    assert len(faces) == 12  # two triangles per cube face
    v = vertices[faces]
    on_a_side = (v == v[:, :1]).all(axis=1).any(axis=1)  # all three corners share an x, y or z
    assert on_a_side.all()
    enclosed = np.einsum("fi,fi->f", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0
    assert enclosed == pytest.approx(1.0, rel=1e-15)  # outward faces enclose the cube's volume
    np.testing.assert_array_equal(connected_parts(tets), np.zeros(6))
    stretched = vertices * [2.0, 1.0, 1.0]
    np.testing.assert_allclose(volume_ratios(vertices, stretched, tets), 2.0, rtol=1e-15)
    np.testing.assert_allclose(volume_ratios(vertices, vertices * [-1.0, 1, 1], tets), -1.0, rtol=1e-15)


def test_boundary_of_two_tets_sharing_a_face():
    vertices, tets = TWO_TETS
    faces = boundary_faces(tets)
    corners = sorted(tuple(sorted(f.tolist())) for f in faces)
    assert corners == [(0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 4), (1, 3, 4), (2, 3, 4)]
    v = vertices[faces]
    enclosed = np.einsum("fi,fi->f", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0
    assert enclosed == pytest.approx(tet_volumes(vertices, tets).sum(), rel=1e-15)
    assert tet_volumes(vertices, tets) == pytest.approx([1 / 6, 1 / 3])
    np.testing.assert_array_equal(connected_parts(tets), [0, 0])
    np.testing.assert_array_equal(connected_parts([[0, 1, 2, 3], [4, 5, 6, 7]]), [0, 1])  # nothing shared
    np.testing.assert_array_equal(connected_parts([[0, 1, 2, 3], [0, 1, 2, 4]]), [0, 0])  # a shared face
    np.testing.assert_array_equal(connected_parts([[0, 1, 2, 3], [0, 1, 4, 5]]), [0, 1])  # only an edge


def test_tet_neighbors_across_the_face_opposite_each_vertex():
    """Entry [t, k] is the tet sharing the three corners of t other than corner k, as a search of every
    other tet for those corners finds it; boundary faces and a face of three tets have none."""
    _, tets = cube_tets()
    neighbors = tet_neighbors(tets)
    for t, k in itertools.product(range(len(tets)), range(4)):
        face = set(tets[t].tolist()) - {int(tets[t, k])}
        sharing = [u for u in range(len(tets)) if u != t and face <= set(tets[u].tolist())]
        assert neighbors[t, k] == (sharing[0] if sharing else -1)
    assert (neighbors >= 0).sum() == 12  # 6 inner faces of the cube, seen from both sides
    np.testing.assert_array_equal(tet_neighbors(TWO_TETS[1]), [[1, -1, -1, -1], [0, -1, -1, -1]])
    fan = [[0, 1, 2, 3], [0, 1, 2, 4], [0, 1, 2, 5]]  # three tets on the face (0, 1, 2): not a manifold
    np.testing.assert_array_equal(tet_neighbors(fan), -np.ones((3, 4)))


def test_tet_quality_is_one_for_a_regular_tet_and_signed():
    regular = np.array([[1.0, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]])
    assert tet_quality(regular, [[1, 0, 2, 3]]) == pytest.approx([1.0], rel=1e-14)
    assert tet_quality(regular, [[0, 1, 2, 3]]) == pytest.approx([-1.0], rel=1e-14)
    flat = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    assert tet_quality(flat, [[0, 1, 2, 3]]) == pytest.approx([0.0], abs=1e-15)


def test_checks_name_the_array_and_the_problem():
    assert check_tets(np.array([[0, 1, 2, 3]], np.int32), 4).dtype == np.int64
    with pytest.raises(ValueError, match=r"tets: expected \(T, 4\) integers"):
        check_tets(np.zeros((2, 3), np.int64), 4)
    with pytest.raises(ValueError, match="outside 0..3"):
        check_tets([[0, 1, 2, 4]], 4)
    with pytest.raises(ValueError, match="no tetrahedra"):
        check_tets(np.zeros((0, 4), np.int64), 4)
    assert check_tets(np.zeros((0, 4), np.int64), 4, allow_empty=True).shape == (0, 4)
    with pytest.raises(ValueError, match=r"rest: expected shape \(N, 3\)"):
        check_points("rest", np.zeros((4, 2)))
