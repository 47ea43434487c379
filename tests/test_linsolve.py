"""The Newton steps' linear solvers (shellsim.linsolve) on a known system: a random symmetric positive
definite matrix with the stiffness pattern of a tet mesh, assembled from per-tet blocks through
block_topology, against numpy's dense solve."""

import numpy as np
import pytest
import warp as wp
from meshes import kuhn_grid

from shellsim.linsolve import block_topology, bsr_cg_solver, serial_pcg_solver

wp.init()
DEVICE = "cpu"
mat33, vec3 = wp.mat33d, wp.vec3d


def spd_system(seed: int = 0):
    """(dense A (3V, 3V), blocks (nnz, 3, 3), offsets, columns, diag_index, b (V, 3)) for a 2x2x3 Kuhn grid:
    A = sum over tets of G_t^T G_t (G_t random 12 x 12) + I, scattered into the pattern by block_index."""
    rng = np.random.default_rng(seed)
    verts, tets, _ = kuhn_grid(0.0, 1.0, (2, 2, 3))
    n = len(verts)
    offsets, columns, block_index, diag_index = block_topology(tets, n)
    blocks = np.zeros((len(columns), 3, 3))
    dense = np.eye(3 * n)
    for t, tet in enumerate(tets):
        g = rng.normal(size=(12, 12))
        element = g.T @ g
        for a in range(4):
            for c in range(4):
                block = element[3 * a : 3 * a + 3, 3 * c : 3 * c + 3]
                blocks[block_index[t, 4 * a + c]] += block
                dense[3 * tet[a] : 3 * tet[a] + 3, 3 * tet[c] : 3 * tet[c] + 3] += block
    blocks[diag_index] += np.eye(3)
    rows = np.repeat(np.arange(n), np.diff(offsets))
    rebuilt = np.zeros_like(dense)  # the pattern holds exactly the assembled matrix
    for k, (i, j) in enumerate(zip(rows, columns, strict=True)):
        rebuilt[3 * i : 3 * i + 3, 3 * j : 3 * j + 3] = blocks[k]
    np.testing.assert_allclose(rebuilt, dense, rtol=0, atol=1e-12)
    return dense, blocks, offsets, columns, diag_index, rng.normal(size=(n, 3))


@pytest.mark.parametrize("solver", ["serial", "bsr"])
def test_solvers_match_a_dense_solve(solver):
    dense, blocks, offsets, columns, diag_index, b = spd_system()
    n = len(b)
    exact = np.linalg.solve(dense, b.ravel()).reshape(n, 3)
    inv_diag = wp.array(np.linalg.inv(blocks[diag_index]), dtype=mat33, device=DEVICE)
    b_wp = wp.array(b, dtype=vec3, device=DEVICE)
    d = wp.zeros(n, dtype=vec3, device=DEVICE)
    columns_wp = wp.array(columns, dtype=wp.int32, device=DEVICE)
    if solver == "serial":
        work = [wp.zeros(n, dtype=vec3, device=DEVICE) for _ in range(5)]
        result = wp.zeros(2, dtype=wp.float64, device=DEVICE)
        solve = serial_pcg_solver(
            wp.array(offsets, dtype=wp.int32, device=DEVICE),
            columns_wp,
            wp.array(blocks, dtype=mat33, device=DEVICE),
            wp.array(diag_index, dtype=wp.int32, device=DEVICE),
            inv_diag,
            b_wp,
            d,
            work,
            result,
            1e-10,
            1000,
            DEVICE,
        )
    else:
        values, solve = bsr_cg_solver(offsets, columns, columns_wp, inv_diag, b_wp, d, 1e-10, 1000, DEVICE)
        values.assign(wp.array(blocks, dtype=mat33, device=DEVICE))
    iterations = solve(0.0)
    assert 0 < iterations <= 3 * n  # CG in exact arithmetic: at most 3V steps
    np.testing.assert_allclose(d.numpy(), exact, atol=1e-8 * np.abs(exact).max())
    d.assign(wp.array(exact, dtype=vec3, device=DEVICE))  # from the solution: nothing to do
    assert solve(0.0) == 0
