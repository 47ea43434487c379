"""Small synthetic scenes that tests render themselves with reference renderers, written in the
NeRF-synthetic format (``transforms_train.json`` + RGBA PNGs) so they go through the real loaders.

- :func:`write_sphere_scene`: an opaque coloured sphere, ray-traced analytically (colour from the normal).
- :func:`write_fuzzy_scene`: a solid sphere with a translucent, cloud-like shell on one side (+x), rendered
  by brute-force volume integration of an emission-absorption density.
- :class:`SphereField`: an analytic stand-in for the neural field (exact sphere SDF, constant kernel) for
  renderers that take a field.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
from PIL import Image


def look_at(eye: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """(4, 4) OpenGL camera-to-world at ``eye`` (3,) looking at ``target`` (3,): camera +z points away from
    the target, camera +y towards the world direction ``up``."""
    back = (eye - target) / np.linalg.norm(eye - target)
    right = np.cross(up, back)
    right /= np.linalg.norm(right)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, np.cross(back, right), back, eye
    return m


def orbit_cameras(n: int, radius: float, seed: int = 0) -> np.ndarray:
    """(n, 4, 4) camera-to-world matrices (OpenGL axes) on a sphere around the origin, z up."""
    rng = np.random.default_rng(seed)
    mats = []
    for i in range(n):
        azim = 2 * math.pi * (i + rng.uniform(0, 0.5)) / n
        elev = math.radians(rng.uniform(-20, 60))
        eye = radius * np.array(
            [math.cos(elev) * math.cos(azim), math.cos(elev) * math.sin(azim), math.sin(elev)]
        )
        mats.append(look_at(eye, np.zeros(3)))
    return np.stack(mats)


def _rays(c2w: np.ndarray, size: int, angle_x: float) -> tuple[np.ndarray, np.ndarray]:
    focal = 0.5 * size / math.tan(0.5 * angle_x)
    j, i = np.meshgrid(np.arange(size) + 0.5, np.arange(size) + 0.5, indexing="ij")
    d_cam = np.stack([(i - size / 2) / focal, -(j - size / 2) / focal, -np.ones_like(i)], -1)
    d = d_cam @ c2w[:3, :3].T
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return np.broadcast_to(c2w[:3, 3], d.shape).reshape(-1, 3), d.reshape(-1, 3)


def sphere_color(normals: np.ndarray) -> np.ndarray:
    """(N, 3) albedo pattern of the test sphere: smooth colour bands from the normal direction."""
    return np.clip(
        0.5 + 0.4 * np.stack([normals[:, 0], normals[:, 1] * normals[:, 2] * 2, normals[:, 2]], -1), 0, 1
    )


def _write(root: Path, images: list[np.ndarray], c2ws: np.ndarray, angle_x: float) -> Path:
    (root / "train").mkdir(parents=True, exist_ok=True)
    frames = []
    for k, (img, m) in enumerate(zip(images, c2ws, strict=True)):
        Image.fromarray((np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8), "RGBA").save(
            root / "train" / f"r_{k}.png"
        )
        frames.append({"file_path": f"./train/r_{k}", "transform_matrix": m.tolist()})
    (root / "transforms_train.json").write_text(json.dumps({"camera_angle_x": angle_x, "frames": frames}))
    return root


def write_sphere_scene(root: Path, n_views: int = 24, size: int = 32, radius: float = 0.6) -> Path:
    """An opaque sphere of ``radius`` at the origin, ``n_views`` RGBA views of ``size``^2 pixels."""
    angle_x = 0.69
    c2ws = orbit_cameras(n_views, 3.0)
    images = []
    for m in c2ws:
        o, d = _rays(m, size, angle_x)
        b = (o * d).sum(-1)
        disc = b * b - ((o * o).sum(-1) - radius**2)
        hit = disc > 0
        t = -b - np.sqrt(np.maximum(disc, 0))
        n = (o + t[:, None] * d) / radius
        shade = 0.35 + 0.65 * np.clip((n * np.array([0.3, 0.5, 0.8])).sum(-1), 0, 1)
        rgb = sphere_color(n) * shade[:, None]
        rgba = np.concatenate([np.where(hit[:, None], rgb, 0), hit[:, None].astype(float)], -1)
        images.append(rgba.reshape(size, size, 4))
    return _write(Path(root), images, c2ws, angle_x)


def fuzzy_density(x: np.ndarray, core: float = 0.45, fuzz: float = 0.3, sigma: float = 2.0) -> np.ndarray:
    """(N,) density: an opaque core sphere everywhere, plus a thin cloud layer of thickness ``fuzz``
    around it on the +x half only (the volumetric part)."""
    r = np.linalg.norm(x, axis=-1)
    solid = np.where(r < core, 400.0, 0.0)
    cloud = np.where((r >= core) & (r < core + fuzz) & (x[:, 0] > 0.1), sigma, 0.0)
    return solid + cloud


def write_fuzzy_scene(root: Path, n_views: int = 24, size: int = 32, steps: int = 192) -> Path:
    """Solid sphere with a cloud layer on +x, rendered by brute-force emission-absorption integration."""
    angle_x = 0.69
    c2ws = orbit_cameras(n_views, 3.0, seed=1)
    t = np.linspace(1.5, 4.5, steps)
    dt = t[1] - t[0]
    images = []
    for m in c2ws:
        o, d = _rays(m, size, angle_x)
        x = o[:, None, :] + t[None, :, None] * d[:, None, :]
        sigma = fuzzy_density(x.reshape(-1, 3)).reshape(len(o), steps)
        alpha = 1 - np.exp(-sigma * dt)
        trans = np.cumprod(np.concatenate([np.ones((len(o), 1)), 1 - alpha[:, :-1]], 1), 1)
        w = alpha * trans
        r = np.linalg.norm(x, axis=-1, keepdims=True)
        color = np.where(r < 0.46, np.array([0.8, 0.3, 0.2]), np.array([0.3, 0.5, 0.9]))
        acc = w.sum(1, keepdims=True)
        rgb = (w[..., None] * color).sum(1) / np.maximum(
            acc, 1e-8
        )  # PNG alpha is straight, not premultiplied
        images.append(np.concatenate([rgb, acc], -1).reshape(size, size, 4))
    return _write(Path(root), images, c2ws, angle_x)


class Geometry(NamedTuple):
    """What the renderers read of a field's geometry at N points."""

    sdf: torch.Tensor  # (N,)
    inv_s: torch.Tensor  # (N,)
    normal: torch.Tensor  # (N, 3)


