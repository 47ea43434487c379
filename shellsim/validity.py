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


def volumes6(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(T,) six times the signed tet volumes; vertices (V, 3), tets (T, 4) int."""
    e = vertices[tets[:, 1:]] - vertices[tets[:, :1]]
    return np.einsum("ti,ti->t", e[:, 0], np.cross(e[:, 1], e[:, 2]))


def volume_ratios(rest_vertices: np.ndarray, positions: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(T,) deformed / rest volume of each tet (``det F``); rest_vertices, positions (V, 3), tets (T, 4)
    positively oriented at rest."""
    rest = np.asarray(rest_vertices, np.float64)
    tets = np.asarray(tets, np.int64)
    return volumes6(np.asarray(positions, np.float64), tets) / volumes6(rest, tets)
