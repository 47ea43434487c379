"""Implicit (backward Euler) hyperelastic FEM on linear tetrahedra, in Warp, on plain arrays (no torch): one
step of a :class:`shellsim.physics.model.Model` from one :class:`shellsim.physics.state.State` to another.

A step of length ``h`` minimises the incremental potential (Martin et al. 2011; Li et al. 2020)

    E(x) = sum_t V_t [Psi(F_t) + (beta / h) D(A_t)] + sum_i E_i(x_i)

over the vertex positions ``x`` (V, 3), then sets ``v = (x - x^n) / h``. The per-vertex terms ``E_i``
(inertia, drag, penalty contact, lagged friction) are in :mod:`shellsim.physics.contact`; the pins and the
external forces of the step's :class:`shellsim.physics.control.Control` enter the inertial prediction. Per
tetrahedron, with rest volume ``V_t``, deformation gradient ``F = D_s D_m^-1`` and ``J = det F``:

- **Stable Neo-Hookean** (Smith et al. 2018, in the form of Kim & Eberle 2022, Sec. 6.5)::

      Psi(F) = mu/2 (|F|^2 - 3) - mu (J - 1) + phi(J),     phi(J) = lam/2 (J - 1)^2 + b(J),

  ``lam = lambda_Lame + mu``: rest-stable, linearising to Lamé's ``mu``, ``lambda``, plus a volume barrier
  ``b(J) = -kb lam (J - Jb)^2 log(J / Jb)`` for ``J < Jb`` (``Jb = 0.5``, ``kb = 10``: ``BARRIER_J``,
  ``BARRIER_STIFFNESS`` in :mod:`shellsim.physics.elastic`; C2, zero for ``J >= Jb``, infinite at ``J = 0``).
  Without it a tet flattened to ``J = 0`` costs only ``(mu + lam) / 2`` per volume: soft bodies (10 kPa
  jelly) squashed on impact flattened tets bridging concave creases, and the line search, which refuses
  steps that invert a tet, then stalled at det F ~ 0. The stress is ``P = mu F + (phi'(J) - mu) dJ/dF``
  and the Hessian ``mu I + phi''(J) dJ dJ^T + k d2J``, ``k = phi'(J) - mu``, has the analytic eigensystem
  of Smith et al. 2019: with ``F = U diag(s) V^T`` (rotations U, V; ``J = s0 s1 s2``) the twist and flip
  modes ``U t_m V^T``, ``U l_m V^T`` have eigenvalues ``mu + k s_m`` and ``mu - k s_m``, and the three
  scaling modes ``U diag(q) V^T`` are the eigenvectors ``q`` of
  ``mu I + phi'' c c^T + k [[0, s2, s1], [s2, 0, s0], [s1, s0, 0]]``, ``c = (s1 s2, s0 s2, s0 s1)``.
  Definiteness fix: the eigenvalues need only the singular values (closed form, no SVD); where the smallest
  is above ``-SHIFT_LIMIT mu`` the exact Hessian is shifted by it (``+ shift I`` in F-space, cheap), else
  the element takes the SVD and every negative eigenvalue is clamped to 0.
- **Kelvin-Voigt damping** on the Green strain rate (Rayleigh dissipation, invariant to rigid motion):
  ``A = F^n^T (F - F^n)`` (``F^n`` at the step start), ``D(A) = mu |sym A|^2 + lambda/2 tr(A)^2``;
  ``beta`` [s] is the ratio of viscosity to stiffness.

Newton's method solves each step: the PSD Hessian is assembled into a block-sparse (3x3) matrix with a
fixed sparsity pattern and the step solves ``H d = -grad E`` by preconditioned conjugate gradients, warm
started from the previous step's correction. On CPU one Warp kernel runs the whole PCG loop with an
SSOR preconditioner (:data:`shellsim.physics.linsolve.SSOR_OMEGA`; Warp runs CPU kernels on one thread, so
launch overhead would dominate and a serial preconditioner costs nothing in parallelism: 3x fewer iterations
than block-Jacobi, a quarter fewer than symmetric Gauss-Seidel);
on CUDA :func:`warp.optim.linear.cg` with block-Jacobi. A backtracking line search on ``E`` keeps the energy
decreasing and the tets uninverted; its passes also compute the force, so the accepted point's energy, det F
and force serve the next iteration's test, and the Hessian pass computes only the Hessian; a later iteration
whose step has moved x by at most :data:`ELASTIC_HESSIAN_REUSE` tolerances since the tets' blocks were
evaluated keeps those blocks and evaluates only the vertices' (contact and friction). The first solves
of a step stop early (:class:`Forcing`, inexact Newton), the last ones reach ``cg_tol``. Newton stops when
its step is below ``newton_tol``; that last step, already solved for, is taken too when it lowers E (one
energy pass), which leaves x much closer to the step's minimum than the tolerance (``bench/sim_bench.py
--accuracy``) and the next step a better start. Whether the result is valid (det F, speed, stretch) is the
frame driver's to judge (:mod:`shellsim.physics.driver`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from neural.device import cpu_threads as default_cpu_threads
from neural.device import run_in_chunks
from shellsim.physics.contact import lag_friction, vertex_terms
from shellsim.physics.control import Control
from shellsim.physics.elastic import (
    ENERGY,
    FORCE,
    HESSIAN,
    SHIFT_LIMIT,
    deformation_gradient,
    f64,
    mat33,
    tet_terms,
    vec3,
)
from shellsim.physics.linsolve import block_topology, bsr_cg_solver, serial_pcg_solver
from shellsim.physics.model import Model
from shellsim.physics.state import State

#: Fewest tets for which the CPU assembles a Hessian on several threads: 2k-tet Hessians are too quick
#: (about 0.5 ms) for a thread hand-off to pay (6.2-6.5 against 5.0 ms per step); 10k and 41k-tet ones gain
#: 4-5% of a step.
PARALLEL_HESSIAN_TETS = 8192
#: A Newton iteration keeps the tets' Hessian blocks of an earlier iteration of its step while the steps
#: taken since then add up to at most this many Newton tolerances (``newton_tol * size * h``): the elastic
#: blocks then change by well under a percent, while the contact and friction blocks, which jump as vertices
#: touch, stick and slip, are always evaluated afresh.
ELASTIC_HESSIAN_REUSE = 20.0
wp.set_module_options({"enable_backward": False})  # no autodiff here; halves compile time


@dataclass
class SolveStats:
    """What one :meth:`ImplicitSolver.step` took and where it ended. ``energy`` and ``max_speed`` are nan
    when the state turned non-finite (``state_out`` is then undefined)."""

    newton_iterations: int = 0
    converged: bool = False  # False: it hit newton_iterations or stalled in the line search
    cg_iterations: int = 0
    hessians: int = 0  # Newton iterations that evaluated the tets' Hessian blocks (the rest reused them)
    energy: float = math.nan  # incremental potential at state_out
    min_volume_ratio: float = math.nan  # min det F of state_out
    max_speed: float = math.nan  # max |v| of state_out [m/s]


# ----------------------------------------------------------------------------------------------------------
# Step bookkeeping
# ----------------------------------------------------------------------------------------------------------


@wp.kernel
def predict(
    x: wp.array(dtype=vec3),
    v: wp.array(dtype=vec3),
    mass: wp.array(dtype=f64),
    pinned: wp.array(dtype=wp.int32),
    targets: wp.array(dtype=vec3),
    forces: wp.array(dtype=vec3),
    h: f64,
    gravity: vec3,
    x_tilde: wp.array(dtype=vec3),
):
    """Inertial prediction x~ = x + h v + h^2 (g + f / m); a pinned vertex's is its target."""
    i = wp.tid()
    if pinned[i] != 0:
        x_tilde[i] = targets[i]
    else:
        x_tilde[i] = x[i] + h * v[i] + h * h * (gravity + forces[i] / mass[i])


