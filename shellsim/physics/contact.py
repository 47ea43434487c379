"""Per-vertex terms of the backward-Euler incremental potential (:mod:`shellsim.physics.solver`): inertia,
drag, penalty contact with the ground plane and static obstacles, and lagged, smoothed Coulomb friction.

With substep ``h``, lumped mass ``m_i``, previous positions ``x^n`` and inertial prediction
``x~ = x^n + h v^n + h^2 g``, vertex ``i`` contributes

    E_i(x_i) = m_i / (2 h^2) |x_i - x~_i|^2                                 inertia
             + alpha m_i / (2 h) |x_i - x^n_i|^2                             drag (alpha [1/s])
             + sum_c  kappa m_i / 2 * max(d_c(x_i), 0)^2                     penalty contact
             + mu_f lambda_i f0(|T_i (x_i - x^n_i)|)                         friction (IPC, Li et al. 2020)

where ``d_c`` is the penetration depth into collider ``c`` (ground plane, sphere, axis-aligned box) with
outward normal ``n_c``, ``kappa`` [1/s^2] a penalty stiffness per unit mass (a resting vertex sinks about
``g / kappa`` times the number of vertices it carries), ``lambda_i = kappa m_i d`` the normal force of the
deepest contact at the start of the substep (lagged), ``T_i = I - n n^T`` its tangent projector, and
``f0`` the C1 smoothing of ``|u|`` below ``eps_u = friction_velocity * h``::

    f0(y) = y^2 / eps_u - y^3 / (3 eps_u^2) + eps_u / 3   (y < eps_u),   y otherwise.

All Hessians are 3x3 diagonal blocks; the contact curvature of spheres (negative inside) is dropped, so
every block is positive semi-definite.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

vec3 = wp.vec3d
mat33 = wp.mat33d
f64 = wp.float64

wp.set_module_options({"enable_backward": False})  # no autodiff here; halves compile time


@dataclass(frozen=True)
class Sphere:
    """A static solid sphere: ``center`` (3,) and ``radius`` in simulation units (metres)."""

    center: tuple[float, float, float]
    radius: float

    def __post_init__(self):
        _check_vector("Sphere.center", self.center)
        if not (math.isfinite(self.radius) and self.radius > 0):
            raise ValueError(f"Sphere.radius must be > 0, got {self.radius}")


@dataclass(frozen=True)
class Box:
    """A static solid axis-aligned box: ``center`` (3,) and ``half_extents`` (3,) > 0, in metres."""

    center: tuple[float, float, float]
    half_extents: tuple[float, float, float]

    def __post_init__(self):
        _check_vector("Box.center", self.center)
        _check_vector("Box.half_extents", self.half_extents)
        if min(self.half_extents) <= 0:
            raise ValueError(f"Box.half_extents must be > 0, got {self.half_extents}")


def _check_vector(name: str, value) -> None:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (3,) or not np.isfinite(arr).all():
        raise ValueError(f"{name} must be 3 finite numbers, got {value!r}")


@wp.struct
class Colliders:
    """What the vertices collide with, simulation units: the ground plane ``dot(x, up) = ground`` (when
    ``has_ground`` != 0), spheres (S,) vec4d (centre, radius) and axis-aligned boxes (B,) (centre, half
    extents)."""

    up: vec3
    ground: f64
    has_ground: int
    spheres: wp.array(dtype=wp.vec4d)
    box_center: wp.array(dtype=vec3)
    box_half: wp.array(dtype=vec3)


def collider_arrays(spheres, boxes, device) -> tuple[wp.array, wp.array, wp.array]:
    """Warp arrays for :class:`Colliders`: spheres (S,) vec4d (centre, radius), box centres and half extents
    (B,)."""
    sph = np.array([[*s.center, s.radius] for s in spheres], np.float64).reshape(-1, 4)
    box_c = np.array([b.center for b in boxes], np.float64).reshape(-1, 3)
    box_h = np.array([b.half_extents for b in boxes], np.float64).reshape(-1, 3)
    return (
        wp.array(sph, dtype=wp.vec4d, device=device),
        wp.array(box_c, dtype=vec3, device=device),
        wp.array(box_h, dtype=vec3, device=device),
    )


def make_colliders(up, ground: float | None, arrays: tuple[wp.array, wp.array, wp.array]) -> Colliders:
    """:class:`Colliders` of the unit ``up`` (3,), the ground height (None: no ground) and
    :func:`collider_arrays`."""
    colliders = Colliders()
    colliders.up = vec3(*up)
    colliders.ground = f64(ground or 0.0)
    colliders.has_ground = int(ground is not None)
    colliders.spheres, colliders.box_center, colliders.box_half = arrays
    return colliders


@wp.func
def sphere_contact(x: vec3, sphere: wp.vec4d):
    """Penetration depth into a sphere and its outward normal at ``x``."""
    r = x - vec3(sphere[0], sphere[1], sphere[2])
    dist = wp.length(r)
    n = vec3(f64(0.0), f64(0.0), f64(1.0))
    if dist > f64(0.0):
        n = r / dist
    return sphere[3] - dist, n


@wp.func
def box_contact(x: vec3, center: vec3, half: vec3):
    """Penetration depth into an axis-aligned box (distance to the nearest face) and that face's normal."""
    p = x - center
    q = vec3(wp.abs(p[0]) - half[0], wp.abs(p[1]) - half[1], wp.abs(p[2]) - half[2])
    k = int(0)  # noqa: UP018 (a mutable Warp variable, not a constant)
    if q[1] > q[k]:
        k = 1
    if q[2] > q[k]:
        k = 2
    n = vec3(f64(0.0), f64(0.0), f64(0.0))
    n[k] = wp.where(p[k] < f64(0.0), f64(-1.0), f64(1.0))
    return -q[k], n


