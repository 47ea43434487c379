"""Several bodies in one implicit solve with incremental potential contact (shellsim.physics.solver, ipc):
checked against conservation laws, the barrier's guarantee (no surfaces ever cross) and statics."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from shellsim.physics.control import Control
from shellsim.physics.driver import FrameDriver
from shellsim.physics.ipc import BodySurface, Contact, StaticSurface
from shellsim.physics.materials import get_material
from shellsim.physics.model import Model, SolverSettings
from shellsim.physics.solver import Solver
from shellsim.tetcage.embed import embed_points
from tests.meshes import kuhn_grid, own_surface

pytest.importorskip("ipctk")

DHAT = 1e-3


def embedding(cage_vertices, cage_tets, points) -> sp.csr_matrix:
    """(P, V) barycentric weights of ``points`` in the cage (a slow, independent assembly of the map)."""
    tet, bary = embed_points(cage_vertices, cage_tets, points)
    rows = np.repeat(np.arange(len(points)), 4)
    return sp.csr_matrix(
        (bary.ravel(), (rows, cage_tets[tet].ravel())), shape=(len(points), len(cage_vertices))
    )


def cube(half: float, cells: int, centre) -> tuple[np.ndarray, np.ndarray]:
    v, t, _ = kuhn_grid(-half, half, cells)
    return v + np.asarray(centre, np.float64), t


@pytest.fixture(scope="module")
def ball():
    """A tetrahedralised sphere of radius 5 cm and its surface, 642 vertices (fTetWild, once per module)."""
    import trimesh

    from shellsim.tetcage.tetwild import tetrahedralize

    ico = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    v, t, _ = tetrahedralize(ico.vertices, ico.faces, 0.02, 1e-3)
    return v, t, np.asarray(ico.vertices), np.asarray(ico.faces)


def run_substeps(solver, states, controls, h, n, check=None):
    other = [m.state() for m in solver.models]
    for _ in range(n):
        stats = solver.step(states, other, controls, h)
        states, other = other, states
        assert np.isfinite(stats.energy)
        if check is not None:
            check(states)
    return states


@pytest.mark.parametrize("integrator", ["euler", "bdf2"])
def test_spheres_head_on_conserve_momentum_never_touch_and_separate_along_the_impact_line(ball, integrator):
    """Two identical spheres (the second turned arbitrarily about its centre, so their facets meet in a
    generic way) meet head-on along x at 1.5 and -0.5 m/s, without gravity or ground; either integrator."""
    from scipy.spatial.transform import Rotation

    v, t, sv, sf = ball
    turn = Rotation.from_rotvec([0.3, 0.5, 0.7]).as_matrix()
    settings = SolverSettings(gravity=0.0, substeps=1, integrator=integrator)
    rubber = get_material("rubber")
    models = [
        Model(v + [-0.06, 0, 0], t, rubber, settings),
        Model(v @ turn.T + [0.06, 0, 0], t, rubber, settings),
    ]
    w = embedding(v, t, sv)
    contact = Contact(
        [BodySurface(w, sf, 0.0)] * 2,
        [0, len(v)],
        np.concatenate([m.rest_vertices for m in models]),
        [],
        DHAT,
        1e-2,
    )
    solver = Solver(models, contact, settings)
    states = [models[0].state(linear=(1.5, 0, 0)), models[1].state(linear=(-0.5, 0, 0))]
    controls = [Control(m) for m in models]
    mass = models[0].masses.sum()
    assert models[1].masses.sum() == pytest.approx(mass)
    p0 = mass * np.array([1.0, 0, 0])
    gaps = []

    def check(states):
        x = np.concatenate([s.positions.numpy() for s in states])
        gaps.append(contact.least_distance(x))

    states = run_substeps(solver, states, controls, 1.0 / 240, 14, check)
    velocities = [
        m.masses @ s.velocities.numpy() / m.masses.sum() for m, s in zip(models, states, strict=True)
    ]
    p = mass * (velocities[0] + velocities[1])
    assert np.linalg.norm(p - p0) <= 0.01 * np.linalg.norm(p0)
    assert min(gaps) > 0  # the surfaces never touched nor crossed
    assert np.isfinite(min(gaps))  # and they did come within the barrier's reach
    relative = velocities[1] - velocities[0]
    assert relative[0] > 0.1  # they separate ...
    assert np.linalg.norm(relative[1:]) < np.tan(np.radians(5)) * relative[0]  # ... along the line of impact


def test_a_stack_of_boxes_comes_to_rest_with_gaps_within_the_barrier_reach():
    settings = SolverSettings(gravity=9.81, substeps=4, damping=0.01)
    lower, lower_t = cube(0.05, 2, (0, 0, 0.05 + 0.5 * DHAT))
    upper, upper_t = cube(0.04, 2, (0.01, 0, 0.1 + 0.04 + 1.5 * DHAT))
    rubber = get_material("rubber", youngs=1e6)
    models = [Model(lower, lower_t, rubber, settings), Model(upper, upper_t, rubber, settings)]
    surfaces = [own_surface(lower_t, len(lower)), own_surface(upper_t, len(upper))]
    contact = Contact(surfaces, [0, len(lower)], np.concatenate([lower, upper]), [], DHAT, 1e-2, 0.5)
    driver = FrameDriver(Solver(models, contact, settings))
    states = [m.state() for m in models]
    for _ in range(30):
        stats = driver.step(states)
    assert stats.max_speed < 0.02
    low, up = (s.positions.numpy() for s in states)
    ground_gap = low[:, 2].min()
    stack_gap = up[:, 2].min() - low[:, 2].max()
    assert 0 < ground_gap <= DHAT
    assert 0 < stack_gap <= DHAT


def test_a_body_at_rest_has_its_visible_surface_on_the_ground_not_its_cage(ball):
    """The collision surface (a sphere) inside a cage 2 cm wider (a box): the sphere rests on the ground and
    the cage's bottom goes below it, unseen."""
    _, _, sv, sf = ball
    cage, cage_t = cube(0.07, 3, (0, 0, 0.0))
    sphere = sv + [0, 0, 0.0]
    lift = -sphere[:, 2].min() + 0.5 * DHAT
    cage, sphere = cage + [0, 0, lift], sphere + [0, 0, lift]
    settings = SolverSettings(gravity=9.81, substeps=4, damping=0.02)
    model = Model(cage, cage_t, get_material("rubber", youngs=2e6), settings)
    surface = BodySurface(embedding(cage, cage_t, sphere), sf, 0.5)
    contact = Contact([surface], [0], cage, [], DHAT, 1e-2, 0.5)
    driver = FrameDriver(Solver([model], contact, settings))
    states = [model.state()]
    for _ in range(20):
        stats = driver.step(states)
    assert stats.max_speed < 0.02
    x = states[0].positions.numpy()
    lowest_visible = (surface.weights @ x)[:, 2].min()
    assert 0 < lowest_visible <= 1e-3
    assert x[:, 2].min() < -0.015  # the cage itself reaches below the ground


