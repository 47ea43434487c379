"""Several elastic bodies in one implicit solve, touching through incremental potential contact.

Each body keeps its own :class:`shellsim.physics.model.Model` (rest cage, material, masses) and an
:class:`shellsim.physics.solver.ImplicitSolver`, which measures its elastic, damping, inertia and drag terms
and their Hessian blocks on Warp; the bodies' models have no penalty colliders (the ground and every
obstacle are contact surfaces of :class:`shellsim.physics.ipc.Contact`). A step of ``h`` minimises over all
cage vertices ``x`` (N, 3) at once

    E(x) = sum_b E_b(x_b) + kappa B(W x) + D(W (x - x^n))

by Newton's method: the Hessian is the block diagonal of the bodies' plus ``W^T H_contact W``, solved by
:class:`NewtonSystems`; every step is first shortened to the collision-free fraction that continuous
collision detection finds, then halved until ``E`` decreases and no tet inverts. Newton starts from the
inertial prediction when the way there is free of contact, else from the last step's end with the pinned
vertices (timed pins, grabs) at their targets, as far as contact lets them; their rows are the identity.

:class:`SceneDriver` runs frames of substeps with the checks and retries of
:class:`shellsim.physics.driver.FrameDriver`, asking a schedule for each substep's pins and forces.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import Protocol

import numpy as np
import scipy.sparse as sp
import warp as wp

from shellsim.physics.control import Control
from shellsim.physics.driver import (
    FrameStats,
    SimulationError,
    largest_stretch,
    substep_problem,
    warn_stretched,
)
from shellsim.physics.elastic import ENERGY, FORCE, HESSIAN, f64, vec3
from shellsim.physics.ipc import Contact
from shellsim.physics.model import Model, SimSettings
from shellsim.physics.solver import ImplicitSolver, SolveStats
from shellsim.physics.state import State

#: Newton iterations of a contact step: at least this many (contact needs more than the free solver's).
CONTACT_NEWTON_ITERATIONS = 40
#: Newton's step tolerance with contact is at most this fraction of the barrier's reach ``dhat``, so that the
#: gaps the barrier balances are resolved.
NEWTON_TOL_GAP = 0.01
#: Conjugate-gradient iterations a Newton system may take with an earlier Hessian's factorisation as its
#: preconditioner before the current Hessian is factorised.
REUSE_ITERATIONS = 25
#: Halvings of a step in the line search.
LINE_SEARCH_TRIES = 16


class SceneSolver:
    """Backward-Euler Newton solver of several ``models`` with ``contact`` among them (None: none, then the
    bodies are independent); ``settings`` the tolerances (``newton_tol``, ``newton_iterations``)."""

    def __init__(self, models: Sequence[Model], contact: Contact | None, settings: SimSettings):
        self.models = list(models)
        self.solvers = [ImplicitSolver(m) for m in self.models]
        self.contact = contact
        self.settings = settings
        counts = [m.n_vertices for m in self.models]
        self.starts = np.concatenate([[0], np.cumsum(counts)]).astype(int)
        self._work = [m.state() for m in self.models]  # Warp scratch positions of each body
        self.masses = np.concatenate([m.masses for m in self.models])
        rest = np.concatenate([m.rest_vertices for m in self.models])
        self.size = float(np.linalg.norm(rest.max(0) - rest.min(0)))
        self._tol_size = min(m.size for m in self.models)
        self.systems = NewtonSystems()

    def split(self, x: np.ndarray) -> list[np.ndarray]:
        """The bodies' rows of global positions ``x`` (N, 3)."""
        return [x[a:b] for a, b in zip(self.starts[:-1], self.starts[1:], strict=True)]

    def _bodies(self, x: np.ndarray, steps, order: int):
        """The bodies' terms at ``x`` (N, 3): (energy, min det F, force (N, 3) or None for ENERGY)."""
        energy, min_det = 0.0, math.inf
        for solver, work, part, step in zip(self.solvers, self._work, self.split(x), steps, strict=True):
            work.positions.assign(wp.array(part, dtype=vec3, device=work.positions.device))
            e, d, _ = solver.evaluate(work.positions, step, order)
            energy, min_det = energy + e, min(min_det, d)
        force = np.concatenate([s.force for s in self.solvers]) if order == FORCE else None
        return energy, min_det, force

    def _hessian(self, x: np.ndarray, steps) -> sp.csr_matrix:
        blocks = []
        for solver, work, part, step in zip(self.solvers, self._work, self.split(x), steps, strict=True):
            work.positions.assign(wp.array(part, dtype=vec3, device=work.positions.device))
            solver.evaluate(work.positions, step, HESSIAN)
            blocks.append(solver.hessian_matrix())
        return sp.block_diag(blocks, format="csr")

    def step(
        self, states_in: Sequence[State], states_out: Sequence[State], controls: Sequence[Control], h: float
    ) -> SolveStats:
        """One step of ``h`` [s] of every body from ``states_in`` into ``states_out`` under ``controls``."""
        s, contact = self.settings, self.contact
        stats = SolveStats()
        steps = [
            solver.prepare(a, b, c, h)
            for solver, a, b, c in zip(self.solvers, states_in, states_out, controls, strict=True)
        ]
        x_n = np.concatenate([st.positions.numpy() for st in states_in])
        x_tilde = np.concatenate([solver.prediction for solver in self.solvers])
        pinned = np.concatenate([c.pinned for c in controls])
        free = (~pinned).astype(np.float64)
        keep_free = sp.diags(np.repeat(free, 3))

        def total(x, candidates=None, order=ENERGY):
            energy, min_det, force = self._bodies(x, steps, order)
            if contact is not None and min_det > 0 and math.isfinite(energy):
                energy += contact.energy(x, candidates)
            return energy, min_det, force

        tol = s.newton_tol * self._tol_size * h
        held = x_n.copy()
        held[pinned] = x_tilde[pinned]
        start_fraction = 1.0
        if contact is not None:

            def grad_energy():
                return -self._bodies(x_n, steps, FORCE)[2]

            contact.begin_step(x_n, h, grad_energy, float(self.masses.mean()) / (h * h), self.size)
            _, start_fraction = contact.candidates(x_n, x_tilde)
            if start_fraction < 1.0 and pinned.any():
                _, pin_fraction = contact.candidates(x_n, held)
                held = x_n + pin_fraction * (held - x_n)
            tol = min(tol, NEWTON_TOL_GAP * contact.dhat)
        # the prediction when the way there is free of contact and inverts no tet; else the last step's end
        # with the pinned vertices moved to their targets (as far as contact lets them): a start clamped short
        # of a contact would sit closer than the last step's balanced gap, and a loose Newton test could take
        # it as the answer. The line search only lowers E, so the pins must be at their targets from the
        # start.
        x = x_tilde.copy() if start_fraction >= 1.0 else held
        energy, min_det, _ = total(x)
        if x is not held and not (min_det > 0 and math.isfinite(energy)):
            x = held
        for iteration in range(1, max(s.newton_iterations, CONTACT_NEWTON_ITERATIONS) + 1):
            stats.newton_iterations = iteration
            energy, min_det, force = total(x, order=FORCE)
            if not math.isfinite(energy):
                return stats
            hessian = self._hessian(x, steps)
            if contact is not None:
                grad, contact_hessian = contact.derivatives(x)
                force = force - grad * free[:, None]
                hessian = hessian + keep_free @ contact_hessian @ keep_free
            stats.hessians += 1
            rhs = force
            rhs[pinned] = x_tilde[pinned] - x[pinned]
            d = self.systems.solve(hessian, rhs.ravel()).reshape(-1, 3)
            if not np.isfinite(d).all():
                return stats
            length = float(np.linalg.norm(d, axis=1).max(initial=0.0))
            if length <= tol:
                stats.converged = True
                break
            step_fraction = 1.0
            candidates = None
            if contact is not None:
                candidates, step_fraction = contact.candidates(x, x + d)
            accepted = False
            for _ in range(LINE_SEARCH_TRIES):
                trial = x + step_fraction * d
                trial_energy, trial_det, _ = total(trial, candidates)
                if trial_energy <= energy and (trial_det > 0 or min_det <= 0):
                    x, accepted = trial, True
                    break
                step_fraction *= 0.5
            if not accepted:
                break
            if contact is not None:
                contact.update_stiffness(x)
        energy, min_det, _ = total(x)
        velocities = (x - x_n) / h
        for state_in, state_out, part, v in zip(
            states_in, states_out, self.split(x), self.split(velocities), strict=True
        ):
            state_out.set(part, v, state_in.time + h)
        stats.energy, stats.min_volume_ratio = energy, min_det
        stats.max_speed = float(np.linalg.norm(velocities, axis=1).max())
        return stats


