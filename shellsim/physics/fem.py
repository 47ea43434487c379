"""Implicit (backward Euler) hyperelastic FEM on linear tetrahedra, in Warp, on plain arrays (no torch).

Each substep of length ``h`` minimises the incremental potential (Martin et al. 2011; Li et al. 2020)

    E(x) = sum_t V_t [Psi(F_t) + (beta / h) D(A_t)] + sum_i E_i(x_i)

over the vertex positions ``x`` (V, 3), then sets ``v = (x - x^n) / h``. The per-vertex terms ``E_i``
(inertia, drag, penalty contact, lagged friction) are in :mod:`shellsim.physics.contact`. Per tetrahedron, with
rest volume ``V_t``, deformation gradient ``F = D_s D_m^-1`` and ``J = det F``:

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
  ``A = F^n^T (F - F^n)`` (``F^n`` at the substep start), ``D(A) = mu |sym A|^2 + lambda/2 tr(A)^2``;
  ``beta`` [s] is the ratio of viscosity to stiffness.

Newton's method solves each substep: the PSD Hessian is assembled into a block-sparse (3x3) matrix with a
fixed sparsity pattern and the step solves ``H d = -grad E`` by preconditioned conjugate gradients, warm
started from the previous substep's correction. On CPU one Warp kernel runs the whole PCG loop with an
SSOR preconditioner (:data:`shellsim.physics.linsolve.SSOR_OMEGA`; Warp runs CPU kernels on one thread, so launch
overhead would dominate and a serial preconditioner costs nothing in parallelism: 3x fewer iterations than
block-Jacobi, a quarter fewer than symmetric Gauss-Seidel);
on CUDA :func:`warp.optim.linear.cg` with block-Jacobi. A backtracking line search on ``E`` keeps the energy
decreasing and the tets uninverted; its passes also compute the force, so the accepted point's energy, det F
and force serve the next iteration's test, and the Hessian pass computes only the Hessian; a later iteration
whose substep has moved x by at most :data:`ELASTIC_HESSIAN_REUSE` tolerances since the tets' blocks were
evaluated keeps those blocks and evaluates only the vertices' (contact and friction). The first solves
of a substep stop early (:class:`Forcing`, inexact Newton), the last ones reach ``cg_tol``. Newton stops when
its step is below ``newton_tol``; that last step, already solved for, is taken too when it lowers E (one
energy pass), which leaves x much closer to the substep's minimum than the tolerance (``bench/sim_bench.py
--accuracy``) and the next substep a better start. A frame whose state squeezes a tet below
``min_volume_ratio`` (:data:`shellsim.cage.geometry.MIN_VOLUME_RATIO`: inverted or near-degenerate), turns
non-finite or exceeds ``max_speed`` is redone with more substeps, then raises
:class:`SimulationError`.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import asdict, dataclass, field

import numpy as np
import warp as wp

from neural.device import cpu_threads as default_cpu_threads
from neural.device import run_in_chunks
from neural.errors import InputError, ShellsimError
from shellsim.cage.geometry import MIN_VOLUME_RATIO, check_tets, tet_volumes
from shellsim.physics.contact import Box, Sphere, collider_arrays, lag_friction, make_colliders, vertex_terms
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
from shellsim.physics.materials import Material

log = logging.getLogger(__name__)
#: Fewest tets for which the CPU assembles a Hessian on several threads: 2k-tet Hessians are too quick
#: (about 0.5 ms) for a thread hand-off to pay (6.2-6.5 against 5.0 ms per step); 10k and 41k-tet ones gain
#: 4-5% of a step.
PARALLEL_HESSIAN_TETS = 8192
#: A Newton iteration keeps the tets' Hessian blocks of an earlier iteration of its substep while the steps
#: taken since then add up to at most this many Newton tolerances (``newton_tol * size * h``): the elastic
#: blocks then change by well under a percent, while the contact and friction blocks, which jump as vertices
#: touch, stick and slip, are always evaluated afresh.
ELASTIC_HESSIAN_REUSE = 20.0
wp.set_module_options({"enable_backward": False})  # no autodiff here; halves compile time


class SimulationError(ShellsimError):
    """A frame left the valid regime with every substep count tried.

    kind : "collapse" (min det F below ``SimSettings.min_volume_ratio``), "speed" (above ``max_speed``)
    or "nonfinite"; value : that min det F or speed [m/s] (nan for "nonfinite"); time : the frame's start
    [s]; substeps : the counts tried; frame : its index in the motion, set by :func:`simulate`.
    """

    def __init__(self, kind: str, value: float, limit: float, time: float, substeps: tuple[int, ...]):
        super().__init__(kind, value, limit, time, substeps)
        self.kind, self.value, self.limit, self.time, self.substeps = kind, value, limit, time, substeps
        self.frame: int | None = None

    def __str__(self) -> str:
        what = {
            "collapse": f"the smallest tet volume ratio (det F) fell to {self.value:.3g}, "
            f"below {self.limit:g}",
            "speed": f"a vertex reached {self.value:.3g} m/s, above max_speed {self.limit:g} m/s",
            "nonfinite": "positions became non-finite",
        }[self.kind]
        tried = ", ".join(str(n) for n in self.substeps)
        frame = "" if self.frame is None else f"frame {self.frame} "
        return f"{frame}(t = {self.time:.3f} s) is invalid with {tried} substeps: {what}"


@dataclass
class SimSettings:
    """Settings of :class:`Simulator`, SI units. A frame lasts ``dt`` and is split into ``substeps``."""

    dt: float = 1.0 / 30.0  # frame duration [s]
    substeps: int = 8  # backward-Euler steps per frame
    gravity: float = 9.81  # [m/s^2], along -up
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    ground: float | None = 0.0  # height of the ground plane along ``up`` [m]; None: no ground
    spheres: tuple[Sphere, ...] = ()
    boxes: tuple[Box, ...] = ()
    contact_stiffness: float = 1.0e6  # penalty kappa per unit mass [1/s^2]
    friction: float = 0.5  # Coulomb coefficient
    friction_velocity: float = 1.0e-2  # sliding speed below which friction is smoothed [m/s]
    damping: float = 0.0  # Kelvin-Voigt beta [s]
    drag: float = 0.0  # velocity drag alpha [1/s]
    newton_iterations: int = 10
    newton_tol: float = 1.0e-2  # stop when max |dx| / h < newton_tol * (rest bounding-box diagonal) per s
    cg_tol: float = 1.0e-3  # relative residual of the Newton system (of the last solves: see Forcing)
    cg_forcing: float = 0.05  # loosest relative residual of a Newton step's solve (Forcing); 0: cg_tol always
    cg_iterations: int = 500
    max_speed: float = 100.0  # [m/s]; faster means the simulation exploded
    retry_factors: tuple[int, ...] = (2, 4)  # substep multipliers tried after a failed frame
    min_volume_ratio: float = MIN_VOLUME_RATIO  # smallest det F a frame may reach (near-degenerate tets)
    linear_solver: str = "auto"  # "serial" (one-kernel SGS-PCG), "cg" (warp.optim.linear.cg), "auto"

    def __post_init__(self):
        positive = ("dt", "contact_stiffness", "friction_velocity", "newton_tol", "cg_tol", "max_speed")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"SimSettings.{name} must be > 0, got {value}")
        if not 0 <= self.cg_forcing < 1:
            raise ValueError(f"SimSettings.cg_forcing must lie in [0, 1), got {self.cg_forcing}")
        for name in ("gravity", "friction", "damping", "drag"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"SimSettings.{name} must be >= 0, got {value}")
        for name in ("substeps", "newton_iterations", "cg_iterations"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"SimSettings.{name} must be >= 1, got {getattr(self, name)}")
        up = np.asarray(self.up, dtype=np.float64)
        if up.shape != (3,) or not np.isfinite(up).all() or np.linalg.norm(up) == 0:
            raise ValueError(f"SimSettings.up must be a non-zero 3-vector, got {self.up!r}")
        if self.ground is not None and not math.isfinite(self.ground):
            raise ValueError(f"SimSettings.ground must be finite or None, got {self.ground}")
        if not 0 <= self.min_volume_ratio < 1:
            raise ValueError(f"SimSettings.min_volume_ratio must lie in [0, 1), got {self.min_volume_ratio}")
        if any(int(f) < 2 for f in self.retry_factors):
            raise ValueError(f"SimSettings.retry_factors must be integers >= 2, got {self.retry_factors}")
        if self.linear_solver not in ("auto", "serial", "cg"):
            raise ValueError(
                f"SimSettings.linear_solver must be auto, serial or cg, got {self.linear_solver!r}"
            )

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass
class StepStats:
    """What one :meth:`Simulator.step` (one frame) took."""

    substeps: int = 0  # substeps of the successful attempt
    retries: int = 0  # failed attempts before it
    newton_iterations: int = 0  # over all substeps of the successful attempt
    max_newton_iterations: int = 0  # in one substep
    unconverged_substeps: int = 0  # substeps that hit newton_iterations or stalled in the line search
    cg_iterations: int = 0
    hessians: int = 0  # Newton iterations that evaluated the tets' Hessian blocks (the rest reused them)
    min_volume_ratio: float = 1.0  # min det F at the end of the frame
    max_speed: float = 0.0  # [m/s] at the end of the frame
    seconds: float = 0.0  # wall time
    energy: float = 0.0  # incremental potential of the last substep's solution
    notes: list[str] = field(default_factory=list)


# ----------------------------------------------------------------------------------------------------------
# Substep bookkeeping
# ----------------------------------------------------------------------------------------------------------


@wp.kernel
def begin_substep(
    x: wp.array(dtype=vec3),
    v: wp.array(dtype=vec3),
    pinned: wp.array(dtype=wp.int32),
    h: f64,
    gravity: vec3,
    x_prev: wp.array(dtype=vec3),
    x_tilde: wp.array(dtype=vec3),
):
    """x^n = x; inertial prediction x~ = x + h v + h^2 g (pinned vertices stay)."""
    i = wp.tid()
    x_prev[i] = x[i]
    if pinned[i] != 0:
        x_tilde[i] = x[i]
    else:
        x_tilde[i] = x[i] + h * v[i] + h * h * gravity


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
def end_substep(
    x: wp.array(dtype=vec3),
    x_prev: wp.array(dtype=vec3),
    x_tilde: wp.array(dtype=vec3),
    inv_h: f64,
    v: wp.array(dtype=vec3),
    correction: wp.array(dtype=vec3),
    max_speed: wp.array(dtype=f64),
):
    """v = (x - x^n) / h; keep x - x~ as the next substep's first Newton guess; max |v|."""
    i = wp.tid()
    vi = (x[i] - x_prev[i]) * inv_h
    v[i] = vi
    correction[i] = x[i] - x_tilde[i]
    wp.atomic_max(max_speed, 0, wp.length(vi))


