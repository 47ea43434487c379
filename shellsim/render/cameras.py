"""Rendering an asset at rest and deformed by a motion of its cage (paper Sec. 5, DESIGN.md step 7).

Images are made by the one pipeline of :mod:`neural.render.view` (sample, optional map to rest space,
shade); this module supplies, for one frame with cage vertices ``p`` (V, 3), the deformed sampler and the map
to rest space. :class:`DeformedRenderer`

1. **deforms the shells**: every ``M+`` / ``M-`` vertex is the barycentric interpolation of ``p`` in its
   rest tet (:func:`shellsim.deform.inverse_map.deform_points`, as :meth:`~neural.render.raycast.WarpCaster.refit_blended`
   computes it in a Warp kernel); the BVHs of their Warp meshes, built once from the rest shells, are
   refitted, and meanwhile the inverse map (:class:`shellsim.deform.inverse_map.InverseMap`) is updated to the frame;
2. **samples**: casts the camera rays against the deformed shells and places samples in the deformed narrow
   band (Procedure 3, the asset's ``NarrowBandConfig`` in world units);
3. **maps** every sample back to rest space: ``x_rest = Phi^-1(x)``, the ray direction by finite
   differences ``d_rest = normalize(Phi^-1(x + eps d) - Phi^-1(x))`` and the local stretch
   ``|Phi^-1(x + eps d) - Phi^-1(x)| / eps``, which turns a deformed section of length ``delta`` into a
   rest-space one of length ``stretch * delta`` (:meth:`InverseMap.map_rays`). Samples outside the deformed
   cage (``inside = False``) are dropped: the cage contains everything the field shows;
4. **shades** the rest-space samples with the field and composites them along the deformed rays (Eq. 2-3),
   over the asset's background.

With no cage positions it renders the rest shells directly (plain narrow-band rendering, Sec. 3.4): the
pipeline without a map, with the asset's rest sampler, exactly what ``shellsim eval`` measures.

:func:`render_motion` renders a motion file frame by frame to ``DIR/00000.png ...`` (frame ``k`` of the
motion is ``k:05d.png``) and optionally assembles an MP4; :func:`render_views` renders every camera of a
camera file at rest. Every PNG records what made it (:func:`frame_record`: the motion frame, camera, size,
asset and renderer settings, as JSON in a PNG text chunk); a PNG already on disk is kept only when its record
matches, so an interrupted render resumes and frames of another motion, camera or size are rendered again.
"""

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
