"""Small synthetic scenes that tests render themselves with reference renderers, written in the
NeRF-synthetic format (``transforms_train.json`` + RGBA PNGs) or, for a real-capture-like scene, the
instant-ngp / nerfstudio format (``transforms.json`` + RGB PNGs) so they go through the real loaders.

- :func:`write_sphere_scene`: an opaque coloured sphere, ray-traced analytically (colour from the normal).
- :func:`write_block_scene`: an opaque block with coloured faces photographed only from above (its
  underside unseen), ray-traced analytically; :data:`BLOCK` holds its geometry.
- :func:`write_fuzzy_scene`: a solid sphere with a translucent, cloud-like shell on one side (+x), rendered
  by brute-force volume integration of an emission-absorption density.
- :func:`write_unbounded_scene`: an unbounded capture (:data:`UNBOUNDED`): a sphere on a textured table
  disc inside a textured room sphere, every pixel sees something; :func:`trace_unbounded` is its exact ray
  tracer and :func:`unbounded_object_mask` says which pixels see the object.
- :class:`SphereField`: an analytic stand-in for the neural field (exact sphere SDF, constant kernel) for
  renderers that take a field.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
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


def orbit_cameras(
    n: int,
    radius: float,
    seed: int = 0,
    center=(0.0, 0.0, 0.0),
    elevation: tuple[float, float] = (-20.0, 60.0),
    jitter: float = 0.0,
) -> np.ndarray:
    """(n, 4, 4) camera-to-world matrices (OpenGL axes) at ``radius`` around ``center`` (3,), z up, each
    looking at ``center``: azimuths spread around the circle, elevations uniform in ``elevation`` (degrees),
    then each eye moved by a seeded normal offset of ``jitter`` world units per axis (0: none)."""
    rng = np.random.default_rng(seed)
    center = np.asarray(center, dtype=np.float64)
    mats = []
    for i in range(n):
        azim = 2 * math.pi * (i + rng.uniform(0, 0.5)) / n
        elev = math.radians(rng.uniform(*elevation))
        eye = center + radius * np.array(
            [math.cos(elev) * math.cos(azim), math.cos(elev) * math.sin(azim), math.sin(elev)]
        )
        if jitter:
            eye = eye + rng.normal(0.0, jitter, 3)
        mats.append(look_at(eye, center))
    return np.stack(mats)


def pinhole_rays(c2w: np.ndarray, fx, fy, cx, cy, px, py) -> tuple[np.ndarray, np.ndarray]:
    """Origins and unit directions (both (..., 3)) of the rays of the pinhole camera ``c2w`` (4, 4), OpenGL
    axes, through the continuous pixel positions ``px, py`` (...) (pixel centres at +0.5, y down)."""
    px, py = np.asarray(px, dtype=np.float64), np.asarray(py, dtype=np.float64)
    d_cam = np.stack([(px - cx) / fx, -(py - cy) / fy, -np.ones_like(px)], -1)
    d = d_cam @ c2w[:3, :3].T
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return np.broadcast_to(c2w[:3, 3], d.shape), d


def _rays(c2w: np.ndarray, size: int, angle_x: float) -> tuple[np.ndarray, np.ndarray]:
    focal = 0.5 * size / math.tan(0.5 * angle_x)
    j, i = np.meshgrid(np.arange(size) + 0.5, np.arange(size) + 0.5, indexing="ij")
    o, d = pinhole_rays(c2w, focal, focal, size / 2, size / 2, i, j)
    return o.reshape(-1, 3), d.reshape(-1, 3)


def sphere_color(normals: np.ndarray) -> np.ndarray:
    """(N, 3) albedo pattern of the test sphere: smooth colour bands from the normal direction."""
    return np.clip(
        0.5 + 0.4 * np.stack([normals[:, 0], normals[:, 1] * normals[:, 2] * 2, normals[:, 2]], -1), 0, 1
    )


def _save_png(path: Path, img: np.ndarray) -> None:
    """Save (H, W, 3 or 4) floats in [0, 1] as an 8-bit RGB or (straight-alpha) RGBA PNG."""
    Image.fromarray(
        (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8), "RGBA" if img.shape[2] == 4 else "RGB"
    ).save(path)


def _write(root: Path, images: list[np.ndarray], c2ws: np.ndarray, angle_x: float) -> Path:
    (root / "train").mkdir(parents=True, exist_ok=True)
    frames = []
    for k, (img, m) in enumerate(zip(images, c2ws, strict=True)):
        _save_png(root / "train" / f"r_{k}.png", img)
        frames.append({"file_path": f"./train/r_{k}", "transform_matrix": m.tolist()})
    (root / "transforms_train.json").write_text(json.dumps({"camera_angle_x": angle_x, "frames": frames}))
    return root


def write_sphere_scene(
    root: Path, n_views: int = 24, size: int = 32, radius: float = 0.6, elevation=(-20.0, 60.0)
) -> Path:
    """An opaque sphere of ``radius`` at the origin, ``n_views`` RGBA views of ``size``^2 pixels from cameras
    at ``elevation`` (degrees, see :func:`orbit_cameras`)."""
    angle_x = 0.69
    c2ws = orbit_cameras(n_views, 3.0, elevation=elevation)
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


@dataclass(frozen=True)
class Block:
    """The fixed geometry of :func:`write_block_scene` (world units, z up): an axis-aligned block."""

    half: tuple[float, float, float] = (0.55, 0.45, 0.25)  # half extents; the centre is the origin
    top: tuple[float, float, float] = (0.85, 0.25, 0.2)  # albedo of the +z face
    x_sides: tuple[float, float, float] = (0.2, 0.65, 0.3)  # of the +-x faces
    y_sides: tuple[float, float, float] = (0.25, 0.35, 0.85)  # of the +-y faces, and of the unseen -z face
    elevation: tuple[float, float] = (20.0, 70.0)  # degrees: every camera looks down on it


BLOCK = Block()


def trace_block(o: np.ndarray, d: np.ndarray, block: Block = BLOCK) -> tuple[np.ndarray, np.ndarray]:
    """Slab-method hits of rays ``o``, ``d`` (N, 3) on the block: (N,) bool and (N, 3) shaded colour."""
    half = np.asarray(block.half)
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = (-half - o) / d, (half - o) / d
    near, far = np.minimum(t0, t1), np.maximum(t0, t1)
    t_in, axis = near.max(1), near.argmax(1)
    hit = (t_in <= far.min(1)) & (t_in > 0)
    normal = np.zeros_like(o)
    normal[np.arange(len(o)), axis] = -np.sign(d[np.arange(len(o)), axis])
    albedo = np.select(
        [axis[:, None] == 2, axis[:, None] == 0],
        [np.asarray(block.top), np.asarray(block.x_sides)],
        block.y_sides,
    )
    albedo = np.where((axis[:, None] == 2) & (normal[:, 2:] < 0), np.asarray(block.y_sides), albedo)
    shade = 0.55 + 0.45 * np.clip(normal @ np.array([0.3, 0.5, 0.81]), 0, 1)
    return hit, albedo * shade[:, None]


def write_block_scene(root: Path, n_views: int = 24, size: int = 32, block: Block = BLOCK) -> Path:
    """The block of ``block``, ``n_views`` RGBA views of ``size``^2 pixels from cameras above it only (at
    ``block.elevation``): no view sees its underside."""
    angle_x = 0.69
    c2ws = orbit_cameras(n_views, 3.0, seed=2, elevation=block.elevation)
    images = []
    for m in c2ws:
        o, d = _rays(m, size, angle_x)
        hit, rgb = trace_block(o, d, block)
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


@dataclass(frozen=True)
class UnboundedScene:
    """The fixed geometry of :func:`write_unbounded_scene` (world units, z up)."""

    object_center: tuple[float, float, float] = (0.0, 0.0, 0.5)  # opaque sphere resting on the table
    object_radius: float = 0.5
    table_radius: float = 4.0  # disc of the plane z = 0
    table_period: float = 0.5  # of its smooth checker, in x and y
    table_colors: tuple = ((0.80, 0.68, 0.50), (0.30, 0.20, 0.14))
    room_radius: float = 12.0  # textured sphere about the origin enclosing everything
    target: tuple[float, float, float] = (0.0, 0.0, 0.4)  # every camera looks at it
    camera_distance: float = 2.2  # from ``target``, before the position jitter
    elevation: tuple[float, float] = (15.0, 45.0)  # degrees, of the cameras above ``target``
    focal_per_width: float = 0.85  # fl_x = fl_y = this * width: the object spans ~0.4 of the width
    aabb_scale: int = 16  # written to transforms.json: the loader's scene radius covers the room sphere


UNBOUNDED = UnboundedScene()
SURFACE_OBJECT, SURFACE_TABLE, SURFACE_ROOM = 0, 1, 2


def table_color(p: np.ndarray, period: float = UNBOUNDED.table_period) -> np.ndarray:
    """(N, 3) albedo of the table at points (N, 3) of z = 0: a smooth two-colour checker of ``period``."""
    k = 2 * math.pi / period
    s = 0.5 + 0.5 * np.sin(k * p[:, 0]) * np.sin(k * p[:, 1])
    a, b = (np.array(c) for c in UNBOUNDED.table_colors)
    return a + s[:, None] * (b - a)


def room_color(p: np.ndarray) -> np.ndarray:
    """(N, 3) albedo of the room sphere at its points (N, 3): 8 stripes in azimuth (fading to the poles)
    and 5 bands in elevation, in different channels, so a view from elsewhere shows it shifted (parallax)."""
    u = p / np.linalg.norm(p, axis=-1, keepdims=True)
    azimuth, elevation = np.arctan2(u[:, 1], u[:, 0]), np.arcsin(np.clip(u[:, 2], -1, 1))
    stripes = np.cos(8 * azimuth) * np.cos(elevation)
    bands = np.sin(10 * elevation)
    return np.clip(
        np.stack([0.5 + 0.35 * stripes, 0.55 + 0.3 * bands, 0.6 - 0.2 * stripes * bands], -1), 0, 1
    )


def _sphere_hits(o: np.ndarray, d: np.ndarray, center, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Near and far ray parameters (N,) of unit-direction rays with a sphere; NaN where they miss."""
    oc = o - np.asarray(center, dtype=np.float64)
    b = (oc * d).sum(-1)
    disc = b * b - ((oc * oc).sum(-1) - radius**2)
    root = np.where(disc >= 0, np.sqrt(np.maximum(disc, 0)), np.nan)
    return -b - root, -b + root


