"""Physics tests of the implicit FEM on the one simulation path (:mod:`shellsim.physics`: model, state,
control, body terms, solver, frame driver; contact by :mod:`shellsim.physics.ipc`) against closed forms and
invariants."""

import numpy as np
import pytest
import warp as wp
from meshes import kuhn_grid, own_surface

from shellsim.errors import SettingError
from shellsim.jobs.recording import record_frames
from shellsim.motion.read import load_motion
from shellsim.motion.writer import MotionWriter
from shellsim.physics import body as body_module
from shellsim.physics.body import BodyTerms, partition_tets
from shellsim.physics.control import Control
from shellsim.physics.driver import FrameDriver
from shellsim.physics.elastic import FORCE, HESSIAN, elastic_energy, snh_energy_reference, snh_min_eigenvalue
from shellsim.physics.ipc import CONTACT_GAP, FRICTION_VELOCITY, Contact, StaticSurface
from shellsim.physics.materials import Material, get_material
from shellsim.physics.model import Model, SolverSettings
from shellsim.physics.solver import Solver
from shellsim.shot.bodies import collider_mesh
from shellsim.shot.spec import ColliderSpec
from shellsim.tetcage.geometry import MIN_VOLUME_RATIO, tet_volumes

G = 9.81


def box_tets(cells=(2, 2, 2), size=(0.1, 0.1, 0.1), origin=(0.0, 0.0, 0.0)):
    """A box split into cubes, each cut into the 6 tets around its main diagonal (conforming, oriented)."""
    verts, tets, _ = kuhn_grid(0.0, size, cells)
    return verts + origin, tets


class Run:
    """A model, its state (at rest, moving rigidly by ``linear``, ``angular``), its pins and a frame driver
    of the one solver, the body's boundary its contact surface with the ``ground`` and the ``statics``
    (:class:`shellsim.physics.ipc.StaticSurface`) when there are any; ``step()`` advances one frame."""

    def __init__(
        self,
        v,
        t,
        material,
        s=None,
        pinned=None,
        linear=(0.0, 0.0, 0.0),
        angular=(0.0, 0.0, 0.0),
        ground=False,
        statics=(),
    ):
        self.model = Model(v, t, material, s, device="cpu")
        self.state = self.model.state(linear, angular)
        contact = None
        if ground or statics:
            surface = own_surface(t, len(v))
            ground_friction = 0.5 if ground else None
            contact = Contact([surface], [0], v, statics, CONTACT_GAP, FRICTION_VELOCITY, ground_friction)
        self.driver = FrameDriver(Solver([self.model], contact, self.model.settings))
        if pinned is not None:
            self.driver.controls[0].set_pins(pinned)

    def step(self):
        return self.driver.step([self.state])

    def snapshot(self):
        return self.positions, self.state.time, {"velocities": self.velocities}

    @property
    def positions(self):
        return self.state.positions.numpy().copy()

    @property
    def velocities(self):
        return self.state.velocities.numpy().copy()


def com(run):
    return run.model.masses @ run.positions / run.model.masses.sum()


def settings(**kw):
    base = dict(gravity=0.0, newton_tol=1e-6)
    base.update(kw)
    return SolverSettings(**base)


RUBBER = get_material("rubber")
SOFT = Material("soft", 1.0e4, 0.3, 1000.0)


def test_rest_mesh_is_consistent():
    v, t = box_tets((2, 3, 2), (0.2, 0.3, 0.1))
    assert np.isclose(tet_volumes(v, t).sum(), 0.2 * 0.3 * 0.1)
    model = Model(v, t, RUBBER, settings(), device="cpu")
    assert np.isclose(model.masses.sum(), RUBBER.density * 0.2 * 0.3 * 0.1)


