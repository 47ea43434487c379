"""Per-vertex terms of the incremental potential (physics.contact.vertex_terms): inertia, drag, penalty
contact with the ground, a sphere and a box, and lagged smoothed friction. The force must be -dE/dx and the
Hessian block d(-force)/dx less the sphere's curvature term that the module drops on purpose (so that
every block stays positive definite), both checked by central differences of the kernel's own energy, at
points chosen away from the places where the terms switch (contact onset, a box's mid-planes, the
friction smoothing radius)."""

import numpy as np
import pytest
import warp as wp

from shellsim.physics.contact import (
    Box,
    Sphere,
    collider_arrays,
    lag_friction,
    make_colliders,
    vec3,
    vertex_terms,
)

wp.init()
DEVICE = "cpu"
UP = (0.0, 0.0, 1.0)
EPS_U = 0.01

#: vertex positions: under the ground with a tangential step below eps_u; inside the sphere with one above;
#: inside the box, nearest its +x face; in free space (inertia and drag only)
X = np.array([[0.10, 0.20, -0.004], [1.0, 0.05, 0.45], [-0.98, 0.02, 0.3], [0.5, 0.5, 2.0]])
X_PREV = X + np.array([[0.003, -0.002, 0.001], [0.03, 0.02, 0.0], [0.004, 0.0, 0.001], [0.01, 0.0, 0.0]])
X_TILDE = X + np.array([[0.01, 0.0, -0.02], [0.0, 0.02, 0.01], [-0.01, 0.01, 0.0], [0.0, 0.0, -0.05]])
MASS = np.array([0.3, 0.2, 0.5, 0.1])
KAPPA = 4000.0
SPHERE_CENTER, SPHERE_RADIUS = np.array([1.0, 0.0, 0.5]), 0.2


def dropped_sphere_curvature(x: np.ndarray, mass: float) -> np.ndarray:
    """(3, 3) the part of the exact Hessian of kappa m / 2 d^2, d = R - |x - c|, that the module leaves out:
    kappa m d (dd/dx)' = -kappa m d / |x - c| (I - n n^T)."""
    r = x - SPHERE_CENTER
    dist = np.linalg.norm(r)
    n = r / dist
    return -KAPPA * mass * (SPHERE_RADIUS - dist) / dist * (np.eye(3) - np.outer(n, n))


def run(x: np.ndarray, order: int, friction: float = 0.6):
    """(energy, force (N, 3), Hessian blocks (N, 3, 3)) of vertex_terms at positions x (N, 3)."""
    n = len(x)
    colliders = make_colliders(
        UP,
        0.0,
        collider_arrays([Sphere((1.0, 0.0, 0.5), 0.2)], [Box((-1.0, 0.0, 0.3), (0.05, 0.2, 0.2))], DEVICE),
    )
    arr = lambda a: wp.array(np.asarray(a, np.float64), dtype=vec3, device=DEVICE)  # noqa: E731
    mass = wp.array(MASS[:n], dtype=wp.float64, device=DEVICE)
    kappa = KAPPA
    normal_force = wp.zeros(n, dtype=wp.float64, device=DEVICE)
    normal = wp.zeros(n, dtype=vec3, device=DEVICE)
    # lagged at the previous positions' depths, which are those of X_PREV: all penetrating but the last
    wp.launch(lag_friction, n, [arr(X_PREV[:n]), mass, colliders, kappa, normal_force, normal], device=DEVICE)
    energy = wp.zeros(1, dtype=wp.float64, device=DEVICE)
    force_sq = wp.zeros(1, dtype=wp.float64, device=DEVICE)
    force = wp.zeros(n, dtype=vec3, device=DEVICE)
    values = wp.zeros(n, dtype=wp.mat33d, device=DEVICE)
    inv_diag = wp.zeros(n, dtype=wp.mat33d, device=DEVICE)
    wp.launch(
        vertex_terms,
        n,
        [
            arr(x),
            arr(X_TILDE[:n]),
            arr(X_PREV[:n]),
            mass,
            wp.zeros(n, dtype=wp.int32, device=DEVICE),
            1.0 / 0.01**2,
            2.0 / 0.01,
            colliders,
            kappa,
            friction,
            normal_force,
            normal,
            EPS_U,
            order,
            energy,
            force_sq,
            force,
            values,
            wp.array(np.arange(n, dtype=np.int32), device=DEVICE),
            inv_diag,
        ],
        device=DEVICE,
    )
    return float(energy.numpy()[0]), force.numpy(), values.numpy()


def test_the_chosen_points_touch_what_they_should():
    """Guards the test's premises: the first three penetrate (depth > 0 at X and X_PREV), friction is on
    for them, the first's tangential step lies below eps_u and the second's above."""
    _, f_on, _ = run(X, 1)
    _, f_off, _ = run(X, 1, friction=0.0)
    assert all(np.abs(f_on[i] - f_off[i]).max() > 1e-3 for i in range(3))
    np.testing.assert_array_equal(f_on[3], f_off[3])
    step = X - X_PREV
    n = (X_PREV[1] - SPHERE_CENTER) / np.linalg.norm(X_PREV[1] - SPHERE_CENTER)  # the lagged normal
    assert np.linalg.norm(step[0, :2]) < EPS_U < np.linalg.norm(step[1] - (step[1] @ n) * n)


@pytest.mark.parametrize("vertex", range(len(X)))
def test_force_is_minus_the_energy_gradient_and_hessian_its_jacobian(vertex):
    _, force, _ = run(X, 1)
    _, _, hess = run(X, 2)
    delta = 1e-6
    grad = np.zeros(3)
    jac = np.zeros((3, 3))
    for k in range(3):
        plus, minus = X.copy(), X.copy()
        plus[vertex, k] += delta
        minus[vertex, k] -= delta
        e_plus, f_plus, _ = run(plus, 1)
        e_minus, f_minus, _ = run(minus, 1)
        grad[k] = (e_plus - e_minus) / (2 * delta)
        jac[:, k] = -(f_plus[vertex] - f_minus[vertex]) / (2 * delta)
    np.testing.assert_allclose(force[vertex], -grad, rtol=1e-6, atol=1e-6 * np.abs(grad).max())
    if vertex == 1:  # inside the sphere
        jac = jac - dropped_sphere_curvature(X[1], MASS[1])
    np.testing.assert_allclose(hess[vertex], jac, rtol=1e-5, atol=1e-5 * np.abs(jac).max())
    np.testing.assert_allclose(hess[vertex], hess[vertex].T, atol=1e-9 * np.abs(jac).max())
    assert np.linalg.eigvalsh(hess[vertex]).min() > 0  # inertia keeps every block positive definite
