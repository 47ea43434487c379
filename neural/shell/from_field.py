"""Adaptive shells of a trained field: sample f and s on a grid over the field's unit cube, run the
level-set extraction there (so the paper's zeta, dt etc. apply in unit space), map the meshes to world.

A field in contracted space (``field.contraction``) is extracted in that space, as the paper does for
unbounded scenes (Sec. 4.7): its cube holds the contracted ball, outside which nothing is (f is raised to
the distance to the ball, :data:`BALL_FILL` of its radius, so no shell reaches infinity), and the meshes'
vertices, held within :data:`SHELL_REACH` of its radius, are carried back to the world by the inverse
contraction."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..field.contraction import CONTRACTED_RADIUS
from .extract import ShellConfig, extract_shells, sample_grid, shell_width_stats

#: The part of the contracted ball (radius) a contracted field's content may fill before its shells are
#: extracted (world radius ``1 / (2 - 2 BALL_FILL)`` object radii), and the most their vertices may reach
#: once dilated: its edge is at infinity, where flat triangles between carried-back vertices turn inside out.
BALL_FILL = 0.94
SHELL_REACH = 0.985


@dataclass
class FieldShells:
    """M+ (``outer``) and M- (``inner``) as world-space ``trimesh.Trimesh`` plus width statistics."""

    outer: object
    inner: object
    stats: dict


def extract_field_shells(field, config: ShellConfig, device: str) -> FieldShells:
    """Procedure 2 on ``field`` (a ``ShellField``) at ``config.resolution``^3 over its unit cube."""
    scale = float(field.scale)
    center = field.center.detach().to(torch.float64).cpu().numpy()

    contraction = getattr(field, "contraction", None)

    def unit_fn(u: torch.Tensor):
        x = field.center + u / scale
        sdf, s = field.sdf_and_kernel(x)
        if contraction is not None:  # the box's unit ball is the contracted ball
            sdf = torch.maximum(sdf, (u.norm(dim=1) - BALL_FILL) / scale)
        return sdf * scale, s * scale

    with torch.no_grad():
        f, s = sample_grid(unit_fn, np.full(3, -1.0), np.full(3, 1.0), config.resolution, device=device)
    spacing = 2.0 / (config.resolution - 1)
    result = extract_shells(f, s, np.full(3, -1.0), spacing, config)
    outer, inner = result.outer, result.inner
    for mesh in (outer, inner):
        offset = mesh.vertices / scale  # (V, 3) world units about the centre (contracted ones if contracted)
        if contraction is not None:  # held within SHELL_REACH of the contracted ball, carried back
            reach = CONTRACTED_RADIUS * contraction.radius * SHELL_REACH
            offset = offset * (reach / np.maximum(np.linalg.norm(offset, axis=1, keepdims=True), reach))
            mesh.vertices = contraction.to_world(torch.as_tensor(offset + center)).numpy()
        else:
            mesh.vertices = offset + center
    stats = {f"width_{k}": float(v) for k, v in shell_width_stats(outer, inner).items()}  # world units
    stats.update(outer_faces=int(len(outer.faces)), inner_faces=int(len(inner.faces)))
    return FieldShells(outer, inner, stats)
