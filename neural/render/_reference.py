"""Slow, obviously-correct twins of the rendering package's fast paths, for tests and benches only.

- :func:`narrow_band_samples_reference`: :func:`neural.render.narrowband.narrow_band_samples` as Procedure 3
  reads (paper Sec. 3.4), one ray at a time, with a brute-force float64 ray-triangle test
  (:func:`neural.render.raycast.ray_triangle_hits`) against every face instead of a ray caster.

Nothing in the library imports this module.
"""

from __future__ import annotations

import numpy as np
import torch
import trimesh

from neural.config import NarrowBandConfig
from neural.render.narrowband import NarrowBandStats, _pack
from neural.render.raycast import as_rays, ray_triangle_hits
from neural.render.samples import RaySamples


def narrow_band_samples_reference(
    outer: trimesh.Trimesh,
    inner: trimesh.Trimesh,
    origins,
    dirs,
    config: NarrowBandConfig | None = None,
    near: float = 0.0,
    device: torch.device | str = "cpu",
    contraction=None,
) -> tuple[RaySamples, NarrowBandStats]:
    """Slow twin of :func:`~neural.render.narrowband.narrow_band_samples`: Procedure 3 line by line, one ray
    at a time, with a brute-force float64 ray-triangle test against every face of ``outer`` (M+) and
    ``inner`` (M-) (and, with a ``contraction``, each interval's width the distance between its contracted
    ends). Same arguments (the meshes in place of the caster) and results; the rules for the cases
    Procedure 3 leaves open are those of :mod:`neural.render.narrowband`'s docstring."""
    config = NarrowBandConfig() if config is None else config
    origins, dirs = as_rays(origins, dirs)
    tri_outer = np.asarray(outer.triangles, dtype=np.float64)
    tri_inner = np.asarray(inner.triangles, dtype=np.float64)
    normals_outer = np.asarray(outer.face_normals, dtype=np.float64)
    samples, intervals, t_inner = [], [], []
    for ray, (origin, direction) in enumerate(zip(origins, dirs, strict=True)):
        norm = np.linalg.norm(direction)
        unit = direction / norm
        start = origin + near * direction
        # Lines 3-7: first hit of M- (reported only for a ray that meets M+, as the fast sampler does).
        t_minus, _ = ray_triangle_hits(tri_inner, start, unit)
        d_minus = t_minus[0] if len(t_minus) else np.inf
        # Lines 9-23: walk the hits of M+.
        t_plus, faces = ray_triangle_hits(tri_outer, start, unit)
        t_inner.append(near + d_minus / norm if len(t_plus) else np.inf)
        d_enter, pending = 0.0, True  # a first hit that exits: the ray starts inside M+
        for n_hits, (hit_distance, face) in enumerate(zip(t_plus, faces, strict=True)):
            if n_hits >= config.max_peel:
                break
            if np.dot(unit, normals_outer[face]) < 0:  # ENTERING
                d_enter, pending = hit_distance, True
            elif pending:  # EXITING
                pending = False
                if d_enter > d_minus:
                    break
                d_exit = min(hit_distance, d_minus)
                w = d_exit - d_enter
                if contraction is not None:
                    ends = torch.as_tensor(np.stack([start + d_enter * unit, start + d_exit * unit]))
                    w = float(np.linalg.norm(np.diff(contraction.to_field(ends).numpy(), axis=0)))
                n = min(int(np.ceil(max(w - config.w_s, 0.0) / config.delta_s)) + 1, config.n_max)
                tau = np.linspace(d_enter, d_exit, n + 2)
                bounds = np.concatenate([[d_enter], 0.5 * (tau[1:-2] + tau[2:-1]), [d_exit]])
                for k in range(n):
                    samples.append((ray, bounds[k], bounds[k + 1], tau[k + 1], norm))
                intervals.append((ray, d_enter, d_exit, norm))
                if hit_distance > d_minus:
                    break

    def columns(rows, width):
        return np.array(rows, dtype=np.float64).reshape(-1, width).T

    s_ray, s_start, s_end, s_pos, s_norm = columns(samples, 5)
    i_ray, i_enter, i_exit, i_norm = columns(intervals, 4)
    s_ray, i_ray = s_ray.astype(np.int64), i_ray.astype(np.int64)
    return (
        _pack(
            s_ray, near + s_start / s_norm, near + s_end / s_norm, near + s_pos / s_norm, len(origins), device
        ),
        NarrowBandStats(
            counts=np.bincount(s_ray, minlength=len(origins)).astype(np.int64),
            interval_rays=i_ray,
            interval_enter=near + i_enter / i_norm,
            interval_exit=near + i_exit / i_norm,
            t_inner=np.array(t_inner, dtype=np.float64),
        ),
    )
