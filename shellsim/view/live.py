"""Live mode of the viewer: a scene's solver stepping frame after frame on coarse cages, and pokes.

:class:`LiveShot` is :class:`shellsim.shot.simulation.SceneSimulation` on a :func:`live_spec` of the scene:
every body's cage coarsened to about :data:`LIVE_TETS` tets (fTetWild, once, cached like any cage: the first
live start of a scene builds them and may take a minute), contact and the ground as in the scene, and of
its actions only the pins, held for as long as the live shot runs (the grabs, pushes and wind are the
shot's timed script; live, the user's hand replaces them). :meth:`LiveShot.step` advances one frame.

A **poke** is newton's picking (``newton/_src/viewer/picking.py``) on a cage: a spring from a material
point of a body (picked on its surface, embedded once in the tet of the deformed cage that holds it) to the
cursor's world point ``c``. With ``p``, ``v`` the point's position and velocity and ``M`` the body's mass,

    a = k (c - p) - d v,    a capped at |a| <= a_max g,    F = M a,

so the gains are accelerations, the same for a light body and a heavy one (:class:`PokeSettings`). ``F`` is
spread on the 4 vertices of the point's tet by its barycentric weights (clipped to [0, 1]) and enters the
implicit step as an external force (:class:`shellsim.physics.control.Control`), recomputed every substep.
A finished poke is a :class:`PokeRecord` that :meth:`LiveShot.push_action` turns into the scene's ``push``
action: a box of selection rules around the point where it was at t = 0, the poke's window and its mean
force.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shellsim.physics.driver import FrameStats, SimulationError
from shellsim.shot.spec import ActionSpec, SceneSpec
from shellsim.tetcage.build import CageConfig

log = logging.getLogger(__name__)

#: Tets a live cage aims for (fTetWild lands within a factor 1.5: about 1,500 to 1,800 for the LEGO and
#: the furry bunny).
LIVE_TETS = 1200
#: Least dilation of a live cage around M+ (relative to its bounding-box diagonal): fTetWild's envelope
#: follows the margin, and a cage as tight as the shot's (0.02) needs some 5,000 tets however few it aims for.
LIVE_MARGIN = 0.05
#: Substeps per live frame and Newton iterations per substep at most. On 2 CPU cores, a poke held on the
#: furry bunny / the LEGO resting on it (``examples/scenes/lego_on_bunny.toml``, live cages of 1,799 and
#: 1,602 tets) runs at 7.2-8.8 / 9.4-10.0 frames/s with these, 13.5 / 17.7 with 1 substep (which strays: a
#: pulled cantilever's point drifts sideways in tests/test_view_live.py's scene), 4.2 / 7.4 with 2 substeps
#: converged (``bench/live_bench.py``); most of an iteration is the Newton system's factorisation.
LIVE_SUBSTEPS = 2
LIVE_NEWTON_ITERATIONS = 3
#: Half-width of a recorded push's region, relative to the body's largest extent at t = 0.
REGION_FRACTION = 0.08
STANDARD_GRAVITY = 9.81  # [m/s^2]


@dataclass(frozen=True)
class PokeSettings:
    """The spring of a poke, newton's picking defaults: ``stiffness`` [1/s^2] acceleration per metre
    between the point and the cursor, ``damping`` [1/s] per m/s of the point, ``max_acceleration`` the cap
    on ``|a|`` in multiples of g (the force is at most ``max_acceleration * g * M``); ``max_strain`` caps the
    force at ``max_strain * E * l^2`` too (``E`` the body's Young's modulus, ``l`` the edge of a regular tet
    of the picked tet's volume): a point load strains the material around it by about ``F / (E l^2)``, so a
    jelly body is pulled out of shape, not torn, while a stiff one moves as a whole."""

    stiffness: float = 50.0
    damping: float = 5.0
    max_acceleration: float = 5.0
    max_strain: float = 0.5

    def __post_init__(self):
        for key in ("stiffness", "damping", "max_acceleration", "max_strain"):
            value = getattr(self, key)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{key}: expected a finite number >= 0, got {value!r}")


def spring_force(
    point, velocity, target, mass: float, settings: PokeSettings, max_force: float = math.inf
) -> np.ndarray:
    """(3,) the poke's force [N] (module docstring) on a point at ``point`` (3,) [m] moving at ``velocity``
    (3,) [m/s], pulled toward ``target`` (3,) [m], on a body of ``mass`` [kg]: ``|F| <= max_acceleration g
    mass`` and ``<= max_force`` [N]."""
    a = settings.stiffness * (np.asarray(target, np.float64) - point) - settings.damping * np.asarray(
        velocity, np.float64
    )
    force = mass * a
    cap = min(settings.max_acceleration * STANDARD_GRAVITY * mass, max_force)
    norm = float(np.linalg.norm(force))
    if norm > cap:
        force *= cap / norm
    return force


def strain_cap(youngs: float, tet_volume: float, max_strain: float) -> float:
    """[N] the largest poke force on a tet of ``tet_volume`` [m^3] of a material of Young's modulus
    ``youngs`` [Pa]: ``max_strain * E * l^2``, ``l`` the edge of the regular tet of that volume."""
    edge = (6.0 * math.sqrt(2.0) * tet_volume) ** (1.0 / 3.0)
    return max_strain * youngs * edge * edge


def live_spec(
    spec: SceneSpec,
    target_tets: int = LIVE_TETS,
    margin: float = LIVE_MARGIN,
    substeps: int | None = None,
    actions: str = "pins",
) -> SceneSpec:
    """``spec`` for live mode: each body's cage aiming for at most ``target_tets`` tets with at least
    ``margin`` (a mesh body's cage stays undilated), ``substeps`` per frame (None: the scene's), and of the
    actions ``"pins"`` (held from t = 0 for ever), ``"all"`` (the shot's, on its clock) or ``"none"``."""
    if actions not in ("pins", "all", "none"):
        raise ValueError(f"actions: expected 'pins', 'all' or 'none', got {actions!r}")
    default = CageConfig()
    bodies = tuple(
        dataclasses.replace(
            b,
            cage=dataclasses.replace(
                b.cage,
                target_tets=min(b.cage.target_tets or default.target_tets, target_tets),
                margin=max(b.cage.margin if b.cage.margin is not None else default.margin, margin),
            ),
        )
        for b in spec.bodies
    )
    kept = spec.actions
    if actions == "pins":
        kept = tuple(dataclasses.replace(a, start=0.0, end=math.inf) for a in spec.actions if a.kind == "pin")
    elif actions == "none":
        kept = ()
    world = spec.world if substeps is None else dataclasses.replace(spec.world, substeps=int(substeps))
    return dataclasses.replace(spec, world=world, bodies=bodies, actions=kept)


@dataclass
class _Spring:
    """A poke being held: ``body`` (index), ``corners`` (4,) its tet's vertices (the body's numbering),
    ``weights`` (4,) the point's barycentric coordinates, ``rest`` (3,) where the point is at t = 0 [m],
    ``picked`` (3,) the world point it was picked at, ``target`` (3,) the cursor [m]; since ``start`` [s] it
    gave ``impulse`` (3,) [N s] over ``duration`` [s]; ``max_force`` [N] its material cap
    (:func:`strain_cap`); ``force`` (3,) [N] of the last substep."""

    body: int
    corners: np.ndarray
    weights: np.ndarray
    rest: np.ndarray
    picked: np.ndarray
    target: np.ndarray
    start: float
    impulse: np.ndarray
    max_force: float = math.inf
    duration: float = 0.0
    force: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))


