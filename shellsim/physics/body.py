"""One body's terms of the incremental potential, in Warp, on plain arrays (no torch): energy, force and
Hessian blocks of a :class:`shellsim.physics.model.Model` at any iterate of a backward-Euler step.

A step of length ``h`` minimises over the vertex positions ``x`` (V, 3) (Martin et al. 2011; Li et al. 2020)

    E(x) = sum_t V_t [Psi(F_t) + (beta / h) D(A_t)] + sum_i m_i / (2 h^2) |x_i - x~_i|^2
           + sum_i alpha m_i / (2 h) |x_i - x^n_i|^2

with the inertial prediction ``x~ = x^n + h v^n + h^2 (g + f / m)`` (the external forces ``f`` and the
pins of the step's :class:`shellsim.physics.control.Control`: a pinned vertex's prediction is its target,
its row of the Newton system the identity) and the velocity drag ``alpha``. Contact is added by the solver
(:mod:`shellsim.physics.solver`, :mod:`shellsim.physics.ipc`). Per tetrahedron, with rest volume ``V_t``,
deformation gradient ``F = D_s D_m^-1`` and ``J = det F``:

- **Stable Neo-Hookean** (Smith et al. 2018, in the form of Kim & Eberle 2022, Sec. 6.5)::

      Psi(F) = mu/2 (|F|^2 - 3) - mu (J - 1) + phi(J),     phi(J) = lam/2 (J - 1)^2 + b(J),

  ``lam = lambda_Lame + mu``: rest-stable, linearising to Lamé's ``mu``, ``lambda``, plus a volume barrier
  ``b(J) = -kb lam (J - Jb)^2 log(J / Jb)`` for ``J < Jb`` (``Jb = 0.5``, ``kb = 10``: ``BARRIER_J``,
  ``BARRIER_STIFFNESS`` in :mod:`shellsim.physics.elastic`; C2, zero for ``J >= Jb``, infinite at ``J = 0``).
  Without it a tet flattened to ``J = 0`` costs only ``(mu + lam) / 2`` per volume: soft bodies (10 kPa
  jelly) squashed on impact flattened tets bridging concave creases. The stress is
  ``P = mu F + (phi'(J) - mu) dJ/dF`` and the Hessian ``mu I + phi''(J) dJ dJ^T + k d2J``,
  ``k = phi'(J) - mu``, has the analytic eigensystem of Smith et al. 2019: with ``F = U diag(s) V^T`` the
  twist and flip modes ``U t_m V^T``, ``U l_m V^T`` have eigenvalues ``mu + k s_m`` and ``mu - k s_m``, and
  the three scaling modes ``U diag(q) V^T`` are the eigenvectors ``q`` of
  ``mu I + phi'' c c^T + k [[0, s2, s1], [s2, 0, s0], [s1, s0, 0]]``, ``c = (s1 s2, s0 s2, s0 s1)``.
  Definiteness fix: where the smallest eigenvalue (closed form, no SVD) is above ``-SHIFT_LIMIT mu`` the
  exact Hessian is shifted by it, else the element takes the SVD and every negative eigenvalue is clamped.
- **Kelvin-Voigt damping** on the Green strain rate (Rayleigh dissipation, invariant to rigid motion):
  ``A = F^n^T (F - F^n)`` (``F^n`` at the step start), ``D(A) = mu |sym A|^2 + lambda/2 tr(A)^2``;
  ``beta`` [s] is the ratio of viscosity to stiffness.

The Hessian is assembled into a block-sparse (3x3) matrix with a fixed sparsity pattern; on a CPU the tets
of a large body are assembled on several threads (:func:`partition_tets`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from neural.device import cpu_threads as default_cpu_threads
from neural.device import run_in_chunks
from shellsim.physics.control import Control
from shellsim.physics.elastic import (
    FORCE,
    HESSIAN,
    SHIFT_LIMIT,
    block_topology,
    deformation_gradient,
    f64,
    mat33,
    tet_terms,
    vec3,
)
from shellsim.physics.model import Model
from shellsim.physics.state import State

#: Fewest tets for which the CPU assembles a Hessian on several threads: 2k-tet Hessians are too quick
#: (about 0.5 ms) for a thread hand-off to pay; 10k and 41k-tet ones gain.
PARALLEL_HESSIAN_TETS = 8192
wp.set_module_options({"enable_backward": False})  # no autodiff here; halves compile time


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
def vertex_terms(
    x: wp.array(dtype=vec3),
    x_tilde: wp.array(dtype=vec3),
    x_prev: wp.array(dtype=vec3),
    mass: wp.array(dtype=f64),
    pinned: wp.array(dtype=wp.int32),
    inv_h2: f64,
    drag_over_h: f64,
    order: int,
    energy: wp.array(dtype=f64),
    force: wp.array(dtype=vec3),
    values: wp.array(dtype=mat33),
    diag_index: wp.array(dtype=wp.int32),
):
    """Vertex ``i``'s inertia and drag (module docstring): for ``order`` ENERGY and FORCE its energy, for
    FORCE also its force ``-dE/dx_i`` (added to ``force``); for HESSIAN only its Hessian block (added to the
    diagonal block ``values[diag_index[i]]``). Pinned vertices get an identity row and no force."""
    i = wp.tid()
    if pinned[i] != 0:
        if order == 1:
            force[i] = vec3(f64(0.0), f64(0.0), f64(0.0))
        if order == 2:
            values[diag_index[i]] = wp.identity(n=3, dtype=f64)
        return
    m = mass[i]
    if order == 2:
        values[diag_index[i]] = values[diag_index[i]] + (m * inv_h2 + drag_over_h * m) * wp.identity(
            n=3, dtype=f64
        )
        return
    dx = x[i] - x_tilde[i]
    step = x[i] - x_prev[i]
    wp.atomic_add(
        energy, 0, f64(0.5) * m * inv_h2 * wp.dot(dx, dx) + f64(0.5) * drag_over_h * m * wp.dot(step, step)
    )
    if order == 1:
        force[i] = force[i] - m * inv_h2 * dx - drag_over_h * m * step


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
    """The fixed inputs of the step being solved: its length ``h`` [s], the start ``x_prev`` (state_in's
    positions) and ``pinned`` (V,) int32, the control's pins."""

    h: float
    x_prev: wp.array
    pinned: wp.array