@pytest.mark.parametrize("shift_limit", [0.1, 0.0])
def test_energy_gradient_hessian_match_finite_differences(rng, shift_limit):
    v, t = box_tets((1, 1, 2), (1.0, 1.0, 2.0))
    mat = Material("m", 3.0, 0.3, 1.0)
    x = 1.15 * v + 0.03 * rng.normal(size=v.shape)  # stretched: every element Hessian is positive definite
    energy, grad, hess = elastic_energy(v, t, x, mat, device="cpu", shift_limit=shift_limit)
    # energy against the NumPy twin
    dm = np.stack([v[t][:, i] - v[t][:, 0] for i in (1, 2, 3)], axis=2)
    ds = np.stack([x[t][:, i] - x[t][:, 0] for i in (1, 2, 3)], axis=2)
    ref = (tet_volumes(v, t) * snh_energy_reference(ds @ np.linalg.inv(dm), mat.mu, mat.lam + mat.mu)).sum()
    assert energy == pytest.approx(ref, rel=1e-12)
    # gradient: central differences of the energy; Hessian: central differences of the gradient
    eps = 1e-6
    fd_grad = np.zeros(x.size)
    fd_hess = np.zeros((x.size, x.size))
    for k in range(x.size):
        dx = np.zeros(x.size)
        dx[k] = eps
        ep, gp, _ = elastic_energy(v, t, x + dx.reshape(-1, 3), mat, device="cpu")
        em, gm, _ = elastic_energy(v, t, x - dx.reshape(-1, 3), mat, device="cpu")
        fd_grad[k] = (ep - em) / (2 * eps)
        fd_hess[:, k] = (gp - gm).ravel() / (2 * eps)
    np.testing.assert_allclose(grad.ravel(), fd_grad, atol=1e-7 * np.abs(fd_grad).max())
    np.testing.assert_allclose(hess.toarray(), fd_hess, atol=1e-6 * np.abs(fd_hess).max())


@wp.kernel
def _min_eigenvalues(
    F: wp.array(dtype=wp.mat33d), mu: wp.float64, lam: wp.float64, out: wp.array(dtype=wp.float64)
):
    i = wp.tid()
    out[i] = snh_min_eigenvalue(F[i], mu, lam)


def test_smallest_stress_derivative_eigenvalue_matches_a_dense_eigensolve(rng):
    """snh_min_eigenvalue (closed form from the singular values; the scaling modes' eigen-solve skipped where
    they lie above the twist/flip minimum) against numpy's eigenvalues of the 9x9 d2Psi/dF2
    = mu I + lam vec(cof F) vec(cof F)^T + (lam (J - 1) - mu) d2J/dF2, d2J/dF_ij dF_kl = eps_ikm eps_jln F_mn,
    at rest and over random deformations (J > 0.55, no barrier), both kinds of minimum among them."""
    F = np.eye(3) + rng.normal(size=(300, 3, 3)) * np.repeat([0.05, 0.2, 0.5], 100)[:, None, None]
    F = np.concatenate([np.eye(3)[None], np.diag([1.3, 1.0, 0.8])[None], F[np.linalg.det(F) > 0.55]])
    mu, lam = 1.0, 5.0
    out = wp.zeros(len(F), dtype=wp.float64, device="cpu")
    wp.launch(
        _min_eigenvalues, len(F), [wp.array(F, dtype=wp.mat33d, device="cpu"), mu, lam, out], device="cpu"
    )
    eps = np.zeros((3, 3, 3))
    eps[0, 1, 2] = eps[1, 2, 0] = eps[2, 0, 1] = 1.0
    eps[0, 2, 1] = eps[2, 1, 0] = eps[1, 0, 2] = -1.0
    J = np.linalg.det(F)
    cof = (J[:, None, None] * np.linalg.inv(F).transpose(0, 2, 1)).reshape(-1, 9)
    d2J = np.einsum("ikm,jln,tmn->tijkl", eps, eps, F).reshape(-1, 9, 9)
    hess = (
        mu * np.eye(9) + lam * cof[:, :, None] * cof[:, None, :] + (lam * (J - 1) - mu)[:, None, None] * d2J
    )
    smallest = np.linalg.eigvalsh(hess)[:, 0]
    twist_flip = mu - np.abs(lam * (J - 1) - mu) * np.linalg.svd(F, compute_uv=False)[:, 0]
    assert 0 < (smallest < twist_flip - 1e-9).sum() < len(F)  # scaling and twist/flip minima both occur
    np.testing.assert_allclose(out.numpy(), smallest, rtol=0, atol=1e-11)


