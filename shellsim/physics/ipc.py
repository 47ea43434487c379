"""Incremental potential contact between several bodies and static colliders, with the IPC Toolkit
(``ipctk``).

Contact acts on each body's collision surface (:mod:`shellsim.cage.collision`: the asset's visible surface,
embedded in its cage), never on the cage itself. A surface vertex is a fixed linear combination of cage
vertices, so the collision vertices of every body are ``U = W x``: ``W`` (S, N) stacks the bodies' embedding
weights over the global cage vertices ``x`` (N, 3), and the static colliders' vertices (boxes, spheres,
meshes) follow as rows that never move; the ground is ipctk's plane z = 0 (exact, unbounded). On ``U`` the
step's incremental potential gains (Li et al. 2020, "Incremental Potential Contact")

    kappa B(U) + D(U - U^n)

- ``B``: ipctk's log barrier summed over the point-triangle and edge-edge pairs closer than ``dhat``
  (infinite at contact, zero beyond ``dhat``); ``kappa`` from ``ipctk.initial_barrier_stiffness`` at each
  step and raised by ``ipctk.update_barrier_stiffness`` while the gaps shrink;
- ``D``: lagged Coulomb friction, ipctk's ``FrictionPotential`` on the step's displacement with
  ``eps_v = friction_velocity * h`` (metres: the slip below which friction is smoothed), the normal forces
  and tangent bases of the contacts at the step's start; a pair's coefficient is the mean of its two sides'
  (with the ground: of the body's and the ground's).

Gradients and Hessians map back through ``W``: ``grad_x = W^T grad_U``, ``H_x = W^T H_U W`` (per axis). The
Hessians are projected to positive semi-definite per contact (``CLAMP``). Continuous collision detection
(``Candidates.compute_collision_free_stepsize``, Tight-Inclusion) bounds every step the Newton solver takes,
so no two surfaces ever pass through each other and ``B`` stays finite.

Self-contact within one body is filtered out (``make_vertex_patches_filter``: a body's vertices share a
patch): the surface is embedded in an elastic cage whose volume barrier already keeps it from folding
through itself, and a body's own surface parts lie within ``dhat`` at creases, where a barrier would push
them apart at rest. Static colliders never test against each other.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

#: The barrier's reach ``dhat`` [m] unless a scene sets its own: contact forces act across gaps below it.
CONTACT_GAP = 1.0e-3
#: Sliding speed [m/s] below which friction is smoothed (static friction is this slow creep).
FRICTION_VELOCITY = 1.0e-2


@dataclass(frozen=True)
class BodySurface:
    """A body's collision surface: vertices ``weights @ cage_positions``; ``weights`` (S, V) sparse,
    ``faces`` (F, 3) outward, ``friction`` its Coulomb coefficient."""

    weights: sp.spmatrix
    faces: np.ndarray
    friction: float


@dataclass(frozen=True)
class StaticSurface:
    """A static collider's surface: ``vertices`` (S, 3) world metres, ``faces`` (F, 3) outward."""

    vertices: np.ndarray
    faces: np.ndarray
    friction: float