class NewtonSystems:
    """Solves a run's Newton systems ``H d = r`` (H sparse symmetric positive definite, (n, n)): conjugate
    gradients preconditioned by the exact factorisation (SuperLU, minimum-degree ordering of ``A^T + A``,
    symmetric pivoting) of an earlier ``H``, refactored from the current one when CG would need more than
    :data:`REUSE_ITERATIONS`. Consecutive Hessians of a trajectory differ little, so one factorisation
    serves many steps (a factorisation costs some 40 solves with it on cage Hessians)."""

    def __init__(self, rtol: float = 1e-4):
        self.rtol = rtol
        self._factor = None
        self.factorisations = 0

    def solve(self, matrix: sp.spmatrix, rhs: np.ndarray) -> np.ndarray:
        """``d`` (n,) with ``|H d - r| <= rtol |r|`` (all nan where ``H`` cannot be factorised)."""
        from scipy.sparse.linalg import LinearOperator, cg, splu

        matrix = matrix.tocsc()
        n = len(rhs)
        if self._factor is not None and self._factor.shape == matrix.shape:
            preconditioner = LinearOperator((n, n), matvec=self._factor.solve)
            d, info = cg(matrix, rhs, rtol=self.rtol, maxiter=REUSE_ITERATIONS, M=preconditioner)
            if info == 0:
                return d
        try:
            self._factor = splu(matrix, permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True})
        except RuntimeError:
            self._factor = None
            return np.full(n, np.nan)
        self.factorisations += 1
        return self._factor.solve(rhs)


