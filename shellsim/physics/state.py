"""The running state of a simulation (newton's ``State``): vertex positions, velocities and the clock.

A solver step reads one :class:`State` and writes another (``step(model, state_in, state_out, control,
dt)``), so a state holds nothing but these arrays; :meth:`shellsim.physics.model.Model.state` makes one at
rest.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from shellsim.physics.elastic import vec3


class State:
    """Positions and velocities of V vertices at ``time``.

    positions, velocities : (V,) vec3d Warp arrays [m, m/s] on ``device``; time [s]. Built from (V, 3)
    array-likes (``velocities`` None: at rest).
    """

    def __init__(self, positions, velocities=None, time: float = 0.0, device=None):
        positions = check_vectors("positions", positions)
        velocities = np.zeros_like(positions) if velocities is None else velocities
        velocities = check_vectors("velocities", velocities, len(positions))
        dev = wp.get_device(device)
        self.positions = wp.array(positions, dtype=vec3, device=dev)
        self.velocities = wp.array(velocities, dtype=vec3, device=dev)
        self.time = float(time)

    @property
    def n_vertices(self) -> int:
        return self.positions.shape[0]

    def set(self, positions=None, velocities=None, time: float | None = None) -> None:
        """Replace the positions (V, 3), the velocities (V, 3) and/or the clock [s]."""
        for name, value, target in (
            ("positions", positions, self.positions),
            ("velocities", velocities, self.velocities),
        ):
            if value is not None:
                target.assign(
                    wp.array(check_vectors(name, value, self.n_vertices), dtype=vec3, device=target.device)
                )
        if time is not None:
            self.time = float(time)

    def assign(self, other: State) -> None:
        """Copy ``other``'s positions, velocities and time into this state (same size and device)."""
        wp.copy(self.positions, other.positions)
        wp.copy(self.velocities, other.velocities)
        self.time = other.time


def check_vectors(name: str, value, n: int | None = None) -> np.ndarray:
    """``value`` as finite (n, 3) float64 (any n >= 1 when ``n`` is None), else a ``ValueError`` naming
    ``name``."""
    value = np.asarray(value, dtype=np.float64)
    if value.ndim != 2 or value.shape[1] != 3 or len(value) != (n or len(value)) or not len(value):
        raise ValueError(f"{name}: expected finite ({n or 'V'}, 3), got {value.shape}")
    if not np.isfinite(value).all():
        raise ValueError(f"{name}: expected finite ({n or 'V'}, 3), got non-finite values")
    return value