def trace_unbounded(
    o: np.ndarray, d: np.ndarray, table_period: float = UNBOUNDED.table_period
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact first hits of rays (origins, unit directions (N, 3)) starting inside the room sphere and
    outside the object: (rgb (N, 3) albedo, surface (N,) ``SURFACE_*``, distance t (N,)); the table's
    checker has period ``table_period``."""
    o, d = np.broadcast_arrays(np.asarray(o, dtype=np.float64), np.asarray(d, dtype=np.float64))
    t = _sphere_hits(o, d, (0.0, 0.0, 0.0), UNBOUNDED.room_radius)[1]
    surface = np.full(len(t), SURFACE_ROOM)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_table = np.where(d[:, 2] < 0, -o[:, 2] / d[:, 2], np.inf)
    on_table = np.hypot(*(o[:, :2] + t_table[:, None] * d[:, :2]).T) <= UNBOUNDED.table_radius
    table = on_table & (t_table > 0) & (t_table < t)
    t, surface = np.where(table, t_table, t), np.where(table, SURFACE_TABLE, surface)
    t_object = _sphere_hits(o, d, UNBOUNDED.object_center, UNBOUNDED.object_radius)[0]
    obj = (t_object > 0) & (t_object < t)  # False for NaN (a miss)
    t, surface = np.where(obj, t_object, t), np.where(obj, SURFACE_OBJECT, surface)
    p = o + t[:, None] * d
    rgb = room_color(p)
    rgb[table] = table_color(p[table], table_period)
    rgb[obj] = sphere_color((p[obj] - UNBOUNDED.object_center) / UNBOUNDED.object_radius)
    return rgb, surface, t


def unbounded_cameras(n_views: int = 24, seed: int = 0, jitter: float = 0.05) -> np.ndarray:
    """(n_views, 4, 4) camera-to-world (OpenGL axes) of :func:`write_unbounded_scene`: a ring at
    ``camera_distance`` around ``target``, elevations in ``elevation``, eyes jittered by ``jitter`` (normal,
    per axis), all looking at ``target``."""
    return orbit_cameras(
        n_views,
        UNBOUNDED.camera_distance,
        seed=seed,
        center=UNBOUNDED.target,
        elevation=UNBOUNDED.elevation,
        jitter=jitter,
    )


def write_unbounded_scene(
    root: Path,
    n_views: int = 24,
    width: int = 40,
    height: int = 30,
    focal: float | None = None,
    samples: int = 2,
    seed: int = 0,
    jitter: float = 0.05,
    table_period: float = UNBOUNDED.table_period,
) -> Path:
    """A real-capture-like unbounded scene (:data:`UNBOUNDED`) as instant-ngp / nerfstudio data: ``root``/
    ``transforms.json`` (shared ``fl_x fl_y cx cy w h``, zero OPENCV distortion, ``aabb_scale``) and
    ``images/frame_00000.png`` ... RGB PNGs without alpha, ``n_views`` cameras of :func:`unbounded_cameras`.

    Each pixel is the mean albedo (:func:`trace_unbounded`) of ``samples`` x ``samples`` stratified rays
    jittered inside it, seeded by ``seed`` (deterministic); the table's checker has period ``table_period``.
    ``focal`` defaults to ``UNBOUNDED.focal_per_width * width`` pixels (both axes). Returns ``root``.
    """
    root = Path(root)
    (root / "images").mkdir(parents=True, exist_ok=True)
    focal = UNBOUNDED.focal_per_width * width if focal is None else float(focal)
    cx, cy = width / 2, height / 2
    c2ws = unbounded_cameras(n_views, seed, jitter)
    rng = np.random.default_rng(seed)
    rows, cols = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    frames = []
    for k, c2w in enumerate(c2ws):
        rgb = np.zeros((height, width, 3))
        for a in range(samples):
            for b in range(samples):
                px = cols + (b + rng.uniform(size=cols.shape)) / samples
                py = rows + (a + rng.uniform(size=rows.shape)) / samples
                o, d = pinhole_rays(c2w, focal, focal, cx, cy, px, py)
                rgb += trace_unbounded(o.reshape(-1, 3), d.reshape(-1, 3), table_period)[0].reshape(
                    height, width, 3
                )
        name = f"images/frame_{k:05d}.png"
        _save_png(root / name, rgb / samples**2)
        frames.append({"file_path": name, "transform_matrix": c2w.tolist()})
    meta = {
        "camera_model": "OPENCV",
        "fl_x": focal,
        "fl_y": focal,
        "cx": cx,
        "cy": cy,
        "w": width,
        "h": height,
        "k1": 0.0,
        "k2": 0.0,
        "p1": 0.0,
        "p2": 0.0,
        "aabb_scale": UNBOUNDED.aabb_scale,
        "frames": frames,
    }
    (root / "transforms.json").write_text(json.dumps(meta, indent=1))
    return root


def unbounded_object_mask(cameras, i: int, pad: float = 0.0) -> np.ndarray:
    """(H, W) bool: the pixels of camera ``i`` of ``cameras`` (a ``neural.data.Cameras`` or anything with its
    ``c2w fx fy cx cy width height`` arrays; no distortion) whose centre ray hits the object sphere grown by
    ``pad`` world units (negative: only pixels well inside its silhouette). Nothing hides the object: a ray
    that hits it sees it first."""
    w, h = int(cameras.width[i]), int(cameras.height[i])
    rows, cols = np.meshgrid(np.arange(h) + 0.5, np.arange(w) + 0.5, indexing="ij")
    o, d = pinhole_rays(
        np.asarray(cameras.c2w[i]), cameras.fx[i], cameras.fy[i], cameras.cx[i], cameras.cy[i], cols, rows
    )
    near = _sphere_hits(
        o.reshape(-1, 3), d.reshape(-1, 3), UNBOUNDED.object_center, UNBOUNDED.object_radius + pad
    )[0]
    return (near > 0).reshape(h, w)


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

    def sdf_and_kernel(self, x):
        geo = self.geometry(x)
        return geo.sdf, 1.0 / geo.inv_s

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
