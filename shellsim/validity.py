"""Is a deformed cage still a valid cage? The one check that :mod:`shellsim.fem` and :mod:`shellsim.wind`
share before a frame is written.

A tet's volume ratio is ``det F`` = deformed volume / rest volume. At or below 0 the tet is inverted and
the shells embedded in it fold through each other; close to 0 it is a sliver that smears whatever it holds.
Both are refused below :data:`MIN_VOLUME_RATIO`: a tet squeezed to a fifth of its volume. Normal motion
stays far above it (a 0.3 m jelly cube dropped 0.1 m onto the ground: 0.75 at worst; rubber, foam,
plastic: above 0.99). Plain numpy.
"""

from __future__ import annotations

import numpy as np

MIN_VOLUME_RATIO = 0.2  # smallest det F a written frame may have


def tet_volumes(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volumes ``det[v1 - v0, v2 - v0, v3 - v0] / 6``: vertices (V, 3), tets (T, 4) -> (T,) float64."""
    p = np.asarray(vertices, dtype=np.float64)[np.asarray(tets)]  # (T, 4, 3)
    e = p[:, 1:] - p[:, :1]
    return np.einsum("ti,ti->t", e[:, 0], np.cross(e[:, 1], e[:, 2])) / 6.0


def volume_ratios(rest_vertices: np.ndarray, positions: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(T,) deformed / rest volume of each tet (``det F``); rest_vertices, positions (V, 3), tets (T, 4)
    positively oriented at rest."""
    tets = np.asarray(tets, np.int64)
    return tet_volumes(positions, tets) / tet_volumes(rest_vertices, tets)
