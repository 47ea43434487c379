"""A shot made to move: every body of a :class:`~shellsim.shot.spec.SceneSpec` built and placed
(:mod:`shellsim.shot.bodies`), its first instant checked, and one implicit solve over all of them per substep
(:class:`shellsim.physics.solver.Solver`) with incremental potential contact between the bodies' visible
surfaces, the colliders and the ground (:mod:`shellsim.physics.ipc`) and the actions' pins, grabs, pushes and
wind (:mod:`shellsim.shot.actions`). Arrays in, arrays out: the jobs record the frames
(:mod:`shellsim.jobs.recording`).

**Said before simulating**: a body whose standing column sags (:func:`shellsim.physics.sag.column_sag`) more
than :data:`SAG_WARNING` of its visible height gets one warning naming it, the sag and the ``youngs`` that
holds it to :data:`SAG_HELD`.

**Settling** (``[world] settle``, :meth:`SceneSimulation.settle`): before frame 0 the bodies move from rest
for ``settle`` seconds under gravity, contact and the pins and grabs that hold at t = 0 (as pins, where
their regions are), with no other action, and strongly damped: a body of height ``H`` whose slowest elastic
motion has the frequency scale ``omega = sqrt(E / rho) / H`` takes the Kelvin-Voigt damping ``beta = 1 /
omega`` and the drag ``alpha = min(omega, 1 / SETTLE_DRAG_TIME)`` (or the world's and its own, when they
are larger). Either alone damps that motion at half of critical (``beta omega / 2 = alpha / (2 omega) =
1/2``), both together critically, and the drag stops a rigid motion in ``1 / alpha``. Then the clock is set
back to 0, each body's ``velocity`` and ``spin`` are added to what is left of its motion, and frame 0 is the
settled state.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable

import numpy as np

from neural.errors import InputError
from shellsim.motion.format import Surface
from shellsim.physics.driver import FrameDriver, FrameStats
from shellsim.physics.ipc import BodySurface, Contact, StaticSurface
from shellsim.physics.model import Model, SolverSettings
from shellsim.physics.sag import column_sag, holding_youngs
from shellsim.physics.solver import Solver
from shellsim.shot.actions import Actions, BodyInfo
from shellsim.shot.bodies import SceneBody, build_body, check_start, collider_mesh, lowest_start
from shellsim.shot.spec import SceneSpec
from shellsim.tetcage.geometry import boundary_faces

log = logging.getLogger(__name__)

#: Prefix of the actions' state arrays in a motion's state (after the velocities).
ACTION_STATE = "action_"
#: Prefix of the integrator's memory of the last step in a motion's state (BDF2's).
SOLVER_STATE = "solver_"
#: A body whose estimated sag exceeds this fraction of its height is warned about; the ``youngs`` the
#: warning names holds it to :data:`SAG_HELD`.
SAG_WARNING = 0.10
SAG_HELD = 0.05
#: [s] While settling, a rigid motion decays at least this fast (the drag's cap, 1 / alpha).
SETTLE_DRAG_TIME = 0.05


class _Schedule:
    """:class:`shellsim.physics.driver.Schedule` of the scene's actions, bodies in order."""

    def __init__(self, actions: Actions, names: list[str]):
        self.actions, self.names = actions, names

    def inputs(self, t, h, positions, velocities):
        by_name = (
            dict(zip(self.names, positions, strict=True)),
            dict(zip(self.names, velocities, strict=True)),
        )
        got = self.actions.inputs(t, h, *by_name)
        return [(got[n].pinned, got[n].targets, got[n].forces) for n in self.names]

    def state(self) -> dict:
        return self.actions.state()

    def restore(self, state: dict) -> None:
        self.actions.restore(state)