class SphereField:
    """Exact SDF ``|x - c| - R`` of a sphere, a constant kernel and a colour that varies with position."""

    def __init__(self, radius=1.0, inv_s=1000.0, center=(0.0, 0.0, 0.0)):
        self.radius, self.inv_s, self.center = radius, inv_s, torch.tensor(center)

    def geometry(self, x):
        r = x - self.center.to(x)
        dist = r.norm(dim=1)
        return Geometry(dist - self.radius, torch.full_like(dist, self.inv_s), r / dist[:, None])

    def radiance(self, x, d, geo):
        return torch.sigmoid(torch.stack([x[:, 0] + d[:, 2], x[:, 1], x[:, 2] * 2.0], dim=1))


class RecordingSphereField(SphereField):
    """A :class:`SphereField` that records the rows of each call: ``geometry_calls`` and ``radiance_calls``,
    lists of ints (what a renderer evaluated, and in how many calls)."""

    def __init__(self, radius=1.0, inv_s=1000.0, center=(0.0, 0.0, 0.0)):
        super().__init__(radius, inv_s, center)
        self.geometry_calls: list[int] = []
        self.radiance_calls: list[int] = []

    def geometry(self, x):
        self.geometry_calls.append(len(x))
        return super().geometry(x)

    def radiance(self, x, d, geo):
        self.radiance_calls.append(len(x))
        return super().radiance(x, d, geo)