@dataclass(frozen=True)
class PokeRecord:
    """A finished poke: on ``body`` (its name), at the material point that was at ``point`` (3,) [m] at
    t = 0, from ``start`` to ``end`` [s] on the live clock, with the mean ``force`` (3,) [N] over that
    window; ``reach`` [m] the half-width of a box around ``point`` that holds its tet's cage vertices."""

    body: str
    point: tuple[float, float, float]
    start: float
    end: float
    force: tuple[float, float, float]
    reach: float


class _LiveSchedule:
    """The scene's schedule (:class:`shellsim.physics.driver.Schedule`) plus the poke's spring."""

    def __init__(self, inner, shot: LiveShot):
        self.inner, self.shot = inner, shot
        self._saved = None

    def inputs(self, t, h, positions, velocities):
        out = self.inner.inputs(t, h, positions, velocities)
        spring = self.shot._spring
        if spring is None:
            return out
        k = spring.body
        pinned, targets, forces = out[k]
        p = spring.weights @ positions[k][spring.corners]
        v = spring.weights @ velocities[k][spring.corners]
        force = spring_force(
            p, v, spring.target, self.shot.masses[k], self.shot.poke_settings, spring.max_force
        )
        forces = np.array(forces, np.float64)
        forces[spring.corners] += spring.weights[:, None] * force
        out[k] = (pinned, targets, forces)
        spring.impulse = spring.impulse + h * force
        spring.duration += h
        spring.force = force
        return out

    def state(self) -> dict:
        spring = self.shot._spring
        self._saved = None if spring is None else (spring, spring.impulse.copy(), spring.duration)
        return self.inner.state()

    def restore(self, state: dict) -> None:
        if self._saved is not None and self._saved[0] is self.shot._spring:
            spring, spring.impulse, spring.duration = self._saved[0], self._saved[1].copy(), self._saved[2]
        self.inner.restore(state)


