"""Frames of a simulation: substeps of :class:`shellsim.physics.solver.Solver` over every body, the timed
inputs of a schedule, the checks that stop a run and the retry policy. Arrays in, arrays out: no files, no
progress bars (the jobs record frames: :mod:`shellsim.jobs.recording`).

A frame of ``dt`` runs ``substeps`` solver steps. It is invalid when a step leaves a tet's det F below
``min_volume_ratio`` (:data:`shellsim.tetcage.geometry.MIN_VOLUME_RATIO`: inverted or near-degenerate), a
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
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import warp as wp

from neural.errors import ShellsimError
from shellsim.physics.control import Control
from shellsim.physics.elastic import f64, max_principal_stretch
from shellsim.physics.model import Model
from shellsim.physics.solver import Solver, SolveStats
from shellsim.physics.state import State

log = logging.getLogger(__name__)


class SimulationError(ShellsimError):
    """A frame left the valid regime with every substep count tried.

    kind : "collapse" (min det F below ``SolverSettings.min_volume_ratio``), "speed" (above ``max_speed``),
    "stretch" (the largest principal stretch above ``max_stretch``) or "nonfinite"; value : that min det F,
    speed [m/s] or stretch (nan for "nonfinite"); time : the frame's start [s]; substeps : the counts tried;
    frame : its index in the motion, set by whoever records the frames.
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
    hessians: int = 0  # Hessians assembled
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
        self.hessians += step.hessians
        self.energy = step.energy
        self.min_volume_ratio = step.min_volume_ratio
        self.max_speed = step.max_speed

    def figures(self) -> dict[str, float]:
        """The frame's figures a motion's statistics add up (``max_`` and ``min_`` ones: the extremes)."""
        return {
            "substeps": self.substeps,
            "newton_iterations": self.newton_iterations,
            "retries": self.retries,
            "unconverged_substeps": self.unconverged_substeps,
            "min_volume_ratio": self.min_volume_ratio,
            "max_stretch": self.max_stretch,
        }


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
    (:class:`shellsim.physics.model.SolverSettings`), as (kind, value, limit) of :class:`SimulationError`, or
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


class Schedule(Protocol):
    """The timed inputs of a scene (e.g. :class:`shellsim.shot.actions.Actions`)."""

    def inputs(self, t: float, h: float, positions: list, velocities: list) -> list:
        """Per body, (pinned (V,) bool, targets (V, 3), forces (V, 3)) for the substep [t, t + h]."""

    def state(self) -> dict: ...

    def restore(self, state: dict) -> None: ...


class FrameDriver:
    """Advances the bodies of ``solver`` by frames of ``settings.dt`` (``settings.substeps`` each), with
    ``schedule``'s pins and forces (None: none), checking every frame (module docstring) and retrying a
    failed one with more substeps (and warning once of a stretch it allows)."""

    def __init__(self, solver: Solver, schedule: Schedule | None = None):
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
