"""The Newton systems' linear solves (shellsim.physics.newton_systems) against dense NumPy solves, and a drop
solved both ways."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from shellsim.physics.newton_systems import NewtonSystems, pardiso_available

needs_pardiso = pytest.mark.skipif(not pardiso_available(), reason="pypardiso (MKL) is not installed")


def grid_stiffness(n: int, shift: float, extra: tuple[int, int] | None = None) -> sp.csr_matrix:
    """An (n^3, n^3) 3D grid Laplacian plus ``shift`` on the diagonal (SPD for shift > 0), with a coupling of
    the two nodes ``extra`` added (a contact between far nodes: a new sparsity pattern)."""
    line = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1])
    eye = sp.identity(n)
    lap = (
        sp.kron(sp.kron(line, eye), eye) + sp.kron(sp.kron(eye, line), eye) + sp.kron(sp.kron(eye, eye), line)
    )
    matrix = (lap + shift * sp.identity(n**3)).tolil()
    if extra is not None:
        i, j = extra
        matrix[i, i] += 1.0
        matrix[j, j] += 1.0
        matrix[i, j] -= 1.0
        matrix[j, i] -= 1.0
    return matrix.tocsr()


def given(systems: NewtonSystems, matrix: sp.csr_matrix) -> sp.csr_matrix:
    """The part of the symmetric ``matrix`` that ``systems`` takes."""
    return sp.triu(matrix, format="csr") if systems.triangle == "upper" else matrix


@pytest.mark.parametrize("method", [pytest.param("cholesky", marks=needs_pardiso), "cg"])
def test_a_solve_matches_the_dense_solution(method):
    systems = NewtonSystems(method, rtol=1e-10)
    rng = np.random.default_rng(0)
    for shift in (0.5, 0.4, 0.3):  # a run's matrices: the same pattern, other values
        matrix = grid_stiffness(6, shift)
        rhs = rng.normal(size=matrix.shape[0])
        expected = np.linalg.solve(matrix.toarray(), rhs)
        np.testing.assert_allclose(systems.solve(given(systems, matrix), rhs), expected, rtol=1e-7, atol=1e-9)


@needs_pardiso
def test_cholesky_keeps_its_analysis_while_the_pattern_holds():
    systems = NewtonSystems("cholesky")
    rng = np.random.default_rng(1)
    matrices = [grid_stiffness(5, 0.5), grid_stiffness(5, 0.7), grid_stiffness(5, 0.7, extra=(0, 124))]
    analyses = []
    for matrix in matrices:
        rhs = rng.normal(size=matrix.shape[0])
        np.testing.assert_allclose(
            systems.solve(given(systems, matrix), rhs), np.linalg.solve(matrix.toarray(), rhs), rtol=1e-9
        )
        analyses.append(systems._cholesky.analyses)
    assert analyses == [1, 1, 2]  # new values: factorised only; a new coupling: analysed again
    assert systems.factorisations == 3


def coupling(n: int, i: int, j: int, stiffness: float) -> sp.csr_matrix:
    """(n, n) a spring between unknowns ``i`` and ``j``: a contact's PSD term."""
    matrix = sp.lil_matrix((n, n))
    matrix[i, i] = matrix[j, j] = stiffness
    matrix[i, j] = matrix[j, i] = -stiffness
    return matrix.tocsr()


@pytest.mark.parametrize("method", [pytest.param("cholesky", marks=needs_pardiso), "cg"])
def test_contacts_that_come_and_go_are_solved_with_the_cages_and_analysed_once_each(method):
    """The cages' part keeps its pattern, the contacts' changes: each system is solved exactly, and Cholesky
    analyses again only when a coupling it has not seen appears (its pattern is the union seen so far)."""
    systems = NewtonSystems(method, rtol=1e-12)
    base = grid_stiffness(5, 0.5)
    rng = np.random.default_rng(4)
    contacts = [coupling(125, 0, 124, 2.0), None, coupling(125, 3, 77, 1.0), coupling(125, 0, 124, 5.0)]
    analyses = []
    for extra in contacts:
        rhs = rng.normal(size=125)
        whole = base if extra is None else base + extra
        got = systems.solve(given(systems, base), rhs, None if extra is None else given(systems, extra))
        np.testing.assert_allclose(got, np.linalg.solve(whole.toarray(), rhs), rtol=1e-8, atol=1e-12)
        if systems._cholesky is not None:
            analyses.append(systems._cholesky.analyses)
    if method == "cholesky":
        assert analyses == [1, 1, 2, 2]


