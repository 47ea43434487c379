"""The timed actions of a scene (pin, grab, push, wind) as what the solver takes at each substep.

:class:`Actions` turns the :class:`~shellsim.shot.spec.ActionSpec` list of a scene into, for each body and
each substep ``[t, t + h]``, the inputs of :class:`shellsim.physics.control.Control`: a pinned mask, the
pins' targets and external forces. An action acts in the substeps that overlap its window ``[start, end)``
(an impulse, ``end == start``: the substep containing ``start``):

- a pin or a grab captures its region where it is at the beginning of its first substep and holds it there,
  or moves it rigidly along its keyframes; targets are for the end of the substep, ``t + h``;
- a push's force is weighted by the substep's overlap with the window, so its impulse is exact however the
  window falls on the substeps;
- wind drags the boundary triangles by the normal component of the air's velocity relative to them.

Forces add up; where pins overlap, the action listed later holds the vertex. Plain numpy and scipy.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from shellsim.physics.selection import parse_selection
from shellsim.shot.spec import ActionSpec, SceneError

AIR_DENSITY = 1.2  # [kg/m^3]
WIND_RAMP = 0.25  # [s] the wind rises and falls smoothly over this time at the ends of its window
_TURBULENCE_MODES = 3
_TURBULENCE_HZ = 1.0  # the longest turbulence mode's frequency when the gusts have none
_EPS = 1e-6  # of a substep: times closer than this to a substep boundary are on it


@dataclass(frozen=True)
class BodyInfo:
    """What the actions need of a body: its ``name``; ``rest`` (V, 3) cage vertices where the body is at
    t = 0 [m]; ``masses`` (V,) lumped masses [kg]; ``faces`` (B, 3) int, the cage's boundary triangles,
    counter-clockwise seen from outside (for the wind)."""

    name: str
    rest: np.ndarray
    masses: np.ndarray
    faces: np.ndarray


@dataclass
class BodyInputs:
    """A body's inputs for one substep: ``pinned`` (V,) bool; ``targets`` (V, 3) where the pinned vertices
    are at the end of the substep [m] (rows of free vertices: the rest positions, ignored); ``forces``
    (V, 3) external forces [N]."""

    pinned: np.ndarray
    targets: np.ndarray
    forces: np.ndarray


class Actions:
    """The actions of a scene on its bodies.

    actions : the scene's actions, in the order of the file, in their domain (:mod:`shellsim.shot.file`);
    bodies : every body of the scene. Each region is resolved once on its body's t = 0 vertices; one that
    selects no vertex is a :class:`SceneError` naming the action's ``where``.
    """

    def __init__(self, actions: Sequence[ActionSpec], bodies: Sequence[BodyInfo]):
        self._bodies = {b.name: b for b in bodies}
        self._actions = tuple(actions)
        self._regions: dict[int, np.ndarray] = {}  # action -> (R,) vertex indices (pin, grab, push)
        self._paths: dict[int, _Path] = {}  # grab -> its poses
        self._air: dict[int, _Air] = {}  # wind -> its air
        self._anchors: dict[int, np.ndarray] = {}  # pin, grab -> (R, 3) positions captured at start
        for k, action in enumerate(self._actions):
            if action.kind == "wind":
                self._air[k] = _Air(action, seed=k)
                continue
            self._regions[k] = _region(action, self._bodies[action.body])
            if action.kind == "grab":
                self._paths[k] = _Path(action)

    def inputs(
        self, t: float, h: float, positions: dict[str, np.ndarray], velocities: dict[str, np.ndarray]
    ) -> dict[str, BodyInputs]:
        """Each body's inputs for the substep ``[t, t + h]``; called once per substep, in time order.

        positions, velocities : body name -> (V, 3) at ``t`` [m], [m/s]: where a pin or a grab captures its
        region, and what the wind's drag depends on (only the bodies these actions act on are read).
        """
        out = {
            name: BodyInputs(
                np.zeros(len(b.rest), bool), np.array(b.rest, np.float64), np.zeros((len(b.rest), 3))
            )
            for name, b in self._bodies.items()
        }
        for k, action in enumerate(self._actions):
            if not _acts(action, t, h):
                continue
            if action.kind == "wind":
                for name in self._bodies if action.body is None else (action.body,):
                    out[name].forces += self._air[k].drag(
                        self._bodies[name].faces, positions[name], velocities[name], t + 0.5 * h
                    )
                continue
            body, region = out[action.body], self._regions[k]
            if action.kind == "push":
                body.forces[region] += self._push(action, t, h, self._bodies[action.body].masses[region])
                continue
            if k not in self._anchors:
                self._anchors[k] = np.array(positions[action.body][region], np.float64)
            anchor = self._anchors[k]
            body.pinned[region] = True
            body.targets[region] = anchor if action.kind == "pin" else self._paths[k].move(anchor, t + h)
        return out

    @staticmethod
    def _push(action: ActionSpec, t: float, h: float, masses: np.ndarray) -> np.ndarray:
        """(R, 3) forces [N] of a push on its region's vertices of ``masses`` (R,) over ``[t, t + h]``."""
        if action.end == action.start:  # an impulse
            return np.outer(masses, action.velocity) / h
        fraction = (min(t + h, action.end) - max(t, action.start)) / h
        if action.force is not None:
            return np.outer(masses / masses.sum(), action.force) * fraction
        return np.outer(masses, action.velocity) * (fraction / (action.end - action.start))

    def state(self) -> dict[str, np.ndarray]:
        """What resuming needs: ``anchor_K`` (R, 3), the positions captured by the K-th action (a pin or a
        grab that has begun)."""
        return {f"anchor_{k}": a.copy() for k, a in self._anchors.items()}

    def restore(self, state: dict[str, np.ndarray]) -> None:
        """Continue from :meth:`state` of the same actions on the same bodies; anything else is a
        ``ValueError``."""
        held = {f"anchor_{k}": k for k, a in enumerate(self._actions) if a.kind in ("pin", "grab")}
        anchors = {}
        for key, value in state.items():
            k = held.get(key)
            if k is None or np.shape(value) != (len(self._regions[k]), 3):
                raise ValueError(f"actions state {key!r} {np.shape(value)}: not an anchor of these actions")
            anchors[k] = np.array(value, np.float64)
        self._anchors = anchors

    def active(self, t: float) -> list[str]:
        """One line for each action acting at time ``t`` [s] (an impulse: at its ``start``)."""
        return [_describe(a) for a in self._actions if a.start <= t < a.end or a.start == t == a.end]