@wp.func
def deepest_contact(x: vec3, c: Colliders):
    """Largest penetration depth over all colliders (<= 0 when none touches) and its outward normal."""
    depth = f64(-1.0e30)
    normal = c.up
    if c.has_ground != 0:
        depth = c.ground - wp.dot(x, c.up)
    for s in range(c.spheres.shape[0]):
        d, n = sphere_contact(x, c.spheres[s])
        if d > depth:
            depth = d
            normal = n
    for b in range(c.box_center.shape[0]):
        d, n = box_contact(x, c.box_center[b], c.box_half[b])
        if d > depth:
            depth = d
            normal = n
    return depth, normal


@wp.func
def penalty(d: f64, n: vec3, k: f64, energy: f64, force: vec3, hess: mat33):
    """Add ``k/2 max(d, 0)^2`` (force ``k d n``, Hessian ``k n n^T``) to the running sums."""
    if d > f64(0.0):
        energy += f64(0.5) * k * d * d
        force += k * d * n
        hess += k * wp.outer(n, n)
    return energy, force, hess


@wp.kernel
def lag_friction(
    x: wp.array(dtype=vec3),
    mass: wp.array(dtype=f64),
    colliders: Colliders,
    kappa: f64,
    normal_force: wp.array(dtype=f64),
    normal: wp.array(dtype=vec3),
):
    """Lagged contact state at the start of a substep: ``lambda_i = kappa m_i max(d, 0)`` and ``n_i``."""
    i = wp.tid()
    d, n = deepest_contact(x[i], colliders)
    normal_force[i] = kappa * mass[i] * wp.max(d, f64(0.0))
    normal[i] = n


@wp.kernel
def vertex_terms(
    x: wp.array(dtype=vec3),
    x_tilde: wp.array(dtype=vec3),
    x_prev: wp.array(dtype=vec3),
    mass: wp.array(dtype=f64),
    pinned: wp.array(dtype=wp.int32),
    inv_h2: f64,
    drag_over_h: f64,
    colliders: Colliders,
    kappa: f64,
    friction: f64,
    normal_force: wp.array(dtype=f64),
    normal: wp.array(dtype=vec3),
    eps_u: f64,
    order: int,
    energy: wp.array(dtype=f64),
    force_sq: wp.array(dtype=f64),
    force: wp.array(dtype=vec3),
    values: wp.array(dtype=mat33),
    diag_index: wp.array(dtype=wp.int32),
    inv_diag: wp.array(dtype=mat33),
):
    """For ``order`` 0 and 1 the energy of vertex ``i`` (module docstring), for 1 also its force ``-dE/dx_i``
    (added to ``force``, whose squared norm is summed in ``force_sq``); for ``order`` 2 only its Hessian block
    (added to the diagonal block ``values[diag_index[i]]``) and the inverse of that completed diagonal block
    (block-Jacobi preconditioner). Pinned vertices get an identity row and no force."""
    i = wp.tid()
    zero3 = vec3(f64(0.0), f64(0.0), f64(0.0))
    if pinned[i] != 0:
        if order == 1:
            force[i] = zero3
        if order == 2:
            values[diag_index[i]] = wp.identity(n=3, dtype=f64)
            inv_diag[i] = wp.identity(n=3, dtype=f64)
        return
    m = mass[i]
    xi = x[i]
    dx = xi - x_tilde[i]
    step = xi - x_prev[i]
    e = f64(0.5) * m * inv_h2 * wp.dot(dx, dx) + f64(0.5) * drag_over_h * m * wp.dot(step, step)
    f = -m * inv_h2 * dx - drag_over_h * m * step
    h = (m * inv_h2 + drag_over_h * m) * wp.identity(n=3, dtype=f64)

    k = kappa * m
    c = colliders
    if c.has_ground != 0:
        e, f, h = penalty(c.ground - wp.dot(xi, c.up), c.up, k, e, f, h)
    for s in range(c.spheres.shape[0]):
        d, n = sphere_contact(xi, c.spheres[s])
        e, f, h = penalty(d, n, k, e, f, h)
    for b in range(c.box_center.shape[0]):
        d, n = box_contact(xi, c.box_center[b], c.box_half[b])
        e, f, h = penalty(d, n, k, e, f, h)

    lam = friction * normal_force[i]
    if lam > f64(0.0):
        nf = normal[i]
        u = step - wp.dot(step, nf) * nf
        y = wp.length(u)
        tangent = wp.identity(n=3, dtype=f64) - wp.outer(nf, nf)
        if y < eps_u:
            e += lam * (y * y / eps_u - y * y * y / (f64(3.0) * eps_u * eps_u) + eps_u / f64(3.0))
            f -= lam * (f64(2.0) / eps_u - y / (eps_u * eps_u)) * u
            h += lam * (f64(2.0) / eps_u - y / (eps_u * eps_u)) * tangent
            if y > f64(0.0):
                h -= lam / (eps_u * eps_u * y) * wp.outer(u, u)
        else:
            uhat = u / y
            e += lam * y
            f -= lam * uhat
            h += lam / y * (tangent - wp.outer(uhat, uhat))

    if order == 2:
        block = values[diag_index[i]] + h
        values[diag_index[i]] = block
        inv_diag[i] = wp.inverse(block)
        return
    wp.atomic_add(energy, 0, e)
    if order == 1:
        total = force[i] + f
        force[i] = total
        wp.atomic_add(force_sq, 0, wp.dot(total, total))
