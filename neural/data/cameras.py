"""Pinhole cameras with OpenCV radial-tangential distortion, ray generation and projection.

Conventions (shared by every loader and renderer in the project):

- ``c2w`` (N, 4, 4) camera-to-world in the OpenGL / Blender convention: camera x right, y up, the camera
  looks down its -z axis. World coordinates are the dataset's own.
- Pixel coordinates are continuous, x to the right and y down, with the centre of pixel (i, j) (row i,
  column j) at ``(px, py) = (j + 0.5, i + 0.5)``; ``cx, cy`` are in the same coordinates.
- Distortion is OpenCV's ``k1 k2 p1 p2`` applied to normalised image coordinates ``(x, y) = (X/Z, Y/Z)`` of
  the OpenCV camera frame (y down, looking down +z)::

      r2 = x^2 + y^2,  d = 1 + k1 r2 + k2 r2^2
      x_d = x d + 2 p1 x y + p2 (r2 + 2 x^2)
      y_d = y d + p1 (r2 + 2 y^2) + 2 p2 x y
      px = fx x_d + cx,  py = fy y_d + cy

  :func:`pixel_to_ray` inverts it with Newton's method, :func:`project` applies it.

Rays and projections are vectorised torch (float64 inside, float32 out by default) so the training loop
can call :func:`pixel_to_ray` on a random pixel batch every step on any device.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

NEWTON_ITERATIONS = 10


@dataclass(eq=False)
class Cameras:
    """N pinhole cameras. Treat the arrays as read-only: ray generation caches them as tensors.

    Attributes:
        c2w: (N, 4, 4) float64 camera-to-world, OpenGL axes (x right, y up, looking down -z).
        fx, fy, cx, cy: (N,) float64 intrinsics in pixels (pixel centres at +0.5).
        width, height: (N,) int64 image size in pixels.
        distortion: (N, 4) float64 OpenCV ``k1 k2 p1 p2``; zeros mean none.
        names: N names (image file stems or frame names).
    """

    c2w: np.ndarray
    fx: np.ndarray
    fy: np.ndarray
    cx: np.ndarray
    cy: np.ndarray
    width: np.ndarray
    height: np.ndarray
    distortion: np.ndarray
    names: list[str]
    _tensors: dict = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self):
        self.c2w = np.asarray(self.c2w, dtype=np.float64)
        if self.c2w.ndim != 3 or self.c2w.shape[1:] != (4, 4):
            raise ValueError(f"c2w: expected shape (N, 4, 4), got {self.c2w.shape}")
        if not np.all(np.isfinite(self.c2w)):
            raise ValueError("c2w: expected finite numbers, got NaN or infinity")
        n = self.c2w.shape[0]
        for name in ("fx", "fy", "cx", "cy"):
            value = np.asarray(getattr(self, name), dtype=np.float64)
            if value.shape != (n,):
                raise ValueError(f"{name}: expected shape ({n},), got {value.shape}")
            bad = ~np.isfinite(value) | ((value <= 0) if name in ("fx", "fy") else False)
            if bad.any():
                what, first = ("positive" if name in ("fx", "fy") else "finite"), int(bad.argmax())
                raise ValueError(
                    f"{name}: expected {what} numbers, got {float(value[first])} at camera {first}"
                )
            setattr(self, name, value)
        for name in ("width", "height"):
            value = np.asarray(getattr(self, name))
            if value.shape != (n,) or not np.all(value == np.round(value)) or np.any(value < 1):
                raise ValueError(f"{name}: expected ({n},) positive integers, got {value!r}")
            setattr(self, name, value.astype(np.int64))
        self.distortion = np.asarray(self.distortion, dtype=np.float64)
        if self.distortion.shape != (n, 4):
            raise ValueError(f"distortion: expected shape ({n}, 4), got {self.distortion.shape}")
        if not np.all(np.isfinite(self.distortion)):
            raise ValueError("distortion: expected finite numbers, got NaN or infinity")
        self.names = list(self.names)
        if len(self.names) != n:
            raise ValueError(f"names: expected {n} names, got {len(self.names)}")

    def __len__(self) -> int:
        return self.c2w.shape[0]

    @property
    def has_distortion(self) -> bool:
        return bool(np.any(self.distortion != 0))

    def subset(self, indices) -> Cameras:
        """The cameras at ``indices`` (int array or list), in that order."""
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        return Cameras(
            c2w=self.c2w[idx],
            fx=self.fx[idx],
            fy=self.fy[idx],
            cx=self.cx[idx],
            cy=self.cy[idx],
            width=self.width[idx],
            height=self.height[idx],
            distortion=self.distortion[idx],
            names=[self.names[i] for i in idx],
        )

    def scaled(self, downscale: float) -> Cameras:
        """Cameras for images shrunk by ``downscale`` (``--downscale``): sizes :func:`scaled_size`."""
        return self.resized(scaled_size(self.width, downscale), scaled_size(self.height, downscale))

    def resized(self, width, height) -> Cameras:
        """The same cameras imaging at ``width`` x ``height`` (ints or (N,) ints) pixels.

        Every intrinsic is scaled by the size ratio ``W' / W`` (``H' / H`` in y), which keeps pixel
        centres consistent with an area-filter resize of the whole image. Distortion lives in normalised
        coordinates and is unchanged.
        """
        width = np.broadcast_to(np.asarray(width, dtype=np.int64), self.width.shape)
        height = np.broadcast_to(np.asarray(height, dtype=np.int64), self.height.shape)
        sx, sy = width / self.width, height / self.height
        return Cameras(
            c2w=self.c2w.copy(),
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=self.cx * sx,
            cy=self.cy * sy,
            width=width.copy(),
            height=height.copy(),
            distortion=self.distortion.copy(),
            names=list(self.names),
        )

    def _packed(self, device: torch.device) -> torch.Tensor:
        """(N, 20) float64 on ``device``: c2w[:3] (12), fx fy cx cy (4), distortion (4); cached."""
        key = str(device)
        if key not in self._tensors:
            n = len(self)
            packed = np.concatenate(
                [
                    self.c2w[:, :3, :].reshape(n, 12),
                    np.stack([self.fx, self.fy, self.cx, self.cy], axis=1),
                    self.distortion,
                ],
                axis=1,
            )
            self._tensors[key] = torch.as_tensor(packed, dtype=torch.float64).to(device)
        return self._tensors[key]


def scaled_size(size, downscale: float):
    """Image size (int or int array) after ``--downscale``: ``max(1, round(size / downscale))``."""
    if not np.isfinite(downscale) or downscale <= 0:
        raise ValueError(f"downscale: expected a positive number, got {downscale!r}")
    return np.maximum(1, np.round(np.asarray(size) / downscale)).astype(np.int64)


@dataclass(eq=False)
class Normalisation:
    """Similarity map from world to the unit cube the field covers: ``u = (x - center) * scale``.

    Attributes:
        center: (3,) float64 world point mapped to the origin.
        scale: world-to-unit factor; the object lies in ``[-1, 1]^3`` after the map.
    """

    center: np.ndarray
    scale: float

    def __post_init__(self):
        self.center = np.asarray(self.center, dtype=np.float64)
        if self.center.shape != (3,):
            raise ValueError(f"center: expected shape (3,), got {self.center.shape}")
        self.scale = float(self.scale)
        if not np.isfinite(self.scale) or self.scale <= 0:
            raise ValueError(f"scale: expected a positive number, got {self.scale!r}")

    def _center_like(self, x):
        if isinstance(x, torch.Tensor):
            return torch.as_tensor(self.center, dtype=x.dtype, device=x.device)
        return self.center

    def to_unit(self, x):
        """(..., 3) world points (numpy or torch) -> unit-cube points of the same kind."""
        return (x - self._center_like(x)) * self.scale

    def to_world(self, u):
        """(..., 3) unit-cube points (numpy or torch) -> world points of the same kind."""
        return u / self.scale + self._center_like(u)

    def as_dict(self) -> dict:
        """``{"center": [x, y, z], "scale": k}`` as stored in ``asset.json``."""
        return {"center": [float(v) for v in self.center], "scale": self.scale}

    @classmethod
    def from_dict(cls, data: dict) -> Normalisation:
        return cls(center=data["center"], scale=data["scale"])


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """(4, 4) float64 OpenGL camera-to-world matrix of a camera at ``eye`` (3,) looking at ``target`` (3,).

    The camera's y axis is ``up`` (3,) made orthogonal to the viewing direction; ``up`` must not be
    parallel to it.
    """
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    for name, v in (("eye", eye), ("target", target), ("up", up)):
        if v.shape != (3,):
            raise ValueError(f"{name}: expected shape (3,), got {v.shape}")
    back = eye - target
    if np.linalg.norm(back) == 0:
        raise ValueError("look_at: eye and target coincide")
    back /= np.linalg.norm(back)
    right = np.cross(up, back)
    if np.linalg.norm(right) < 1e-12:
        raise ValueError(f"up: {up.tolist()} is parallel to the viewing direction")
    right /= np.linalg.norm(right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, np.cross(back, right), back, eye
    return c2w


def _as_tensor(x, device) -> torch.Tensor:
    return x.to(device) if isinstance(x, torch.Tensor) else torch.as_tensor(np.asarray(x), device=device)


def _distort(x: torch.Tensor, y: torch.Tensor, k: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """OpenCV radial-tangential model on (M,) normalised coordinates; ``k`` (M, 4) = k1 k2 p1 p2."""
    k1, k2, p1, p2 = k.unbind(-1)
    r2 = x * x + y * y
    d = 1 + r2 * (k1 + k2 * r2)
    return (
        x * d + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
        y * d + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y,
    )


def _undistort(xd: torch.Tensor, yd: torch.Tensor, k: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Invert :func:`_distort` by Newton's method on the 2x2 system, starting from the distorted point.

    A fixed iteration count keeps it free of host synchronisation. Measured to float64 round-off: 3 steps
    for the fox phone capture, 8 for k1 = 0.3 at the image corners. The inverse is unique only where the
    model is monotonic in the radius, which holds inside the image of any calibrated lens.
    """
    k1, k2, p1, p2 = k.unbind(-1)
    x, y = xd.clone(), yd.clone()
    for _ in range(NEWTON_ITERATIONS):
        r2 = x * x + y * y
        d = 1 + r2 * (k1 + k2 * r2)
        dd = 2 * (k1 + 2 * k2 * r2)  # d(d)/dx = dd x, d(d)/dy = dd y
        fx = x * d + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) - xd
        fy = y * d + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y - yd
        a = d + dd * x * x + 2 * p1 * y + 6 * p2 * x  # dfx/dx
        b = dd * x * y + 2 * p1 * x + 2 * p2 * y  # dfx/dy = dfy/dx
        c = d + dd * y * y + 6 * p1 * y + 2 * p2 * x  # dfy/dy
        det = a * c - b * b
        det = torch.where(det.abs() < 1e-12, torch.full_like(det, 1e-12), det)
        x = x - (c * fx - b * fy) / det
        y = y - (a * fy - b * fx) / det
    return x, y


