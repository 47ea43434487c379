"""A shot made to move: every body of a :class:`~shellsim.shot.spec.SceneSpec` built and placed
(:mod:`shellsim.shot.bodies`), its first instant checked, and one implicit solve over all of them per substep
(:class:`shellsim.physics.solver.Solver`) with incremental potential contact between the bodies' visible
surfaces, the colliders and the ground (:mod:`shellsim.physics.ipc`) and the actions' pins, grabs, pushes and
wind (:mod:`shellsim.shot.actions`). Arrays in, arrays out: the jobs record the frames
(:mod:`shellsim.jobs.recording`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from neural.errors import InputError
from shellsim.motion.format import Surface
from shellsim.physics.driver import FrameDriver, FrameStats
from shellsim.physics.ipc import BodySurface, Contact, StaticSurface
from shellsim.physics.model import Model, SolverSettings
from shellsim.physics.solver import Solver
from shellsim.shot.actions import Actions, BodyInfo
from shellsim.shot.bodies import SceneBody, build_body, check_start, collider_mesh, lowest_start
from shellsim.shot.spec import SceneSpec
from shellsim.tetcage.geometry import boundary_faces

#: Prefix of the actions' state arrays in a motion's state (after the velocities).
ACTION_STATE = "action_"


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
            max_stretch=max_stretch,
            allow_stretch=allow_stretch,
            **({} if newton_iterations is None else {"newton_iterations": int(newton_iterations)}),
        )
        models = [
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
        names = [b.name for b in self.bodies]
        self.actions = Actions(
            spec.actions,
            [
                BodyInfo(b.name, b.rest, m.masses, boundary_faces(b.tets))
                for b, m in zip(self.bodies, models, strict=True)
            ],
        )
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

    def snapshot(self) -> tuple[np.ndarray, float, dict]:
        """(positions (N, 3), time [s], state): the current frame and what continuing from it needs, the
        velocities (N, 3) and the actions' state (prefixed :data:`ACTION_STATE`)."""
        x = np.concatenate([st.positions.numpy() for st in self.states])
        v = np.concatenate([st.velocities.numpy() for st in self.states])
        state = {"velocities": v, **{ACTION_STATE + k: a for k, a in self.actions.state().items()}}
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
