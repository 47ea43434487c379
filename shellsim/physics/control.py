"""Scripted inputs of a simulation (newton's ``Control``), apart from the model and the state: which vertices
are pinned and where they are held, and external forces.

A pinned vertex is not a degree of freedom: each step puts it at its target (its inertial prediction is the
target and its row of the Newton system is the identity with no force), so a target moved between steps
drags it along. An external force ``f_i`` [N] on a free vertex enters the inertial prediction,
``x~_i = x_i + h v_i + h^2 (g + f_i / m_i)`` (Martin et al. 2011): the incremental potential gains
``-f_i . x_i`` up to a constant.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from shellsim.physics.elastic import vec3
from shellsim.physics.state import check_vectors


class Control:
    """The pins and forces of a :class:`shellsim.physics.model.Model`'s vertices.

    pinned : (V,) bool, the held vertices (None: none); targets : (V, 3) where they are held [m] (None:
    their rest positions; rows of free vertices are ignored); forces : (V, 3) external forces [N] (None:
    none; rows of pinned vertices are ignored).
    Host: ``pinned`` (V,) bool (read-only numpy), ``min_free_mass`` [kg] (the lightest free vertex's mass,
    1 when every vertex is pinned: it bounds the Newton step's tolerance). Device (Warp, on the model's
    device): ``pinned_wp`` (V,) int32, ``targets_wp`` (V,) vec3d, ``forces_wp`` (V,) vec3d.
    """

    def __init__(self, model, pinned=None, targets=None, forces=None):
        self._model = model
        n, dev = model.n_vertices, model.device
        self.pinned_wp = wp.zeros(n, dtype=wp.int32, device=dev)
        self.targets_wp = wp.zeros(n, dtype=vec3, device=dev)
        self.forces_wp = wp.zeros(n, dtype=vec3, device=dev)
        self.set_pins(np.zeros(n, bool) if pinned is None else pinned, targets)
        if forces is not None:
            self.set_forces(forces)

    def set_pins(self, pinned, targets=None) -> None:
        """Hold the ``pinned`` (V,) bool vertices at ``targets`` (V, 3) [m] (None: their rest positions)."""
        n = self._model.n_vertices
        pinned = np.array(pinned, dtype=bool)
        if pinned.shape != (n,):
            raise ValueError(f"pinned: expected ({n},) bool, got {pinned.shape}")
        targets = self._model.rest_vertices if targets is None else check_vectors("targets", targets, n)
        pinned.setflags(write=False)
        self.pinned = pinned
        free = self._model.masses[~pinned]
        self.min_free_mass = float(free.min()) if len(free) else 1.0
        self.pinned_wp.assign(wp.array(pinned.astype(np.int32), dtype=wp.int32, device=self.pinned_wp.device))
        self.targets_wp.assign(wp.array(targets, dtype=vec3, device=self.targets_wp.device))

    def set_forces(self, forces) -> None:
        """Apply ``forces`` (V, 3) [N] to the vertices (the pinned ones ignore theirs)."""
        forces = check_vectors("forces", forces, self._model.n_vertices)
        self.forces_wp.assign(wp.array(forces, dtype=vec3, device=self.forces_wp.device))