def _acts(action: ActionSpec, t: float, h: float) -> bool:
    """Whether ``action`` acts in the substep ``[t, t + h]``: the substep overlaps ``[start, end)`` (a pin or
    a grab: by more than a rounding error), or contains ``start`` for an impulse."""
    eps = _EPS * h
    if action.end == action.start:
        return t <= action.start + eps < t + h
    if action.kind == "push":  # weighted by the overlap: exact without a tolerance
        return min(t + h, action.end) > max(t, action.start)
    return action.start + eps < t + h and t < action.end - eps


def _region(action: ActionSpec, body: BodyInfo) -> np.ndarray:
    """(R,) indices of the vertices of ``body`` at t = 0 that every rule of ``action.region`` selects."""
    chosen = np.ones(len(body.rest), bool)
    for text in action.region:
        rule = parse_selection(text)
        mask = rule.select(body.rest)
        if not mask.any():
            raise SceneError(
                f"{action.where} region: {text!r} selects no vertex of {body.name!r} "
                f"({_span(body, [rule.axis])})"
            )
        chosen &= mask
    if not chosen.any():
        axes = sorted({parse_selection(text).axis for text in action.region})
        raise SceneError(
            f"{action.where} region: {', '.join(map(repr, action.region))} together select no vertex of "
            f"{body.name!r} ({_span(body, axes)})"
        )
    return np.flatnonzero(chosen)


def _span(body: BodyInfo, axes: list[int]) -> str:
    """``"its vertices span x 0 .. 1, z -0.5 .. 2 m"``: where ``body`` lies at t = 0 along ``axes``."""
    lo, hi = body.rest.min(0), body.rest.max(0)
    spans = ", ".join(f"{'xyz'[a]} {lo[a]:.4g} .. {hi[a]:.4g}" for a in axes)
    return f"its vertices span {spans} m"


class _Path:
    """A grab's rigid motion: the pose (rotation, offset) at the keyframes, identity at ``start``; linear
    in the offset and spherical in the rotation between them, held after the last."""

    def __init__(self, action: ActionSpec):
        self._times = times = np.array([action.start] + [k.time for k in action.keyframes])
        self._offsets = np.array([(0.0, 0.0, 0.0)] + [k.position for k in action.keyframes])
        turns = Rotation.from_euler(
            "xyz", [(0.0, 0.0, 0.0)] + [k.rotation for k in action.keyframes], degrees=True
        )
        self._slerp = Slerp(times, turns)

    def move(self, anchor: np.ndarray, t: float) -> np.ndarray:
        """(R, 3) the captured positions ``anchor`` (R, 3) moved to the pose at time ``t`` [s]: turned about
        their centroid, then offset."""
        t = min(max(t, self._times[0]), self._times[-1])
        offset = np.array([np.interp(t, self._times, c) for c in self._offsets.T])
        turn = self._slerp(t).as_matrix()
        centre = anchor.mean(0)
        return centre + (anchor - centre) @ turn.T + offset