@pytest.mark.slow
def test_static_collider_friction_holds_a_body_on_a_gentle_slope_and_lets_it_slide_on_a_steep_one():
    """Coulomb: a block on a plane tilted by theta sticks when tan(theta) < mu and slides when it is above."""
    from scipy.spatial.transform import Rotation

    settings = SolverSettings(gravity=9.81, substeps=4, damping=0.01)
    moved = {}
    for degrees in (10.0, 40.0):  # tan 10 = 0.18 and tan 40 = 0.84 against mu = 0.5
        turn = Rotation.from_euler("y", degrees, degrees=True).as_matrix()
        plane = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float) @ turn.T
        block, block_t = cube(0.02, 1, (0, 0, 0.02 + 0.5 * DHAT))
        block = block @ turn.T
        model = Model(block, block_t, get_material("rubber", youngs=1e6), settings)
        slope = StaticSurface(plane, np.array([[0, 1, 2], [0, 2, 3]]), 0.5)
        contact = Contact([own_surface(block_t, len(block))], [0], block, [slope], DHAT, 1e-2)
        driver = FrameDriver(Solver([model], contact, settings))
        states = [model.state()]
        for _ in range(10):
            driver.step(states)
        moved[degrees] = np.linalg.norm(states[0].positions.numpy().mean(0) - block.mean(0))
    assert moved[10.0] < 2e-3
    assert moved[40.0] > 0.05