def pixel_to_ray(
    cameras: Cameras, cam_idx, px, py, *, device=None, dtype: torch.dtype = torch.float32
) -> tuple[torch.Tensor, torch.Tensor]:
    """World-space rays through continuous pixel positions.

    Args:
        cameras: the N cameras.
        cam_idx: (M,) int camera index per ray (torch or numpy).
        px, py: (M,) pixel coordinates (pixel centres at +0.5; torch or numpy).
        device: output device; default that of ``px`` when a tensor, else cpu.
        dtype: output dtype (computed in float64).

    Returns:
        origins (M, 3), dirs (M, 3) unit vectors, torch ``dtype`` on ``device``.
    """
    if device is None:
        device = px.device if isinstance(px, torch.Tensor) else torch.device("cpu")
    idx = _as_tensor(cam_idx, device).long()
    px = _as_tensor(px, device).to(torch.float64)
    py = _as_tensor(py, device).to(torch.float64)
    if idx.ndim != 1 or px.shape != idx.shape or py.shape != idx.shape:
        raise ValueError(
            f"cam_idx, px, py: expected three (M,) arrays, got {tuple(idx.shape)}, {tuple(px.shape)}, "
            f"{tuple(py.shape)}"
        )
    cam = _packed_rows(cameras, idx, device)  # (M, 20), or (1, 20) for one camera
    x = (px - cam[:, 14]) / cam[:, 12]
    y = (py - cam[:, 15]) / cam[:, 13]
    if cameras.has_distortion:
        x, y = _undistort(x, y, cam[:, 16:20])
    rot = cam[:, :12].reshape(-1, 3, 4)
    local = torch.stack([x, -y, -torch.ones_like(x)], dim=-1)  # OpenCV -> OpenGL camera axes
    if len(cam) == 1:
        dirs = local @ rot[0, :, :3].T
    else:
        dirs = torch.einsum("mij,mj->mi", rot[:, :, :3], local)
    dirs = dirs / dirs.norm(dim=-1, keepdim=True)
    return rot[:, :, 3].expand(len(dirs), 3).to(dtype).contiguous(), dirs.to(dtype)