class Schedule(Protocol):
    """The timed inputs of a scene (e.g. :class:`shellsim.scene.actions.Actions`)."""

    def inputs(self, t: float, h: float, positions: list, velocities: list) -> list:
        """Per body, (pinned (V,) bool, targets (V, 3), forces (V, 3)) for the substep [t, t + h]."""

    def state(self) -> dict: ...

    def restore(self, state: dict) -> None: ...


class SceneDriver:
    """Advances the bodies of ``solver`` by frames of ``settings.dt`` (``settings.substeps`` each), with
    ``schedule``'s pins and forces (None: none), checking every frame as
    :class:`shellsim.physics.driver.FrameDriver` does and retrying a failed one with more substeps (and
    warning once of a stretch it allows)."""

    def __init__(self, solver: SceneSolver, schedule: Schedule | None = None):
        self.solver = solver
        self.schedule = schedule
        models = solver.models
        self.controls = [Control(m) for m in models]
        self._other = [m.state() for m in models]
        self._start = [m.state() for m in models]
        self._scalars = [wp.zeros(1, dtype=f64, device=m.device) for m in models]
        self._stretch_warned = False

    def step(self, states: Sequence[State]) -> FrameStats:
        """Advance ``states`` one frame; redo it with more substeps while it is invalid, and raise
        :class:`SimulationError` with the states back at the frame's start if every count fails."""
        s = self.solver.settings
        start = time.perf_counter()
        for saved, state in zip(self._start, states, strict=True):
            saved.assign(state)
        schedule_state = self.schedule.state() if self.schedule else None
        failures = []
        for attempt, factor in enumerate((1, *s.retry_factors)):
            if attempt:
                for saved, state in zip(self._start, states, strict=True):
                    state.assign(saved)
                if self.schedule:
                    self.schedule.restore(schedule_state)
            stats = FrameStats(substeps=s.substeps * factor, retries=attempt)
            problem = self._run_frame(states, stats)
            if problem is None:
                stats.seconds = time.perf_counter() - start
                stats.notes = [f"{n} substeps: {kind} {value:.3g}" for n, (kind, value, _) in failures]
                if stats.max_stretch > s.max_stretch and not self._stretch_warned:
                    self._stretch_warned = True
                    warn_stretched(states[0].time, stats.max_stretch, s.max_stretch)
                return stats
            failures.append((stats.substeps, problem))
        for saved, state in zip(self._start, states, strict=True):
            state.assign(saved)
        if self.schedule:
            self.schedule.restore(schedule_state)
        kind, value, limit = failures[-1][1]
        raise SimulationError(kind, value, limit, self._start[0].time, tuple(n for n, _ in failures))

    def _set_inputs(self, t: float, h: float, states: Sequence[State]) -> None:
        if self.schedule is None:
            return
        positions = [st.positions.numpy() for st in states]
        velocities = [st.velocities.numpy() for st in states]
        for control, (pinned, targets, forces) in zip(
            self.controls, self.schedule.inputs(t, h, positions, velocities), strict=True
        ):
            if pinned.any() or control.pinned.any():
                control.set_pins(pinned, targets)
            control.set_forces(forces)

    def _run_frame(self, states: Sequence[State], stats: FrameStats):
        s = self.solver.settings
        h = s.dt / stats.substeps
        current, other = list(states), self._other
        for _ in range(stats.substeps):
            self._set_inputs(current[0].time, h, current)
            step = self.solver.step(current, other, self.controls, h)
            current, other = other, current
            stats.add(step)
            problem = substep_problem(step, s)
            if problem is not None:
                return problem
        if current[0] is not states[0]:
            for state, result in zip(states, current, strict=True):
                state.assign(result)
        stats.max_stretch = max(
            largest_stretch(m, st, scratch)
            for m, st, scratch in zip(self.solver.models, states, self._scalars, strict=True)
        )
        if stats.max_stretch > s.max_stretch and not s.allow_stretch:
            return ("stretch", stats.max_stretch, s.max_stretch)
        return None


class OneBodyDriver:
    """A :class:`SceneDriver` of one body behind the interface of
    :class:`shellsim.physics.driver.FrameDriver` (``step(state, control)``), for
    :func:`shellsim.physics.driver.simulate`."""

    def __init__(self, solver: SceneSolver):
        self.scene = SceneDriver(solver)

    def step(self, state: State, control: Control) -> FrameStats:
        self.scene.controls[0] = control
        return self.scene.step([state])
