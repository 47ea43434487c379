"""Frames of a simulation: substeps of :class:`shellsim.physics.solver.ImplicitSolver`, the checks that stop
a run, the retry policy, and writing the frames to a motion writer with a progress bar.

A frame of ``dt`` runs ``substeps`` solver steps. It is invalid when a step leaves a tet's det F below
``min_volume_ratio`` (:data:`shellsim.cage.geometry.MIN_VOLUME_RATIO`: inverted or near-degenerate), a
vertex faster than ``max_speed`` or a non-finite state, or when the frame ends with a tet stretched past
``max_stretch`` (its largest principal stretch, the largest singular value of ``F = Ds Dm^-1``); an invalid
frame is redone from its start with ``retry_factors`` times the substeps, and raises
:class:`SimulationError` when every count fails. With ``allow_stretch`` a stretched frame is kept, with one
warning per driver.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from neural.errors import InputError, ShellsimError
from shellsim.physics.control import Control
from shellsim.physics.elastic import f64, max_principal_stretch
from shellsim.physics.model import Model
from shellsim.physics.solver import ImplicitSolver, SolveStats
from shellsim.physics.state import State

log = logging.getLogger(__name__)


class SimulationError(ShellsimError):
    """A frame left the valid regime with every substep count tried.

    kind : "collapse" (min det F below ``SimSettings.min_volume_ratio``), "speed" (above ``max_speed``),
    "stretch" (the largest principal stretch above ``max_stretch``) or "nonfinite"; value : that min det F,
    speed [m/s] or stretch (nan for "nonfinite"); time : the frame's start [s]; substeps : the counts tried;
    frame : its index in the motion, set by :func:`simulate`.
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
            "stretch": f"a tet was stretched to {self.value:.3g} times its rest length (largest principal "
            f"stretch), above {self.limit:g}",
            "nonfinite": "positions became non-finite",
        }[self.kind]
        tried = ", ".join(str(n) for n in self.substeps)
        frame = "" if self.frame is None else f"frame {self.frame} "
        return f"{frame}(t = {self.time:.3f} s) is invalid with {tried} substeps: {what}"


@dataclass
class FrameStats:
    """What one :meth:`FrameDriver.step` (one frame) took."""

    substeps: int = 0  # substeps of the successful attempt
    retries: int = 0  # failed attempts before it
    newton_iterations: int = 0  # over all substeps of the successful attempt
    max_newton_iterations: int = 0  # in one substep
    unconverged_substeps: int = 0  # substeps that hit newton_iterations or stalled in the line search
    cg_iterations: int = 0
    hessians: int = 0  # Newton iterations that evaluated the tets' Hessian blocks (the rest reused them)
    min_volume_ratio: float = 1.0  # min det F at the end of the frame
    max_speed: float = 0.0  # [m/s] at the end of the frame
    max_stretch: float = 1.0  # largest principal stretch of a tet at the end of the frame
    seconds: float = 0.0  # wall time
    energy: float = 0.0  # incremental potential of the last substep's solution
    notes: list[str] = field(default_factory=list)

    def add(self, step: SolveStats) -> None:
        """Count a substep's solve in."""
        self.newton_iterations += step.newton_iterations
        self.max_newton_iterations = max(self.max_newton_iterations, step.newton_iterations)
        self.unconverged_substeps += not step.converged
        self.cg_iterations += step.cg_iterations
        self.hessians += step.hessians
        self.energy = step.energy
        self.min_volume_ratio = step.min_volume_ratio
        self.max_speed = step.max_speed


class FrameDriver:
    """Advances a :class:`State` of ``model`` by frames of ``model.settings.dt`` (module docstring) with
    ``solver`` (None: an :class:`ImplicitSolver` of the model). With ``allow_stretch`` the first frame past
    ``max_stretch`` is logged as a warning, once per driver."""

    def __init__(self, model: Model, solver: ImplicitSolver | None = None):
        self.model = model
        self.solver = solver or ImplicitSolver(model)
        self._start, self._other = model.state(), model.state()  # the frame's start; the solver's output
        self._scalars = wp.zeros(1, dtype=f64, device=model.device)
        self._stretch_warned = False

    def step(self, state: State, control: Control) -> FrameStats:
        """Advance ``state`` one frame under ``control``; redo it with more substeps while it is invalid, and
        raise :class:`SimulationError` with ``state`` back at the frame's start if every count fails."""
        s = self.model.settings
        start = time.perf_counter()
        self._start.assign(state)
        failures = []
        for attempt, factor in enumerate((1, *s.retry_factors)):
            if attempt:
                state.assign(self._start)
            stats = FrameStats(substeps=s.substeps * factor, retries=attempt)
            problem = self._run_frame(state, control, stats)
            if problem is None:
                stats.seconds = time.perf_counter() - start
                stats.notes = [f"{n} substeps: {kind} {value:.3g}" for n, (kind, value, _) in failures]
                if stats.max_stretch > s.max_stretch and not self._stretch_warned:
                    self._stretch_warned = True
                    warn_stretched(state.time, stats.max_stretch, s.max_stretch)
                return stats
            failures.append((stats.substeps, problem))
            log.debug(
                "frame at t=%.4f s failed with %d substeps: %s", self._start.time, stats.substeps, problem
            )
        state.assign(self._start)
        kind, value, limit = failures[-1][1]
        raise SimulationError(kind, value, limit, self._start.time, tuple(n for n, _ in failures))

    def max_stretch(self, state: State) -> float:
        """The largest principal stretch over the tets of ``state`` (1 at rest)."""
        return largest_stretch(self.model, state, self._scalars)

    def _run_frame(
        self, state: State, control: Control, stats: FrameStats
    ) -> tuple[str, float, float] | None:
        """Run ``stats.substeps`` substeps on ``state``; return why the frame is invalid, as (kind, value,
        limit) of :class:`SimulationError`, or None."""
        s = self.model.settings
        h = s.dt / stats.substeps
        current, other = state, self._other
        for _ in range(stats.substeps):
            step = self.solver.step(self.model, current, other, control, h)
            current, other = other, current
            stats.add(step)
            problem = substep_problem(step, s)
            if problem is not None:
                return problem
        if current is not state:
            state.assign(current)
        stats.max_stretch = self.max_stretch(state)
        if stats.max_stretch > s.max_stretch and not s.allow_stretch:
            return ("stretch", stats.max_stretch, s.max_stretch)
        return None