class Contact:
    """Barrier contact and friction among ``bodies`` (their surfaces; body ``k``'s cage vertices are rows
    ``starts[k]:starts[k] + V_k`` of the global ``x`` (N, 3)), ``statics`` and, unless ``ground_friction`` is
    None, the ground z = 0 with that Coulomb coefficient; ``dhat`` [m] the barrier's reach,
    ``friction_velocity`` [m/s]. ``kappa`` is the current barrier stiffness (set by
    :meth:`begin_step`)."""

    def __init__(
        self,
        bodies: Sequence[BodySurface],
        starts: Sequence[int],
        n_vertices: int,
        statics: Sequence[StaticSurface],
        dhat: float,
        friction_velocity: float,
        ground_friction: float | None = None,
    ):
        import ipctk

        blocks, faces, patch, mu, offset = [], [], [], [], 0
        for k, (body, start) in enumerate(zip(bodies, starts, strict=True)):
            w = sp.csr_matrix(body.weights)
            cols = sp.csr_matrix((w.data, w.indices + start, w.indptr), shape=(w.shape[0], n_vertices))
            blocks.append(cols)
            faces.append(np.asarray(body.faces, np.int64) + offset)
            patch.append(np.full(w.shape[0], k))
            mu.append(np.full(w.shape[0], body.friction))
            offset += w.shape[0]
        self.n_dynamic = offset
        static_vertices = [np.zeros((0, 3))]
        for s in statics:
            static_vertices.append(np.asarray(s.vertices, np.float64))
            faces.append(np.asarray(s.faces, np.int64) + offset)
            patch.append(np.full(len(s.vertices), len(bodies)))
            mu.append(np.full(len(s.vertices), s.friction))
            offset += len(s.vertices)
        self.weights = sp.vstack([*blocks, sp.csr_matrix((offset - self.n_dynamic, n_vertices))]).tocsr()
        self.static = np.concatenate(static_vertices)
        self.faces = np.concatenate(faces).astype(np.int32)
        self.friction = np.concatenate(mu)
        self.dhat, self.friction_velocity = float(dhat), float(friction_velocity)
        self.ground_friction = ground_friction
        self._ipctk = ipctk
        self._dof_map = sp.kron(self.weights, sp.identity(3), format="csr")  # (3S, 3N)
        self._edges = ipctk.edges(self.faces)
        self.kappa = 0.0
        self._kappa_max = 0.0
        self._mesh = None
        self._patch = np.concatenate(patch).astype(np.int32)

    def surface(self, x: np.ndarray) -> np.ndarray:
        """(S, 3) the collision vertices for cage positions ``x`` (N, 3): the bodies' then the statics'."""
        moving = self.weights[: self.n_dynamic] @ x
        return np.ascontiguousarray(np.concatenate([moving, self.static]))

    def mesh(self, rest: np.ndarray):
        """The ``ipctk.CollisionMesh`` (built once, at the first positions ``rest`` (N, 3))."""
        if self._mesh is None:
            ipctk = self._ipctk
            self._mesh = ipctk.CollisionMesh(self.surface(rest), self._edges, self.faces)
            self._mesh.can_collide = ipctk.make_vertex_patches_filter(self._patch)
            if self.ground_friction is not None:
                self._mesh.planes = [ipctk.Hyperplane(np.array([0.0, 0.0, 1.0]), np.zeros(3))]
        return self._mesh

    # ------------------------------------------------------------------------------------------------------
    # one step
    # ------------------------------------------------------------------------------------------------------

    def begin_step(
        self, x_start: np.ndarray, h: float, grad_energy: np.ndarray, average_mass: float, size: float
    ) -> None:
        """Fix the barrier stiffness and the lagged friction of a step of ``h`` [s] at its start ``x_start``
        (N, 3): ``grad_energy`` (N, 3) the gradient of the rest of the potential there, ``average_mass`` the
        mean vertex mass over ``h^2`` (the inertia term's scale), ``size`` the scene's bounding-box
        diagonal."""

        ipctk = self._ipctk
        mesh = self.mesh(x_start)
        self._start = self.surface(x_start)
        self._size = size
        unit = ipctk.BarrierPotential(self.dhat, 1.0)
        collisions = self._collisions(self._start)
        grad_barrier = self._dof_map.T @ unit.gradient(collisions, mesh, self._start)
        self.kappa, self._kappa_max = ipctk.initial_barrier_stiffness(
            size, unit.barrier, self.dhat, average_mass, grad_energy.ravel(), grad_barrier
        )
        self._barrier = ipctk.BarrierPotential(self.dhat, self.kappa)
        self._min_distance = self.min_distance(collisions, self._start)
        self._tangential = ipctk.TangentialCollisions()
        mu = np.ascontiguousarray(self.friction, np.float64)
        self._tangential.build(mesh, self._start, collisions, self._barrier, mu, mu)
        if self.ground_friction is not None:
            for k in range(len(self._tangential)):
                pair = self._tangential[k]
                if isinstance(pair, ipctk.PlaneVertexTangentialCollision):
                    pair.mu_s = pair.mu_k = 0.5 * (pair.mu_s + self.ground_friction)
        self._friction = ipctk.FrictionPotential(self.friction_velocity * h)

    def update_stiffness(self, x: np.ndarray) -> None:
        """Raise ``kappa`` (ipctk's rule) when the least gap at ``x`` (N, 3) shrank toward zero."""
        u = self.surface(x)
        distance = self.min_distance(self._collisions(u), u)
        kappa = self._ipctk.update_barrier_stiffness(
            self._min_distance, distance, self._kappa_max, self.kappa, self._size
        )
        self._min_distance = distance
        if kappa != self.kappa:
            self.kappa = kappa
            self._barrier = self._ipctk.BarrierPotential(self.dhat, kappa)

    def _collisions(self, u: np.ndarray, candidates=None):
        """The pairs within ``dhat`` at ``u`` (S, 3), among ``candidates`` (else found afresh; through
        candidates, since ipctk 1.6 leaves the planes out of a build without them)."""
        ipctk = self._ipctk
        if candidates is None:
            candidates = ipctk.Candidates()
            candidates.build(self._mesh, u, self.dhat)
        collisions = ipctk.NormalCollisions()
        collisions.build(candidates, self._mesh, u, self.dhat)
        return collisions

    def min_distance(self, collisions, u: np.ndarray) -> float:
        """The least distance [m] among ``collisions`` at ``u`` (S, 3) (inf when there are none)."""
        if len(collisions) == 0:
            return math.inf
        return math.sqrt(max(collisions.compute_minimum_distance(self._mesh, u), 0.0))

    def candidates(self, x0: np.ndarray, x1: np.ndarray):
        """The pairs that may come within ``dhat`` on the straight path from ``x0`` to ``x1`` (N, 3), and the
        largest fraction of that path free of intersections (continuous collision detection)."""
        ipctk = self._ipctk
        u0, u1 = self.surface(x0), self.surface(x1)
        candidates = ipctk.Candidates()
        candidates.build(self._mesh, u0, u1, self.dhat)
        return candidates, candidates.compute_collision_free_stepsize(self._mesh, u0, u1)

    def energy(self, x: np.ndarray, candidates=None) -> float:
        """``kappa B + D`` [J] at cage positions ``x`` (N, 3) (candidates: from :meth:`candidates` of a path
        through ``x``, else found afresh)."""
        u = self.surface(x)
        barrier = self._barrier(self._collisions(u, candidates), self._mesh, u)
        return float(barrier + self._friction(self._tangential, self._mesh, u - self._start))

    def derivatives(self, x: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
        """The gradient (N, 3) and the PSD-projected Hessian (3N, 3N) of :meth:`energy` at ``x`` (N, 3)."""
        ipctk = self._ipctk
        u = self.surface(x)
        du = u - self._start
        collisions = self._collisions(u)
        psd = ipctk.PSDProjectionMethod.CLAMP
        grad = self._barrier.gradient(collisions, self._mesh, u) + self._friction.gradient(
            self._tangential, self._mesh, du
        )
        hess = self._barrier.hessian(collisions, self._mesh, u, psd) + self._friction.hessian(
            self._tangential, self._mesh, du, psd
        )
        m = self._dof_map
        return (m.T @ grad).reshape(-1, 3), (m.T @ hess @ m).tocsr()

    def least_distance(self, x: np.ndarray) -> float:
        """The least distance [m] between surfaces that may touch (different bodies, or a body and a static
        collider) at ``x`` (N, 3), found without the ``dhat`` cut-off's limit: inf when none is within
        ``dhat``, 0 when two intersect."""
        u = self.surface(x)
        below = self.ground_friction is not None and u[: self.n_dynamic, 2].min(initial=np.inf) <= 0
        if below or self._ipctk.has_intersections(self._mesh, u):
            return 0.0
        return self.min_distance(self._collisions(u), u)
