"""The world of a shot: metres, z up, the ground at z = 0, and where each body lies in it.

Everything a user types or reads about the world is in this frame: obstacles, absolute pin and anchor
rules, drop heights, velocities, and the positions a motion stores. An asset lives in its own frame (the
dataset's coordinates, where its field, shells and rest cage are); a :class:`Placement` (a similarity:
uniform scale, rotation, translation) puts it into the world. :func:`place_on_ground` makes the usual one:
the asset's up axis turned onto +z, its largest extent scaled to a size in metres, its lowest point at a
given height above the ground and its bounding box centred over the origin. Rendering maps world points back
through the inverse (:meth:`Placement.to_asset`); a :class:`Placement` is also the frame of a field drawn in
the world (:class:`neural.render.bodies.FieldBody`). :class:`WorldLook` is how the world looks in the frames
(the ground's checker, the light, the sky, the colliders' colour); :mod:`shellsim.film.ground` draws it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from neural.errors import InputError

#: Height of the ground plane (metres); the world's up axis.
GROUND_Z = 0.0
UP = (0.0, 0.0, 1.0)
#: How the world's time advances, a simulation's step: backward Euler (first order: it damps motion
#: numerically, and a rubber ball's bounce dies with it) or BDF2 (second order: far less numerical damping at
#: the same step).
INTEGRATORS = ("euler", "bdf2")
#: Named views of the world: (azimuth, elevation) in degrees of the direction from what is viewed to the
#: camera, the azimuth about up from +x towards +y; None: the camera's own elevation. The presets of a
#: motion's camera (:class:`shellsim.film.cameras.CameraSettings`) and of a scene file's ``[[camera]]``.
CAMERA_PRESETS = {
    "front": (-90.0, 0.0),
    "side": (0.0, 0.0),
    "top": (-90.0, 90.0),
    "three-quarter": (-45.0, None),
}
#: Metres per unit of a mesh file's coordinates (a mesh body's or collider's ``units``).
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "ft": 0.3048}
#: Size in metres of a body's largest extent when none is given.
BODY_SIZE = 0.3


def has_ground(settings: dict) -> bool:
    """Whether the motion whose producer's ``settings`` these are has a ground at z = 0: a simulation records
    ``drop_height`` None when made without one; a wind animation's body stands on it."""
    return settings.get("drop_height", 0.0) is not None


def up_rotation(up) -> np.ndarray:
    """(3, 3) the smallest rotation R with R @ up = +z (half a turn about x for up = -z)."""
    u = np.asarray(up, np.float64)
    u = u / np.linalg.norm(u)
    z = np.array(UP)
    v, c = np.cross(u, z), float(u @ z)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k / (1.0 + c)


@dataclass(frozen=True)
class Placement:
    """``x_world = scale * rotation @ x_asset + translation``: scale in metres per asset unit, rotation (3, 3)
    orthonormal with determinant +1, translation (3,) in metres."""

    scale: float = 1.0
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        r = np.asarray(self.rotation, np.float64)
        t = np.asarray(self.translation, np.float64)
        if not (isinstance(self.scale, int | float) and math.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"scale: expected a positive number of metres per unit, got {self.scale!r}")
        if r.shape != (3, 3) or not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
            raise ValueError(f"rotation: expected a (3, 3) rotation matrix, got {r.tolist()}")
        if t.shape != (3,) or not np.isfinite(t).all():
            raise ValueError(f"translation: expected 3 finite numbers, got {t.tolist()}")
        object.__setattr__(self, "scale", float(self.scale))
        object.__setattr__(self, "rotation", r)
        object.__setattr__(self, "translation", t)

    def to_world(self, x) -> np.ndarray:
        """(..., 3) asset-frame points -> world metres (float64)."""
        return self.scale * np.asarray(x, np.float64) @ self.rotation.T + self.translation

    def to_asset(self, x) -> np.ndarray:
        """(..., 3) world points -> the asset's frame (float64); the inverse of :meth:`to_world`."""
        return (np.asarray(x, np.float64) - self.translation) @ self.rotation / self.scale

    def as_dict(self) -> dict:
        """JSON form, kept in a motion's header."""
        return {
            "scale": self.scale,
            "rotation": self.rotation.tolist(),
            "translation": self.translation.tolist(),
        }

    @classmethod
    def from_dict(cls, record: dict, source: str) -> Placement:
        """The placement a motion's header records; an :class:`InputError` naming ``source`` if malformed.
        An empty record is the identity (motions made before the world was in metres)."""
        if not record:
            return cls()
        try:
            return cls(record["scale"], np.array(record["rotation"]), np.array(record["translation"]))
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"{source}: malformed placement in its header ({err})") from None