@pytest.mark.parametrize("shift_limit", [0.1, 0.0])
def test_hessian_is_positive_semidefinite_under_large_deformation(rng, shift_limit):
    v, t = box_tets((1, 1, 1), (1.0, 1.0, 1.0))
    mat = Material("m", 1.0, 0.45, 1.0)
    for scale in (0.3, 0.6, 1.0):  # up to inverted elements
        x = v + scale * rng.normal(size=v.shape)
        _, _, hess = elastic_energy(v, t, x, mat, device="cpu", shift_limit=shift_limit)
        dense = hess.toarray()
        np.testing.assert_allclose(dense, dense.T, atol=1e-12 * np.abs(dense).max())
        assert np.linalg.eigvalsh(dense)[0] >= -1e-10 * np.abs(dense).max()


def test_free_fall_matches_the_discrete_and_continuous_solutions():
    v, t = box_tets((2, 2, 2))
    s = settings(gravity=G, up=(0.0, 1.0, 0.0), dt=1 / 30, substeps=4)
    sim = Run(v, t, RUBBER, s)
    c0 = com(sim)
    frames = 6
    for _ in range(frames):
        sim.step()
    n, h = frames * s.substeps, s.dt / s.substeps
    drop = c0[1] - com(sim)[1]
    # backward Euler: v_k = -g h k, x_n = x_0 - g h^2 n (n + 1) / 2, exactly
    assert drop == pytest.approx(G * h * h * n * (n + 1) / 2, rel=1e-9)
    assert drop == pytest.approx(G * (n * h) ** 2 / 2, rel=1.5 / n)
    np.testing.assert_allclose(com(sim)[[0, 2]], c0[[0, 2]], atol=1e-12)
    # no deformation in free fall
    np.testing.assert_allclose(sim.positions - sim.positions.mean(0), v - v.mean(0), atol=1e-9)


def test_rigid_motion_keeps_shape_and_linear_momentum():
    v, t = box_tets((2, 2, 2))
    sim = Run(
        v, t, RUBBER, settings(dt=1 / 60, substeps=4), linear=(0.3, -0.2, 0.1), angular=(2.0, 1.0, -3.0)
    )
    p0 = sim.model.masses @ sim.velocities
    for _ in range(10):
        sim.step()
    x = sim.positions
    dist = np.linalg.norm(x[:, None] - x[None], axis=-1)
    dist0 = np.linalg.norm(v[:, None] - v[None], axis=-1)
    np.testing.assert_allclose(dist, dist0, atol=2e-4 * dist0.max())
    np.testing.assert_allclose(sim.model.masses @ sim.velocities, p0, atol=1e-9)
    # the centre of mass moves uniformly
    np.testing.assert_allclose(com(sim), v.mean(0) + np.array([0.3, -0.2, 0.1]) * sim.state.time, atol=1e-9)


def test_stretched_bar_relaxes_toward_rest():
    v, t = box_tets((4, 1, 1), (0.4, 0.1, 0.1))
    sim = Run(v, t, SOFT, settings(damping=0.05, newton_tol=1e-4))
    stretched = v * np.array([1.2, 1.0, 1.0])
    sim.state.set(positions=stretched)
    e0, _, _ = elastic_energy(v, t, stretched, SOFT, device="cpu")
    for _ in range(30):
        sim.step()
    e1, _, _ = elastic_energy(v, t, sim.positions, SOFT, device="cpu")
    length = np.ptp(sim.positions[:, 0])
    assert length == pytest.approx(0.4, rel=0.02)
    assert e1 < 0.01 * e0


def test_body_resting_on_the_ground_settles_without_drift():
    """A block set down half the barrier's reach above the ground settles on it and stays: its surface never
    passes the ground, every gap ends within the reach, and nothing drifts or creeps."""
    v, t = box_tets((3, 3, 2), (0.1, 0.1, 0.05), origin=(0.0, 0.0, 0.5 * CONTACT_GAP))
    s = SolverSettings(dt=1 / 30, substeps=4, newton_tol=1e-5)
    sim = Run(v, t, get_material("rubber"), s, ground=True)
    lowest = []
    for frame in range(20):
        sim.step()
        lowest.append(sim.positions[:, 2].min())
        if frame == 9:
            settled = sim.positions
    x = sim.positions
    assert min(lowest) > 0 and lowest[-1] <= CONTACT_GAP
    np.testing.assert_allclose(com(sim)[:2], v.mean(0)[:2], atol=1e-5)
    np.testing.assert_allclose(x[:, :2], v[:, :2], atol=5e-5)
    np.testing.assert_allclose(x, settled, atol=1e-6)
    assert np.abs(sim.velocities).max() < 1e-4


