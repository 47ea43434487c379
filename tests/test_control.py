"""Scripted inputs (:mod:`shellsim.physics.control`) through the solver's ``step(model, state_in, state_out,
control, dt)``: one step of free fall is backward Euler's closed form, external forces accelerate the body by
f / m, and pinned vertices follow their targets and ignore forces."""

import numpy as np
import pytest
from meshes import kuhn_grid

from shellsim.physics.control import Control
from shellsim.physics.driver import FrameDriver
from shellsim.physics.materials import get_material
from shellsim.physics.model import Model, SolverSettings
from shellsim.physics.solver import Solver

RUBBER = get_material("rubber")
TIGHT = dict(newton_tol=1e-6)


def box():
    v, t, _ = kuhn_grid(0.0, (0.1, 0.1, 0.1), 2)
    return v, t


def test_one_step_of_free_fall_is_backward_euler():
    """x1 = x0 + h v0 + h^2 g and v1 = v0 + h g, exactly (no deformation); state_in is left as it was."""
    v, t = box()
    model = Model(v, t, RUBBER, SolverSettings(**TIGHT), device="cpu")
    solver = Solver([model], None, model.settings)
    state_in, state_out = model.state(linear=(0.5, 0.0, 1.0)), model.state()
    state_in.time, h = 0.25, 0.01
    stats = solver.step([state_in], [state_out], [Control(model)], h)
    v0, g = np.array([0.5, 0.0, 1.0]), np.array([0.0, 0.0, -9.81])
    np.testing.assert_allclose(state_out.positions.numpy(), v + h * v0 + h * h * g, rtol=1e-13)
    np.testing.assert_allclose(state_out.velocities.numpy(), np.broadcast_to(v0 + h * g, v.shape))
    assert state_out.time == pytest.approx(0.26) and stats.converged
    assert stats.min_volume_ratio == pytest.approx(1.0)
    np.testing.assert_array_equal(state_in.positions.numpy(), v)


def test_external_forces_accelerate_the_body_as_f_over_m():
    """Forces f_i = m_i a (no gravity): the body falls along a as under gravity, x_n = x_0 + a h^2 n (n + 1)
    / 2 after n steps of h; a pinned vertex ignores its force (and the body then hangs from it)."""
    v, t = box()
    a = np.array([1.0, -2.0, 0.5])
    model = Model(v, t, RUBBER, SolverSettings(gravity=0.0, substeps=4, **TIGHT), device="cpu")
    state, driver = model.state(), FrameDriver(Solver([model], None, model.settings))
    driver.controls[0].set_forces(model.masses[:, None] * a)
    frames = 3
    for _ in range(frames):
        driver.step([state])
    n, h = frames * 4, model.settings.dt / 4
    np.testing.assert_allclose(state.positions.numpy(), v + a * h * h * n * (n + 1) / 2, rtol=0, atol=1e-12)

    pinned = np.zeros(len(v), bool)
    pinned[0] = True
    driver.controls[0].set_pins(pinned)
    state = model.state()
    driver.step([state])
    x = state.positions.numpy()
    np.testing.assert_array_equal(x[0], v[0])
    assert (x[1:] - v[1:]).mean(0) @ a > 0  # the rest is pulled along a


def test_pinned_vertices_follow_their_targets():
    """One end of a bar held, then its targets moved 1 cm along y: after a frame the held vertices are there
    exactly and the free end has followed part of the way."""
    v, t, _ = kuhn_grid(0.0, (0.2, 0.02, 0.02), (4, 1, 1))
    model = Model(v, t, RUBBER, SolverSettings(gravity=0.0, **TIGHT), device="cpu")
    held = v[:, 0] < 1e-9
    state, driver = model.state(), FrameDriver(Solver([model], None, model.settings))
    control = driver.controls[0]
    control.set_pins(held)
    driver.step([state])
    np.testing.assert_array_equal(state.positions.numpy(), v)  # no gravity, no force: nothing moves
    control.set_pins(held, v + [0.0, 0.01, 0.0])
    for _ in range(3):
        driver.step([state])
    x = state.positions.numpy()
    np.testing.assert_array_equal(x[held], v[held] + [0.0, 0.01, 0.0])
    tip = v[:, 0] > 0.2 - 1e-9
    assert (x[tip, 1] > v[tip, 1] + 1e-4).all()