class _Air:
    """A wind's air velocity ``u(x, t)`` [m/s]: ``speed`` along ``direction``, times a ramp over
    :data:`WIND_RAMP` at both ends of the window and the gusts ``1 + gust sin(2 pi gust_frequency t)``, plus
    the turbulence of :mod:`shellsim.physics.wind`: :data:`_TURBULENCE_MODES` sinusoids of frequency
    ``k f`` (``f`` the gust frequency, or :data:`_TURBULENCE_HZ` when it is 0) advected with the wind
    (wavelength ``speed / (k f)``, fronts leaning by up to 27 degrees, phases from ``seed``), along the
    wind and sideways, ``|u_turbulence| <= turbulence * speed``."""

    def __init__(self, action: ActionSpec, seed: int):
        self._action = action
        self._wind = np.asarray(action.direction, np.float64) / np.linalg.norm(action.direction)
        side = np.cross((0.0, 0.0, 1.0), self._wind)
        self._side = side / np.linalg.norm(side)  # the direction is horizontal
        rng = np.random.default_rng(seed)
        self._phases = rng.uniform(0, 2 * math.pi, (2, _TURBULENCE_MODES))
        across = np.cross(self._wind, rng.normal(size=(2, _TURBULENCE_MODES, 3)))
        self._lean = (
            rng.uniform(-0.5, 0.5, (2, _TURBULENCE_MODES, 1))
            * across
            / np.linalg.norm(across, axis=-1, keepdims=True)
        )

    def envelope(self, t: float) -> float:
        """The ramp at time ``t`` [s]: 0 outside the window, rising and falling smoothly at its ends."""
        a = self._action
        ramp = min(WIND_RAMP, 0.5 * (a.end - a.start))
        tau = min(max(min(t - a.start, a.end - t) / ramp, 0.0), 1.0)
        return tau * tau * (3.0 - 2.0 * tau)

    def velocity(self, x: np.ndarray, t: float) -> np.ndarray:
        """(N, 3) the air's velocity [m/s] at the points ``x`` (N, 3) at time ``t`` [s]."""
        a = self._action
        mean = a.speed * self.envelope(t)
        gusts = 1 + a.gust * math.sin(2 * math.pi * a.gust_frequency * t)
        u = np.tile(mean * gusts * self._wind, (len(x), 1))
        if a.turbulence > 0:
            k = np.arange(1, _TURBULENCE_MODES + 1)
            wavenumber = 2 * math.pi * k * (a.gust_frequency or _TURBULENCE_HZ) / a.speed  # (M,)
            along = x @ self._wind - a.speed * t  # (N,)
            phase = wavenumber * (along[None, :, None] + np.einsum("nc,smc->snm", x, self._lean))
            weights = (1.0 / k) / (1.0 / k).sum()
            noise = np.sin(phase + self._phases[:, None, :]) @ weights  # (2, N) in [-1, 1]
            swirl = 0.8 * noise[0][:, None] * self._wind + 0.6 * noise[1][:, None] * self._side  # |.| <= 1
            u += a.turbulence * mean * swirl
        return u

    def drag(self, faces: np.ndarray, x: np.ndarray, v: np.ndarray, t: float) -> np.ndarray:
        """(V, 3) drag forces [N] at time ``t`` [s] on a body at ``x`` (V, 3) [m] moving at ``v`` (V, 3)
        [m/s]: on each face (B, 3) of area ``A`` and outward normal ``n``, with ``w`` the air's velocity at
        its centroid relative to the mean of its vertices' velocities, the pressure of the air it faces,
        ``0.5 rho C_d A (w . n)^2`` along ``-n`` where ``w . n < 0`` (nothing on the faces turned away: a
        closed body feels the drag equation's ``0.5 rho C_d A_front |w|^2``), shared equally by its
        vertices."""
        corners = np.asarray(x, np.float64)[faces]  # (B, 3, 3)
        area_normal = 0.5 * np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        area = np.linalg.norm(area_normal, axis=1)
        normal = area_normal / np.maximum(area, 1e-300)[:, None]
        w = self.velocity(corners.mean(1), t) - np.asarray(v, np.float64)[faces].mean(1)
        wn = np.minimum((w * normal).sum(1), 0.0)  # only the faces the air blows onto
        force = (0.5 * AIR_DENSITY * self._action.drag_coefficient * area * np.abs(wn) * wn)[:, None] * normal
        out = np.zeros((len(x), 3))
        np.add.at(out, faces, force[:, None, :] / 3.0)
        return out


def _describe(action: ActionSpec) -> str:
    """``"pin bunny (z<10%)"``, ``"push bunny by 0, 0, 2 m/s"``, ``"wind 5 m/s on every body"``."""
    on = action.body if action.body is not None else "every body"
    region = f" ({', '.join(action.region)})" if action.region else ""
    if action.kind == "wind":
        return f"wind {action.speed:g} m/s on {on}"
    if action.kind == "push":
        what = (
            f"by {_plain(action.velocity)} m/s"
            if action.velocity is not None
            else f"{_plain(action.force)} N"
        )
        return f"push {on}{region} {what}"
    return f"{action.kind} {on}{region}"


def _plain(v) -> str:
    return ", ".join(f"{c:g}" for c in v)
