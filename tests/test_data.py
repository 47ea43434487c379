import json
import logging
import math
import re

import numpy as np
import pytest
import torch
from PIL import Image

from neural.data import (
    Cameras,
    Normalisation,
    camera_rays,
    load_camera_file,
    load_dataset,
    look_at,
    pixel_to_ray,
    project,
)
from neural.data.datasets import NGP_CUBE_FRACTION
from neural.errors import InputError

F64 = dict(dtype=torch.float64)


def _orbit(n, radius=4.0, target=(0.0, 0.0, 0.0), height=1.0):
    """(n, 4, 4) cameras on a horizontal circle around ``target``, all looking at it."""
    target = np.asarray(target, dtype=np.float64)
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.stack(
        [look_at(target + [radius * np.cos(a), radius * np.sin(a), height], target) for a in angles]
    )


def _cameras(rng, n=5, distortion=None):
    c2w = _orbit(n)
    c2w[:, :3, 3] += rng.normal(scale=0.1, size=(n, 3))
    return Cameras(
        c2w=c2w,
        fx=rng.uniform(40, 60, n),
        fy=rng.uniform(40, 60, n),
        cx=rng.uniform(28, 36, n),
        cy=rng.uniform(20, 28, n),
        width=np.full(n, 64),
        height=np.full(n, 48),
        distortion=np.zeros((n, 4)) if distortion is None else np.tile(distortion, (n, 1)),
        names=[f"cam{i}" for i in range(n)],
    )


# --- cameras -----------------------------------------------------------------------------------------------

PHONE = [0.0578421, -0.0805099, -0.000980296, 0.00015575]  # the fox capture's k1 k2 p1 p2
STRONG = [-0.25, 0.08, 0.003, -0.002]


@pytest.mark.parametrize("distortion", [None, PHONE, STRONG])
def test_project_inverts_pixel_to_ray(rng, distortion):
    cams = _cameras(rng, distortion=distortion)
    m = 500
    idx = rng.integers(0, len(cams), m)
    px = rng.uniform(0, 64, m)
    py = rng.uniform(0, 48, m)
    origins, dirs = pixel_to_ray(cams, idx, px, py, **F64)
    assert torch.allclose(dirs.norm(dim=1), torch.ones(m, dtype=torch.float64))
    depth = torch.tensor(rng.uniform(0.5, 10, m))
    qx, qy = project(cams, idx, origins + depth[:, None] * dirs, **F64)
    np.testing.assert_allclose(qx.numpy(), px, atol=1e-8)
    np.testing.assert_allclose(qy.numpy(), py, atol=1e-8)
    # the default float32 output is good to a thousandth of a pixel
    o32, d32 = pixel_to_ray(cams, torch.tensor(idx), torch.tensor(px), torch.tensor(py))
    assert o32.dtype == torch.float32 and d32.dtype == torch.float32
    qx, qy = project(cams, idx, (o32 + depth[:, None].float() * d32).double(), **F64)
    np.testing.assert_allclose(qx.numpy(), px, atol=2e-3)


@pytest.mark.parametrize("distortion", [None, STRONG])
def test_pixel_to_ray_inverts_project(rng, distortion):
    cams = _cameras(rng, distortion=distortion)
    m = 200
    idx = rng.integers(0, len(cams), m)
    points = rng.uniform(-0.8, 0.8, (m, 3))  # near the origin all cameras look at
    px, py = project(cams, idx, points, **F64)
    origins, dirs = pixel_to_ray(cams, idx, px, py, **F64)
    expected = points - cams.c2w[idx, :3, 3]
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    np.testing.assert_allclose(origins.numpy(), cams.c2w[idx, :3, 3])
    np.testing.assert_allclose(dirs.numpy(), expected, atol=1e-9)


def _camera_at_z4(width=64, height=48, fx=50.0, fy=40.0):
    c2w = np.eye(4)
    c2w[2, 3] = 4.0  # at (0, 0, 4), looking down -z at the origin, y up
    return Cameras(
        c2w[None], [fx], [fy], [width / 2], [height / 2], [width], [height], np.zeros((1, 4)), ["z4"]
    )