def largest_stretch(model: Model, state: State, scratch: wp.array) -> float:
    """The largest principal stretch over the tets of ``model`` at ``state`` (1 at rest); ``scratch`` one
    float64 on the model's device."""
    scratch.zero_()
    wp.launch(
        max_principal_stretch,
        model.n_tets,
        [state.positions, model.tets_wp, model.dm_inv_wp, scratch],
        device=model.device,
    )
    return float(scratch.numpy()[0])


def substep_problem(step: SolveStats, s) -> tuple[str, float, float] | None:
    """Why a substep's solve ``step`` leaves the valid regime of the settings ``s``
    (:class:`shellsim.physics.model.SimSettings`), as (kind, value, limit) of :class:`SimulationError`, or
    None."""
    if not (math.isfinite(step.energy) and math.isfinite(step.max_speed)):
        return ("nonfinite", math.nan, math.nan)
    if not step.min_volume_ratio >= s.min_volume_ratio:
        return ("collapse", step.min_volume_ratio, s.min_volume_ratio)
    if step.max_speed > s.max_speed:
        return ("speed", step.max_speed, s.max_speed)
    return None


def summary(history: list[FrameStats]) -> str:
    """One line of a run's frames: ms and Newton iterations per substep, retried frames."""
    substeps = max(sum(h.substeps for h in history), 1)
    return (
        f"{len(history)} frames: {1e3 * sum(h.seconds for h in history) / substeps:.1f} ms per substep, "
        f"{sum(h.newton_iterations for h in history) / substeps:.2f} Newton iterations per substep, "
        f"{sum(h.retries > 0 for h in history)} retried frames"
    )


def warn_stretched(t: float, stretch: float, limit: float) -> None:
    """The one warning of a run whose frames may pass ``max_stretch`` (``allow_stretch``)."""
    log.warning(
        "at t = %.3f s a tet is stretched to %.3g times its rest length, above %g; allowed, going on "
        "(warned once)",
        t,
        stretch,
        limit,
    )


def restore_state(state: State, writer) -> None:
    """Set ``state`` to the last frame of ``writer``'s motion, written by :func:`simulate`: its positions,
    time and the velocities of its state (``state["velocities"]`` (V, 3)), as they are, so that
    :func:`simulate` continues the trajectory exactly. A missing or malformed state is an
    :class:`InputError`."""
    velocities = writer.motion.state.get("velocities")
    shape = writer.motion.rest_vertices.shape
    if velocities is None or velocities.shape != shape or not np.isfinite(velocities).all():
        raise InputError(
            f"{writer.path}: no simulation state ({shape[0]} finite velocities) after its last frame; cannot "
            "resume it"
        )
    state.set(writer.last_positions, velocities, writer.last_time)


def simulate(
    driver: FrameDriver, state: State, control: Control, frames: int, writer, progress: bool = True
) -> list[FrameStats]:
    """Step ``state`` ``frames`` times with ``driver`` under ``control``, appending each frame to ``writer``.

    An empty ``writer`` first gets the current state as frame 0. Each frame is appended with its positions
    (V, 3) and the state ``velocities`` (V, 3) float64, as they are (so :func:`restore_state` continues
    exactly), after ``writer.motion.meta["stats"]`` is updated. A frame that :meth:`FrameDriver.step` finds
    invalid (e.g. a tet squeezed below ``min_volume_ratio``) is not written: the :class:`SimulationError`
    gets its index as ``frame``. The writer is flushed on every exit, so an error or an interrupt keeps every
    frame made before. Returns the list of :class:`FrameStats`.
    """
    from tqdm.auto import tqdm

    meta = writer.motion.meta

    def record(stats: FrameStats | None):
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
        positions, velocities = state.positions.numpy().copy(), state.velocities.numpy().copy()
        writer.append(positions, state.time, {"velocities": velocities})

    history = []
    try:
        if writer.n_frames == 0:
            record(None)
        with tqdm(total=frames, disable=not progress, unit="frame", desc="simulate") as bar:
            for _ in range(frames):
                try:
                    stats = driver.step(state, control)
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