class BodyTerms:
    """The incremental potential's terms of one :class:`Model` (module docstring); owns the Hessian blocks
    and every scratch buffer, sized for that model."""

    def __init__(self, model: Model):
        self.model = model
        self.device = dev = model.device
        n = model.n_vertices
        # per-tet arrays in the order of the threads' slabs (Hessians assembled in parallel on a CPU)
        parallel = dev.is_cpu and model.n_tets >= PARALLEL_HESSIAN_TETS
        order, ranges = partition_tets(
            model.rest_vertices, model.tets, default_cpu_threads() if parallel else 1
        )
        tets = model.tets[order]
        offsets, columns, block_index, diag_index = block_topology(tets, n)

        def arr(a, dtype):
            return wp.array(a, dtype=dtype, device=dev)

        self._offsets, self._columns = offsets, columns
        self._diag_index = arr(diag_index, wp.int32)
        self._values = wp.zeros(len(columns), dtype=mat33, device=dev)
        self._x_tilde = wp.zeros(n, dtype=vec3, device=dev)
        self._force = wp.zeros(n, dtype=vec3, device=dev)
        self._f_prev = wp.zeros(model.n_tets, dtype=mat33, device=dev)
        self._scalars = wp.zeros(2, dtype=f64, device=dev)  # energy, min det F
        self._scalars_init = wp.array([0.0, 1.0e300], dtype=f64, device=dev)
        self._tets = arr(tets.astype(np.int32), wp.int32)
        per_tet = (
            self._tets,
            arr(model.dm_inv[order], mat33),
            arr(model.volumes[order], f64),
            self._f_prev,
            arr(block_index, wp.int32),
        )
        self._per_tet = per_tet
        self._tet_parts = [tuple(a[lo:hi] for a in per_tet) for lo, hi in ranges]
        self._dm_inv = per_tet[1]

    def prepare(self, state_in: State, control: Control, h: float) -> StepInputs:
        """The fixed inputs of a step of ``h`` [s] from ``state_in`` under ``control``: the inertial
        prediction and the deformation gradients at the start (damping). :meth:`evaluate` then measures
        any iterate."""
        model = self.model
        x_in = state_in.positions
        wp.launch(
            predict,
            model.n_vertices,
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
            device=self.device,
        )
        wp.launch(
            store_deformation,
            model.n_tets,
            [x_in, self._tets, self._dm_inv, self._f_prev],
            device=self.device,
        )
        return StepInputs(h, x_in, control.pinned_wp)

    @property
    def prediction(self) -> np.ndarray:
        """(V, 3) a copy of the inertial prediction of the last step prepared (pinned vertices: their
        targets)."""
        return self._x_tilde.numpy().copy()

    @property
    def force(self) -> np.ndarray:
        """(V, 3) ``-dE/dx`` of the last FORCE :meth:`evaluate` (zero on pinned vertices); a copy."""
        return self._force.numpy().copy()

    def evaluate(self, x: wp.array, step: StepInputs, order: int) -> tuple[float, float] | None:
        """ENERGY, FORCE: (the incremental potential at ``x`` (V,) vec3d, min det F); FORCE also fills
        :attr:`force`. HESSIAN: only the Hessian blocks (None), the tets of each slab
        (:func:`partition_tets`) on a thread of their own."""
        s, m = self.model.settings, self.model.material
        if order == HESSIAN:
            self._values.zero_()
        else:
            wp.copy(self._scalars, self._scalars_init)
        if order == FORCE:
            self._force.zero_()
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
                    m.lam + m.mu,
                    damp * m.mu,
                    damp * m.lam,
                    SHIFT_LIMIT,
                    step.pinned,
                    block_index,
                    order,
                    self._scalars[0:1],
                    self._scalars[1:2],
                    self._force,
                    self._values,
                ],
                device=self.device,
            )

        slabs = len(self._tet_parts) - 1
        if order == HESSIAN and slabs > 0:
            # the slabs' tets on a thread each (they write disjoint blocks), then the tets between them;
            # energies and forces (cheap) go in one launch per part
            def slab_range(lo: int, hi: int) -> None:
                for k in range(lo, hi):
                    tet_range(self._tet_parts[k])

            run_in_chunks(slabs, slab_range, slabs, 1)
            tet_range(self._tet_parts[slabs])
        else:
            tet_range(self._per_tet)
        wp.launch(
            vertex_terms,
            self.model.n_vertices,
            [
                x,
                self._x_tilde,
                step.x_prev,
                self.model.masses_wp,
                step.pinned,
                1.0 / (step.h * step.h),
                s.drag / step.h,
                order,
                self._scalars[0:1],
                self._force,
                self._values,
                self._diag_index,
            ],
            device=self.device,
        )
        if order == HESSIAN:
            return None
        energy, min_det = self._scalars.numpy()
        return float(energy), float(min_det)

    def hessian_matrix(self):
        """The last HESSIAN :meth:`evaluate`'s matrix as a ``scipy.sparse.bsr_matrix`` (3V, 3V) with 3x3
        blocks (pinned vertices: identity rows and zero columns)."""
        from scipy.sparse import bsr_matrix

        n = self.model.n_vertices
        return bsr_matrix((self._values.numpy(), self._columns, self._offsets), shape=(3 * n, 3 * n))

    def hessian_blocks(self) -> np.ndarray:
        """(B, 3, 3) the last HESSIAN :meth:`evaluate`'s blocks (a view: the next evaluation overwrites it),
        in the order of :attr:`hessian_pattern`."""
        return self._values.numpy()

    @property
    def hessian_pattern(self) -> tuple[np.ndarray, np.ndarray]:
        """The block-CSR pattern of the Hessian's 3x3 blocks: ``offsets`` (V+1,) and sorted block
        ``columns`` (B,)."""
        return self._offsets, self._columns
