"""The implicit step of every body of a scene at once, with incremental potential contact among them.

Each body keeps its own :class:`shellsim.physics.model.Model` (rest cage, material, masses) and
:class:`shellsim.physics.body.BodyTerms`, which measures its elastic, damping, inertia and drag terms and
their Hessian blocks on Warp; the ground, the colliders and the other bodies act through the contact
surfaces of :class:`shellsim.physics.ipc.Contact`. A step of ``h`` minimises over all cage vertices ``x``
(N, 3) at once

    E(x) = sum_b E_b(x_b) + kappa B(W x) + D(W (x - x^n))

by Newton's method: the Hessian is the block diagonal of the bodies' plus ``W^T H_contact W``, solved by
:class:`NewtonSystems`; every step is first shortened to the collision-free fraction that continuous
collision detection finds, then halved until ``E`` decreases and no tet inverts. Newton starts from the
inertial prediction when the way there is free of contact, else from the last step's end with the pinned
vertices (timed pins, grabs) at their targets, as far as contact lets them; their rows are the identity.

The step is backward Euler's (``integrator = "euler"``: from ``x^n``, ``v^n``, of length ``h``) or BDF2's
(``"bdf2"``: the same potential from ``(4 x^n - x^(n-1)) / 3`` and ``(4 v^n - v^(n-1)) / 3``, of length
``2h/3``, the new velocity ``(x - start) / (2h/3)``; the first step, and one after a different step or a
state set from outside, is backward Euler's).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import warp as wp

from shellsim.physics.body import BodyTerms
from shellsim.physics.control import Control
from shellsim.physics.elastic import ENERGY, FORCE, HESSIAN, vec3
from shellsim.physics.ipc import Contact
from shellsim.physics.model import Model, SolverSettings
from shellsim.physics.newton_systems import NewtonSystems, row_pointers
from shellsim.physics.state import State

#: Newton's step tolerance with contact is at most this fraction of the barrier's reach ``dhat``, so that the
#: gaps the barrier balances are resolved: the loosest that keeps sim_bench's spinning cubes within 0.1 mm of
#: a tightly converged run (0.03 mm at 8k tets after 4 frames; 0.01 of dhat: 0.13 mm).
NEWTON_TOL_GAP = 0.005
#: Halvings of a step in the line search.
LINE_SEARCH_TRIES = 16


@dataclass
class SolveStats:
    """What one :meth:`Solver.step` took and where it ended. ``energy`` and ``max_speed`` are nan when the
    state turned non-finite (the states out are then undefined)."""

    newton_iterations: int = 0
    converged: bool = False  # False: it hit newton_iterations or stalled in the line search
    hessians: int = 0  # Hessians assembled
    energy: float = math.nan  # incremental potential at the states out
    min_volume_ratio: float = math.nan  # min det F of the states out
    max_speed: float = math.nan  # max |v| of the states out [m/s]


class Solver:
    """Newton solver of the implicit step of several ``models`` with ``contact`` among them (None: none,
    then the bodies are independent); ``settings`` the integrator and the tolerances (``newton_tol``,
    ``newton_iterations``); ``linear_solver`` how the Newton systems are solved (:class:`NewtonSystems`)."""

    def __init__(
        self,
        models: Sequence[Model],
        contact: Contact | None,
        settings: SolverSettings,
        linear_solver: str = "auto",
    ):
        self.models = list(models)
        self.bodies = [BodyTerms(m) for m in self.models]
        self.contact = contact
        self.settings = settings
        counts = [m.n_vertices for m in self.models]
        self.starts = np.concatenate([[0], np.cumsum(counts)]).astype(int)
        self._work = [m.state() for m in self.models]  # Warp scratch positions of each body
        self.masses = np.concatenate([m.masses for m in self.models])
        rest = np.concatenate([m.rest_vertices for m in self.models])
        self.size = float(np.linalg.norm(rest.max(0) - rest.min(0)))
        self._tol_size = min(m.size for m in self.models)
        self.systems = NewtonSystems(linear_solver)
        self._base = [m.state() for m in self.models]  # BDF2's starting states
        #: BDF2's memory: the last step's (x_in, v_in, x_out, v_out) (N, 3) and its h, or None
        self._history: tuple | None = None
        self._pattern = _block_diagonal_pattern(
            [t.hessian_pattern for t in self.bodies], self.starts, upper=self.systems.triangle == "upper"
        )

    def memory(self) -> dict[str, np.ndarray]:
        """What BDF2 keeps of the last step, which led to the current state, for a run to continue exactly:
        ``last_positions``, ``last_velocities`` (N, 3) and ``last_step`` (1,) [s]; empty when there is none
        (backward Euler, or no step yet)."""
        if self._history is None:
            return {}
        x_last, v_last, _, _, h = self._history
        return {"last_positions": x_last, "last_velocities": v_last, "last_step": np.array([h])}

    def remember(self, memory: dict[str, np.ndarray], positions: np.ndarray, velocities: np.ndarray) -> None:
        """Take back a :meth:`memory` of the step that led to ``positions``, ``velocities`` (N, 3) (empty:
        the next step starts afresh, as BDF2's first does); a ValueError when it does not fit."""
        if not memory:
            self._history = None
            return
        x_last, v_last = (
            np.asarray(memory.get(k), np.float64) for k in ("last_positions", "last_velocities")
        )
        h = np.asarray(memory.get("last_step"), np.float64).ravel()
        if x_last.shape != positions.shape or v_last.shape != positions.shape or h.shape != (1,):
            raise ValueError("the integrator's memory of the last step does not fit the bodies")
        self._history = (x_last, v_last, positions.copy(), velocities.copy(), float(h[0]))

    def split(self, x: np.ndarray) -> list[np.ndarray]:
        """The bodies' rows of global positions ``x`` (N, 3)."""
        return [x[a:b] for a, b in zip(self.starts[:-1], self.starts[1:], strict=True)]

    def _bodies(self, x: np.ndarray, steps, order: int):
        """The bodies' terms at ``x`` (N, 3): (energy, min det F, force (N, 3) or None for ENERGY)."""
        energy, min_det = 0.0, math.inf
        for terms, work, part, step in zip(self.bodies, self._work, self.split(x), steps, strict=True):
            work.positions.assign(wp.array(part, dtype=vec3, device=work.positions.device))
            e, d = terms.evaluate(work.positions, step, order)
            energy, min_det = energy + e, min(min_det, d)
        force = np.concatenate([t.force for t in self.bodies]) if order == FORCE else None
        return energy, min_det, force

    def _hessian(self, x: np.ndarray, steps) -> sp.csr_matrix:
        """The bodies' Hessian at ``x`` (N, 3): (3N, 3N) block diagonal on a fixed pattern, only its upper
        triangle when the Newton systems take that."""
        blocks = []
        for terms, work, part, step in zip(self.bodies, self._work, self.split(x), steps, strict=True):
            work.positions.assign(wp.array(part, dtype=vec3, device=work.positions.device))
            terms.evaluate(work.positions, step, HESSIAN)
            blocks.append(terms.hessian_blocks().ravel())
        n = 3 * int(self.starts[-1])
        indptr, indices, gather = self._pattern
        return sp.csr_matrix((np.concatenate(blocks)[gather], indices, indptr), shape=(n, n))

    @staticmethod
    def _direction(d: np.ndarray | None, rhs: np.ndarray, pinned: np.ndarray) -> np.ndarray | None:
        """The Newton step (N, 3) from a solution ``d`` (3N,) of the system with right-hand side ``rhs``
        (N, 3): the pinned vertices' rows are the identity, so their step is ``rhs`` exactly (not a
        solver's approximation); None when ``d`` is None or not finite."""
        if d is None or not np.isfinite(d).all():
            return None
        d = d.reshape(-1, 3)
        d[pinned] = rhs[pinned]
        return d

    def step(
        self, states_in: Sequence[State], states_out: Sequence[State], controls: Sequence[Control], h: float
    ) -> SolveStats:
        """One step of ``h`` [s] of every body from ``states_in`` into ``states_out`` under ``controls``."""
        s, contact = self.settings, self.contact
        stats = SolveStats()
        x_n = np.concatenate([st.positions.numpy() for st in states_in])
        v_n = np.concatenate([st.velocities.numpy() for st in states_in])
        # the state the step starts from and its length: the last state and h (backward Euler), or BDF2's
        # combination of the last two states and 2h/3 (when the last step led here with the same h)
        base, x_base, h_step = states_in, x_n, h
        if s.integrator == "bdf2" and self._history is not None:
            x_last, v_last, x_end, v_end, h_last = self._history
            if h_last == h and np.array_equal(x_end, x_n) and np.array_equal(v_end, v_n):
                x_base, h_step = (4.0 * x_n - x_last) / 3.0, 2.0 * h / 3.0
                v_base = (4.0 * v_n - v_last) / 3.0
                base = self._base
                for state, x_part, v_part in zip(base, self.split(x_base), self.split(v_base), strict=True):
                    state.set(x_part, v_part)
        steps = [terms.prepare(a, c, h_step) for terms, a, c in zip(self.bodies, base, controls, strict=True)]
        x_tilde = np.concatenate([terms.prediction for terms in self.bodies])
        pinned = np.concatenate([c.pinned for c in controls])
        free = (~pinned).astype(np.float64)
        keep_free = sp.diags(np.repeat(free, 3)) if pinned.any() else None

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

            # the barrier's first stiffness from the step h (not BDF2's 2h/3), so that a run continued with
            # BDF2's memory sets it as the run from the start did
            contact.begin_step(
                x_n, h_step, grad_energy, float(self.masses.mean()) / (h * h), self.size, x_base
            )
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
        energy, min_det, force = total(x, order=FORCE)
        if x is not held and not (min_det > 0 and math.isfinite(energy)):
            x = held
            energy, min_det, force = total(x, order=FORCE)
        for iteration in range(1, s.newton_iterations + 1):
            stats.newton_iterations = iteration
            if not math.isfinite(energy):
                return stats
            rhs = force if contact is None else force - contact.gradient(x) * free[:, None]
            rhs[pinned] = x_tilde[pinned] - x[pinned]
            if iteration > 1:
                # the step the last factorisation gives from here: when it is below the tolerance, x has
                # converged without a new Hessian (a step's last Hessian would only confirm it). Taken as a
                # step (a chord step) it converges only linearly: on the spinning cubes of sim_bench, more
                # Newton iterations for 10% fewer factorisations and twice the error at the same tolerance
                chord = self._direction(self.systems.resolve(rhs.ravel()), rhs, pinned)
                if chord is not None and np.linalg.norm(chord, axis=1).max(initial=0.0) <= tol:
                    stats.converged = True
                    break
            hessian, contact_hessian = self._hessian(x, steps), None
            if contact is not None:
                contact_hessian = contact.hessian(x)
                if keep_free is not None:
                    contact_hessian = keep_free @ contact_hessian @ keep_free
                if self.systems.triangle == "upper":
                    contact_hessian = sp.triu(contact_hessian, format="csr")
            stats.hessians += 1
            d = self._direction(self.systems.solve(hessian, rhs.ravel(), contact_hessian), rhs, pinned)
            if d is None:
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
                trial_energy, trial_det, trial_force = total(trial, candidates, FORCE)
                if trial_energy <= energy and (trial_det > 0 or min_det <= 0):
                    x, energy, min_det, force, accepted = trial, trial_energy, trial_det, trial_force, True
                    break
                step_fraction *= 0.5
            if not accepted:
                break
            if contact is not None and contact.update_stiffness(x):
                energy, min_det, force = total(x, order=FORCE)  # the barrier's weight changed
        velocities = (x - x_base) / h_step
        self._history = (x_n, v_n, x, velocities, h) if s.integrator == "bdf2" else None
        for state_in, state_out, part, v in zip(
            states_in, states_out, self.split(x), self.split(velocities), strict=True
        ):
            state_out.set(part, v, state_in.time + h)
        stats.energy, stats.min_volume_ratio = energy, min_det
        stats.max_speed = float(np.linalg.norm(velocities, axis=1).max())
        return stats


def _block_diagonal_pattern(patterns, starts: np.ndarray, upper: bool) -> tuple[np.ndarray, ...]:
    """The scalar CSR ``indptr``, sorted ``indices`` and the entries' places ``gather`` in the bodies'
    concatenated flattened 3x3 Hessian blocks, of the block diagonal of the bodies' Hessians (their block
    patterns ``(offsets, columns)``, the k-th at vertex ``starts[k]``); only the upper triangle when
    ``upper``."""
    block_rows = np.concatenate(
        [
            np.repeat(np.arange(len(o) - 1), np.diff(o)) + s
            for (o, _), s in zip(patterns, starts, strict=False)
        ]
    )
    block_columns = np.concatenate(
        [c.astype(np.int64) + s for (_, c), s in zip(patterns, starts, strict=False)]
    )
    slot, a, b = (
        g.ravel() for g in np.meshgrid(np.arange(len(block_rows)), np.arange(3), np.arange(3), indexing="ij")
    )
    rows, columns, gather = 3 * block_rows[slot] + a, 3 * block_columns[slot] + b, 9 * slot + 3 * a + b
    keep = columns >= rows if upper else slice(None)
    rows, columns, gather = rows[keep], columns[keep], gather[keep]
    order = np.lexsort((columns, rows))
    indptr = row_pointers(rows, 3 * int(starts[-1]))
    return indptr, columns[order].astype(np.int32), gather[order]
