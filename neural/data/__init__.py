"""Cameras and posed-image datasets (NeRF-synthetic and instant-ngp / nerfstudio formats)."""

from .cameras import Cameras, Normalisation, camera_rays, look_at, pixel_to_ray, project, scaled_size
from .datasets import SceneData, load_camera_file, load_dataset

__all__ = [
    "Cameras",
    "Normalisation",
    "SceneData",
    "camera_rays",
    "load_camera_file",
    "load_dataset",
    "look_at",
    "pixel_to_ray",
    "project",
    "scaled_size",
]
