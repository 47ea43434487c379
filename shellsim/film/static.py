"""The static part of a renderer's world, drawn once per camera view (issue 57).

The ground, the obstacles and the static meshes of a shot do not move, and neither does the light: what a
camera ray sees of them, lit as far as they let the light through (their shadows on each other), is the same
in every frame seen from the same view. A :class:`StaticWorld` keeps that
(:class:`~shellsim.film.ground.StaticLayer`, :func:`~shellsim.film.ground.static_layer`) for every pixel of
the views it has been asked for in two frames running, keyed by the view itself (its camera-to-world,
intrinsics, size and distortion: :func:`view_key`), so a fixed camera draws the static world once per
anti-aliasing offset, and a moving one, whose views never repeat, keeps nothing and pays nothing more. Each
frame only what moves is drawn over the kept layer (:func:`~shellsim.film.ground.world_colors`): the
fields' shadows and a scene's mesh bodies.
"""

from __future__ import annotations

import hashlib
from typing import TYPE_CHECKING

import numpy as np

from shellsim.film.ground import StaticLayer, static_layer
from shellsim.film.obstacles import Obstacles

if TYPE_CHECKING:
    from neural.data import Cameras

#: Bytes of layers a :class:`StaticWorld` keeps at most (44 a pixel and view in float32: a 512x512 frame with
#: 4 rays per pixel keeps 46 MB); views beyond it are drawn anew in every frame.
LAYER_BUDGET = 256 * 2**20


#: Rays a static layer is drawn for at once.
LAYER_CHUNK = 65536


def view_key(view: Cameras) -> str:
    """Digest of what the rays of a one-camera ``view`` depend on: camera-to-world, intrinsics, size and
    distortion."""
    h = hashlib.blake2b(digest_size=16)
    for name in ("c2w", "fx", "fy", "cx", "cy", "width", "height", "distortion"):
        h.update(np.ascontiguousarray(getattr(view, name)).tobytes())
    return h.hexdigest()


class StaticWorld:
    """The static world around a renderer's bodies and the layers of the views it was seen from.

    look : :class:`shellsim.world.WorldLook` (ground, light, shadows, sky)
    frame : :class:`shellsim.world.Placement` of the renderer's rays in the world
    obstacles : :class:`~shellsim.film.obstacles.Obstacles` (None: none)
    meshes : static :class:`~shellsim.film.obstacles.Meshes` (colliders), built once
    sky_colors : ``sky(dirs_w (K, 3)) -> (K, 3)`` instead of the look's sky (a capture's environment map)
    budget : bytes of layers kept at most

    State: the layers of every pixel of the views asked for in this frame and the one before (when both asked
    for them), and the keys of the views asked for in each; ``kept`` and ``drawn`` count the layers taken
    from it and drawn anew.
    """

    def __init__(self, look, frame, obstacles=None, meshes=(), sky_colors=None, budget: int = LAYER_BUDGET):
        self.look, self.frame = look, frame
        self.obstacles = Obstacles() if obstacles is None else obstacles
        self.meshes = tuple(meshes)
        self.sky_colors = sky_colors
        self.budget = budget
        self._layers: dict[str, StaticLayer] = {}
        self._asked: set[str] = set()  # views asked for in this frame
        self._before: set[str] = set()  # and in the one before
        self.kept = self.drawn = 0

    def layer(self, origins, dirs) -> StaticLayer:
        """The :class:`StaticLayer` of rays ``origins``, ``dirs`` (R, 3) of the renderer's frame, drawn
        :data:`LAYER_CHUNK` rays at a time (its float64 work stays that small)."""
        self.drawn += 1
        parts = [
            static_layer(
                self.look,
                self.frame,
                origins[i : i + LAYER_CHUNK],
                dirs[i : i + LAYER_CHUNK],
                self.obstacles,
                self.meshes,
                self.sky_colors,
            )
            for i in range(0, max(len(origins), 1), LAYER_CHUNK)
        ]
        return parts[0] if len(parts) == 1 else StaticLayer.cat(parts)

    def view_layer(self, view: Cameras, pixels, origins, dirs) -> StaticLayer:
        """The :class:`StaticLayer` of the rays ``origins``, ``dirs`` (P, 3) through the pixels ``pixels``
        (P,) int64 (row-major; None: all) of the one-camera ``view``: kept from an earlier frame, else drawn
        for every pixel of the view when the frame before asked for it too (and kept while the budget
        allows), else drawn for these rays alone."""
        import torch

        from neural.data import camera_rays

        key = view_key(view)
        self._asked.add(key)
        if key not in self._layers and key in self._before:
            w, h = int(view.width[0]), int(view.height[0])
            if self._bytes() + h * w * (8 + 9 * origins.element_size()) <= self.budget:
                self._layers[key] = self.layer(*camera_rays(view, 0, device=origins.device))
        if key in self._layers:
            self.kept += 1
            rows = None if pixels is None else torch.as_tensor(pixels, device=origins.device)
            return self._layers[key].select(rows)
        return self.layer(origins, dirs)

    def next_frame(self) -> None:
        """Start a frame: forget the layers of the views the last frame did not ask for."""
        self._layers = {k: v for k, v in self._layers.items() if k in self._asked}
        self._before, self._asked = self._asked, set()

    def _bytes(self) -> int:
        return sum(layer.nbytes for layer in self._layers.values())
