"""Soft (gel-like) bodies: the stable Neo-Hookean energy with its volume barrier keeps tets from being
flattened (det F -> 0), which the line search cannot prevent on its own, only stall at."""

import numpy as np
import pytest
from meshes import kuhn_grid, own_surface

from shellsim.physics.driver import FrameDriver
from shellsim.physics.elastic import elastic_energy, snh_energy_reference
from shellsim.physics.ipc import CONTACT_GAP, FRICTION_VELOCITY, Contact
from shellsim.physics.materials import Material
from shellsim.physics.model import Model, SolverSettings
from shellsim.physics.solver import Solver
from shellsim.tetcage.geometry import MIN_VOLUME_RATIO, tet_volumes

GEL = Material("gel", 1.0e4, 0.45, 1050.0)


def _unit_tet():
    return np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float), np.array([[0, 1, 2, 3]])


def test_flattening_a_tet_costs_unbounded_energy():
    """Squashing a tet along one axis to thickness s: without a barrier the energy stays below
    (mu + lam') / 2 per unit volume (lam' = lambda + mu) however flat it gets; it must grow without bound."""
    v, t = _unit_tet()
    bound = (GEL.mu + GEL.lam + GEL.mu) / 2 * tet_volumes(v, t)[0]
    energies = []
    for s in (1e-2, 1e-4, 1e-8):
        energies.append(elastic_energy(v, t, v * [1, 1, s], GEL, device="cpu")[0])
    assert energies[0] > bound
    assert energies[0] < energies[1] < energies[2] and energies[2] > 10 * bound


def test_compressed_energy_and_gradient_match_the_reference_and_finite_differences(rng):
    """Compressed tets (det F in 0.1-0.5, where the barrier acts): the energy matches the NumPy twin, the
    gradient central differences, and the definiteness-fixed Hessian is positive semi-definite."""
    v, t, _ = kuhn_grid(0.0, 1.0, 1)
    for scale in (0.5, 0.6, 0.75):
        x = v * scale + 0.02 * rng.normal(size=v.shape)
        dm = np.stack([v[t][:, i] - v[t][:, 0] for i in (1, 2, 3)], axis=2)
        ds = np.stack([x[t][:, i] - x[t][:, 0] for i in (1, 2, 3)], axis=2)
        F = ds @ np.linalg.inv(dm)
        assert np.linalg.det(F).min() < 0.5
        energy, grad, hess = elastic_energy(v, t, x, GEL, device="cpu")
        ref = (tet_volumes(v, t) * snh_energy_reference(F, GEL.mu, GEL.lam + GEL.mu)).sum()
        assert energy == pytest.approx(ref, rel=1e-12)
        eps = 1e-7
        fd = np.zeros(x.size)
        for k in range(x.size):
            dx = np.zeros(x.size)
            dx[k] = eps
            ep = elastic_energy(v, t, x + dx.reshape(-1, 3), GEL, device="cpu")[0]
            em = elastic_energy(v, t, x - dx.reshape(-1, 3), GEL, device="cpu")[0]
            fd[k] = (ep - em) / (2 * eps)
        np.testing.assert_allclose(grad.ravel(), fd, atol=1e-6 * np.abs(fd).max())
        dense = hess.toarray()
        assert np.linalg.eigvalsh(dense)[0] >= -1e-10 * np.abs(dense).max()


def test_a_slumping_soft_block_keeps_every_tet_above_the_validity_floor():
    """A 0.3 m block of 1 kPa gel (rho g L / E = 3) slumps on the ground. Without a barrier its corner
    tets are flattened to det F = 0.054 (frame 8); with it every frame stays above MIN_VOLUME_RATIO (0.41 at
    worst), the contact holds it on the ground (never below it)."""
    v, t, _ = kuhn_grid((0.0, 0.0, 0.1), (0.3, 0.2, 0.25), (4, 3, 2))
    s = SolverSettings(substeps=2, retry_factors=(2,), min_volume_ratio=0.0)
    model = Model(v, t, Material("limp", 1.0e3, 0.45, 1100.0), s, device="cpu")
    contact = Contact([own_surface(t, len(v))], [0], v, [], CONTACT_GAP, FRICTION_VELOCITY, 0.5)
    state, driver = model.state(), FrameDriver(Solver([model], contact, s))
    worst, lowest = 1.0, 1.0
    for _ in range(40):
        stats = driver.step([state])
        worst = min(worst, stats.min_volume_ratio)
        lowest = min(lowest, state.positions.numpy()[:, 2].min())
    assert worst > MIN_VOLUME_RATIO
    assert lowest > 0
    assert np.isfinite(state.positions.numpy()).all()