def test_a_camera_at_z4_sends_its_centre_ray_through_the_origin():
    cam = _camera_at_z4()
    origins, dirs = pixel_to_ray(cam, [0], [32.0], [24.0], **F64)
    np.testing.assert_allclose(origins[0].numpy(), [0, 0, 4])
    np.testing.assert_allclose(dirs[0].numpy(), [0, 0, -1])
    # world (1, 0, 0) is at x_n = 1/4 (right); world (0, 1, 0) is up, so above the centre (smaller py)
    px, py = project(cam, [0, 0], np.array([[1.0, 0, 0], [0, 1.0, 0]]), **F64)
    np.testing.assert_allclose(px.numpy(), [32 + 50 / 4, 32])
    np.testing.assert_allclose(py.numpy(), [24, 24 - 40 / 4])
    origins, dirs = pixel_to_ray(cam, [0, 0], px, py, **F64)
    np.testing.assert_allclose((origins + 4 * np.sqrt(1 + 1 / 16) * dirs).numpy(), [[1, 0, 0], [0, 1, 0]])


def test_distortion_follows_the_opencv_model():
    cam = _camera_at_z4()
    cam.distortion[0] = k1, k2, p1, p2 = STRONG
    # world (1, 0.5, 0) seen from (0, 0, 4): OpenCV camera coordinates (x right, y down, z forward)
    x, y = 1 / 4, -0.5 / 4
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    px, py = project(cam, [0], np.array([[1.0, 0.5, 0.0]]), **F64)
    np.testing.assert_allclose([px[0], py[0]], [50 * xd + 32, 40 * yd + 24], rtol=1e-12)
    origins, dirs = pixel_to_ray(cam, [0], px, py, **F64)
    np.testing.assert_allclose(
        (origins + math.sqrt(1 + 0.25 + 16) * dirs)[0].numpy(), [1, 0.5, 0], atol=1e-12
    )


def test_camera_rays_are_row_major_over_pixel_centres():
    cam = _camera_at_z4(width=5, height=3, fx=2.0, fy=3.0)
    origins, dirs = camera_rays(cam, 0, dtype=torch.float64)
    assert origins.shape == dirs.shape == (15, 3)
    rows, cols = np.divmod(np.arange(15), 5)
    expected = np.stack([(cols + 0.5 - 2.5) / 2.0, -(rows + 0.5 - 1.5) / 3.0, -np.ones(15)], axis=1)
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    np.testing.assert_allclose(dirs.numpy(), expected, atol=1e-12)
    np.testing.assert_allclose(origins.numpy(), np.tile([0, 0, 4.0], (15, 1)))


def test_look_at_builds_opengl_axes():
    np.testing.assert_allclose(look_at([0, 0, 4], [0, 0, 0], up=[0, 1, 0])[:3, :3], np.eye(3), atol=1e-15)
    c2w = look_at([4, 0, 0], [0, 0, 0])  # z up
    np.testing.assert_allclose(-c2w[:3, 2], [-1, 0, 0], atol=1e-15)  # viewing direction
    np.testing.assert_allclose(c2w[:3, 1], [0, 0, 1], atol=1e-15)  # camera up
    np.testing.assert_allclose(c2w[:3, 0], [0, 1, 0], atol=1e-15)  # right
    with pytest.raises(ValueError, match="up"):
        look_at([0, 0, 4], [0, 0, 0], up=[0, 0, 1])


def test_scaled_keeps_pixel_centres_consistent(rng):
    cams = _cameras(rng, distortion=PHONE)
    half = cams.scaled(2)
    assert half.width.tolist() == [32] * 5 and half.height.tolist() == [24] * 5
    np.testing.assert_allclose(half.fx, cams.fx / 2)
    np.testing.assert_allclose(half.cy, cams.cy / 2)
    points = rng.uniform(-0.5, 0.5, (5, 3))
    px, py = project(cams, np.arange(5), points, **F64)
    hx, hy = project(half, np.arange(5), points, **F64)
    np.testing.assert_allclose(hx.numpy(), px.numpy() / 2)
    np.testing.assert_allclose(hy.numpy(), py.numpy() / 2)
    third = cams.scaled(3)  # 64 / 3 -> 21, 48 / 3 -> 16
    assert third.width[0] == 21 and third.height[0] == 16
    np.testing.assert_allclose(third.fx, cams.fx * 21 / 64)
    np.testing.assert_allclose(third.fy, cams.fy * 16 / 48)