@wp.kernel
def store_deformation(
    x: wp.array(dtype=vec3),
    tets: wp.array2d(dtype=wp.int32),
    dm_inv: wp.array(dtype=mat33),
    f_prev: wp.array(dtype=mat33),
):
    t = wp.tid()
    f_prev[t] = deformation_gradient(x, tets, t, dm_inv[t])


@wp.kernel
def step_positions(x: wp.array(dtype=vec3), d: wp.array(dtype=vec3), alpha: f64, out: wp.array(dtype=vec3)):
    i = wp.tid()
    out[i] = x[i] + alpha * d[i]


@wp.kernel
def end_step(
    x: wp.array(dtype=vec3),
    x_prev: wp.array(dtype=vec3),
    x_tilde: wp.array(dtype=vec3),
    inv_h: f64,
    v: wp.array(dtype=vec3),
    correction: wp.array(dtype=vec3),
    max_speed: wp.array(dtype=f64),
):
    """v = (x - x^n) / h; keep x - x~ as the next step's first Newton guess; max |v|."""
    i = wp.tid()
    vi = (x[i] - x_prev[i]) * inv_h
    v[i] = vi
    correction[i] = x[i] - x_tilde[i]
    wp.atomic_max(max_speed, 0, wp.length(vi))


@wp.kernel
def max_length(d: wp.array(dtype=vec3), out: wp.array(dtype=f64)):
    wp.atomic_max(out, 0, wp.length(d[wp.tid()]))


