"""Incremental potential contact between several bodies and static colliders, with the IPC Toolkit
(``ipctk``).

Contact acts on each body's collision surface (:mod:`shellsim.tetcage.collision`: the asset's visible surface,
embedded in its cage), never on the cage itself. A surface vertex is a fixed linear combination of cage
vertices, so the collision vertices of every body are ``U = W x``: ``W`` (S, N) stacks the bodies' embedding
weights over the global cage vertices ``x`` (N, 3), and the static colliders' vertices (boxes, spheres,
meshes) follow as rows that never move; the ground is ipctk's plane z = 0 (exact, unbounded). On ``U`` the
step's incremental potential gains (Li et al. 2020, "Incremental Potential Contact")

    kappa B(U) + D(U - U^n)

- ``B``: ipctk's log barrier of the point-triangle and edge-edge pairs closer than ``dhat``
  (infinite at contact, zero beyond ``dhat``); ``kappa`` from ``ipctk.initial_barrier_stiffness`` at the
  first step, then raised by ``ipctk.update_barrier_stiffness`` while the gaps shrink, and kept from step to
  step (the lagged friction takes its normal forces from the barrier at the step's start, balanced with the
  stiffness the last step was solved with);
- ``D``: lagged Coulomb friction, ipctk's ``FrictionPotential`` on the step's displacement with
  ``eps_v = friction_velocity * h`` (metres: the slip below which friction is smoothed), the normal forces
  and tangent bases of the contacts at the step's start; a pair's coefficient is the mean of its two sides'
  (with the ground: of the body's and the ground's). A body sliding across an edge shared by two triangles of
  another surface meets that edge too (edge-edge and edge-vertex pairs on top of the vertex-face ones), whose
  normal forces add friction: 1.3 to 1.5 times Coulomb's while a block crosses it (ipctk's
  ``IMPROVED_MAX_APPROX`` set, which counts such pairs once, needs area weighting, which this contact's
  stiffness and friction are not yet set up for).

Gradients and Hessians map back through ``W``: ``grad_x = W^T grad_U``, ``H_x = W^T H_U W`` (per axis). The
Hessians are projected to positive semi-definite per contact (``CLAMP``). Continuous collision detection
(``Candidates.compute_collision_free_stepsize``, Tight-Inclusion) bounds every step the Newton solver takes,
so no two surfaces ever pass through each other and ``B`` stays finite.

The ground is a plane of its own ipctk mesh holding the bodies' surface vertices only (no edges or faces, so
no pair among them, and its broad phase is cheap): ipctk tests a plane against every vertex of a mesh, and a
collider standing on the ground must not.

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


def broad_phase(ipctk):
    """ipctk's broad phase used: its linear BVH, measured on the live cages of lego_on_bunny (1,832 surface
    vertices, a step's path; 2 cores): 5.4 ms a build, against 15.8 for the hash grid, 18.4 for sweep and
    prune and 29 for the spatial hash (docs/measurements.md)."""
    return ipctk.LBVH()


class _Part:
    """One ipctk collision mesh of the contact and what it needs: ``rows`` of the collision vertices it holds
    (its vertices ``U[rows]``), their map ``dof_map`` from the cage's degrees of freedom (3R, 3N), the
    per-vertex Coulomb coefficients ``mu``, and ``plane_friction`` (the ground's coefficient when its mesh is
    the ground's, whose plane-vertex pairs take the mean of the body's and the ground's)."""

    def __init__(self, mesh, rows: slice, dof_map: sp.csr_matrix, mu: np.ndarray, plane_friction=None):
        self.mesh, self.rows, self.dof_map, self.mu = mesh, rows, dof_map, mu
        self.dof_map_t = dof_map.T.tocsr()  # (3N, 3R)
        self.plane_friction = plane_friction

    def collisions(self, ipctk, u: np.ndarray, dhat: float, candidates=None):
        """The pairs within ``dhat`` at ``u`` (this part's vertices), among ``candidates`` (else found
        afresh; through candidates, since ipctk 1.6 leaves the planes out of a build without them)."""
        if candidates is None:
            candidates = ipctk.Candidates()
            candidates.build(self.mesh, u, dhat, broad_phase(ipctk))
        collisions = ipctk.NormalCollisions()
        collisions.build(candidates, self.mesh, u, dhat)
        return collisions

    def tangential(self, ipctk, u: np.ndarray, collisions, barrier):
        """The friction pairs of ``collisions`` at ``u`` (normal forces from ``barrier``), lagged."""
        pairs = ipctk.TangentialCollisions()
        pairs.build(self.mesh, u, collisions, barrier, self.mu, self.mu)
        if self.plane_friction is not None:
            for k in range(len(pairs)):
                pair = pairs[k]
                if isinstance(pair, ipctk.PlaneVertexTangentialCollision):
                    pair.mu_s = pair.mu_k = 0.5 * (pair.mu_s + self.plane_friction)
        return pairs


class Contact:
    """Barrier contact and friction among ``bodies`` (their surfaces; body ``k``'s cage vertices are rows
    ``starts[k]:starts[k] + V_k`` of the global ``x`` (N, 3), at rest ``rest`` (N, 3)), ``statics`` and,
    unless ``ground_friction`` is None, the ground z = 0 with that Coulomb coefficient; ``dhat`` [m] the
    barrier's reach, ``friction_velocity`` [m/s]. ``kappa`` is the current barrier stiffness (set by
    :meth:`begin_step`)."""

    def __init__(
        self,
        bodies: Sequence[BodySurface],
        starts: Sequence[int],
        rest: np.ndarray,
        statics: Sequence[StaticSurface],
        dhat: float,
        friction_velocity: float,
        ground_friction: float | None = None,
    ):
        import ipctk

        n_vertices = len(rest)
        blocks, faces, patch, mu, offset = [], [], [], [], 0
        for k, (body, start) in enumerate(zip(bodies, starts, strict=True)):
            w = sp.csr_matrix(body.weights)
            cols = sp.csr_matrix((w.data, w.indices + start, w.indptr), shape=(w.shape[0], n_vertices))
            blocks.append(cols)
            faces.append(np.asarray(body.faces, np.int64) + offset)
            patch.append(np.full(w.shape[0], k))
            mu.append(np.full(w.shape[0], body.friction))
            offset += w.shape[0]
        self.n_dynamic = n_dynamic = offset
        static_vertices = [np.zeros((0, 3))]
        for s in statics:
            static_vertices.append(np.asarray(s.vertices, np.float64))
            faces.append(np.asarray(s.faces, np.int64) + offset)
            patch.append(np.full(len(s.vertices), len(bodies)))
            mu.append(np.full(len(s.vertices), s.friction))
            offset += len(s.vertices)
        self.weights = sp.vstack([*blocks, sp.csr_matrix((offset - n_dynamic, n_vertices))]).tocsr()
        self.static = np.concatenate(static_vertices)
        self.faces = np.concatenate(faces).astype(np.int32)
        self.friction = np.concatenate(mu)
        self.dhat, self.friction_velocity = float(dhat), float(friction_velocity)
        self.ground_friction = ground_friction
        self._moving = self.weights[:n_dynamic]  # (S_dynamic, N)
        self._ipctk = ipctk
        dof_map = sp.kron(self.weights, sp.identity(3), format="csr")  # (3S, 3N)
        self.kappa = 0.0
        self._kappa_max = 0.0
        rest = self.surface(np.asarray(rest, np.float64))
        mesh = ipctk.CollisionMesh(rest, ipctk.edges(self.faces), self.faces)  # the surfaces among themselves
        mesh.can_collide = ipctk.make_vertex_patches_filter(np.concatenate(patch).astype(np.int32))
        # the surfaces among themselves, when there are two that may touch
        self._mesh = mesh if len(bodies) + bool(statics) >= 2 else None
        self._parts = (
            [] if self._mesh is None else [_Part(mesh, slice(0, offset), dof_map, self.friction.copy())]
        )
        self._cached: tuple[np.ndarray, list] | None = None  # (x, [(part, its vertices, collisions)])
        if ground_friction is not None:  # the bodies' surface vertices and the plane: plane-vertex pairs only
            nothing = np.zeros((0, 2), np.int32), np.zeros((0, 3), np.int32)
            ground = ipctk.CollisionMesh(np.ascontiguousarray(rest[:n_dynamic]), *nothing)
            # its vertices are points to ipctk (codimensional): no vertex-vertex pair among them
            ground.can_collide = ipctk.make_vertex_patches_filter(np.zeros(n_dynamic, np.int32))
            ground.planes = [ipctk.Hyperplane(np.array([0.0, 0.0, 1.0]), np.zeros(3))]
            mu_dynamic = np.ascontiguousarray(self.friction[:n_dynamic])
            self._parts.append(
                _Part(ground, slice(0, n_dynamic), dof_map[: 3 * n_dynamic], mu_dynamic, ground_friction)
            )

    def surface(self, x: np.ndarray) -> np.ndarray:
        """(S, 3) the collision vertices for cage positions ``x`` (N, 3): the bodies' then the statics'."""
        moving = self._moving @ x
        return np.ascontiguousarray(np.concatenate([moving, self.static]))

    def _each(self, u: np.ndarray):
        """(part, its vertices) for the collision vertices ``u`` (S, 3)."""
        return [(part, np.ascontiguousarray(u[part.rows])) for part in self._parts]

    def _found(self, x: np.ndarray, candidates=None) -> list:
        """[(part, its vertices, the pairs within ``dhat``)] at cage positions ``x`` (N, 3), among
        ``candidates`` (per part, from :meth:`candidates` of a path through ``x``) or found afresh. The last
        positions' are kept: a Newton iteration measures the barrier, its derivatives and the stiffness
        update at the point its line search accepted."""
        if self._cached is not None and np.array_equal(self._cached[0], x):
            return self._cached[1]
        ipctk = self._ipctk
        found = [
            (part, u, part.collisions(ipctk, u, self.dhat, None if candidates is None else candidates[k]))
            for k, (part, u) in enumerate(self._each(self.surface(x)))
        ]
        self._cached = (x.copy(), found)
        return found

    # ------------------------------------------------------------------------------------------------------
    # one step
    # ------------------------------------------------------------------------------------------------------

    def begin_step(
        self,
        x_start: np.ndarray,
        h: float,
        grad_energy,
        average_mass: float,
        size: float,
        x_base: np.ndarray | None = None,
    ) -> None:
        """Fix the barrier stiffness and the lagged friction of a step of ``h`` [s] at its start ``x_start``
        (N, 3): ``grad_energy()`` (N, 3) the gradient of the rest of the potential there (called only at the
        first step, which sets the stiffness), ``average_mass`` the mean vertex mass over ``h^2`` (the
        inertia term's scale), ``size`` the scene's bounding-box diagonal; friction's slip is measured from
        ``x_base`` (N, 3), the point the step's velocity is taken from (None: ``x_start``; BDF2's differs)."""
        ipctk = self._ipctk
        found = self._found(x_start)
        if x_base is None or x_base is x_start:
            self._starts = [(part, u) for part, u, _ in found]  # (part, its vertices slip is measured from)
        else:
            self._starts = self._each(self.surface(x_base))
        self._size = size
        unit = ipctk.BarrierPotential(self.dhat, 1.0)
        if self.kappa == 0.0:  # the first step; later ones keep the stiffness the gaps were balanced with
            grad_barrier = np.zeros(3 * self.weights.shape[1])
            for part, u, c in found:
                grad_barrier += part.dof_map_t @ unit.gradient(c, part.mesh, u)
            self.kappa, self._kappa_max = ipctk.initial_barrier_stiffness(
                size, unit.barrier, self.dhat, average_mass, grad_energy().ravel(), grad_barrier
            )
        self._barrier = ipctk.BarrierPotential(self.dhat, self.kappa)
        self._min_distance = min((self._least(part, c, u) for part, u, c in found), default=math.inf)
        self._tangential = [part.tangential(ipctk, u, c, self._barrier) for part, u, c in found]
        self._friction = ipctk.FrictionPotential(self.friction_velocity * h)

    def update_stiffness(self, x: np.ndarray) -> bool:
        """Raise ``kappa`` (ipctk's rule) when the least gap at ``x`` (N, 3) shrank toward zero; whether it
        changed."""
        ipctk = self._ipctk
        distance = min((self._least(part, c, u) for part, u, c in self._found(x)), default=math.inf)
        kappa = ipctk.update_barrier_stiffness(
            self._min_distance, distance, self._kappa_max, self.kappa, self._size
        )
        self._min_distance = distance
        if kappa == self.kappa:
            return False
        self.kappa = kappa
        self._barrier = ipctk.BarrierPotential(self.dhat, kappa)
        return True

    @staticmethod
    def _least(part: _Part, collisions, u: np.ndarray) -> float:
        """The least distance [m] among ``collisions`` of ``part`` at ``u`` (inf when there are none)."""
        if len(collisions) == 0:
            return math.inf
        return math.sqrt(max(collisions.compute_minimum_distance(part.mesh, u), 0.0))

    def candidates(self, x0: np.ndarray, x1: np.ndarray):
        """The pairs that may come within ``dhat`` on the straight path from ``x0`` to ``x1`` (N, 3), per
        part, and the largest fraction of that path free of intersections (continuous collision detection)."""
        ipctk = self._ipctk
        found, fraction = [], 1.0
        for (part, u0), (_, u1) in zip(
            self._each(self.surface(x0)), self._each(self.surface(x1)), strict=True
        ):
            candidates = ipctk.Candidates()
            candidates.build(part.mesh, u0, u1, self.dhat, broad_phase(ipctk))
            fraction = min(fraction, candidates.compute_collision_free_stepsize(part.mesh, u0, u1))
            found.append(candidates)
        return found, fraction

    def energy(self, x: np.ndarray, candidates=None) -> float:
        """``kappa B + D`` [J] at cage positions ``x`` (N, 3) (candidates: from :meth:`candidates` of a path
        through ``x``, else found afresh)."""
        total = 0.0
        for k, ((part, u, found), (_, u0)) in enumerate(
            zip(self._found(x, candidates), self._starts, strict=True)
        ):
            total += self._barrier(found, part.mesh, u) + self._friction(
                self._tangential[k], part.mesh, u - u0
            )
        return float(total)

    def gradient(self, x: np.ndarray) -> np.ndarray:
        """(N, 3) the gradient of :meth:`energy` at ``x`` (N, 3)."""
        n = self.weights.shape[1]
        grad = np.zeros(3 * n)
        for k, ((part, u, found), (_, u0)) in enumerate(zip(self._found(x), self._starts, strict=True)):
            g = self._barrier.gradient(found, part.mesh, u) + self._friction.gradient(
                self._tangential[k], part.mesh, u - u0
            )
            grad += part.dof_map_t @ g
        return grad.reshape(-1, 3)

    def hessian(self, x: np.ndarray) -> sp.csr_matrix:
        """(3N, 3N) the Hessian of :meth:`energy` at ``x`` (N, 3), projected to PSD per contact."""
        psd = self._ipctk.PSDProjectionMethod.CLAMP
        n = self.weights.shape[1]
        hess = sp.csr_matrix((3 * n, 3 * n))
        for k, ((part, u, found), (_, u0)) in enumerate(zip(self._found(x), self._starts, strict=True)):
            h = self._barrier.hessian(found, part.mesh, u, psd) + self._friction.hessian(
                self._tangential[k], part.mesh, u - u0, psd
            )
            hess = hess + part.dof_map_t @ (h @ part.dof_map)
        return hess.tocsr()

    def least_distance(self, x: np.ndarray) -> float:
        """The least distance [m] between surfaces that may touch (different bodies, a body and a static
        collider, a body and the ground) at ``x`` (N, 3): inf when none is within ``dhat``, 0 when two
        intersect or a body reaches the ground."""
        ipctk = self._ipctk
        u = self.surface(x)
        below = self.ground_friction is not None and u[: self.n_dynamic, 2].min(initial=np.inf) <= 0
        if below or (self._mesh is not None and ipctk.has_intersections(self._mesh, u)):
            return 0.0
        return min((self._least(part, c, v) for part, v, c in self._found(x)), default=math.inf)