def test_subset_and_len(rng):
    cams = _cameras(rng)
    sub = cams.subset([3, 1])
    assert len(sub) == 2 and sub.names == ["cam3", "cam1"]
    np.testing.assert_array_equal(sub.c2w, cams.c2w[[3, 1]])


def test_cameras_reject_bad_shapes():
    with pytest.raises(ValueError, match="c2w"):
        Cameras(np.eye(4), [1], [1], [0], [0], [2], [2], np.zeros((1, 4)), ["a"])
    with pytest.raises(ValueError, match="distortion"):
        Cameras(np.eye(4)[None], [1], [1], [0], [0], [2], [2], np.zeros(4), ["a"])


def test_normalisation_round_trips(rng):
    norm = Normalisation(center=[1.0, -2.0, 0.5], scale=0.25)
    x = rng.normal(size=(10, 3))
    np.testing.assert_allclose(norm.to_world(norm.to_unit(x)), x)
    np.testing.assert_allclose(norm.to_unit(np.array([5.0, -2.0, 0.5])), [1, 0, 0])
    t = torch.tensor(x, dtype=torch.float32)
    assert torch.allclose(norm.to_world(norm.to_unit(t)), t, atol=1e-6)
    again = Normalisation.from_dict(json.loads(json.dumps(norm.as_dict())))
    np.testing.assert_array_equal(again.center, norm.center)
    assert again.scale == norm.scale


# --- NeRF-synthetic loader ------------------------------------------------------------------------------


def _write_synthetic(root, n_per_split, size=(16, 12), angle=0.69, rng=None, rgba=None):
    """Write transforms_<split>.json + RGBA PNGs; returns {relative path: rgba uint8 array}."""
    rng = rng or np.random.default_rng(1)
    written = {}
    for split, n in n_per_split.items():
        (root / split).mkdir(parents=True, exist_ok=True)
        frames = []
        for i, c2w in enumerate(_orbit(n)):
            image = rgba if rgba is not None else rng.integers(0, 256, (size[1], size[0], 4), dtype=np.uint8)
            Image.fromarray(image, "RGBA").save(root / split / f"r_{i}.png")
            written[f"{split}/r_{i}"] = image
            frames.append({"file_path": f"./{split}/r_{i}", "transform_matrix": c2w.tolist()})
        (root / f"transforms_{split}.json").write_text(
            json.dumps({"camera_angle_x": angle, "frames": frames})
        )
    return written


def test_synthetic_rgba_is_composited_exactly_on_the_background(tmp_path):
    written = _write_synthetic(tmp_path, {"train": 3})
    bg = np.array([0.2, 0.4, 0.6])
    data = load_dataset(tmp_path, background=bg)
    assert data.format == "nerf-synthetic" and data.images.dtype == np.float32
    for k, rgba in enumerate(written.values()):
        a = rgba[..., 3:] / 255.0
        np.testing.assert_allclose(data.images[k], rgba[..., :3] / 255.0 * a + bg * (1 - a), atol=1e-6)
        np.testing.assert_allclose(data.alphas[k], a[..., 0], atol=1e-7)


def test_synthetic_uses_every_split_and_the_focal_formula(tmp_path):
    _write_synthetic(tmp_path, {"train": 3, "val": 2, "test": 2}, size=(16, 12), angle=0.69)
    data = load_dataset(tmp_path)
    assert data.images.shape == (7, 12, 16, 3)
    assert data.cameras.names == ["r_0", "r_1", "r_2", "r_0", "r_1", "r_0", "r_1"]
    np.testing.assert_allclose(data.cameras.fx, 0.5 * 16 / math.tan(0.5 * 0.69))
    np.testing.assert_allclose(data.cameras.fy, data.cameras.fx)
    np.testing.assert_allclose(data.cameras.cx, 8.0)
    np.testing.assert_allclose(data.cameras.cy, 6.0)
    # the left image edge is half the field of view away from the optical axis
    _, dirs = pixel_to_ray(data.cameras, [0], [0.0], [6.0], **F64)
    axis = -data.cameras.c2w[0, :3, 2]
    assert math.acos(float(dirs[0] @ torch.tensor(axis))) == pytest.approx(0.5 * 0.69, abs=1e-12)
    np.testing.assert_allclose(data.normalisation.center, 0)
    assert data.normalisation.scale == pytest.approx(1 / 1.5)
    np.testing.assert_allclose(data.up, [0, 0, 1])
    assert load_dataset(tmp_path, bound=3.0).normalisation.scale == pytest.approx(1 / 3)


