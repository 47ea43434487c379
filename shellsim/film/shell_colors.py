"""Colours of an asset's outer shell M+ from its field, so that an export keeps the look (USD, PLY).

Each M+ vertex gets the colour a camera looking straight at it sees: one ray, cast from just outside the
vertex along its inward normal, rendered by the asset's own pipeline (:func:`neural.render.view.render_pixels`
with its rest narrow-band sampler, over its background). Why a composited ray and not the radiance network at
the vertex: M+ lies outside the surface, up to a band width away, where the field is empty and its radiance
network was never trained; the ray reaches the surface wherever it lies in the band and weighs the colours
along it as every render does (fur and translucent parts included). Its direction, head-on, is the one from
which the vertex's patch is seen best; the colour is the view-dependent radiance of that one direction.
"""

from __future__ import annotations

import numpy as np
import torch

#: How far outside its vertex a ray starts, as a fraction of the shell's bounding-box diagonal: enough for
#: the ray caster to see it enter M+, far less than any band width.
RAY_START = 1e-4


@torch.no_grad()
def shell_colors(asset, field, device: str = "cpu") -> np.ndarray:
    """(V, 3) float32 in [0, 1]: the colour of each of the V vertices of ``asset``'s outer shell M+, seen
    head-on by a ray along its inward normal (module docstring); ``field``: the asset's field, on ``device``
    (its device)."""
    from neural.render.view import asset_sampler, render_pixels

    outer = asset.outer_mesh()
    inward = -np.asarray(outer.vertex_normals, np.float64)
    start = RAY_START * float(np.linalg.norm(np.ptp(outer.vertices, axis=0)))
    origins = np.asarray(outer.vertices, np.float64) - start * inward
    origins, dirs, background = (
        torch.as_tensor(a, dtype=torch.float32, device=device) for a in (origins, inward, asset.background)
    )
    colors, _ = render_pixels(field, origins, dirs, asset_sampler(asset), background)
    return colors.clamp(0, 1).cpu().numpy().astype(np.float32)