# ----------------------------------------------------------------------------------------------------------
# Solver
# ----------------------------------------------------------------------------------------------------------


class Forcing:
    """Relative tolerances of one step's Newton-step solves (inexact Newton; Eisenstat & Walker 1996,
    choice 2): ``loosest`` for the first solve, then ``0.9 (|F_k| / |F_k-1|)^2`` from the force norms of
    consecutive iterates (no less than ``0.9 eta_k-1^2`` while that exceeds 0.1), within ``[tightest,
    loosest]``. Far from the minimum, where the next step corrects this one anyway, a solve stops early; as
    Newton converges the force ratio falls and the solves tighten to ``tightest``. ``loosest <= tightest``
    gives ``tightest`` always."""

    GAMMA = 0.9

    def __init__(self, tightest: float, loosest: float):
        self.tightest = tightest
        self.loosest = self.eta = max(loosest, tightest)
        self.previous: float | None = None

    def next(self, force_norm: float) -> float:
        """The relative tolerance of the solve at an iterate whose force norm is ``force_norm``."""
        if self.previous is not None and self.previous > 0:
            eta = self.GAMMA * (force_norm / self.previous) ** 2
            safeguard = self.GAMMA * self.eta**2
            self.eta = min(max(eta, safeguard) if safeguard > 0.1 else eta, self.loosest)
        self.previous = force_norm
        return max(self.eta, self.tightest)