class SceneSimulation:
    """The bodies of ``spec`` moving from t = 0 (module docstring), on the Warp ``device``.

    ``max_stretch`` and ``allow_stretch`` are the frame checks of
    :class:`shellsim.physics.model.SolverSettings`, ``newton_iterations`` its cap on a substep's Newton
    iterations (None: its default; fewer end substeps unconverged, as a live preview may). Building loads
    or builds every body's cage and collision surface (cached) and refuses a first instant where bodies
    overlap each other, a collider or the ground, or an action's region selects nothing.

    Attributes: ``bodies`` (:class:`shellsim.shot.bodies.SceneBody`), ``starts`` (B + 1,) their first
    vertex in the concatenated cage, ``rest`` (N, 3) and ``tets`` (T, 4) the concatenated rest cage [m],
    ``settings`` the solver's, ``time`` [s] of the current state.
    """

    def __init__(
        self,
        spec: SceneSpec,
        device=None,
        max_stretch: float = 3.0,
        allow_stretch: bool = False,
        newton_iterations: int | None = None,
    ):
        world = spec.world
        self.spec = spec
        self.bodies: list[SceneBody] = [build_body(b, lowest_start(world)) for b in spec.bodies]
        colliders = [collider_mesh(c) for c in spec.colliders]
        check_start(spec, self.bodies, colliders)
        self.settings = SolverSettings(
            gravity=world.gravity,
            damping=world.damping,
            drag=world.drag,
            dt=1.0 / world.fps,
            substeps=world.substeps,
            integrator=world.integrator,
            max_stretch=max_stretch,
            allow_stretch=allow_stretch,
            **({} if newton_iterations is None else {"newton_iterations": int(newton_iterations)}),
        )
        self.device = device
        self.models = models = [
            Model(
                b.rest,
                b.tets,
                b.material,
                self.settings
                if b.spec.damping is None
                else dataclasses.replace(self.settings, damping=b.spec.damping),
                device=device,
            )
            for b in self.bodies
        ]
        warn_sagging(self.bodies, world.gravity)
        self.starts = np.concatenate([[0], np.cumsum([m.n_vertices for m in models])]).astype(int)
        self.rest = np.concatenate([b.rest for b in self.bodies])
        self.tets = np.concatenate(
            [b.tets + start for b, start in zip(self.bodies, self.starts[:-1], strict=True)]
        )
        statics = [
            StaticSurface(v, f, c.friction) for (v, f), c in zip(colliders, spec.colliders, strict=True)
        ]
        self.contact = Contact(
            [
                BodySurface(b.surface.weights(len(b.rest)), b.surface.faces, b.spec.friction)
                for b in self.bodies
            ],
            self.starts[:-1],
            self.rest,
            statics,
            world.contact_gap,
            world.friction_velocity,
            world.ground_friction if world.ground else None,
        )
        self._infos = [
            BodyInfo(b.name, b.rest, m.masses, boundary_faces(b.tets))
            for b, m in zip(self.bodies, models, strict=True)
        ]
        self.actions = Actions(spec.actions, self._infos)
        names = [b.name for b in self.bodies]
        self.driver = FrameDriver(Solver(models, self.contact, self.settings), _Schedule(self.actions, names))
        self.states = [
            m.state(b.spec.velocity, b.spec.spin) for m, b in zip(models, self.bodies, strict=True)
        ]

    @property
    def time(self) -> float:
        return self.states[0].time

    def advance(self) -> FrameStats:
        """One frame of every body (:meth:`shellsim.physics.driver.FrameDriver.step`)."""
        return self.driver.step(self.states)

    @property
    def settle_frames(self) -> int:
        """Frames of :meth:`settle`: ``ceil(settle * fps)`` (0 without settling)."""
        world = self.spec.world
        return math.ceil(world.settle * world.fps - 1e-9) if world.settle > 0 else 0

    def settle(self, each_frame: Callable[[FrameStats], None] | None = None) -> dict:
        """Settle the bodies for ``[world] settle`` seconds from rest (module docstring), in frames of the
        shot's substeps (``ceil(settle * fps)`` frames), calling ``each_frame`` with each frame's stats; then
        the clock is 0 and the bodies have their velocities and spins added. Returns what the motion's meta
        records of it: ``seconds``, ``frames``, ``substeps``, per body ``damping`` [s] and ``drag`` [1/s],
        and ``max_speed`` [m/s] of the settled state ({} without settling). A frame that leaves the valid
        regime raises :class:`shellsim.physics.driver.SimulationError`."""
        world, frames = self.spec.world, self.settle_frames
        if not frames:
            return {}
        settings = dataclasses.replace(self.settings, dt=world.settle / frames)
        models, dampings, drags = [], [], []
        for body, model in zip(self.bodies, self.models, strict=True):
            beta, alpha = settle_damping(model.material, _height(body.surface_world))
            own = dataclasses.replace(
                settings, damping=max(model.settings.damping, beta), drag=max(model.settings.drag, alpha)
            )
            models.append(Model(body.rest, body.tets, body.material, own, device=self.device))
            dampings.append(own.damping)
            drags.append(own.drag)
        held = [
            dataclasses.replace(a, kind="pin", start=0.0, end=math.inf, keyframes=())
            for a in self.spec.actions
            if a.kind in ("pin", "grab") and a.start == 0
        ]
        schedule = _Schedule(Actions(held, self._infos), [b.name for b in self.bodies])
        driver = FrameDriver(Solver(models, self.contact, settings), schedule)
        for state in self.states:
            state.set(velocities=np.zeros((state.n_vertices, 3)), time=0.0)
        for _ in range(frames):
            stats = driver.step(self.states)
            if each_frame is not None:
                each_frame(stats)
        speed = 0.0
        for body, model, state in zip(self.bodies, self.models, self.states, strict=True):
            x, v = state.positions.numpy(), state.velocities.numpy()
            speed = max(speed, float(np.linalg.norm(v, axis=1).max()))
            state.set(velocities=v + _rigid(model.masses, x, body.spec.velocity, body.spec.spin), time=0.0)
        return {
            "seconds": world.settle,
            "frames": frames,
            "substeps": settings.substeps,
            "damping": dampings,
            "drag": drags,
            "max_speed": speed,
        }

    def speeds(self) -> dict[str, float]:
        """Each body's largest vertex speed [m/s] in the current state, by name."""
        return {
            b.name: float(np.linalg.norm(st.velocities.numpy(), axis=1).max())
            for b, st in zip(self.bodies, self.states, strict=True)
        }

    def snapshot(self) -> tuple[np.ndarray, float, dict]:
        """(positions (N, 3), time [s], state): the current frame and what continuing from it needs, the
        velocities (N, 3), the actions' state (prefixed :data:`ACTION_STATE`) and the integrator's memory of
        the last step (prefixed :data:`SOLVER_STATE`; BDF2's)."""
        x = np.concatenate([st.positions.numpy() for st in self.states])
        v = np.concatenate([st.velocities.numpy() for st in self.states])
        state = {
            "velocities": v,
            **{ACTION_STATE + k: a for k, a in self.actions.state().items()},
            **{SOLVER_STATE + k: a for k, a in self.driver.solver.memory().items()},
        }
        return x, self.time, state

    def restore(self, positions: np.ndarray, time: float, state: dict, source: str) -> None:
        """Continue from a :meth:`snapshot` read back from ``source`` (a motion's last frame and state); a
        missing or malformed state is an :class:`InputError` naming ``source``."""
        velocities = state.get("velocities")
        if velocities is None or velocities.shape != positions.shape or not np.isfinite(velocities).all():
            raise InputError(
                f"{source}: no simulation state ({len(positions)} finite velocities) after its last frame; "
                "cannot resume it"
            )
        for k, st in enumerate(self.states):
            a, b = self.starts[k], self.starts[k + 1]
            st.set(positions[a:b], velocities[a:b], time)
        try:
            self.actions.restore(
                {k[len(ACTION_STATE) :]: v for k, v in state.items() if k.startswith(ACTION_STATE)}
            )
            self.driver.solver.remember(
                {k[len(SOLVER_STATE) :]: v for k, v in state.items() if k.startswith(SOLVER_STATE)},
                np.concatenate([st.positions.numpy() for st in self.states]),
                np.concatenate([st.velocities.numpy() for st in self.states]),
            )
        except ValueError as err:
            raise InputError(f"{source}: {err}; cannot resume it") from None

    def surface(self) -> Surface:
        """Every body's collision surface (its visible surface) as one :class:`Surface` of the
        concatenated cage."""
        tets, bary, faces, tet_start, vertex_start = [], [], [], 0, 0
        for body in self.bodies:
            tets.append(np.asarray(body.surface.tet, np.int64) + tet_start)
            bary.append(np.asarray(body.surface.bary, np.float64))
            faces.append(np.asarray(body.surface.faces, np.int64) + vertex_start)
            tet_start += len(body.tets)
            vertex_start += len(body.surface.tet)
        return Surface(np.concatenate(tets), np.concatenate(bary), np.concatenate(faces))

    def body_records(self) -> list[dict]:
        """The motion's record of each body: name, source (the asset's name and digest, or the mesh's path
        and digest), cage digest (asset frame), placement, vertex and tet ranges in the concatenated cage."""
        records, tet_start = [], 0
        for body, start, end in zip(self.bodies, self.starts[:-1], self.starts[1:], strict=True):
            records.append(
                {
                    "name": body.name,
                    "source": body.source,
                    "cage": body.cage_digest,
                    "placement": body.placement.as_dict(),
                    "vertices": [int(start), int(end)],
                    "tets": [tet_start, tet_start + len(body.tets)],
                }
            )
            tet_start += len(body.tets)
        return records