def test_every_eighth_view_is_held_out(tmp_path):
    _write_synthetic(tmp_path, {"train": 17}, size=(4, 4))
    data = load_dataset(tmp_path)
    assert data.test_idx.tolist() == [0, 8, 16]
    assert data.train_idx.tolist() == [i for i in range(17) if i % 8]
    assert load_dataset(tmp_path, holdout_every=0).test_idx.size == 0


def test_downscale_area_filters_images_and_scales_intrinsics(tmp_path):
    written = _write_synthetic(tmp_path, {"train": 2}, size=(16, 12))
    bg = np.array([0.0, 1.0, 0.5])
    full = load_dataset(tmp_path, background=bg)
    half = load_dataset(tmp_path, downscale=2, background=bg)
    assert half.images.shape == (2, 6, 8, 3) and half.alphas.shape == (2, 6, 8)
    rgba = next(iter(written.values())) / 255.0
    a = rgba[..., 3:]
    composite = rgba[..., :3] * a + bg * (1 - a)
    block_mean = composite.reshape(6, 2, 8, 2, 3).mean(axis=(1, 3))
    np.testing.assert_allclose(half.images[0], block_mean, atol=1e-6)
    np.testing.assert_allclose(half.alphas[0], a[..., 0].reshape(6, 2, 8, 2).mean(axis=(1, 3)), atol=1e-6)
    np.testing.assert_allclose(half.cameras.fx, full.cameras.fx / 2)
    np.testing.assert_allclose(half.cameras.cx, 4.0)
    np.testing.assert_allclose(half.cameras.cy, 3.0)
    odd = load_dataset(tmp_path, downscale=3)  # 16x12 -> 5x4, not an integer factor in x
    assert odd.images.shape == (2, 4, 5, 3)
    np.testing.assert_allclose(odd.cameras.fx, full.cameras.fx * 5 / 16)
    np.testing.assert_allclose(odd.cameras.cx, 2.5)
    assert odd.images.min() >= 0 and odd.images.max() <= 1


def test_non_integer_downscale_keeps_a_uniform_image_uniform(tmp_path):
    rgba = np.empty((12, 16, 4), np.uint8)
    rgba[...] = [200, 100, 50, 128]
    _write_synthetic(tmp_path, {"train": 1}, size=(16, 12), rgba=rgba)
    data = load_dataset(tmp_path, downscale=3, background=(0.0, 0.0, 1.0))
    a = 128 / 255
    expected = np.array([200, 100, 50]) / 255 * a + np.array([0, 0, 1]) * (1 - a)
    np.testing.assert_allclose(data.images[0], np.broadcast_to(expected, (4, 5, 3)), atol=1e-6)
    np.testing.assert_allclose(data.alphas[0], a, atol=1e-6)


def test_missing_images_are_warned_once_and_skipped(tmp_path, caplog):
    _write_synthetic(tmp_path, {"train": 4}, size=(4, 4))
    (tmp_path / "train" / "r_1.png").unlink()
    (tmp_path / "train" / "r_3.png").unlink()
    with caplog.at_level(logging.WARNING, logger="neural.data"):
        data = load_dataset(tmp_path)
    assert data.cameras.names == ["r_0", "r_2"]
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1
    assert "2 of 4" in warnings[0] and "r_1.png" in warnings[0] and "r_3.png" in warnings[0]


def test_no_images_left_is_an_input_error(tmp_path):
    _write_synthetic(tmp_path, {"train": 2}, size=(4, 4))
    for p in (tmp_path / "train").iterdir():
        p.unlink()
    with pytest.raises(InputError, match="none of the 2 images"):
        load_dataset(tmp_path)


def test_malformed_json_names_the_file(tmp_path):
    (tmp_path / "transforms_train.json").write_text('{"camera_angle_x": 0.7, "frames": [')
    with pytest.raises(InputError, match=r"transforms_train\.json: malformed JSON"):
        load_dataset(tmp_path)