def place_on_ground(vertices, up=UP, size: float | None = BODY_SIZE, height: float = 0.0, scale=None):
    """The :class:`Placement` of a body whose asset-frame points are ``vertices`` (V, 3): ``up`` (3,) turned
    onto +z, scaled so its largest extent measures ``size`` metres (or by ``scale`` metres per unit when
    ``size`` is None), its lowest point at z = ``height`` and its bounding box centred over x = y = 0."""
    v = np.asarray(vertices, np.float64)
    rotation = up_rotation(up)
    turned = v @ rotation.T
    lo, hi = turned.min(0), turned.max(0)
    if size is not None:
        scale = size / float((hi - lo).max())
    centre = 0.5 * (lo + hi) * scale
    translation = np.array([-centre[0], -centre[1], height - lo[2] * scale])
    return Placement(float(scale), rotation, translation)


def describe_placement(name: str, placement: Placement, world_vertices) -> str:
    """One log line: the extent in metres of the body's ``world_vertices`` (N, 3; its visible surface, or its
    cage), its lowest point and the ground."""
    w = np.asarray(world_vertices, np.float64)
    lo, hi = w.min(0), w.max(0)
    extent = " x ".join(f"{e:.3f}" for e in hi - lo)
    return (
        f"{name}: placed in the world (metres, z up, ground at z = {GROUND_Z:g}): extent {extent} m "
        f"(x, y, z), {placement.scale:.6g} m per asset unit; spans x {lo[0]:.3f}..{hi[0]:.3f}, "
        f"y {lo[1]:.3f}..{hi[1]:.3f}; lowest point at z = {lo[2]:.3f}, top at z = {hi[2]:.3f}"
    )


def _colour(name: str, value) -> tuple[float, float, float]:
    """``value`` as an RGB triple in [0, 1]; else a ValueError naming ``name``."""
    rgb = tuple(float(v) for v in np.asarray(value, np.float64).reshape(-1))
    if len(rgb) != 3 or not all(0.0 <= v <= 1.0 for v in rgb):
        raise ValueError(f"{name}: expected 3 numbers in [0, 1], got {value!r}")
    return rgb


@dataclass(frozen=True)
class WorldLook:
    """How the world behind a body looks: settings only (recorded with every frame), drawn by
    :mod:`shellsim.film.ground`.

    ground : draw the ground plane z = 0 (else only the sky)
    square : side of the checker's squares in metres (the ground's scale)
    ground_colors : the checker's two RGB colours in [0, 1]
    light : (3,) direction toward the directional light in world coordinates (any length, z > 0 lights the
        ground from above)
    ambient, diffuse : the sky's and the light's share of a lit ground point's brightness
    shadows : shadow rays through the field (else the light is never blocked)
    zenith, horizon : RGB of the sky straight up and at the horizon (and below it)
    obstacle_color : RGB albedo of the static obstacles (boxes, spheres)
    """

    ground: bool = True
    square: float = 0.1
    ground_colors: tuple = ((0.82, 0.82, 0.80), (0.62, 0.63, 0.62))
    light: tuple = (0.35, 0.5, 1.0)
    ambient: float = 0.35
    diffuse: float = 0.65
    shadows: bool = True
    zenith: tuple = (0.62, 0.74, 0.90)
    horizon: tuple = (0.93, 0.94, 0.96)
    obstacle_color: tuple = (0.78, 0.52, 0.36)

    def __post_init__(self):
        if not (math.isfinite(self.square) and self.square > 0):
            raise ValueError(f"square: expected a positive number of metres, got {self.square!r}")
        colors = np.asarray(self.ground_colors, np.float64)
        if colors.shape != (2, 3):
            raise ValueError(f"ground_colors: expected two RGB colours, got {self.ground_colors!r}")
        object.__setattr__(self, "ground_colors", tuple(_colour("ground_colors", c) for c in colors))
        light = tuple(float(v) for v in np.asarray(self.light, np.float64).reshape(-1))
        if len(light) != 3 or not np.isfinite(light).all() or np.linalg.norm(light) == 0:
            raise ValueError(f"light: expected a non-zero direction x, y, z, got {self.light!r}")
        object.__setattr__(self, "light", light)
        for name in ("ambient", "diffuse"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name}: expected a number >= 0, got {value!r}")
        for name in ("zenith", "horizon", "obstacle_color"):
            object.__setattr__(self, name, _colour(name, getattr(self, name)))

    def light_unit(self) -> np.ndarray:
        """(3,) unit direction toward the light (world)."""
        light = np.asarray(self.light, np.float64)
        return light / np.linalg.norm(light)
