"""What a simulation is about, fixed for a run (newton's ``Model``): one elastic body of linear tets (rest
shape, material, lumped masses) under gravity, and the :class:`SolverSettings` of the run.

The running state (positions, velocities, time) is a :class:`shellsim.physics.state.State`; the scripted
inputs (pinned vertices, external forces) a :class:`shellsim.physics.control.Control`; a body's terms of the
incremental potential :class:`shellsim.physics.body.BodyTerms`; the implicit step of every body with contact
:class:`shellsim.physics.solver.Solver`, frames and their checks :class:`shellsim.physics.driver.FrameDriver`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import warp as wp

from shellsim.physics.elastic import f64, mat33
from shellsim.physics.materials import Material
from shellsim.physics.state import State
from shellsim.tetcage.geometry import MIN_VOLUME_RATIO, check_tets, tet_volumes
from shellsim.world import INTEGRATORS


@dataclass(frozen=True)
class SolverSettings:
    """Settings of a simulation, SI units: the world the bodies share (gravity, damping, drag), Newton's
    method (:class:`shellsim.physics.solver.Solver`) and the frames with the checks that stop a run
    (:class:`shellsim.physics.driver.FrameDriver`). A frame lasts ``dt`` and is split into ``substeps``;
    contact (the ground, colliders, other bodies) is :class:`shellsim.physics.ipc.Contact`'s."""

    # the world
    gravity: float = 9.81  # [m/s^2], along -up
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    damping: float = 0.0  # Kelvin-Voigt beta [s]
    drag: float = 0.0  # velocity drag alpha [1/s]
    # time integration: "euler" (backward Euler) or "bdf2" (second-order backward differences)
    integrator: str = "euler"
    # Newton's method
    newton_iterations: int = 40  # at most, per substep
    newton_tol: float = 1.0e-2  # stop when max |dx| / h < newton_tol * (smallest body's diagonal) per s
    # the frames
    dt: float = 1.0 / 30.0  # frame duration [s]
    substeps: int = 8  # backward-Euler steps per frame
    retry_factors: tuple[int, ...] = (2, 4)  # substep multipliers tried after a failed frame
    max_speed: float = 100.0  # [m/s]; faster means the simulation exploded
    min_volume_ratio: float = MIN_VOLUME_RATIO  # smallest det F a frame may reach (near-degenerate tets)
    max_stretch: float = 3.0  # largest principal stretch of a tet a frame may reach
    allow_stretch: bool = False  # a frame past max_stretch is only warned about (once), not refused

    def __post_init__(self):
        for name in ("dt", "newton_tol", "max_speed"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"SolverSettings.{name} must be > 0, got {value}")
        for name in ("gravity", "damping", "drag"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"SolverSettings.{name} must be >= 0, got {value}")
        for name in ("substeps", "newton_iterations"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"SolverSettings.{name} must be >= 1, got {getattr(self, name)}")
        if self.integrator not in INTEGRATORS:
            raise ValueError(
                f"SolverSettings.integrator must be one of {', '.join(INTEGRATORS)}, got {self.integrator!r}"
            )
        up = np.asarray(self.up, dtype=np.float64)
        if up.shape != (3,) or not np.isfinite(up).all() or np.linalg.norm(up) == 0:
            raise ValueError(f"SolverSettings.up must be a non-zero 3-vector, got {self.up!r}")
        if not 0 <= self.min_volume_ratio < 1:
            raise ValueError(
                f"SolverSettings.min_volume_ratio must lie in [0, 1), got {self.min_volume_ratio}"
            )
        if not self.max_stretch > 1:
            raise ValueError(f"SolverSettings.max_stretch must be > 1, got {self.max_stretch}")
        if any(int(f) < 2 for f in self.retry_factors):
            raise ValueError(f"SolverSettings.retry_factors must be integers >= 2, got {self.retry_factors}")

    def as_dict(self) -> dict:
        return asdict(self)


class Model:
    """One elastic body of linear tets and its world; nothing in it changes after construction.

    vertices : (V, 3) rest positions [m]; tets : (T, 4) positively oriented, every vertex in one;
    material : :class:`Material`; settings : :class:`SolverSettings` (None: the defaults); device : Warp
    device (None: Warp's default).

    Attributes: ``settings``, ``material``, ``device``, ``n_vertices`` V, ``n_tets`` T, ``size`` the rest
    bounding-box diagonal [m].
    Host arrays (read-only numpy): ``rest_vertices`` (V, 3), ``tets`` (T, 4) int64, ``volumes`` (T,) rest
    volumes [m^3], ``dm_inv`` (T, 3, 3) inverse rest edge matrices ``Dm^-1`` (``Dm = [x1 - x0, x2 - x0,
    x3 - x0]``), ``masses`` (V,) lumped masses [kg] (a quarter of each tet's), ``up`` (3,) unit,
    ``gravity`` (3,) [m/s^2].
    Device arrays (Warp, on ``device``): ``masses_wp`` (V,) float64, ``tets_wp`` (T, 4) int32, ``dm_inv_wp``
    (T,) mat33d.
    """

    def __init__(
        self, vertices, tets, material: Material, settings: SolverSettings | None = None, device=None
    ):
        rest = np.array(vertices, dtype=np.float64)  # a copy: it is made read-only
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
        settings = settings or SolverSettings()
        x = rest[tets]
        dm = np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]], axis=2)
        masses = np.bincount(
            tets.ravel(), np.repeat(material.density * volumes / 4.0, 4), minlength=len(rest)
        )
        up = np.asarray(settings.up, np.float64) / np.linalg.norm(settings.up)
        dev = wp.get_device(device)
        self._set(
            settings=settings,
            material=material,
            device=dev,
            n_vertices=len(rest),
            n_tets=len(tets),
            rest_vertices=rest,
            tets=tets,
            volumes=volumes,
            dm_inv=np.linalg.inv(dm),
            masses=masses,
            up=up,
            gravity=-settings.gravity * up,
            size=float(np.linalg.norm(rest.max(0) - rest.min(0))),
        )
        self._set(
            masses_wp=wp.array(masses, dtype=f64, device=dev),
            tets_wp=wp.array(tets.astype(np.int32), dtype=wp.int32, device=dev),
            dm_inv_wp=wp.array(self.dm_inv, dtype=mat33, device=dev),
        )

    def _set(self, **values) -> None:
        for name, value in values.items():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
            object.__setattr__(self, name, value)

    def __setattr__(self, name, value):
        raise AttributeError(f"Model is immutable: cannot set {name}")

    def state(self, linear=(0.0, 0.0, 0.0), angular=(0.0, 0.0, 0.0)) -> State:
        """A :class:`State` at rest, at time 0, moving rigidly: ``v = linear + angular x (x - c)`` [m/s,
        rad/s] about the centre of mass ``c``."""
        x = self.rest_vertices
        com = self.masses @ x / self.masses.sum()
        v = np.asarray(linear, np.float64) + np.cross(np.asarray(angular, np.float64), x - com)
        return State(x, v, device=self.device)