@wp.kernel
def max_length(d: wp.array(dtype=vec3), out: wp.array(dtype=f64)):
    wp.atomic_max(out, 0, wp.length(d[wp.tid()]))


# ----------------------------------------------------------------------------------------------------------
# Simulator
# ----------------------------------------------------------------------------------------------------------


class Forcing:
    """Relative tolerances of one substep's Newton-step solves (inexact Newton; Eisenstat & Walker 1996,
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


class Simulator:
    """Backward-Euler FEM of one elastic body.

    vertices : (V, 3) rest positions [m]; tets : (T, 4) positively oriented; material : :class:`Material`;
    pinned : (V,) bool, vertices held in place; device : Warp device (None: Warp's default).
    Running state: ``positions``, ``velocities`` (V, 3) [m, m/s], ``time`` [s].
    """

    def __init__(
        self,
        vertices,
        tets,
        material: Material,
        settings: SimSettings | None = None,
        *,
        pinned=None,
        device=None,
    ):
        rest = np.asarray(vertices, dtype=np.float64)
        if rest.ndim != 2 or rest.shape[1] != 3 or len(rest) < 4 or not np.isfinite(rest).all():
            raise ValueError(f"vertices: expected finite (V >= 4, 3), got {rest.shape}")
        tets = check_tets(tets, len(rest))
        volumes = tet_volumes(rest, tets)
        if (volumes <= 0).any():
            raise ValueError(
                f"tets: {(volumes <= 0).sum()} of {len(tets)} have volume <= 0 (need positive orientation)"
            )
        used = np.zeros(len(rest), bool)
        used[tets.ravel()] = True
        if not used.all():
            raise ValueError(f"vertices: {(~used).sum()} vertices belong to no tet")
        pinned = np.zeros(len(rest), bool) if pinned is None else np.asarray(pinned, dtype=bool)
        if pinned.shape != (len(rest),):
            raise ValueError(f"pinned: expected ({len(rest)},) bool, got {pinned.shape}")

        self.settings = settings or SimSettings()
        self.material = material
        self.device = wp.get_device(device)
        self.n_vertices, self.n_tets = len(rest), len(tets)
        self.rest_vertices = rest
        self.tets = tets.astype(np.int64)
        self.pinned = pinned
        x = rest[tets]
        dm = np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]], axis=2)
        self.masses = np.bincount(
            tets.ravel(), np.repeat(material.density * volumes / 4.0, 4), minlength=len(rest)
        )
        self.size = float(np.linalg.norm(rest.max(0) - rest.min(0)))
        self._min_free_mass = float(self.masses[~pinned].min()) if (~pinned).any() else 1.0
        # internal per-tet arrays in the order of the threads' slabs (Hessians assembled in parallel on a CPU)
        parallel = self.device.is_cpu and len(tets) >= PARALLEL_HESSIAN_TETS
        order, self._tet_ranges = partition_tets(rest, tets, default_cpu_threads() if parallel else 1)
        tets, dm, volumes = tets[order], dm[order], volumes[order]
        offsets, columns, block_index, diag_index = block_topology(tets, len(rest))
        self.nnz_blocks = len(columns)

        dev = self.device
        self.time = 0.0

        def arr(a, dtype):
            return wp.array(a, dtype=dtype, device=dev)

        self._x = arr(rest, vec3)
        self._v = wp.zeros(len(rest), dtype=vec3, device=dev)
        self._tets = arr(tets.astype(np.int32), wp.int32)
        self._dm_inv = arr(np.linalg.inv(dm), mat33)
        self._volume = arr(volumes, f64)
        self._mass = arr(self.masses, f64)
        self._pinned = arr(pinned.astype(np.int32), wp.int32)
        self._offsets = arr(offsets, wp.int32)
        self._columns = arr(columns, wp.int32)
        self._block_index = arr(block_index, wp.int32)
        self._diag_index = arr(diag_index, wp.int32)
        self._values = wp.zeros(len(columns), dtype=mat33, device=dev)
        self._elastic_values = wp.zeros(len(columns), dtype=mat33, device=dev)  # tets' blocks alone
        self._inv_diag = wp.zeros(len(rest), dtype=mat33, device=dev)
        self._collider_arrays = collider_arrays(self.settings.spheres, self.settings.boxes, dev)
        vecs = (
            "_x_prev",
            "_x_tilde",
            "_x_trial",
            "_force",
            "_d",
            "_correction",
            "_fn_normal",
            "_x0",
            "_v0",
            "_r",
            "_z",
            "_p",
            "_q",
            "_t",
        )
        for name in vecs:
            setattr(self, name, wp.zeros(len(rest), dtype=vec3, device=dev))
        self._fn = wp.zeros(len(rest), dtype=f64, device=dev)
        self._f_prev = wp.zeros(len(tets), dtype=mat33, device=dev)
        self._scalars = wp.zeros(3, dtype=f64, device=dev)  # energy, min det F, |force|^2; or a max norm
        self._scalars_init = wp.array([0.0, 1.0e300, 0.0], dtype=f64, device=dev)
        self._cg_result = wp.zeros(2, dtype=f64, device=dev)
        self._per_tet = (self._tets, self._dm_inv, self._volume, self._f_prev, self._block_index)
        self._tet_parts = [tuple(a[lo:hi] for a in self._per_tet) for lo, hi in self._tet_ranges]
        self._solve = self._make_solver(offsets, columns)

    # -- state ---------------------------------------------------------------------------------------------

    @property
    def positions(self) -> np.ndarray:
        """(V, 3) float64 current positions [m] (a copy)."""
        return self._x.numpy().copy()

    @property
    def velocities(self) -> np.ndarray:
        """(V, 3) float64 current velocities [m/s] (a copy)."""
        return self._v.numpy().copy()

    def set_state(self, positions=None, velocities=None, time: float | None = None) -> None:
        """Replace positions (V, 3), velocities (V, 3) and/or the clock; pinned vertices get no velocity."""
        for name, value, target in (("positions", positions, self._x), ("velocities", velocities, self._v)):
            if value is None:
                continue
            value = np.asarray(value, dtype=np.float64)
            if value.shape != (self.n_vertices, 3) or not np.isfinite(value).all():
                raise ValueError(f"{name}: expected finite ({self.n_vertices}, 3), got {value.shape}")
            if name == "velocities":
                value = np.where(self.pinned[:, None], 0.0, value)
            target.assign(wp.array(value, dtype=vec3, device=self.device))
        if time is not None:
            self.time = float(time)

    def set_rigid_velocity(self, linear=(0.0, 0.0, 0.0), angular=(0.0, 0.0, 0.0)) -> None:
        """Velocities of a rigid motion: ``v = linear + angular x (x - centre of mass)`` [m/s, rad/s]."""
        x = self.positions
        com = self.masses @ x / self.masses.sum()
        v = np.asarray(linear, np.float64) + np.cross(np.asarray(angular, np.float64), x - com)
        self.set_state(velocities=v)

    # -- stepping ------------------------------------------------------------------------------------------

    def step(self) -> StepStats:
        """Advance one frame (``settings.dt``); redo it with more substeps if the state turns invalid
        (a tet's det F below ``min_volume_ratio``, non-finite positions, a speed above ``max_speed``), and
        raise :class:`SimulationError` with the state of the frame's start restored if every count fails."""
        s = self.settings
        start = time.perf_counter()
        wp.copy(self._x0, self._x)
        wp.copy(self._v0, self._v)
        t0 = self.time
        failures = []
        for attempt, factor in enumerate((1, *s.retry_factors)):
            if attempt:
                wp.copy(self._x, self._x0)
                wp.copy(self._v, self._v0)
                self.time = t0
            stats = StepStats(substeps=s.substeps * factor, retries=attempt)
            problem = self._run_frame(stats)
            if problem is None:
                stats.seconds = time.perf_counter() - start
                stats.notes = [f"{n} substeps: {kind} {value:.3g}" for n, (kind, value, _) in failures]
                return stats
            failures.append((stats.substeps, problem))
            log.debug("frame at t=%.4f s failed with %d substeps: %s", t0, stats.substeps, problem)
        wp.copy(self._x, self._x0)
        wp.copy(self._v, self._v0)
        self.time = t0
        kind, value, limit = failures[-1][1]
        raise SimulationError(kind, value, limit, t0, tuple(n for n, _ in failures))

    def _run_frame(self, stats: StepStats) -> tuple[str, float, float] | None:
        """Run ``stats.substeps`` substeps; return why the state is invalid, as (kind, value, limit) of
        :class:`SimulationError`, or None."""
        h = self.settings.dt / stats.substeps
        for _ in range(stats.substeps):
            problem = self._substep(h, stats)
            self.time += h
            if problem is not None:
                return problem
        return None

    def _substep(self, h: float, stats: StepStats) -> tuple[str, float, float] | None:
        s = self.settings
        dev = self.device
        n, nt = self.n_vertices, self.n_tets
        up = np.asarray(s.up, np.float64) / np.linalg.norm(s.up)
        gravity = vec3(*(-s.gravity * up))
        wp.launch(
            begin_substep,
            n,
            [self._x, self._v, self._pinned, h, gravity, self._x_prev, self._x_tilde],
            device=dev,
        )
        wp.launch(store_deformation, nt, [self._x, self._tets, self._dm_inv, self._f_prev], device=dev)
        contact = make_colliders(up, s.ground, self._collider_arrays)
        wp.launch(
            lag_friction,
            n,
            [self._x, self._mass, contact, f64(s.contact_stiffness), self._fn, self._fn_normal],
            device=dev,
        )
        terms = dict(h=h, contact=contact)

        # start from the inertial prediction plus the previous substep's correction, or from the prediction
        # alone, whichever has the lower energy and inverts no tet (else from x^n); the former, most often
        # chosen, is evaluated with its force, which Newton's first iteration then needs
        start_energy, start_weight = math.inf, None
        for weight in (0.0, 1.0):
            wp.launch(step_positions, n, [self._x_tilde, self._correction, weight, self._x_trial], device=dev)
            energy, min_det, force_norm = self._evaluate(self._x_trial, terms, FORCE if weight else ENERGY)
            if min_det > 0 and energy < math.inf and energy <= start_energy:
                wp.copy(self._x, self._x_trial)
                start_energy, start_weight = energy, weight
        if start_weight != 1.0:
            energy, min_det, force_norm = self._evaluate(self._x, terms, FORCE)
        # energy, min_det, force_norm stay those of x from here on
        # Newton stops once the step is below tol; H >= M / h^2 bounds |d| <= |force| h^2 / m_min
        tol = s.newton_tol * self.size * h
        force_tol = tol * self._min_free_mass / (h * h)
        converged = False
        iterations = 0
        forcing = Forcing(s.cg_tol, self._loosest_solve)
        moved = math.inf  # bound on how far x moved since the tets' Hessian blocks were evaluated
        while iterations < s.newton_iterations:
            iterations += 1
            if not math.isfinite(energy):
                return ("nonfinite", math.nan, math.nan)
            if force_norm <= force_tol:
                converged = True
                break
            fresh = moved > ELASTIC_HESSIAN_REUSE * tol
            self._evaluate(self._x, terms, HESSIAN, fresh_tets=fresh)
            moved = 0.0 if fresh else moved
            stats.hessians += fresh
            self._d.zero_()
            rtol = forcing.next(force_norm)
            stats.cg_iterations += self._solve(0.1 * force_tol, rtol)
            step = self._max_step()
            if step <= tol and rtol > s.cg_tol:
                # a loose solve may stop short of a step that is not small: the test takes the solve
                # finished to cg_tol (continued from where it stopped)
                stats.cg_iterations += self._solve(0.1 * force_tol, s.cg_tol)
                step = self._max_step()
            if step <= tol:
                # the step that shows convergence is paid for: take it where it lowers E and inverts no
                # tet, so x ends far closer to the minimum than tol (and the next substep starts there)
                evaluation = self._line_search(energy, min_det, terms, tries=1, order=ENERGY)
                if evaluation is not None:
                    energy, min_det, _ = evaluation
                converged = True
                break
            evaluation = self._line_search(energy, min_det, terms)
            if evaluation is None:
                break
            energy, min_det, force_norm = evaluation
            moved += step
        stats.newton_iterations += iterations
        stats.max_newton_iterations = max(stats.max_newton_iterations, iterations)
        stats.unconverged_substeps += not converged
        stats.energy = energy

        self._scalars.zero_()
        wp.launch(
            end_substep,
            n,
            [self._x, self._x_prev, self._x_tilde, 1.0 / h, self._v, self._correction, self._scalars],
            device=dev,
        )
        speed = float(self._scalars.numpy()[0])
        stats.min_volume_ratio, stats.max_speed = min_det, speed
        if not (math.isfinite(energy) and math.isfinite(speed)):
            return ("nonfinite", math.nan, math.nan)
        if not min_det >= s.min_volume_ratio:
            return ("collapse", min_det, s.min_volume_ratio)
        if speed > s.max_speed:
            return ("speed", speed, s.max_speed)
        return None

    def _max_step(self) -> float:
        """max_i |d_i| of the Newton step in ``d``."""
        self._scalars.zero_()
        wp.launch(max_length, self.n_vertices, [self._d, self._scalars], device=self.device)
        return float(self._scalars.numpy()[0])

    def _line_search(
        self, energy: float, min_det: float, terms: dict, tries: int = 12, order: int = FORCE
    ) -> tuple[float, float, float] | None:
        """Backtrack x + alpha d, alpha = 1, 1/2, ... (``tries`` values) until E decreases (and no tet inverts
        that was not); move x there and return :meth:`_evaluate` (``order``) of the new x, or None if no
        alpha does."""
        alpha = 1.0
        for _ in range(tries):
            wp.launch(
                step_positions, self.n_vertices, [self._x, self._d, alpha, self._x_trial], device=self.device
            )
            evaluation = self._evaluate(self._x_trial, terms, order)
            trial, trial_det, _ = evaluation
            if trial <= energy and (trial_det > 0 or min_det <= 0):
                wp.copy(self._x, self._x_trial)
                return evaluation
            alpha *= 0.5
        return None

    def _evaluate(
        self, x: wp.array, terms: dict, order: int, fresh_tets: bool = True
    ) -> tuple[float, float, float] | None:
        """ENERGY, FORCE: the incremental potential at ``x``, min det F and |force| (0 for ENERGY); FORCE
        fills the force. HESSIAN: only the Hessian blocks and the block-Jacobi preconditioner (None), the
        tets of each slab (:func:`partition_tets`) on a thread of their own; without ``fresh_tets`` the tets'
        blocks of the last HESSIAN evaluation are taken again (the vertices' are always evaluated at x)."""
        s, m = self.settings, self.material
        h = terms["h"]
        dev = self.device
        if order == HESSIAN:
            if not fresh_tets:
                wp.copy(self._values, self._elastic_values)
                self._vertex_terms(x, terms, order)
                return None
            self._elastic_values.zero_()
        else:
            wp.copy(self._scalars, self._scalars_init)
        if order == FORCE:
            self._force.zero_()
        lam_snh = m.lam + m.mu
        damp = s.damping / h

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
                    self._pinned,
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
        return self._vertex_terms(x, terms, order)

    def _vertex_terms(self, x: wp.array, terms: dict, order: int) -> tuple[float, float, float] | None:
        """:meth:`_evaluate`'s per-vertex terms (added to the tets' sums and blocks) and its result."""
        s, h = self.settings, terms["h"]
        wp.launch(
            vertex_terms,
            self.n_vertices,
            [
                x,
                self._x_tilde,
                self._x_prev,
                self._mass,
                self._pinned,
                1.0 / (h * h),
                s.drag / h,
                terms["contact"],
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
        s = self.settings
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
                (self._r, self._z, self._p, self._q, self._t),
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


# ----------------------------------------------------------------------------------------------------------
# Driving frames into a motion file
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class WorldMap:
    """World frame <-> simulation metres: ``x_sim = (x_world - origin) * scale`` (scale: metres per unit)."""

    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    scale: float = 1.0

    @classmethod
    def fit(cls, vertices: np.ndarray, size: float) -> WorldMap:
        """Centre the bounding box of ``vertices`` (N, 3) and map its largest extent to ``size`` metres."""
        vertices = np.asarray(vertices, np.float64)
        lo, hi = vertices.min(0), vertices.max(0)
        extent = float((hi - lo).max())
        if not (size > 0 and math.isfinite(size)):
            raise InputError(f"size: expected a positive length in metres, got {size}")
        if extent <= 0:
            raise InputError("the cage has zero extent; cannot scale it to a physical size")
        return cls(tuple(float(c) for c in (lo + hi) / 2), size / extent)

    def to_sim(self, x: np.ndarray) -> np.ndarray:
        return (np.asarray(x, np.float64) - np.asarray(self.origin)) * self.scale

    def to_world(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(x, np.float64) / self.scale + np.asarray(self.origin)


def restore_state(sim: Simulator, writer, world: WorldMap = WorldMap()) -> None:
    """Set ``sim`` to the last frame of ``writer``'s motion, written by :func:`simulate`: its positions, time
    and the velocities of its state (``state["velocities"]`` (V, 3), world units per second), so that
    :func:`simulate` continues the trajectory exactly. A missing or malformed state is an
    :class:`InputError`."""
    velocities = writer.motion.state.get("velocities")
    shape = writer.motion.rest_vertices.shape
    if velocities is None or velocities.shape != shape or not np.isfinite(velocities).all():
        raise InputError(
            f"{writer.path}: no simulation state ({shape[0]} finite velocities) after its last frame; cannot "
            "resume it"
        )
    velocities = np.asarray(velocities, np.float64) * world.scale
    sim.set_state(world.to_sim(writer.last_positions), velocities, writer.last_time)


def simulate(sim: Simulator, frames: int, writer, world: WorldMap = WorldMap(), progress: bool = True):
    """Step ``sim`` ``frames`` times, appending each frame (world coordinates) to ``writer``.

    An empty ``writer`` first gets the current state as frame 0. Each frame is appended with the state
    ``velocities`` (V, 3) float64 in world units per second (so :func:`restore_state` continues exactly),
    after ``writer.motion.meta["stats"]`` is updated.
    A frame that :meth:`Simulator.step` finds invalid (e.g. a tet
    squeezed below ``min_volume_ratio``) is not written: the :class:`SimulationError` gets its index as
    ``frame``. The writer is flushed on every exit, so an error or an interrupt keeps every frame made
    before. Returns the list of :class:`StepStats`.
    """
    from tqdm.auto import tqdm

    meta = writer.motion.meta

    def record(stats: StepStats | None):
        if stats is not None:
            total = meta.setdefault(
                "stats",
                {
                    "frames": 0,
                    "substeps": 0,
                    "newton_iterations": 0,
                    "cg_iterations": 0,
                    "retries": 0,
                    "seconds": 0.0,
                },
            )
            total["frames"] += 1
            total["substeps"] += stats.substeps
            total["newton_iterations"] += stats.newton_iterations
            total["cg_iterations"] += stats.cg_iterations
            total["retries"] += stats.retries
            total["seconds"] += stats.seconds
        velocities = np.asarray(sim.velocities, np.float64) / world.scale
        writer.append(world.to_world(sim.positions), sim.time, {"velocities": velocities})

    history = []
    try:
        if writer.n_frames == 0:
            record(None)
        with tqdm(total=frames, disable=not progress, unit="frame", desc="simulate") as bar:
            for _ in range(frames):
                try:
                    stats = sim.step()
                except SimulationError as err:
                    err.frame = writer.n_frames
                    raise
                history.append(stats)
                record(stats)
                bar.set_postfix(newton=stats.newton_iterations, cg=stats.cg_iterations, retries=stats.retries)
                bar.update()
    finally:
        writer.flush()
    return history
