"""Adaptive shells of a trained field: sample f and s on a grid over the field's unit cube, run the
level-set extraction there (so the paper's zeta, dt etc. apply in unit space), map the meshes to world."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .extract import ShellConfig, extract_shells, sample_grid, shell_width_stats


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

    def unit_fn(u: torch.Tensor):
        x = field.center + u / scale
        sdf, s = field.sdf_and_kernel(x)
        return sdf * scale, s * scale

    with torch.no_grad():
        f, s = sample_grid(unit_fn, np.full(3, -1.0), np.full(3, 1.0), config.resolution, device=device)
    spacing = 2.0 / (config.resolution - 1)
    result = extract_shells(f, s, np.full(3, -1.0), spacing, config)
    outer, inner = result.outer, result.inner
    for mesh in (outer, inner):
        mesh.vertices = mesh.vertices / scale + center
    stats = {f"width_{k}": float(v) for k, v in shell_width_stats(outer, inner).items()}  # world units
    stats.update(outer_faces=int(len(outer.faces)), inner_faces=int(len(inner.faces)))
    return FieldShells(outer, inner, stats)
