"""``shellsim render --cameras`` on an instant-ngp / nerfstudio capture: the rays it renders are the rays the
training loader trains on, with the file's own intrinsics and distortion, at the file's size and scaled.

The capture is written here: 5 cameras around an off-centre point with OpenCV k1 k2 p1 p2 distortion, 16x12
images whose pixels encode (frame, row, column) in their colour, one listed image missing, one frame with
its own intrinsics. Truth independent of the code: a projection with the OpenCV model written out below.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from PIL import Image
from scenes import look_at
from test_render_deformed import make_asset

import neural.render.view
from neural.data import load_camera_file, load_dataset
from neural.train import PixelSampler
from shellsim.cli.main import main

W, H = 16, 12
SHARED = {
    "fl_x": 14.0,
    "fl_y": 13.0,
    "cx": 7.7,
    "cy": 6.2,
    "k1": 0.08,
    "k2": -0.03,
    "p1": 0.004,
    "p2": -0.003,
}
OWN = {"fl_x": 11.0, "fl_y": 11.5, "cx": 8.4, "cy": 5.6, "k1": -0.12, "k2": 0.02, "p1": -0.002, "p2": 0.005}
N_FRAMES, MISSING, OWN_FRAME = 5, 2, 4
TARGET = np.array([0.3, -0.2, 0.1])


def _c2w(i: int) -> np.ndarray:
    """OpenGL camera-to-world of frame ``i``: around TARGET, y axis (the file's own 'up') tilted."""
    a = 2 * math.pi * i / N_FRAMES
    eye = TARGET + 3.0 * np.array([math.cos(a), 0.5, math.sin(a)])
    return look_at(eye, TARGET, up=(0.1, 1.0, 0.0))


def _intrinsics(i: int) -> dict:
    return OWN if i == OWN_FRAME else SHARED


def opencv_project(c2w: np.ndarray, points: np.ndarray, k: dict, sx: float = 1.0, sy: float = 1.0):
    """(M, 2) pixels of world ``points`` (M, 3) by OpenCV's model with intrinsics ``k`` scaled by sx, sy."""
    gl = (points - c2w[:3, 3]) @ c2w[:3, :3]  # world -> camera, OpenGL axes (y up, looking down -z)
    cv = gl * np.array([1.0, -1.0, -1.0])  # OpenCV axes (y down, looking down +z)
    x, y = cv[:, 0] / cv[:, 2], cv[:, 1] / cv[:, 2]
    r2 = x * x + y * y
    radial = 1 + k["k1"] * r2 + k["k2"] * r2 * r2
    xd = x * radial + 2 * k["p1"] * x * y + k["p2"] * (r2 + 2 * x * x)
    yd = y * radial + k["p1"] * (r2 + 2 * y * y) + 2 * k["p2"] * x * y
    return np.stack([sx * (k["fl_x"] * xd + k["cx"]), sy * (k["fl_y"] * yd + k["cy"])], axis=1)


def write_capture(root, with_size: bool):
    """The capture in ``root``: transforms.json (w/h keys or not) and the images that exist."""
    (root / "images").mkdir(parents=True)
    frames = []
    for i in range(N_FRAMES):
        frame = {"file_path": f"images/{i:04d}.png", "transform_matrix": _c2w(i).tolist()}
        if i == OWN_FRAME:
            frame.update(OWN)
        frames.append(frame)
        if i != MISSING:  # pixel colour: red = column, green = row, blue = frame
            rows, cols = np.mgrid[0:H, 0:W]
            rgb = np.stack([cols * 16, rows * 16, np.full_like(rows, i * 40)], axis=2).astype(np.uint8)
            Image.fromarray(rgb).save(root / "images" / f"{i:04d}.png")
    meta = {**SHARED, "camera_model": "OPENCV", "aabb_scale": 4, "frames": frames}
    if with_size:
        meta.update(w=W, h=H)
    (root / "transforms.json").write_text(json.dumps(meta))
    return root


def rendered_rays(monkeypatch, tmp_path, cameras, *size) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per camera, in file order, the (origins, dirs) (H*W, 3) that ``shellsim render --cameras`` renders."""
    seen = []

    def spy(bodies, origins, dirs, *args, **kwargs):
        seen.append((origins.double().numpy(), dirs.double().numpy()))
        n = len(origins)
        stats = {f"{stage}_ms": 0.0 for stage in neural.render.view.STAGES}
        return torch.zeros(n, 3), {**stats, "counts": np.zeros(n, np.int64), "samples_per_pixel": 0.0}

    monkeypatch.setattr(neural.render.view, "render_bodies", spy)
    asset = make_asset(tmp_path / "asset")
    args = ["render", "--asset", str(asset), "--cameras", str(cameras), "--out", str(tmp_path / "out")]
    assert main([*args, *size, "--device", "cpu"]) == 0
    return seen


def training_rays(root, downscale: int):
    """10 000 training rays of the loader, each with (frame, row, column) decoded from its pixel's colour."""
    data = load_dataset(root, downscale=downscale, holdout_every=0)
    origins, dirs, rgb, _ = PixelSampler(data, "cpu", seed=3).sample(10000)
    rgb = np.round(rgb.double().numpy() * 255).astype(np.int64)
    # an area filter of factor f averages f x f pixels: the mean column (f j + (f - 1) / 2) * 16
    col = (rgb[:, 0] / 16 - (downscale - 1) / 2) / downscale
    row = (rgb[:, 1] / 16 - (downscale - 1) / 2) / downscale
    frame = rgb[:, 2] / 40
    for v in (col, row, frame):
        assert np.allclose(v, np.round(v), atol=0.05)
    return (
        origins.double().numpy(),
        dirs.double().numpy(),
        *(np.round(v).astype(int) for v in (frame, row, col)),
    )


@pytest.mark.parametrize("with_size", [True, False], ids=["w-h-keys", "size-from-images"])
def test_render_cameras_are_the_training_rays_of_a_distorted_capture(tmp_path, monkeypatch, with_size):
    root = write_capture(tmp_path / "capture", with_size)
    seen = rendered_rays(monkeypatch, tmp_path, root / "transforms.json")
    assert len(seen) == N_FRAMES  # the frame whose image is missing is a camera too
    assert sorted(p.name for p in (tmp_path / "out").glob("*.png")) == [f"{i:04d}.png" for i in range(5)]

    # truth: the ray through pixel centre (j + 0.5, i + 0.5) passes through points that project there
    centres = np.stack(np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5), axis=2).reshape(-1, 2)
    for i, (o, d) in enumerate(seen):
        assert o.shape == (W * H, 3)
        np.testing.assert_allclose(o, np.broadcast_to(_c2w(i)[:3, 3], o.shape), atol=1e-6)
        pixels = opencv_project(_c2w(i), o + 2.9 * d, _intrinsics(i))
        np.testing.assert_allclose(pixels, centres, atol=1e-3)

    # the training loader's rays (images present only) are the rendered rays of the same pixels
    o, d, frame, row, col = training_rays(root, downscale=1)
    assert set(frame) == {0, 1, 3, 4}
    render_o = np.stack([seen[f][0][r * W + c] for f, r, c in zip(frame, row, col, strict=True)])
    render_d = np.stack([seen[f][1][r * W + c] for f, r, c in zip(frame, row, col, strict=True)])
    np.testing.assert_allclose(o, render_o, atol=1e-5)
    np.testing.assert_allclose(d, render_d, atol=1e-5)