@pytest.mark.parametrize("method", [pytest.param("cholesky", marks=needs_pardiso), "cg"])
def test_resolve_reuses_the_last_factorisation(method):
    systems = NewtonSystems(method, rtol=1e-12)
    assert systems.resolve(np.ones(125)) is None  # nothing factorised yet
    first, second = grid_stiffness(5, 0.5), grid_stiffness(5, 0.6)
    rng = np.random.default_rng(2)
    systems.solve(given(systems, first), rng.normal(size=125))
    rhs = rng.normal(size=125)
    # the exact solution of the factorised matrix, not of a later one
    np.testing.assert_allclose(systems.resolve(rhs), np.linalg.solve(first.toarray(), rhs), rtol=1e-9)
    assert not np.allclose(systems.resolve(rhs), np.linalg.solve(second.toarray(), rhs), rtol=1e-3)


@needs_pardiso
def test_a_matrix_that_is_not_positive_definite_goes_the_lu_way():
    systems = NewtonSystems("cholesky", rtol=1e-12)
    matrix = grid_stiffness(4, -1.5)  # the Laplacian's smallest eigenvalue is 1.15: indefinite
    assert np.linalg.eigvalsh(matrix.toarray()).min() < 0
    rhs = np.random.default_rng(3).normal(size=64)
    np.testing.assert_allclose(
        systems.solve(given(systems, matrix), rhs), np.linalg.solve(matrix.toarray(), rhs), rtol=1e-8
    )


def test_an_unknown_method_is_refused():
    with pytest.raises(ValueError, match="unknown linear solver 'qr'"):
        NewtonSystems("qr")


@needs_pardiso
def test_a_drop_onto_the_ground_is_the_same_either_way():
    """A rubber cube spinning onto the ground (contact, friction), 3 frames converged tightly: Cholesky and
    SuperLU-CG solve the same Newton systems, so the positions agree far below the default tolerance's
    error (0.3 mm here)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
    from sim_bench import cube_surface, cube_tets

    from shellsim.physics.driver import FrameDriver
    from shellsim.physics.ipc import CONTACT_GAP, FRICTION_VELOCITY, Contact
    from shellsim.physics.materials import get_material
    from shellsim.physics.model import Model, SolverSettings
    from shellsim.physics.solver import Solver

    vertices, tets = cube_tets(4)
    vertices[:, 2] -= 0.015  # 5 mm above the ground: it lands in the first frames
    settings = SolverSettings(dt=1 / 30, substeps=4, newton_tol=1e-6, newton_iterations=80)
    ends = {}
    for method in ("cholesky", "cg"):
        model = Model(vertices, tets, get_material("rubber"), settings, device="cpu")
        contact = Contact(
            [cube_surface(tets, len(vertices))], [0], vertices, [], CONTACT_GAP, FRICTION_VELOCITY, 0.5
        )
        solver = Solver([model], contact, settings, linear_solver=method)
        assert solver.systems.method == method
        state, driver = model.state((0.3, 0.0, 0.0), (0.0, 0.0, 4.0)), FrameDriver(solver)
        for _ in range(3):
            driver.step([state])
        ends[method] = state.positions.numpy()
    assert ends["cholesky"][:, 2].min() < 0.002  # it did reach the ground
    assert np.abs(ends["cholesky"] - ends["cg"]).max() < 1e-6  # m


def test_without_pardiso_the_systems_go_the_scipy_way_with_a_one_line_hint(monkeypatch, caplog):
    import logging

    import shellsim.physics.newton_systems as newton_systems

    monkeypatch.setattr(newton_systems, "pardiso_available", lambda: False)
    monkeypatch.setattr(newton_systems, "_hinted", False)
    with caplog.at_level(logging.INFO, logger="shellsim.physics.newton_systems"):
        systems = [NewtonSystems() for _ in range(2)]
    assert [s.method for s in systems] == ["cg", "cg"] and systems[0].triangle == "full"
    hints = [r.getMessage() for r in caplog.records if "pypardiso" in r.getMessage()]
    assert len(hints) == 1  # once per process
    matrix, rhs = grid_stiffness(4, 0.5), np.ones(64)
    np.testing.assert_allclose(
        systems[0].solve(matrix, rhs), np.linalg.solve(matrix.toarray(), rhs), rtol=1e-3
    )