def test_pinned_vertices_hold_and_the_free_end_sags():
    v, t = box_tets((4, 1, 1), (0.4, 0.05, 0.05))
    pinned = v[:, 0] < 1e-9
    sim = Run(v, t, SOFT, SolverSettings(damping=0.02), pinned=pinned)
    for _ in range(10):
        sim.step()
    x = sim.positions
    np.testing.assert_array_equal(x[pinned], v[pinned])
    tip = v[:, 0] > 0.4 - 1e-9
    assert (x[tip, 2] < v[tip, 2] - 1e-3).all()


@pytest.mark.parametrize("obstacle", ["sphere", pytest.param("box", marks=pytest.mark.slow)])
def test_obstacles_stop_a_falling_body(obstacle):
    v, t = box_tets((2, 2, 2), (0.06, 0.06, 0.06), origin=(-0.03, -0.03, 0.02))
    spec = (
        ColliderSpec("ball", "sphere", (0.0, 0.0, -0.2), radius=0.2)
        if obstacle == "sphere"
        else ColliderSpec("slab", "box", (0.0, 0.0, -0.1), half_extents=(0.2, 0.2, 0.1))
    )
    sim = Run(v, t, RUBBER, SolverSettings(), statics=[StaticSurface(*collider_mesh(spec), 0.5)])
    for _ in range(15):
        sim.step()
    x = sim.positions
    if obstacle == "sphere":  # it lands on the top (of the icosphere inside the sphere): nothing sinks in
        depth = 0.2 - np.linalg.norm(x - np.array([0.0, 0.0, -0.2]), axis=1)
        assert depth.max() < 1e-3
    else:  # it lands on the top face z = 0 and stays within the barrier's reach above it
        assert 0 < x[:, 2].min() <= CONTACT_GAP
    assert x[:, 2].min() < 0.02 - 0.01  # it did fall


def test_runaway_simulation_is_retried_then_raises_keeping_the_frames(tmp_path):
    v, t = box_tets((2, 2, 2), (0.1, 0.1, 0.1))
    # an absurd gravity (40 g) accelerates past max_speed after about 7 frames; more substeps cannot help
    s = SolverSettings(gravity=400.0, substeps=2, retry_factors=(2, 4), max_speed=100.0)
    sim = Run(v, t, RUBBER, s)
    path = tmp_path / "motion.npz"
    writer = MotionWriter(path, v, t, {"producer": "test"}, flush_seconds=1e9)
    with pytest.raises(SettingError, match="max_speed") as err:
        record_frames(writer, 60, sim.step, sim.snapshot, advice=lambda e: e.kind, desc="", progress=False)
    message = str(err.value)
    assert "with 2, 4, 8 substeps" in message  # it was retried
    motion = load_motion(path)
    assert motion.n_frames == 8  # frame 0 and the 7 frames below max_speed
    assert message.startswith("frame 8 ") and message.endswith(f"frames 0-7 are kept in {path}; speed")
    np.testing.assert_allclose(motion.positions[0], v, atol=1e-6)
    speed = np.linalg.norm(motion.positions[-1] - motion.positions[-2], axis=1).max() * 30
    assert 50 < speed <= 100
    assert motion.state["velocities"].shape == v.shape  # the state after the last frame, as an array
    # the simulator is left at the last good frame
    np.testing.assert_allclose(sim.positions, motion.positions[-1], atol=1e-5)


def _ratios(rest, positions, tets):
    """(T,) deformed / rest tet volumes from 3x3 determinants."""

    def det(x):
        return np.linalg.det(np.stack([x[tets[:, k]] - x[tets[:, 0]] for k in (1, 2, 3)], axis=2))

    return det(positions) / det(rest)


