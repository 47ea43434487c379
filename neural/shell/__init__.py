"""Adaptive shells (paper Sec. 3.3, Procedures 1-2): level-set dilation/erosion of the learned SDF and
marching cubes to the outer mesh M+ and the inner mesh M-."""

from .extract import (
    ShellConfig,
    ShellResult,
    dilate,
    dilation_velocity,
    erode,
    erosion_velocity,
    extract_shells,
    grid_spacing,
    marching_cubes_mesh,
    sample_grid,
    shell_width_stats,
    voxel_alpha,
)
from .levelset import evolve_level_set, soft_falloff

__all__ = [
    "ShellConfig",
    "ShellResult",
    "dilate",
    "dilation_velocity",
    "erode",
    "erosion_velocity",
    "evolve_level_set",
    "extract_shells",
    "grid_spacing",
    "marching_cubes_mesh",
    "sample_grid",
    "shell_width_stats",
    "soft_falloff",
    "voxel_alpha",
]