def test_missing_key_names_the_file_frame_and_key(tmp_path):
    _write_synthetic(tmp_path, {"train": 5}, size=(4, 4))
    meta = json.loads((tmp_path / "transforms_train.json").read_text())
    del meta["frames"][3]["transform_matrix"]
    (tmp_path / "transforms_train.json").write_text(json.dumps(meta))
    with pytest.raises(
        InputError, match=r"transforms_train\.json: frame 3 \(\./train/r_3\) has no 'transform_matrix'"
    ):
        load_dataset(tmp_path)


def test_missing_focal_length_is_an_input_error(tmp_path):
    _write_synthetic(tmp_path, {"train": 2}, size=(4, 4))
    meta = json.loads((tmp_path / "transforms_train.json").read_text())
    del meta["camera_angle_x"]
    (tmp_path / "transforms_train.json").write_text(json.dumps(meta))
    message = (
        r"transforms_train\.json: no focal length: neither the top level nor frame 0 \(\./train/r_0\) has"
    )
    with pytest.raises(InputError, match=message + " 'fl_x' or 'camera_angle_x'"):
        load_dataset(tmp_path)


def test_a_directory_without_a_dataset_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="not a dataset"):
        load_dataset(tmp_path)
    with pytest.raises(InputError, match="no such dataset"):
        load_dataset(tmp_path / "nowhere")


def test_images_of_different_sizes_are_an_input_error(tmp_path):
    _write_synthetic(tmp_path, {"train": 2}, size=(4, 4))
    Image.fromarray(np.zeros((5, 4, 4), np.uint8), "RGBA").save(tmp_path / "train" / "r_1.png")
    with pytest.raises(InputError, match=r"r_1\.png: image is 4x5"):
        load_dataset(tmp_path)


# --- instant-ngp / nerfstudio loader --------------------------------------------------------------------


def _write_ngp(root, n=9, target=(1.0, 2.0, 3.0), radius=5.0, rng=None, **shared):
    rng = rng or np.random.default_rng(2)
    (root / "images").mkdir(parents=True, exist_ok=True)
    frames = []
    images = []
    for i, c2w in enumerate(_orbit(n, radius=radius, target=target, height=2.0)):
        image = rng.integers(0, 256, (10, 8, 3), dtype=np.uint8)
        Image.fromarray(image, "RGB").save(root / "images" / f"{i:04d}.png")
        images.append(image)
        frames.append({"file_path": f"images/{i:04d}.png", "transform_matrix": c2w.tolist()})
    meta = {"fl_x": 9.0, "fl_y": 10.0, "cx": 4.2, "cy": 4.9, "w": 8, "h": 10, "aabb_scale": 4, **shared}
    meta["frames"] = frames
    (root / "transforms.json").write_text(json.dumps(meta))
    return meta, images


def test_ngp_intrinsics_distortion_and_per_frame_overrides(tmp_path):
    meta, images = _write_ngp(tmp_path, k1=0.05, k2=-0.01, p1=0.001, p2=-0.002)
    meta["frames"][2]["fl_x"] = 11.0
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    data = load_dataset(tmp_path)
    assert data.format == "instant-ngp" and data.alphas is None
    np.testing.assert_allclose(data.images[4], images[4] / 255.0, atol=1e-7)
    np.testing.assert_allclose(data.cameras.fx, [9, 9, 11, 9, 9, 9, 9, 9, 9])
    np.testing.assert_allclose(data.cameras.fy, 10)
    np.testing.assert_allclose(data.cameras.cx, 4.2)
    np.testing.assert_allclose(data.cameras.cy, 4.9)
    np.testing.assert_allclose(data.cameras.distortion, np.tile([0.05, -0.01, 0.001, -0.002], (9, 1)))
    assert data.cameras.names[0] == "0000"


def test_ngp_normalisation_centres_on_the_point_the_cameras_look_at(tmp_path):
    _write_ngp(tmp_path, target=(1.0, 2.0, 3.0), radius=5.0)
    data = load_dataset(tmp_path)
    np.testing.assert_allclose(data.normalisation.center, [1, 2, 3], atol=1e-9)
    distance = math.hypot(5.0, 2.0)  # every camera: 5 out, 2 up
    assert 1 / data.normalisation.scale == pytest.approx(NGP_CUBE_FRACTION * distance)
    assert data.scene_radius == pytest.approx(4 * NGP_CUBE_FRACTION * distance)
    # cameras on a level circle looking at its centre: the mean of their up vectors is +z
    np.testing.assert_allclose(data.up, [0, 0, 1], atol=1e-12)
    assert load_dataset(tmp_path, bound=2.0).normalisation.scale == pytest.approx(0.5)