class LiveShot:
    """The bodies of ``spec`` moving live (module docstring), on the Warp ``device``.

    target_tets, margin, substeps, actions : :func:`live_spec`'s; poke : the spring's
    :class:`PokeSettings`; newton_iterations : at most this many per substep (None: the solver's 40), a
    substep that needs more carries on unconverged (``stats.unconverged_substeps``; contact's continuous
    collision detection still bounds every step, so nothing passes through anything). ``substeps`` None
    and ``newton_iterations`` None simulate as the scene's shot does, 3 to 4 times slower. A live frame is
    never stopped for a stretched tet (it is warned of once); a frame that fails with every substep count
    (:class:`SimulationError`) is logged, the poke released and the bodies left where they were.

    Attributes: ``spec`` (the live spec), ``simulation`` (:class:`SceneSimulation`), ``names`` the bodies,
    ``masses`` (B,) [kg] their masses, ``stats`` the last frame's :class:`FrameStats`, ``time`` [s].
    """

    def __init__(
        self,
        spec: SceneSpec,
        *,
        target_tets: int = LIVE_TETS,
        margin: float = LIVE_MARGIN,
        substeps: int | None = LIVE_SUBSTEPS,
        actions: str = "pins",
        poke: PokeSettings | None = None,
        newton_iterations: int | None = LIVE_NEWTON_ITERATIONS,
        device=None,
    ):
        from shellsim.shot.simulation import SceneSimulation

        self.spec = live_spec(spec, target_tets, margin, substeps, actions)
        self.poke_settings = poke or PokeSettings()
        start = time.perf_counter()
        log.info(
            "live mode: cages of about %d tets for %s, built by fTetWild once and cached (the first live "
            "start of a scene may take a minute or two)",
            target_tets,
            ", ".join(b.name for b in spec.bodies),
        )
        self.simulation = SceneSimulation(
            self.spec, device=device, allow_stretch=True, newton_iterations=newton_iterations
        )
        sim = self.simulation
        self.names = [b.name for b in sim.bodies]
        self.masses = [float(m.masses.sum()) for m in sim.driver.solver.models]
        log.info(
            "live mode ready in %.1f s: %s; %d substeps per frame at %g fps",
            time.perf_counter() - start,
            ", ".join(f"{b.name} {len(b.tets)} tets" for b in sim.bodies),
            self.spec.world.substeps,
            self.spec.world.fps,
        )
        sim.driver.schedule = _LiveSchedule(sim.driver.schedule, self)
        self._spring: _Spring | None = None
        self._display: dict[int, tuple] = {}
        self._initial = sim.snapshot()
        self.stats: FrameStats | None = None

    # -- the clock ---------------------------------------------------------------------------------------

    @property
    def time(self) -> float:
        return self.simulation.time

    def step(self) -> list[np.ndarray]:
        """Advance one frame; returns each body's cage vertices (V_b, 3) [m] in the world."""
        try:
            self.stats = self.simulation.advance()
        except SimulationError as err:
            log.warning("live frame not taken: %s; the poke is released", err)
            self.release()
        return self.positions()

    def positions(self) -> list[np.ndarray]:
        """Each body's current cage vertices (V_b, 3) [m]."""
        return [st.positions.numpy() for st in self.simulation.states]

    def reset(self) -> None:
        """Back to t = 0, at rest where the scene places the bodies; a poke is released."""
        self._spring = None
        self.simulation.restore(*self._initial, source="the live shot's start")

    # -- what the viewer draws ---------------------------------------------------------------------------

    def body_index(self, body: str | int) -> int:
        """The index of ``body`` (a name or an index); anything else is a ``ValueError`` naming it."""
        if isinstance(body, int | np.integer) and not isinstance(body, bool) and 0 <= body < len(self.names):
            return int(body)
        if isinstance(body, str) and body in self.names:
            return self.names.index(body)
        raise ValueError(f"body: {body!r} is not a body of this scene ({', '.join(self.names)})")

    def display_mesh(self, body: str | int) -> tuple[np.ndarray, np.ndarray]:
        """(vertices (P, 3) [m] at t = 0, faces (F, 3)) of the body's display mesh: an asset's M+, a mesh
        body's own mesh, placed in the world; embedded in the live cage on first use."""
        k = self.body_index(body)
        if k not in self._display:
            from shellsim.tetcage.embed import embed_points

            b = self.simulation.bodies[k]
            if b.spec.asset is not None:
                from neural.asset import load_asset

                mesh = load_asset(b.spec.asset).outer_mesh()
            else:
                from neural.asset import load_mesh

                mesh = load_mesh(Path(b.spec.mesh))
            vertices = b.placement.to_world(np.asarray(mesh.vertices, np.float64))
            tet, bary = embed_points(b.rest, b.tets, vertices)
            self._display[k] = (vertices, np.asarray(mesh.faces, np.int64), tet, bary)
        vertices, faces, _, _ = self._display[k]
        return vertices, faces

    def display_positions(self, body: str | int) -> np.ndarray:
        """(P, 3) [m] the body's display mesh vertices where its cage is now."""
        from shellsim.tetcage.embed import interpolate

        k = self.body_index(body)
        self.display_mesh(k)
        _, _, tet, bary = self._display[k]
        st = self.simulation.states[k]
        return interpolate(st.positions.numpy(), self.simulation.bodies[k].tets, tet, bary)

    # -- pokes -------------------------------------------------------------------------------------------

    def poke(self, body: str | int, point, target) -> None:
        """Pull ``body`` at the world ``point`` (3,) [m] (on its surface, where the body is now) toward
        ``target`` (3,) [m]. Called again with the same body and point, it moves the target only; with
        another, the poke held so far is released first."""
        k = self.body_index(body)
        point, target = _vector("point", point), _vector("target", target)
        spring = self._spring
        if spring is not None and spring.body == k and np.array_equal(spring.picked, point):
            spring.target = target
            return
        if spring is not None:
            self.release()
        from shellsim.tetcage.embed import embed_points
        from shellsim.tetcage.geometry import tet_volumes

        b = self.simulation.bodies[k]
        now = self.simulation.states[k].positions.numpy()
        tet, bary = embed_points(now, b.tets, point[None])
        weights = np.clip(bary[0], 0.0, 1.0)  # a point just outside its tet: onto the tet
        weights /= weights.sum()
        corners = b.tets[tet[0]]
        volume = float(tet_volumes(b.rest, b.tets[tet]).item())
        self._spring = _Spring(
            body=k,
            corners=corners,
            weights=weights,
            rest=weights @ b.rest[corners],
            picked=point,
            target=target,
            start=self.time,
            impulse=np.zeros(3),
            max_force=strain_cap(b.material.youngs, volume, self.poke_settings.max_strain),
        )

    def move(self, target) -> None:
        """Move the held poke's target to ``target`` (3,) [m]; nothing when no poke is held."""
        if self._spring is not None:
            self._spring.target = _vector("target", target)

    def spring(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(the picked point where it is now (3,), the target (3,)) [m], the line to draw; None without a
        poke."""
        spring = self._spring
        if spring is None:
            return None
        now = self.simulation.states[spring.body].positions.numpy()
        return spring.weights @ now[spring.corners], spring.target.copy()

    def spring_force(self) -> np.ndarray | None:
        """(3,) [N] the poke's force in the last substep (None without a poke)."""
        return None if self._spring is None else self._spring.force.copy()

    def release(self) -> PokeRecord | None:
        """End the poke; its :class:`PokeRecord` (None when none was held or it lasted no substep)."""
        spring, self._spring = self._spring, None
        if spring is None or spring.duration <= 0:
            return None
        b = self.simulation.bodies[spring.body]
        reach = max(
            REGION_FRACTION * float(np.ptp(b.rest, axis=0).max()),
            float(np.abs(b.rest[spring.corners] - spring.rest).max()),
        )
        return PokeRecord(
            body=b.name,
            point=tuple(float(c) for c in spring.rest),
            start=spring.start,
            end=spring.start + spring.duration,
            force=tuple(float(c) for c in spring.impulse / spring.duration),
            reach=reach,
        )

    def push_action(self, record: PokeRecord) -> ActionSpec:
        """The scene's ``push`` action of ``record``: its mean force over its window on the cage vertices
        within ``reach`` of the point at t = 0 (six selection rules, world metres, widened to 0.1 mm). A
        poke that began after the shot's end is a ``ValueError``: reset the live shot and poke within it."""
        duration = self.spec.world.duration
        if not record.start < duration:
            raise ValueError(
                f"the poke began at t = {record.start:.3f} s, after the shot's end ({duration:g} s); "
                "reset the live shot and poke within the shot to record it"
            )
        return ActionSpec(
            kind="push",
            start=round(record.start, 6),
            end=round(record.end, 6),
            body=record.body,
            region=region_rules(np.asarray(record.point), record.reach),
            force=tuple(round(f, 6) for f in record.force),
        )


def region_rules(point: np.ndarray, reach: float, resolution: float = 1e-4) -> tuple[str, ...]:
    """Selection rules (:mod:`shellsim.physics.selection`) of the box ``point`` (3,) +- ``reach`` [m], its
    bounds rounded outward to ``resolution`` [m]."""
    rules = []
    for axis, c in zip("xyz", point, strict=True):
        lo = math.floor((c - reach) / resolution) * resolution
        hi = math.ceil((c + reach) / resolution) * resolution
        rules += [f"{axis} >= {lo:.4f}", f"{axis} <= {hi:.4f}"]
    return tuple(rules)


def _vector(name: str, value) -> np.ndarray:
    value = np.asarray(value, np.float64)
    if value.shape != (3,) or not np.isfinite(value).all():
        raise ValueError(f"{name}: expected 3 finite numbers [x, y, z] [m], got {value!r}")
    return value
