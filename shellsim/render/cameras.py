"""Cameras for rendering motions: an orbit about the up axis that frames a set of points."""

from __future__ import annotations

import math

import numpy as np

#: Horizontal field of view of the orbit camera, degrees, and its elevation above the horizon.
ORBIT_FOV_DEG = 40.0


ORBIT_ELEVATION_DEG = 25.0


def orbit_camera(
    center,
    distance: float,
    up,
    azimuth: float,
    width: int,
    height: int,
    elevation_deg: float = ORBIT_ELEVATION_DEG,
    fov_deg: float = ORBIT_FOV_DEG,
):
    """One pinhole camera (a ``Cameras`` of length 1) at ``distance`` from ``center`` (3,), ``elevation_deg``
    above the plane normal to ``up`` (3,), at ``azimuth`` radians around ``up``, looking at ``center``
    with a horizontal field of view ``fov_deg``, imaging ``width`` x ``height`` pixels."""
    from neural.data import Cameras, look_at

    up = np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    e1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    el = math.radians(elevation_deg)
    view = math.cos(el) * (math.cos(azimuth) * e1 + math.sin(azimuth) * e2) + math.sin(el) * up
    c2w = look_at(np.asarray(center, dtype=np.float64) + distance * view, center, up)
    focal = 0.5 * width / math.tan(0.5 * math.radians(fov_deg))
    return Cameras(
        c2w[None],
        [focal],
        [focal],
        [0.5 * width],
        [0.5 * height],
        [width],
        [height],
        np.zeros((1, 4)),
        ["orbit"],
    )


def orbit_framing(points) -> tuple[np.ndarray, float]:
    """Centre (3,) and distance of an orbit that keeps ``points`` (N, 3) in view: the bounding box's
    centre and the distance at which its circumscribed sphere fills ``ORBIT_FOV_DEG`` (with 5% room)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lo, hi = points.min(axis=0), points.max(axis=0)
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    return 0.5 * (lo + hi), 1.05 * radius / math.sin(0.5 * math.radians(ORBIT_FOV_DEG))