def test_a_collapsing_body_stops_before_the_first_crushed_frame(tmp_path):
    """A 0.3 m block of 100 Pa gel cannot carry its own weight (rho g L / E = 32): it slumps on the ground
    until some tet is squeezed below MIN_VOLUME_RATIO (the volume barrier keeps det F > 0, so nothing ever
    inverts). That frame is refused; every frame written before it is a valid cage."""
    v, t = box_tets((4, 3, 2), (0.3, 0.2, 0.15), origin=(0.0, 0.0, 0.1))
    s = SolverSettings(substeps=2, retry_factors=(2,))
    sim = Run(v, t, Material("limp", 1.0e2, 0.45, 1100.0), s, ground=True)
    path = tmp_path / "motion.npz"
    writer = MotionWriter(path, v, t, {"producer": "test"}, flush_seconds=1e9)
    collapse = r"with 2, 4 substeps: the smallest tet volume ratio \(det F\) fell to 0\.\d+, below 0\.2"
    with pytest.raises(SettingError, match=collapse) as err:
        record_frames(writer, 60, sim.step, sim.snapshot, advice=lambda e: e.kind, desc="", progress=False)
    motion = load_motion(path)
    message = str(err.value)
    assert motion.n_frames > 2 and message.endswith("; collapse")
    assert message.startswith(f"frame {motion.n_frames} (t = {(motion.n_frames - 1) / 30:.3f} s)")
    ratios = [_ratios(v, p.astype(np.float64), t).min() for p in motion.positions]
    assert min(ratios) >= MIN_VOLUME_RATIO - 1e-3  # float32 positions
    assert ratios[-1] < 0.9  # it was slumping
    # the simulator is left at the last written frame
    np.testing.assert_allclose(sim.positions, motion.positions[-1], atol=1e-5)


def test_settings_and_inputs_are_validated():
    with pytest.raises(ValueError, match="dt"):
        SolverSettings(dt=0.0)
    with pytest.raises(ValueError, match="newton_iterations"):
        SolverSettings(newton_iterations=0)
    with pytest.raises(ValueError, match="max_stretch"):
        SolverSettings(max_stretch=1.0)
    v, t = box_tets((1, 1, 1))
    with pytest.raises(ValueError, match="orientation"):
        Model(v, t[:, [1, 0, 2, 3]], RUBBER, device="cpu")
    with pytest.raises(ValueError, match="tets"):
        Model(v, t + 100, RUBBER, device="cpu")
    model = Model(v, t, RUBBER, device="cpu")
    with pytest.raises(AttributeError, match="immutable"):
        model.masses = None
    with pytest.raises(ValueError, match="read-only"):
        model.rest_vertices[0, 0] = 1.0
    with pytest.raises(ValueError, match="pinned"):
        Control(model, pinned=np.ones(3, bool))
    with pytest.raises(ValueError, match="forces"):
        Control(model, forces=np.full((len(v), 3), np.nan))
    state = model.state()
    with pytest.raises(ValueError, match="positions"):
        state.set(positions=np.zeros((3, 3)))


@pytest.mark.parametrize("damping, drag", [(0.0, 0.0), (0.02, 3.0)])
def test_a_bodys_force_is_minus_its_energy_gradient_and_its_hessian_the_jacobian(rng, damping, drag):
    """BodyTerms (elastic, Kelvin-Voigt damping, inertia with gravity and external forces, drag; two vertices
    pinned) against central differences of its own energy and force, at a deformed iterate of a step from a
    moving, deformed start; pinned rows: no force and the identity."""
    v, t = box_tets((1, 1, 1), (0.1, 0.1, 0.1))
    model = Model(v, t, SOFT, SolverSettings(damping=damping, drag=drag), device="cpu")
    terms = BodyTerms(model)
    state = model.state(linear=(0.1, -0.2, 0.3))
    state.set(positions=v * 1.1 + 0.001 * rng.normal(size=v.shape))
    pinned = np.zeros(len(v), bool)
    pinned[[0, 5]] = True
    control = Control(model, pinned=pinned, forces=0.01 * rng.normal(size=v.shape))
    step = terms.prepare(state, control, 1 / 120)
    x0 = v * 1.15 + 0.003 * rng.normal(size=v.shape)  # stretched: every element's Hessian is definite

    def energy_force(x):
        energy, _ = terms.evaluate(wp.array(x, dtype=wp.vec3d, device="cpu"), step, FORCE)
        return energy, terms.force

    _, force = energy_force(x0)
    terms.evaluate(wp.array(x0, dtype=wp.vec3d, device="cpu"), step, HESSIAN)
    hessian = terms.hessian_matrix().toarray()
    free = np.flatnonzero(~np.repeat(pinned, 3))
    eps, grad, jac = 1e-6, np.zeros(x0.size), np.zeros((x0.size, x0.size))
    for k in free:
        dx = np.zeros(x0.size)
        dx[k] = eps
        (ep, fp), (em, fm) = energy_force(x0 + dx.reshape(-1, 3)), energy_force(x0 - dx.reshape(-1, 3))
        grad[k] = (ep - em) / (2 * eps)
        jac[:, k] = -(fp - fm).ravel() / (2 * eps)
    np.testing.assert_allclose(force.ravel()[free], -grad[free], atol=1e-5 * np.abs(grad).max())
    np.testing.assert_array_equal(force[pinned], 0.0)
    block = np.ix_(free, free)
    np.testing.assert_allclose(hessian[block], jac[block], atol=1e-5 * np.abs(jac).max())
    for i in np.flatnonzero(pinned):
        np.testing.assert_array_equal(hessian[3 * i : 3 * i + 3, 3 * i : 3 * i + 3], np.eye(3))