@pytest.mark.slow
@pytest.mark.parametrize("mu", [0.2, 0.4])
def test_a_stiff_block_slides_down_a_slope_at_the_coulomb_acceleration(mu):
    """A stiff 4 cm block on a 30-degree plane (two triangles whose shared edge stays clear of the block: see
    shellsim.physics.ipc on edges): its centre of mass accelerates down the slope at g (sin 30 - mu cos 30),
    within 3 %."""
    from scipy.spatial.transform import Rotation

    settings = SolverSettings(gravity=9.81, substeps=4, damping=0.01)
    turn = Rotation.from_euler("y", 30.0, degrees=True).as_matrix()
    plane = (np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float) + [0.3, 0.5, 0]) @ turn.T
    block, block_t = cube(0.02, 2, (0, 0, 0.02 + 0.5 * DHAT))
    block = block @ turn.T
    model = Model(block, block_t, get_material("rubber", youngs=1e8), settings)
    surface = own_surface(block_t, len(block))
    surface = BodySurface(surface.weights, surface.faces, mu)
    slope = StaticSurface(plane, np.array([[0, 1, 2], [0, 2, 3]]), mu)
    contact = Contact([surface], [0], block, [slope], DHAT, 1e-2)
    driver = FrameDriver(Solver([model], contact, settings))
    states = [model.state()]
    downhill = turn @ np.array([1.0, 0.0, 0.0])
    travelled = []
    for _ in range(15):
        driver.step(states)
        travelled.append(model.masses @ states[0].positions.numpy() / model.masses.sum() @ downhill)
    t = np.arange(1, 16) / 30.0
    acceleration = 2.0 * np.polyfit(t[3:], travelled[3:], 2)[0]  # once it has settled on the slope
    expected = 9.81 * (np.sin(np.radians(30)) - mu * np.cos(np.radians(30)))
    assert acceleration == pytest.approx(expected, rel=0.03)


def test_the_ground_barrier_is_the_closed_form_sum_over_the_vertices_within_reach():
    """The ground's barrier is ipctk's log barrier of each surface vertex's height alone,
    b(z) = -(z^2 - dhat^2)^2 log(z^2 / dhat^2) for z < dhat, summed (no pair among a body's own vertices,
    however close), and the collision-free fraction of a path down to the plane is a fixed share (ipctk's
    conservative rescaling, 0.8) of where its lowest vertex would reach z = 0."""
    rng = np.random.default_rng(5)
    # a strip of 40 triangles lying just above the ground, its vertices 0.2 dhat apart
    n = 21
    xs = np.arange(n) * 0.2 * DHAT
    points = np.concatenate(
        [np.stack([xs, np.zeros(n), np.zeros(n)], 1), np.stack([xs, 0.2 * DHAT + 0 * xs, 0 * xs], 1)]
    )
    points[:, 2] = rng.uniform(0.05, 1.6, len(points)) * DHAT
    faces = np.array(
        [[i, i + 1, n + i] for i in range(n - 1)] + [[i + 1, n + i + 1, n + i] for i in range(n - 1)]
    )
    weights = sp.identity(len(points), format="csr")
    contact = Contact([BodySurface(weights, faces, 0.0)], [0], points, [], DHAT, 0.01, 0.0)  # frictionless
    contact.begin_step(points, 1e-3, lambda: np.zeros_like(points), 1.0, 1.0)
    z = points[:, 2][points[:, 2] < DHAT]
    expected = contact.kappa * np.sum(-((z * z - DHAT**2) ** 2) * np.log(z * z / DHAT**2))
    assert contact.energy(points) == pytest.approx(expected, rel=1e-10)
    lowered = points - [0.0, 0.0, 2 * DHAT]
    _, fraction = contact.candidates(points, lowered)
    assert fraction == pytest.approx(0.8 * points[:, 2].min() / (2 * DHAT), rel=1e-3)