def test_ngp_focal_from_camera_angles_and_size_from_the_image(tmp_path):
    meta, _ = _write_ngp(tmp_path)
    for key in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
        del meta[key]
    meta["camera_angle_x"] = 1.0
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    cams = load_dataset(tmp_path, downscale=2).cameras
    assert cams.width[0] == 4 and cams.height[0] == 5
    np.testing.assert_allclose(cams.fx, 0.5 * 8 / math.tan(0.5) / 2)
    np.testing.assert_allclose(cams.fy, cams.fx)
    np.testing.assert_allclose(cams.cx, 2.0)
    np.testing.assert_allclose(cams.cy, 2.5)


def test_ngp_size_that_disagrees_with_the_image_is_an_input_error(tmp_path):
    _write_ngp(tmp_path, w=16)
    message = r"transforms\.json: frame 0 \(images/0000\.png\): 'w' x 'h' = 16x10 but .*0000\.png is 8x10"
    with pytest.raises(InputError, match=message):
        load_dataset(tmp_path)


def test_ngp_fisheye_is_refused(tmp_path):
    _write_ngp(tmp_path, camera_model="OPENCV_FISHEYE")
    with pytest.raises(InputError, match="OPENCV_FISHEYE"):
        load_dataset(tmp_path)


def test_ngp_missing_images_are_skipped(tmp_path, caplog):
    _write_ngp(tmp_path, n=4)
    (tmp_path / "images" / "0002.png").unlink()
    with caplog.at_level(logging.WARNING, logger="neural.data"):
        data = load_dataset(tmp_path)
    assert data.cameras.names == ["0000", "0001", "0003"]
    assert "images/0002.png" in caplog.text


# --- camera files -------------------------------------------------------------------------------------------


def _write_camera_file(path, **shared):
    frames = [{"file_path": f"frames/{i}", "transform_matrix": c.tolist()} for i, c in enumerate(_orbit(3))]
    path.write_text(json.dumps({"camera_angle_x": 0.8, **shared, "frames": frames}))


def test_camera_file_without_images(tmp_path):
    path = tmp_path / "path.json"
    _write_camera_file(path)
    cams = load_camera_file(path, width=20, height=10)
    assert len(cams) == 3 and cams.width.tolist() == [20] * 3 and cams.height.tolist() == [10] * 3
    np.testing.assert_allclose(cams.fx, 10 / math.tan(0.4))
    np.testing.assert_allclose(cams.c2w, _orbit(3))
    with pytest.raises(InputError, match=r"path\.json: no image size"):
        load_camera_file(path)


def test_camera_file_frames_need_no_file_path(tmp_path):
    path = tmp_path / "orbit.json"
    frames = [{"transform_matrix": c.tolist()} for c in _orbit(2)]
    path.write_text(json.dumps({"camera_angle_x": 0.8, "w": 8, "h": 6, "frames": frames}))
    cams = load_camera_file(path)
    assert cams.names == ["frame_0", "frame_1"] and cams.width.tolist() == [8, 8]


def test_camera_file_size_from_keys_or_an_existing_image(tmp_path):
    path = tmp_path / "keys.json"
    _write_camera_file(path, w=40, h=30, fl_x=30.0, cx=21.0)
    cams = load_camera_file(path)
    assert cams.width[0] == 40 and cams.height[0] == 30
    half = load_camera_file(path, width=20, height=15)  # pixel intrinsics follow a requested size
    np.testing.assert_allclose(half.fx, 15.0)
    np.testing.assert_allclose(half.cx, 10.5)

    path = tmp_path / "images.json"
    _write_camera_file(path)
    (tmp_path / "frames").mkdir()
    Image.fromarray(np.zeros((6, 12, 3), np.uint8)).save(tmp_path / "frames" / "1.png")
    cams = load_camera_file(path)
    assert cams.width.tolist() == [12] * 3 and cams.height.tolist() == [6] * 3


# --- odd camera files: one line naming the file, the frame and its file_path, or the top-level key --------