def test_tet_slabs_share_no_vertex():
    v, t = box_tets((5, 4, 3), (0.5, 0.4, 0.3))
    order, ranges = partition_tets(v, t, 3)
    assert np.array_equal(np.sort(order), np.arange(len(t)))
    assert ranges[0][0] == 0 and ranges[-1][1] == len(t)
    assert all(a[1] == b[0] for a, b in zip(ranges, ranges[1:], strict=False))
    slab_vertices = [set(t[order[lo:hi]].ravel()) for lo, hi in ranges[:-1]]
    assert all(len(s) > 0 for s in slab_vertices)
    for i in range(3):
        for j in range(i + 1, 3):
            assert not slab_vertices[i] & slab_vertices[j]
    # a straddling tet really touches two slabs: no tet is left out of a slab it could have joined
    lo, hi = ranges[-1]
    for tet in t[order[lo:hi]]:
        assert sum(bool(set(tet) <= s) for s in slab_vertices) == 0
    assert partition_tets(v, t, 1)[1] == [(0, len(t))]


def test_hessian_assembled_on_threads_equals_one_thread(monkeypatch, rng):
    """Three threads each assembling the Hessian blocks of their slab of tets (then the tets between slabs)
    give the same matrix as one thread over every tet, to rounding, at a deformed, damped iterate."""
    v, t = box_tets((6, 3, 3), (0.3, 0.15, 0.15))
    monkeypatch.setattr(body_module, "default_cpu_threads", lambda: 3)
    deformed = v + 0.01 * rng.normal(size=v.shape)
    matrices = []
    for threshold in (10**9, 0):
        monkeypatch.setattr(body_module, "PARALLEL_HESSIAN_TETS", threshold)
        model = Model(v, t, RUBBER, SolverSettings(damping=0.01), device="cpu")
        terms = BodyTerms(model)
        assert len(terms._tet_parts) == (1 if threshold else 4)
        state = model.state(linear=(0.2, 0.0, -0.1))
        step = terms.prepare(state, Control(model), 1 / 240)
        x = wp.array(deformed, dtype=wp.vec3d, device="cpu")
        terms.evaluate(x, step, HESSIAN)
        matrices.append(terms.hessian_matrix().toarray())
    scale = np.abs(matrices[0]).max()
    np.testing.assert_allclose(matrices[1], matrices[0], rtol=0, atol=1e-12 * scale)


@pytest.fixture
def cube_mesh(tmp_path, monkeypatch):
    """A closed cube mesh file; tetrahedralising it gives a 48-tet Kuhn box (no fTetWild)."""
    import types

    import trimesh

    path = tmp_path / "cube.stl"
    trimesh.creation.box((1, 1, 1)).export(path)

    def build_cage(outer, inner, config=None, what=""):
        verts, tets, _ = kuhn_grid(0.0, 1.0, 2)
        return types.SimpleNamespace(vertices=verts + outer.bounds[0], tets=tets)

    monkeypatch.setattr("shellsim.tetcage.build.build_cage", build_cage)
    return path


def _cli_error(argv, capsys):
    from shellsim.cli.main import main

    capsys.readouterr()
    assert main(argv) == 2
    stderr = capsys.readouterr().err
    err = stderr.strip().splitlines()[-1]  # after the progress bar
    assert err.startswith("shellsim: error: ") and "Traceback" not in stderr
    return err[len("shellsim: error: ") :]