def settle_damping(material, height: float) -> tuple[float, float]:
    """(Kelvin-Voigt ``beta`` [s], drag ``alpha`` [1/s]) that settle a body of ``material``
    (:class:`shellsim.physics.materials.Material`) and ``height`` [m] (module docstring)."""
    omega = math.sqrt(material.youngs / material.density) / max(height, 1e-6)
    return 1.0 / omega, min(omega, 1.0 / SETTLE_DRAG_TIME)


def warn_sagging(bodies: list[SceneBody], gravity: float) -> None:
    """One warning for each body whose standing column would sag more than :data:`SAG_WARNING` of its
    visible height under ``gravity`` [m/s^2] (:func:`shellsim.physics.sag.column_sag` of its cage, standing
    on its visible surface's lowest point), naming the ``youngs`` that holds it to :data:`SAG_HELD`."""
    for body in bodies:
        m, surface = body.material, body.surface_world
        height = _height(surface)
        sag = column_sag(body.rest, body.tets, m.density, m.youngs, gravity, base=surface[:, 2].min())
        if height > 0 and sag > SAG_WARNING * height:
            log.warning(
                "%s: as %s (youngs %g Pa, density %g kg/m^3) it will sag about %.0f%% of its %.3g m height "
                "under its own weight (%.2g cm, estimated before simulating); youngs = %g holds it to %.0f%%",
                body.spec.where,
                m.name,
                m.youngs,
                m.density,
                100 * sag / height,
                height,
                100 * sag,
                holding_youngs(m.youngs, sag, height, SAG_HELD),
                100 * SAG_HELD,
            )


def _height(points: np.ndarray) -> float:
    """The height [m] of ``points`` (N, 3) along z."""
    return float(np.ptp(points[:, 2]))


def _rigid(masses: np.ndarray, x: np.ndarray, linear, angular) -> np.ndarray:
    """(V, 3) ``linear + angular x (x - c)`` [m/s] at ``x`` (V, 3), ``c`` the centre of ``masses`` (V,)."""
    centre = masses @ x / masses.sum()
    return np.asarray(linear, np.float64) + np.cross(np.asarray(angular, np.float64), x - centre)
