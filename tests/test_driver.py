"""The frame driver's stretch check (:mod:`shellsim.physics.driver`): the largest principal stretch of a tet
against prescribed uniform deformations (closed form) and numpy's SVD (an independent method); a run stops at
the first frame stretched past the limit, naming it, or warns once and goes on when allowed."""

import logging

import numpy as np
import pytest
import warp as wp
from meshes import kuhn_grid

from shellsim.errors import SettingError
from shellsim.jobs.recording import record_frames
from shellsim.motion.read import load_motion
from shellsim.motion.writer import MotionWriter
from shellsim.physics.driver import FrameDriver, largest_stretch
from shellsim.physics.elastic import f64
from shellsim.physics.materials import get_material
from shellsim.physics.model import Model, SolverSettings
from shellsim.physics.solver import Solver

RUBBER = get_material("rubber")
UNIT_TET = (np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]), np.array([[0, 1, 2, 3]]))


def rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def driver_of(model) -> FrameDriver:
    """The frame driver of ``model`` alone (no contact)."""
    return FrameDriver(Solver([model], None, model.settings))


def stretch_of(model, state) -> float:
    return largest_stretch(model, state, wp.zeros(1, dtype=f64, device=model.device))


def bar(**settings):
    """A 0.1 x 0.02 x 0.02 m bar of 24 tets, every vertex pinned (at rest until the targets move), no
    gravity: (model, state, control, driver)."""
    v, t, _ = kuhn_grid(0.0, (0.1, 0.02, 0.02), (4, 1, 1))
    model = Model(v, t, RUBBER, SolverSettings(gravity=0.0, **settings), device="cpu")
    driver = driver_of(model)
    driver.controls[0].set_pins(np.ones(len(v), bool))
    return model, model.state(), driver.controls[0], driver


@pytest.mark.parametrize("mesh", ["tet", "bar"])
def test_a_prescribed_uniform_deformation_has_its_principal_stretch(rng, mesh):
    """Every vertex held at ``F X`` with ``F = R diag(s) Q^T`` (rotations R, Q): after a frame every tet has
    the deformation gradient F, whose largest principal stretch is max(s)."""
    vertices, tets = UNIT_TET if mesh == "tet" else kuhn_grid(0.0, (0.1, 0.02, 0.02), (4, 1, 1))[:2]
    settings = SolverSettings(gravity=0.0, max_stretch=4.0, max_speed=1e4)  # a jump a frame
    model = Model(vertices, tets, RUBBER, settings, device="cpu")
    state, driver = model.state(), driver_of(model)
    assert stretch_of(model, state) == pytest.approx(1.0, abs=1e-14)
    for s in ([3.5, 0.9, 0.8], [1.7, 2.6, 0.5], [1.0, 1.0, 1.0]):
        F = rotation(rng) @ np.diag(s) @ rotation(rng).T
        driver.controls[0].set_pins(np.ones(len(vertices), bool), vertices @ F.T)
        stats = driver.step([state])
        np.testing.assert_array_equal(state.positions.numpy(), vertices @ F.T)
        assert stats.max_stretch == pytest.approx(max(s), rel=1e-12)


def test_the_stretch_is_the_largest_singular_value_of_each_tets_F(rng):
    """Against numpy's SVD of F = Ds Dm^-1 per tet, over random deformations (none inverted)."""
    v, t, _ = kuhn_grid(0.0, (0.1, 0.02, 0.02), (4, 1, 1))
    model = Model(v, t, RUBBER, device="cpu")
    state = model.state()
    for scale in (0.0005, 0.001, 0.002):
        x = v @ np.diag([2.0, 1.0, 0.7]) + scale * rng.normal(size=v.shape)
        state.set(positions=x)
        ds = np.stack([x[t][:, k] - x[t][:, 0] for k in (1, 2, 3)], axis=2)
        dm = np.stack([v[t][:, k] - v[t][:, 0] for k in (1, 2, 3)], axis=2)
        F = ds @ np.linalg.inv(dm)
        assert np.linalg.det(F).min() > 0
        assert stretch_of(model, state) == pytest.approx(np.linalg.svd(F, compute_uv=False).max(), rel=1e-9)


STRETCHES = (1.6, 2.2, 2.8, 3.4, 4.0, 4.6)  # of frames 1, 2, ...: frame 4 is the first past 3


def _ramp(tmp_path, model, state, control, driver):
    """Pull the pinned bar to STRETCHES along x, a frame each, into a motion file; returns its path."""
    path = tmp_path / "motion.npz"
    writer = MotionWriter(path, model.rest_vertices, model.tets, {"producer": "test"}, flush_seconds=1e9)
    stretches = iter(STRETCHES)

    def advance():
        control.set_pins(control.pinned, model.rest_vertices * [next(stretches), 1.0, 1.0])
        return driver.step([state])

    def snapshot():
        return state.positions.numpy().copy(), state.time, {"velocities": state.velocities.numpy().copy()}

    with writer:
        record_frames(writer, 1 + len(STRETCHES), advance, snapshot, advice=str, desc="", progress=False)
    return path


def test_a_run_stops_at_the_first_frame_stretched_past_the_limit(tmp_path):
    model, state, control, driver = bar()
    with pytest.raises(SettingError, match="stretched to 3.4 times its rest length") as err:
        _ramp(tmp_path, model, state, control, driver)
    message = str(err.value)
    assert message.startswith("frame 4 (t = 0.100 s) is invalid with 8, 16, 32 substeps")  # retried
    assert "(largest principal stretch), above 3; frames 0-3 are kept in" in message
    motion = load_motion(tmp_path / "motion.npz")
    assert motion.n_frames == 4  # frame 0 and the three below the limit
    np.testing.assert_allclose(motion.positions[-1], model.rest_vertices * [2.8, 1.0, 1.0], atol=1e-7)
    # the state is left at the last frame written
    np.testing.assert_allclose(state.positions.numpy(), model.rest_vertices * [2.8, 1.0, 1.0], rtol=1e-14)


def test_allowed_stretch_warns_once_and_goes_on(tmp_path, caplog):
    model, state, control, driver = bar(allow_stretch=True)
    with caplog.at_level(logging.WARNING, logger="shellsim.physics.driver"):
        path = _ramp(tmp_path, model, state, control, driver)
    warnings = [r.getMessage() for r in caplog.records if "stretched" in r.getMessage()]
    assert len(warnings) == 1 and "stretched to 3.4 times" in warnings[0] and "t = 0.133 s" in warnings[0]
    motion = load_motion(path)
    assert motion.n_frames == 1 + len(STRETCHES)
    np.testing.assert_allclose(motion.positions[-1], model.rest_vertices * [4.6, 1.0, 1.0], atol=1e-7)