def partition_tets(
    vertices: np.ndarray, tets: np.ndarray, slabs: int
) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """An order of the tets for ``slabs`` threads: ``order`` (T,) and ``slabs + 1`` ranges of it.

    The vertices are cut into ``slabs`` slabs of equal count along the longest axis of ``vertices`` (V, 3);
    range ``k < slabs`` holds the tets whose 4 vertices lie in slab ``k``, the last range the tets that
    straddle slabs. Tets of different slabs share no vertex, so their Hessian blocks (rows and columns of
    their own vertices only) can be accumulated by separate threads without atomics; the straddling tets
    follow on one thread. ``tets`` (T, 4); ``slabs`` <= 1 gives one range of every tet.
    """
    n = len(tets)
    if slabs <= 1:
        return np.arange(n), [(0, n)]
    axis = int(np.argmax(np.ptp(vertices, axis=0)))
    rank = np.empty(len(vertices), np.int64)
    rank[np.argsort(vertices[:, axis], kind="stable")] = np.arange(len(vertices))
    slab = (rank * slabs // len(vertices))[tets]  # (T, 4)
    owner = np.where((slab == slab[:, :1]).all(axis=1), slab[:, 0], slabs)
    order = np.argsort(owner, kind="stable")
    bounds = np.searchsorted(owner[order], np.arange(slabs + 2))
    return order, [(int(bounds[k]), int(bounds[k + 1])) for k in range(slabs + 1)]


@dataclass
class StepInputs:
    """The arrays and length of the step being solved: ``x`` the iterate (state_out's positions), ``x_prev``
    the start (state_in's), ``pinned`` (V,) int32 the control's pins."""

    h: float
    x: wp.array
    x_prev: wp.array
    pinned: wp.array


class ImplicitSolver:
    """Backward-Euler Newton solver of one :class:`Model` (module docstring); owns the Hessian, the linear
    solver and every scratch buffer, sized for that model. The tolerances are the model's
    :class:`shellsim.physics.model.SimSettings` (``newton_*``, ``cg_*``, ``linear_solver``).
    """

    def __init__(self, model: Model):
        self.model = model
        self.device = dev = model.device
        n = model.n_vertices
        # per-tet arrays in the order of the threads' slabs (Hessians assembled in parallel on a CPU)
        parallel = dev.is_cpu and model.n_tets >= PARALLEL_HESSIAN_TETS
        order, self._tet_ranges = partition_tets(
            model.rest_vertices, model.tets, default_cpu_threads() if parallel else 1
        )
        tets = model.tets[order]
        offsets, columns, block_index, diag_index = block_topology(tets, n)

        def arr(a, dtype):
            return wp.array(a, dtype=dtype, device=dev)

        self._tets = arr(tets.astype(np.int32), wp.int32)
        self._dm_inv = arr(model.dm_inv[order], mat33)
        self._volume = arr(model.volumes[order], f64)
        self._offsets = arr(offsets, wp.int32)
        self._columns = arr(columns, wp.int32)
        self._block_index = arr(block_index, wp.int32)
        self._diag_index = arr(diag_index, wp.int32)
        self._values = wp.zeros(len(columns), dtype=mat33, device=dev)
        self._elastic_values = wp.zeros(len(columns), dtype=mat33, device=dev)  # tets' blocks alone
        self._inv_diag = wp.zeros(n, dtype=mat33, device=dev)
        for name in ("_x_tilde", "_x_trial", "_force", "_d", "_correction", "_fn_normal"):
            setattr(self, name, wp.zeros(n, dtype=vec3, device=dev))
        self._cg_vectors = tuple(wp.zeros(n, dtype=vec3, device=dev) for _ in range(5))
        self._fn = wp.zeros(n, dtype=f64, device=dev)
        self._f_prev = wp.zeros(model.n_tets, dtype=mat33, device=dev)
        self._scalars = wp.zeros(3, dtype=f64, device=dev)  # energy, min det F, |force|^2; or a max norm
        self._scalars_init = wp.array([0.0, 1.0e300, 0.0], dtype=f64, device=dev)
        self._cg_result = wp.zeros(2, dtype=f64, device=dev)
        self._per_tet = (self._tets, self._dm_inv, self._volume, self._f_prev, self._block_index)
        self._tet_parts = [tuple(a[lo:hi] for a in self._per_tet) for lo, hi in self._tet_ranges]
        self._solve = self._make_solver(offsets, columns)

    def step(
        self, model: Model, state_in: State, state_out: State, control: Control, dt: float
    ) -> SolveStats:
        """One backward-Euler step of ``dt`` [s] from ``state_in`` into ``state_out`` (a different
        :class:`State`) under ``control``'s pins and forces; ``model`` must be the solver's. Newton starts
        from the inertial prediction plus this solver's previous correction (``x - x~`` of its last step),
        so consecutive steps of one trajectory start close to their solution."""
        if model is not self.model:
            raise ValueError("model: the solver was built for another model")
        if state_in is state_out:
            raise ValueError("state_out: must be another State than state_in")
        s = model.settings
        dev = self.device
        n = model.n_vertices
        h = float(dt)
        stats = SolveStats()
        x_in, x = state_in.positions, state_out.positions
        step = self.prepare(state_in, state_out, control, h)

        # start from the inertial prediction plus the previous step's correction, or from the prediction
        # alone, whichever has the lower energy and inverts no tet (else from x^n); the former, most often
        # chosen, is evaluated with its force, which Newton's first iteration then needs
        start_energy, start_weight = math.inf, None
        for weight in (0.0, 1.0):
            wp.launch(step_positions, n, [self._x_tilde, self._correction, weight, self._x_trial], device=dev)
            energy, min_det, force_norm = self.evaluate(self._x_trial, step, FORCE if weight else ENERGY)
            if min_det > 0 and energy < math.inf and energy <= start_energy:
                wp.copy(x, self._x_trial)
                start_energy, start_weight = energy, weight
        if start_weight is None:
            wp.copy(x, x_in)
        if start_weight != 1.0:
            energy, min_det, force_norm = self.evaluate(x, step, FORCE)
        # energy, min_det, force_norm stay those of x from here on
        # Newton stops once the step is below tol; H >= M / h^2 bounds |d| <= |force| h^2 / m_min
        tol = s.newton_tol * model.size * h
        force_tol = tol * control.min_free_mass / (h * h)
        iterations = 0
        forcing = Forcing(s.cg_tol, self._loosest_solve)
        moved = math.inf  # bound on how far x moved since the tets' Hessian blocks were evaluated
        while iterations < s.newton_iterations:
            iterations += 1
            if not math.isfinite(energy):
                return stats
            if force_norm <= force_tol:
                stats.converged = True
                break
            fresh = moved > ELASTIC_HESSIAN_REUSE * tol
            self.evaluate(x, step, HESSIAN, fresh_tets=fresh)
            moved = 0.0 if fresh else moved
            stats.hessians += fresh
            self._d.zero_()
            rtol = forcing.next(force_norm)
            stats.cg_iterations += self._solve(0.1 * force_tol, rtol)
            length = self._max_step()
            if length <= tol and rtol > s.cg_tol:
                # a loose solve may stop short of a step that is not small: the test takes the solve
                # finished to cg_tol (continued from where it stopped)
                stats.cg_iterations += self._solve(0.1 * force_tol, s.cg_tol)
                length = self._max_step()
            if length <= tol:
                # the step that shows convergence is paid for: take it where it lowers E and inverts no
                # tet, so x ends far closer to the minimum than tol (and the next step starts there)
                evaluation = self._line_search(energy, min_det, step, tries=1, order=ENERGY)
                if evaluation is not None:
                    energy, min_det, _ = evaluation
                stats.converged = True
                break
            evaluation = self._line_search(energy, min_det, step)
            if evaluation is None:
                break
            energy, min_det, force_norm = evaluation
            moved += length
        stats.newton_iterations = iterations

        self._scalars.zero_()
        wp.launch(
            end_step,
            n,
            [x, x_in, self._x_tilde, 1.0 / h, state_out.velocities, self._correction, self._scalars],
            device=dev,
        )
        state_out.time = state_in.time + h
        stats.energy, stats.min_volume_ratio = energy, min_det
        stats.max_speed = float(self._scalars.numpy()[0])
        return stats

    def prepare(self, state_in: State, state_out: State, control: Control, h: float) -> StepInputs:
        """The fixed inputs of a step of ``h`` [s] from ``state_in`` whose iterate is ``state_out``'s
        positions: the inertial prediction, the deformation gradients at the start (damping) and the lagged
        friction of the penalty colliders. :meth:`evaluate` then measures any iterate."""
        dev, model = self.device, self.model
        n = model.n_vertices
        x_in = state_in.positions
        wp.launch(
            predict,
            n,
            [
                x_in,
                state_in.velocities,
                model.masses_wp,
                control.pinned_wp,
                control.targets_wp,
                control.forces_wp,
                h,
                vec3(*model.gravity),
                self._x_tilde,
            ],
            device=dev,
        )
        wp.launch(store_deformation, model.n_tets, [x_in, self._tets, self._dm_inv, self._f_prev], device=dev)
        s = model.settings
        wp.launch(
            lag_friction,
            n,
            [x_in, model.masses_wp, model.colliders, f64(s.contact_stiffness), self._fn, self._fn_normal],
            device=dev,
        )
        return StepInputs(h, state_out.positions, x_in, control.pinned_wp)

    @property
    def prediction(self) -> np.ndarray:
        """(V, 3) the inertial prediction of the step last prepared (pinned vertices: their targets)."""
        return self._x_tilde.numpy()

    @property
    def force(self) -> np.ndarray:
        """(V, 3) ``-dE/dx`` of the last FORCE :meth:`evaluate` (zero on pinned vertices)."""
        return self._force.numpy()

    def hessian_matrix(self):
        """The last HESSIAN :meth:`evaluate`'s matrix as a ``scipy.sparse.bsr_matrix`` (3V, 3V) with 3x3
        blocks (pinned vertices: identity rows and zero columns)."""
        from scipy.sparse import bsr_matrix

        n = self.model.n_vertices
        return bsr_matrix(
            (self._values.numpy(), self._columns.numpy(), self._offsets.numpy()), shape=(3 * n, 3 * n)
        )

    def _max_step(self) -> float:
        """max_i |d_i| of the Newton step in ``d``."""
        self._scalars.zero_()
        wp.launch(max_length, self.model.n_vertices, [self._d, self._scalars], device=self.device)
        return float(self._scalars.numpy()[0])

    def _line_search(
        self, energy: float, min_det: float, step: StepInputs, tries: int = 12, order: int = FORCE
    ) -> tuple[float, float, float] | None:
        """Backtrack x + alpha d, alpha = 1, 1/2, ... (``tries`` values) until E decreases (and no tet inverts
        that was not); move x there and return :meth:`evaluate` (``order``) of the new x, or None if no
        alpha does."""
        alpha = 1.0
        for _ in range(tries):
            wp.launch(
                step_positions,
                self.model.n_vertices,
                [step.x, self._d, alpha, self._x_trial],
                device=self.device,
            )
            evaluation = self.evaluate(self._x_trial, step, order)
            trial, trial_det, _ = evaluation
            if trial <= energy and (trial_det > 0 or min_det <= 0):
                wp.copy(step.x, self._x_trial)
                return evaluation
            alpha *= 0.5
        return None

    def evaluate(
        self, x: wp.array, step: StepInputs, order: int, fresh_tets: bool = True
    ) -> tuple[float, float, float] | None:
        """ENERGY, FORCE: the incremental potential at ``x``, min det F and |force| (0 for ENERGY); FORCE
        fills the force. HESSIAN: only the Hessian blocks and the block-Jacobi preconditioner (None), the
        tets of each slab (:func:`partition_tets`) on a thread of their own; without ``fresh_tets`` the tets'
        blocks of the last HESSIAN evaluation are taken again (the vertices' are always evaluated at x)."""
        s, m = self.model.settings, self.model.material
        dev = self.device
        if order == HESSIAN:
            if not fresh_tets:
                wp.copy(self._values, self._elastic_values)
                self._vertex_terms(x, step, order)
                return None
            self._elastic_values.zero_()
        else:
            wp.copy(self._scalars, self._scalars_init)
        if order == FORCE:
            self._force.zero_()
        lam_snh = m.lam + m.mu
        damp = s.damping / step.h

        def tet_range(arrays) -> None:
            tets, dm_inv, volume, f_prev, block_index = arrays
            if tets.shape[0] == 0:
                return
            wp.launch(
                tet_terms,
                tets.shape[0],
                [
                    x,
                    tets,
                    dm_inv,
                    volume,
                    f_prev,
                    m.mu,
                    lam_snh,
                    damp * m.mu,
                    damp * m.lam,
                    SHIFT_LIMIT,
                    step.pinned,
                    block_index,
                    order,
                    self._scalars[0:1],
                    self._scalars[1:2],
                    self._force,
                    self._elastic_values,
                ],
                device=dev,
            )

        slabs = len(self._tet_parts) - 1
        if order == HESSIAN and slabs > 0:
            # the slabs' tets on a thread each (they write disjoint blocks), then the tets between them;
            # energies and forces (cheap) go in one launch: threads would cost more than they save there
            def slab_range(lo: int, hi: int) -> None:
                for k in range(lo, hi):
                    tet_range(self._tet_parts[k])

            run_in_chunks(slabs, slab_range, slabs, 1)
            tet_range(self._tet_parts[slabs])
        else:
            tet_range(self._per_tet)
        if order == HESSIAN:
            wp.copy(self._values, self._elastic_values)
        return self._vertex_terms(x, step, order)

    def _vertex_terms(self, x: wp.array, step: StepInputs, order: int) -> tuple[float, float, float] | None:
        """:meth:`evaluate`'s per-vertex terms (added to the tets' sums and blocks) and its result."""
        model = self.model
        s, h = model.settings, step.h
        wp.launch(
            vertex_terms,
            model.n_vertices,
            [
                x,
                self._x_tilde,
                step.x_prev,
                model.masses_wp,
                step.pinned,
                1.0 / (h * h),
                s.drag / h,
                model.colliders,
                f64(s.contact_stiffness),
                f64(s.friction),
                self._fn,
                self._fn_normal,
                f64(s.friction_velocity * h),
                order,
                self._scalars[0:1],
                self._scalars[2:3],
                self._force,
                self._values,
                self._diag_index,
                self._inv_diag,
            ],
            device=self.device,
        )
        if order == HESSIAN:
            return None
        energy, min_det, force_sq = self._scalars.numpy()
        return float(energy), float(min_det), math.sqrt(float(force_sq))

    def _make_solver(self, offsets: np.ndarray, columns: np.ndarray):
        """The Newton-step solver ``H d = force`` from the guess in ``d``: ``solve(atol, rtol) -> CG steps``;
        sets ``_loosest_solve``, the loosest ``rtol`` it takes (the CUDA path's is fixed at ``cg_tol``)."""
        s = self.model.settings
        kind = s.linear_solver
        if kind == "auto":
            kind = "serial" if self.device.is_cpu else "cg"
        self._loosest_solve = s.cg_forcing if kind == "serial" else s.cg_tol
        if kind == "serial":
            return serial_pcg_solver(
                self._offsets,
                self._columns,
                self._values,
                self._diag_index,
                self._inv_diag,
                self._force,
                self._d,
                self._cg_vectors,
                self._cg_result,
                s.cg_tol,
                s.cg_iterations,
                self.device,
            )
        self._values, solve = bsr_cg_solver(
            offsets,
            columns,
            self._columns,
            self._inv_diag,
            self._force,
            self._d,
            s.cg_tol,
            s.cg_iterations,
            self.device,
        )
        return solve