def _rotation_z(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


BAD_POSES = {
    "all zeros": (np.zeros((4, 4)), "is all zeros"),
    "all-zero rotation": (np.diag([0.0, 0.0, 0.0, 1.0]), "all-zero rotation part"),
    "NaN": (np.where(np.eye(4) == 1, np.nan, 0.0), "NaN or infinity"),
    "scaled": (np.diag([2.0, 2.0, 2.0, 1.0]), r"not orthonormal .*column lengths 2, 2, 2"),
    "sheared": (
        np.block([[np.eye(3) + np.triu(np.full((3, 3), 0.3), 1), np.zeros((3, 1))], [0, 0, 0, 1]]),
        "orthonormal",
    ),
    "mirrored": (np.diag([1.0, 1.0, -1.0, 1.0]), "negative determinant: a mirror image"),
    "projective last row": (
        np.vstack([np.eye(4)[:3], [0.0, 0.0, 1.0, 1.0]]),
        "last row 0 0 0 1, got 0 0 1 1",
    ),
    "wrong shape": (np.eye(3), "4x4 or 3x4 matrix"),
}


@pytest.mark.parametrize("kind", BAD_POSES)
@pytest.mark.parametrize("loader", ["nerf-synthetic", "instant-ngp", "camera file"])
def test_a_bad_pose_is_one_line_naming_file_frame_and_path(tmp_path, kind, loader):
    matrix, problem = BAD_POSES[kind]
    if loader == "nerf-synthetic":
        _write_synthetic(tmp_path, {"train": 3}, size=(4, 4))
        path, label = tmp_path / "transforms_train.json", r"frame 1 \(\./train/r_1\)"
    elif loader == "instant-ngp":
        _write_ngp(tmp_path, n=3)
        path, label = tmp_path / "transforms.json", r"frame 1 \(images/0001\.png\)"
    else:
        path, label = tmp_path / "path.json", r"frame 1 \(frames/1\)"
        _write_camera_file(path)
    meta = json.loads(path.read_text())
    meta["frames"][1]["transform_matrix"] = matrix.tolist()
    path.write_text(json.dumps(meta))
    with pytest.raises(InputError) as err:
        load_camera_file(path, 8, 6) if loader == "camera file" else load_dataset(tmp_path)
    message = str(err.value)
    assert "\n" not in message
    assert re.match(rf"{re.escape(str(path))}: {label}: 'transform_matrix' .*{problem}", message), message


def test_poses_within_the_tolerance_load_unchanged(tmp_path):
    """A rotation rounded to 3 decimals (|R^T R - I| ~ 1e-3), and a 3x4 matrix, are poses."""
    path = tmp_path / "path.json"
    rounded = np.eye(4)
    rounded[:3, :3] = np.round(_rotation_z(0.3), 3)
    frames = [{"transform_matrix": rounded.tolist()}, {"transform_matrix": np.eye(4)[:3].tolist()}]
    path.write_text(json.dumps({"camera_angle_x": 0.8, "w": 8, "h": 6, "frames": frames}))
    cams = load_camera_file(path)
    np.testing.assert_array_equal(cams.c2w, [rounded, np.eye(4)])


@pytest.mark.parametrize(
    "key, value, at_top, problem",
    [
        ("camera_angle_x", math.nan, True, "must be a finite number, got nan"),
        ("camera_angle_x", 3.5, True, r"must be a field of view in radians in \(0, pi\), got 3\.5"),
        ("camera_angle_x", 0, False, r"must be a field of view in radians in \(0, pi\), got 0"),
        ("camera_angle_y", math.inf, True, r"must be a finite number, got inf"),
        ("fl_x", -9.0, True, r"must be positive, got -9\.0"),
        ("fl_y", 0, False, "must be positive, got 0"),
        ("cx", "4", True, r"must be a finite number, got '4'"),
        ("cy", math.nan, False, "must be a finite number, got nan"),
        ("w", 0, True, r"must be a positive whole number of pixels, got 0"),
        ("h", 10.5, False, r"must be a positive whole number of pixels, got 10.5"),
        ("k1", math.nan, True, "must be a finite number, got nan"),
        ("k2", True, False, r"must be a finite number, got True"),
        ("p1", math.inf, True, r"must be a finite number, got inf"),
        ("p2", [0.1], False, r"must be a finite number, got \[0\.1\]"),
        ("aabb_scale", -1, True, "must be positive, got -1"),
    ],
)
def test_a_bad_intrinsic_is_one_line_naming_where_it_is(tmp_path, key, value, at_top, problem):
    """A bad top-level key is reported as the file's (not as frame 0's); a per-frame one by its frame."""
    meta, _ = _write_ngp(tmp_path, n=3)
    if key.startswith("camera_angle"):  # an angle is read only without its fl_x / fl_y; a good one at the top
        meta.pop("fl_" + key[-1])
        meta[key] = 0.7
    (meta if at_top else meta["frames"][2])[key] = value
    (tmp_path / "transforms.json").write_text(json.dumps(meta))  # NaN and Infinity as JSON allows
    where = f"top-level '{key}'" if at_top else f"frame 2 (images/0002.png): '{key}'"
    with pytest.raises(InputError) as err:
        load_dataset(tmp_path)
    message = str(err.value)
    assert re.fullmatch(
        rf"{re.escape(str(tmp_path / 'transforms.json'))}: {re.escape(where)} {problem}", message
    )


def test_cameras_refuse_non_finite_values():
    good = dict(
        c2w=np.eye(4)[None],
        fx=[1],
        fy=[1],
        cx=[0],
        cy=[0],
        width=[2],
        height=[2],
        distortion=np.zeros((1, 4)),
        names=["a"],
    )
    Cameras(**good)
    for key, value, words in (
        ("c2w", np.full((1, 4, 4), np.nan), "c2w: expected finite"),
        ("fx", [0.0], "fx: expected positive numbers, got 0.0 at camera 0"),
        ("cy", [np.inf], "cy: expected finite numbers, got inf"),
        ("distortion", np.full((1, 4), np.nan), "distortion: expected finite"),
    ):
        with pytest.raises(ValueError, match=words):
            Cameras(**{**good, key: value})


def test_cameras_all_at_the_centre_they_look_at_is_an_input_error(tmp_path):
    """A turn-on-the-spot capture: every camera at one point, so the ngp rule has no scene size."""
    meta, _ = _write_ngp(tmp_path, n=3)
    for i, frame in enumerate(meta["frames"]):
        c2w = np.eye(4)
        c2w[:3, :3] = _rotation_z(2 * math.pi * i / 3) @ np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])
        frame["transform_matrix"] = c2w.tolist()
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match="every camera sits at the point they look at"):
        load_dataset(tmp_path)
    assert load_dataset(tmp_path, bound=2.0).normalisation.scale == 0.5