def project(
    cameras: Cameras, cam_idx, points, *, device=None, dtype: torch.dtype = torch.float32
) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixel coordinates of world points, with distortion: the inverse of :func:`pixel_to_ray`.

    Args:
        cameras: the N cameras.
        cam_idx: (M,) int camera index per point.
        points: (M, 3) world points; points not in front of their camera give meaningless pixels.
        device, dtype: as in :func:`pixel_to_ray` (``device`` defaults to that of ``points``).

    Returns:
        px, py: (M,) continuous pixel coordinates (pixel centres at +0.5).
    """
    if device is None:
        device = points.device if isinstance(points, torch.Tensor) else torch.device("cpu")
    idx = _as_tensor(cam_idx, device).long()
    points = _as_tensor(points, device).to(torch.float64)
    if idx.ndim != 1 or points.shape != (idx.shape[0], 3):
        raise ValueError(
            f"cam_idx, points: expected (M,) and (M, 3), got {tuple(idx.shape)} and {tuple(points.shape)}"
        )
    cam = _packed_rows(cameras, idx, device)
    rot = cam[:, :12].reshape(-1, 3, 4)
    local = torch.einsum("mji,mj->mi", rot[:, :, :3], points - rot[:, :, 3])  # R^T (p - t)
    x = local[:, 0] / -local[:, 2]
    y = local[:, 1] / local[:, 2]  # OpenGL y up, -z forward -> OpenCV y down
    if cameras.has_distortion:
        x, y = _distort(x, y, cam[:, 16:20])
    return (cam[:, 12] * x + cam[:, 14]).to(dtype), (cam[:, 13] * y + cam[:, 15]).to(dtype)


def camera_rays(
    cameras: Cameras, i: int, *, device=None, dtype: torch.dtype = torch.float32, pixels=None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Rays through every pixel centre of camera ``i``, row-major (row 0 first, left to right), or through
    those of ``pixels`` (P,) int64, their row-major indices (each ray the same as among all).

    Returns:
        origins (H*W or P, 3), dirs (H*W or P, 3) unit vectors, torch ``dtype`` on ``device`` (default cpu).
    """
    if not 0 <= i < len(cameras):
        raise ValueError(f"i: camera index {i} out of range for {len(cameras)} cameras")
    device = torch.device("cpu") if device is None else torch.device(device)
    w, h = int(cameras.width[i]), int(cameras.height[i])
    if pixels is None:
        pixels = torch.arange(h * w, device=device)
    pixels = torch.as_tensor(pixels, device=device)
    if pixels.ndim != 1 or (len(pixels) and not (0 <= int(pixels.min()) and int(pixels.max()) < h * w)):
        raise ValueError(f"pixels: expected (P,) indices in [0, {h * w}), got {tuple(pixels.shape)}")
    rows = torch.div(pixels, w, rounding_mode="floor").double()
    cols = (pixels % w).double()
    idx = torch.full((len(pixels),), i, dtype=torch.long, device=device)
    return pixel_to_ray(cameras, idx, cols + 0.5, rows + 0.5, device=device, dtype=dtype)


def _packed_rows(cameras: Cameras, idx: torch.Tensor, device) -> torch.Tensor:
    """(M, 20) packed camera rows for ``idx`` (M,), range-checked; (1, 20) when there is one camera (the rows
    would all be its own)."""
    n = len(cameras)
    if idx.numel() and (int(idx.min()) < 0 or int(idx.max()) >= n):
        raise ValueError(f"cam_idx: indices must lie in [0, {n}), got [{int(idx.min())}, {int(idx.max())}]")
    packed = cameras._packed(torch.device(device))
    return packed if n == 1 and idx.numel() else packed[idx]