def test_cli_reports_the_collapsing_frame_in_one_line_keeping_the_frames_before(tmp_path, cube_mesh, capsys):
    out = tmp_path / "limp.npz"
    argv = ["simulate", "--mesh", str(cube_mesh), "--youngs", "200", "--substeps", "2", "--frames", "30"]
    err = _cli_error([*argv, "--out", str(out), "--device", "cpu"], capsys)
    motion = load_motion(out)
    assert 2 < motion.n_frames < 30
    assert err.startswith(f"frame {motion.n_frames} (t = ")
    assert "smallest tet volume ratio (det F) fell to 0." in err and "below 0.2" in err
    assert f"frames 0-{motion.n_frames - 1} are kept in {out}" in err
    assert "--youngs; now 200 Pa" in err and "--size" in err


def test_cli_reports_the_stretched_frame_and_goes_on_when_allowed(tmp_path, cube_mesh, capsys, caplog):
    """A 1 m jelly cube held by one face and thrown at 30 m/s from it: frame 2 stretches a tet past 3 (the
    run stops, keeping frames 0-1); given allow_stretch, the same command continues the file (the switch does
    not change the motion), warning once."""
    from shellsim.cli.main import main

    out = tmp_path / "pulled.npz"
    argv = ["simulate", "--mesh", str(cube_mesh), "--material", "jelly", "--pin", "x<-0.49", "--no-ground"]
    argv += ["--velocity", "30,0,0", "--substeps", "2", "--frames", "10", "--out", str(out)]
    argv += ["--device", "cpu"]
    err = _cli_error(argv, capsys)
    assert err.startswith("frame 2 (t = 0.033 s) is invalid with 2, 4, 8 substeps: a tet was stretched to ")
    assert f"above 3; frames 0-1 are kept in {out}" in err
    assert err.endswith("raise --max-stretch, or give --allow-stretch to only warn")
    with caplog.at_level("WARNING", logger="shellsim.physics.driver"):
        assert main([*argv, "--allow-stretch"]) == 0
    assert load_motion(out).n_frames == 10
    assert len([r for r in caplog.records if "stretched to" in r.getMessage()]) == 1


@pytest.mark.parametrize(
    "option, message",
    [
        (["--substeps", "100000000"], "--substeps: expected an integer in [1, 1000], got 100000000"),
        (["--substeps", "0"], "--substeps: expected an integer in [1, 1000], got 0"),
        (["--frames", "0"], "--frames: expected an integer in [1, 10000], got 0"),
        (["--fps", "-30"], "--fps: expected a number of frames per second in (0, 1000], got -30"),
        (["--youngs", "1"], "--youngs: expected a Young's modulus in Pa in [100, 2e+12], got 1"),
        (["--youngs", "nan"], "--youngs: expected a Young's modulus in Pa in [100, 2e+12], got nan"),
        (["--poisson", "0.5"], "--poisson: expected a Poisson ratio in (-1, 0.5), got 0.5"),
        (["--density", "0"], "--density: expected a density in kg/m^3 in [1, 100000], got 0"),
        (["--size", "0"], "--size: expected a length in metres in [0.001, 1000], got 0"),
        (["--drop-height", "-1"], "--drop-height: expected a height in metres in [0, 100], got -1"),
        (["--friction", "inf"], "--friction: expected a Coulomb coefficient in [0, 10], got inf"),
        (["--damping", "-0.1"], "--damping: expected a time in seconds in [0, 10], got -0.1"),
        (["--max-stretch", "1"], "--max-stretch: expected a principal stretch in (1, inf], got 1"),
        (["--tets", "5"], "--tets: expected an integer in [10, 1000000000], got 5"),
        (["--velocity", "300,0,0"], "--velocity: expected a speed in m/s"),
        (
            ["--spin", "0,0,1000", "--size", "0.3"],
            "--spin: expected an angular speed in rad/s at --size 0.3 m in [0, 333.333)",
        ),
        (["--sphere", "0,0,0,-1"], "--sphere: expected a radius in (0, inf), got -1"),
        (["--box", "0,0,0,1,0,1"], "--box: expected half extents in (0, inf), got 0"),
    ],
)
def test_cli_refuses_out_of_range_numbers_at_once(tmp_path, capsys, option, message):
    """Refused with the valid range before the mesh is read: the mesh does not even exist."""
    err = _cli_error(["simulate", "--mesh", str(tmp_path / "missing.ply"), *option], capsys)
    assert err.startswith(message)