def test_a_camera_file_that_is_a_directory_empty_or_not_utf8(tmp_path):
    with pytest.raises(InputError, match="is a directory, not a camera file$"):
        load_camera_file(tmp_path)
    empty = tmp_path / "empty.json"
    empty.write_bytes(b"")
    with pytest.raises(InputError, match=r"empty\.json: the file is empty"):
        load_camera_file(empty)
    latin = tmp_path / "latin.json"
    latin.write_bytes(b'{"frames": [], "note": "caf\xe9"}')
    with pytest.raises(InputError, match=r"latin\.json: not a UTF-8 text file \(byte 0xe9 at offset 27\)$"):
        load_camera_file(latin)


def test_16_bit_grey_images_keep_their_values(tmp_path):
    """PIL's convert('RGB') clips 16-bit grey to 255; the loader scales it by 1/65535 instead."""
    _write_synthetic(tmp_path, {"train": 2}, size=(4, 4))
    grey = np.arange(16, dtype=np.uint16).reshape(4, 4) * 4000
    Image.fromarray(grey).save(tmp_path / "train" / "r_1.png")
    assert Image.open(tmp_path / "train" / "r_1.png").mode.startswith("I;16")
    data = load_dataset(tmp_path)
    np.testing.assert_allclose(data.images[1], np.repeat(grey[:, :, None] / 65535, 3, axis=2), atol=1e-6)
    np.testing.assert_array_equal(data.alphas[1], 1.0)  # no alpha channel: fully covered
    Image.fromarray(grey.astype(np.int32)).save(tmp_path / "train" / "r_1.tif")  # 32-bit 'I'
    meta = json.loads((tmp_path / "transforms_train.json").read_text())
    meta["frames"][1]["file_path"] = "./train/r_1.tif"
    (tmp_path / "transforms_train.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match=r"r_1\.tif: 32-bit 'I' images are not supported"):
        load_dataset(tmp_path)