@pytest.mark.parametrize("with_size", [True, False], ids=["w-h-keys", "size-from-images"])
def test_render_cameras_at_another_size_scale_the_intrinsics(tmp_path, monkeypatch, with_size):
    """--width alone keeps the aspect ratio; a dataset directory is a camera file too (as for train)."""
    root = write_capture(tmp_path / "capture", with_size)
    seen = rendered_rays(monkeypatch, tmp_path, root, "--width", str(W // 2))
    assert len(seen) == N_FRAMES and all(o.shape == (W // 2 * H // 2, 3) for o, _ in seen)

    w, h = W // 2, H // 2
    centres = np.stack(np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5), axis=2).reshape(-1, 2)
    for i, (o, d) in enumerate(seen):  # fx, cx scale by W'/W, fy, cy by H'/H, distortion stays
        pixels = opencv_project(_c2w(i), o + 2.9 * d, _intrinsics(i), w / W, h / H)
        np.testing.assert_allclose(pixels, centres, atol=1e-3)

    o, d, frame, row, col = training_rays(root, downscale=2)  # the loader's half-size images
    render_o = np.stack([seen[f][0][r * w + c] for f, r, c in zip(frame, row, col, strict=True)])
    render_d = np.stack([seen[f][1][r * w + c] for f, r, c in zip(frame, row, col, strict=True)])
    np.testing.assert_allclose(o, render_o, atol=1e-5)
    np.testing.assert_allclose(d, render_d, atol=1e-5)


def test_a_nerf_synthetic_directory_names_its_cameras_by_split(tmp_path):
    """As for ``train --data``: every split's file in order; stems repeated across splits get the split."""
    for split, n in (("train", 2), ("test", 1)):
        frames = [{"file_path": f"./{split}/r_{i}", "transform_matrix": _c2w(i).tolist()} for i in range(n)]
        (tmp_path / f"transforms_{split}.json").write_text(
            json.dumps({"camera_angle_x": 0.8, "frames": frames})
        )
    cameras = load_camera_file(tmp_path, width=8, height=6)
    assert cameras.names == ["train_r_0", "train_r_1", "test_r_0"]
    np.testing.assert_allclose(cameras.c2w, np.stack([_c2w(0), _c2w(1), _c2w(0)]))
    np.testing.assert_allclose(cameras.fx, 4 / math.tan(0.4))
