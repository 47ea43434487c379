"""The Newton steps' linear solvers (shellsim.physics.linsolve) on a known system: a random symmetric positive
definite matrix with the stiffness pattern of a tet mesh, assembled from per-tet blocks through
block_topology, against numpy's dense solve."""

import numpy as np
import pytest
import warp as wp
from meshes import kuhn_grid

from shellsim.physics.linsolve import SSOR_OMEGA, block_topology, bsr_cg_solver, serial_pcg_solver

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


@pytest.mark.parametrize("solver", ["serial", "serial-sgs", "serial-1.9", "bsr"])
def test_solvers_match_a_dense_solve(solver):
    """Each solver (the serial PCG with its SSOR factor, symmetric Gauss-Seidel and strong over-relaxation)
    reaches numpy's solution."""
    dense, blocks, offsets, columns, diag_index, b = spd_system()
    n = len(b)
    exact = np.linalg.solve(dense, b.ravel()).reshape(n, 3)
    inv_diag = wp.array(np.linalg.inv(blocks[diag_index]), dtype=mat33, device=DEVICE)
    b_wp = wp.array(b, dtype=vec3, device=DEVICE)
    d = wp.zeros(n, dtype=vec3, device=DEVICE)
    columns_wp = wp.array(columns, dtype=wp.int32, device=DEVICE)
    if solver.startswith("serial"):
        omega = {"serial": SSOR_OMEGA, "serial-sgs": 1.0, "serial-1.9": 1.9}[solver]
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
            omega,
        )
    else:
        values, solve = bsr_cg_solver(offsets, columns, columns_wp, inv_diag, b_wp, d, 1e-10, 1000, DEVICE)
        values.assign(wp.array(blocks, dtype=mat33, device=DEVICE))
    iterations = solve(0.0)
    assert 0 < iterations <= 3 * n  # CG in exact arithmetic: at most 3V steps
    np.testing.assert_allclose(d.numpy(), exact, atol=1e-8 * np.abs(exact).max())
    d.assign(wp.array(exact, dtype=vec3, device=DEVICE))  # from the solution: nothing to do
    assert solve(0.0) == 0


def test_over_relaxation_saves_cg_steps_on_an_elastic_newton_system():
    """On a backward-Euler Newton system of rubber (the stable Neo-Hookean Hessian of a stretched, twisted
    8^3-cell bar plus M / h^2), SSOR_OMEGA reaches the same solution as symmetric Gauss-Seidel (omega 1) in
    fewer CG steps."""
    from shellsim.physics.elastic import elastic_energy
    from shellsim.physics.materials import get_material

    rubber = get_material("rubber")
    rest, tets, _ = kuhn_grid(0.0, 0.1, 8)
    n = len(rest)
    angle = 2.0 * rest[:, 2]  # twist about z, stretch along z
    c, s = np.cos(angle), np.sin(angle)
    x = np.stack([c * rest[:, 0] - s * rest[:, 1], s * rest[:, 0] + c * rest[:, 1], 1.3 * rest[:, 2]], 1)
    _, _, hessian = elastic_energy(rest, tets, x, rubber)
    h = 1.0 / 240.0
    mass = rubber.density * 0.1**3 / n
    offsets, columns, _, diag_index = block_topology(tets, n)
    blocks = hessian.data.copy()
    blocks[diag_index] += mass / h**2 * np.eye(3)
    b = np.random.default_rng(1).normal(size=(n, 3))
    dense = hessian.toarray() + mass / h**2 * np.eye(3 * n)
    exact = np.linalg.solve(dense, b.ravel()).reshape(n, 3)
    steps = {}
    for omega in (1.0, SSOR_OMEGA):
        d = wp.zeros(n, dtype=vec3, device=DEVICE)
        solve = serial_pcg_solver(
            wp.array(offsets, dtype=wp.int32, device=DEVICE),
            wp.array(columns, dtype=wp.int32, device=DEVICE),
            wp.array(blocks, dtype=mat33, device=DEVICE),
            wp.array(diag_index, dtype=wp.int32, device=DEVICE),
            wp.array(np.linalg.inv(blocks[diag_index]), dtype=mat33, device=DEVICE),
            wp.array(b, dtype=vec3, device=DEVICE),
            d,
            [wp.zeros(n, dtype=vec3, device=DEVICE) for _ in range(5)],
            wp.zeros(2, dtype=wp.float64, device=DEVICE),
            1e-3,
            1000,
            DEVICE,
            omega,
        )
        steps[omega] = solve(0.0)
        error = np.linalg.norm((dense @ d.numpy().ravel()) - b.ravel()) / np.linalg.norm(b)
        assert error <= 1e-3
        np.testing.assert_allclose(d.numpy(), exact, atol=1e-2 * np.abs(exact).max())
    assert steps[SSOR_OMEGA] < 0.85 * steps[1.0], steps
