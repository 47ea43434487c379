"""The world of a shot: metres, z up, the ground at z = 0, and where each body lies in it.

Everything a user types or reads about the world is in this frame: obstacles, absolute pin and anchor
rules, drop heights, velocities, and the positions a motion stores. An asset lives in its own frame (the
dataset's coordinates, where its field, shells and rest cage are); a :class:`Placement` (a similarity:
uniform scale, rotation, translation) puts it into the world. :func:`place_on_ground` makes the usual one:
the asset's up axis turned onto +z, its largest extent scaled to a size in metres, its lowest point at a
given height above the ground and its bounding box centred over the origin. Rendering maps world points back
through the inverse (:meth:`Placement.to_asset`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from neural.errors import InputError

#: Height of the ground plane (metres); the world's up axis.
GROUND_Z = 0.0
UP = (0.0, 0.0, 1.0)
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
