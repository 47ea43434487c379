"""``shellsim poses`` (structure from motion with pycolmap) and COLMAP model directories as ``--data``.

The SfM test renders its own scene: a box with a random two-scale colour-block texture on a textured
ground, ray-cast analytically at 160x120 from 24 known cameras on two rings. The recovered camera centres
must match the known ones after a similarity alignment (Umeyama), and the training loader must read
the written ``transforms.json`` as the same cameras.
"""

from __future__ import annotations

import json
import math
import shutil
import sys
from pathlib import Path

import numpy as np
import pycolmap
import pytest
from PIL import Image
from scenes import look_at

from neural.data import load_dataset
from neural.data.colmap import align_similarity
from neural.errors import InputError
from shellsim.cli.main import main

WIDTH, HEIGHT, FOCAL = 160, 120, 140.0
BOX = 0.6  # the box is [-BOX, BOX]^3; the ground is the plane z = -BOX
RING_RADIUS = 3.2
TRUE_K = np.array([[FOCAL, 0, WIDTH / 2], [0, FOCAL, HEIGHT / 2], [0, 0, 1]])


def ring_cameras(n: int = 24) -> np.ndarray:
    """(n, 4, 4) cameras on two interleaved rings (elevations 25 and 40 degrees) looking at the origin."""
    mats = []
    for i in range(n):
        azim, elev = 2 * math.pi * i / n, math.radians(25 if i % 2 == 0 else 40)
        eye = RING_RADIUS * np.array(
            [math.cos(elev) * math.cos(azim), math.cos(elev) * math.sin(azim), math.sin(elev)]
        )
        mats.append(look_at(eye, np.zeros(3)))
    return np.stack(mats)


def _texture(points: np.ndarray, cells: float, table: np.ndarray) -> np.ndarray:
    """(M, 3) colours of random blocks ``cells`` per unit length at ``points`` (M, 3)."""
    idx = np.floor(points * cells).astype(np.int64)
    key = (idx[:, 0] * 73856093) ^ (idx[:, 1] * 19349663) ^ (idx[:, 2] * 83492791)
    return table[key % len(table)]


def render(c2w: np.ndarray, supersample: int = 2) -> np.ndarray:
    """(HEIGHT, WIDTH, 3) uint8 image of the test scene from one OpenGL camera, pinhole ``TRUE_K``."""
    table = np.random.default_rng(7).uniform(0.0, 1.0, (4096, 3))
    s = supersample
    j, i = np.meshgrid((np.arange(WIDTH * s) + 0.5) / s, (np.arange(HEIGHT * s) + 0.5) / s)
    dirs_cam = np.stack([(j - WIDTH / 2) / FOCAL, -(i - HEIGHT / 2) / FOCAL, -np.ones_like(j)], -1)
    dirs = dirs_cam.reshape(-1, 3) @ c2w[:3, :3].T
    origin = c2w[:3, 3]
    colour = np.empty_like(dirs)
    colour[:] = 0.55 + 0.35 * dirs[:, 2:3] / np.linalg.norm(dirs, axis=1, keepdims=True)  # sky
    # ground plane z = -BOX, |x|, |y| < 4
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ground = (-BOX - origin[2]) / dirs[:, 2]
    hit_ground = t_ground > 0
    p = origin + t_ground[:, None] * dirs
    hit_ground &= (np.abs(p[:, 0]) < 4) & (np.abs(p[:, 1]) < 4)
    t_ground = np.where(hit_ground, t_ground, np.inf)
    # box: slab test
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (-BOX - origin) / dirs, (BOX - origin) / dirs
    t_near = np.minimum(t1, t2).max(axis=1)
    t_far = np.maximum(t1, t2).min(axis=1)
    hit_box = (t_near <= t_far) & (t_near > 0)
    t_box = np.where(hit_box, t_near, np.inf)
    box = t_box < t_ground
    ground = ~box & hit_ground
    pb = origin + t_box[box, None] * dirs[box]
    colour[box] = 0.6 * _texture(pb, 5, table) + 0.4 * _texture(pb + 10, 17, table)
    pg = origin + t_ground[ground, None] * dirs[ground]
    colour[ground] = 0.5 * _texture(pg + 50, 3, table) + 0.5 * _texture(pg + 90, 9, table)
    image = colour.reshape(HEIGHT, s, WIDTH, s, 3).mean(axis=(1, 3))
    return np.round(255 * np.clip(image, 0, 1)).astype(np.uint8)


def write_images(directory, cameras: np.ndarray) -> list[str]:
    """Render ``cameras`` (N, 4, 4) into ``directory/view KK.png`` (a space, as phones name photos);
    returns the names."""
    directory.mkdir(parents=True, exist_ok=True)
    names = [f"view {k:02d}.png" for k in range(len(cameras))]
    for name, c2w in zip(names, cameras, strict=True):
        Image.fromarray(render(c2w)).save(directory / name)
    return names


def _error(capsys, argv) -> str:
    capsys.readouterr()
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    return err.splitlines()[-1]


@pytest.fixture(scope="module")
def solved(tmp_path_factory):
    """(true cameras (N, 4, 4), image dir, OUT) after ``shellsim poses`` on the rendered orbit."""
    root = tmp_path_factory.mktemp("orbit")
    cameras = ring_cameras()
    write_images(root / "images", cameras)
    # photos that cannot be posed: unrelated noise, another size, a broken file
    noise = np.random.default_rng(1).integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8)
    Image.fromarray(noise).save(root / "images" / "noise.png")
    Image.fromarray(noise[::2, ::2]).save(root / "images" / "small.png")
    (root / "images" / "broken.jpg").write_bytes(b"\xff\xd8\xff not really a jpeg")
    assert main(["poses", "--images", str(root / "images"), "--out", str(root / "out")]) == 0
    return cameras, root / "images", root / "out"


def test_align_similarity_recovers_a_known_transform(rng):
    src = rng.normal(size=(10, 3))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    rot = q * np.sign(np.linalg.det(q))  # a proper rotation
    dst = 2.5 * src @ rot.T + np.array([1.0, -2.0, 0.5])
    s, r, t = align_similarity(src, dst)
    assert s == pytest.approx(2.5, rel=1e-12)
    np.testing.assert_allclose(r, rot, atol=1e-12)
    np.testing.assert_allclose(t, [1.0, -2.0, 0.5], atol=1e-12)
    mirrored = src * [1, 1, -1]  # the best rotation of a mirror image is still proper
    assert np.linalg.det(align_similarity(mirrored, dst)[1]) == pytest.approx(1.0)


def test_poses_recovers_the_cameras_of_a_rendered_orbit(solved):
    cameras, images, out = solved
    meta = json.loads((out / "transforms.json").read_text())
    frames = meta["frames"]
    assert len(frames) >= 0.9 * len(cameras)
    # nothing dropped silently: every photo is posed or listed with its reason
    unregistered = {Path(u["file_path"]).name: u["reason"] for u in meta["unregistered"]}
    assert unregistered.pop("noise.png") == "not posed by structure from motion"
    assert unregistered.pop("small.png") == "80x60, the other images are 160x120"
    assert unregistered.pop("broken.jpg").startswith("unreadable")
    assert len(frames) + len(unregistered) == len(cameras)
    # file_path relative to OUT; the index in the name is the true camera
    assert all((out / f["file_path"]).resolve().parent == images.resolve() for f in frames)
    true = cameras[[int(f["file_path"][-6:-4]) for f in frames]]
    found = np.array([f["transform_matrix"] for f in frames])
    s, rot, t = align_similarity(found[:, :3, 3], true[:, :3, 3])
    centre_error = np.linalg.norm(s * found[:, :3, 3] @ rot.T + t - true[:, :3, 3], axis=1)
    assert centre_error.max() < 0.01 * 2 * RING_RADIUS  # within 1% of the orbit's diameter
    # OpenGL axes: the aligned camera rotations are the true ones
    angles = [
        math.degrees(math.acos(np.clip((np.trace(rot @ f[:3, :3] @ g[:3, :3].T) - 1) / 2, -1, 1)))
        for f, g in zip(found, true, strict=True)
    ]
    assert max(angles) < 1.0
    # intrinsics: shared OPENCV camera close to the true pinhole
    assert meta["camera_model"] == "OPENCV" and (meta["w"], meta["h"]) == (WIDTH, HEIGHT)
    assert meta["fl_x"] == pytest.approx(FOCAL, rel=0.03) and meta["fl_y"] == pytest.approx(FOCAL, rel=0.03)
    assert abs(meta["k1"]) < 0.1 and abs(meta["k2"]) < 0.1
    # centred on the point the cameras look at (the true origin), up +z, mean camera distance 4
    np.testing.assert_allclose(t, 0.0, atol=0.02 * RING_RADIUS)
    np.testing.assert_allclose(rot @ [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], atol=0.01)
    assert np.linalg.norm(found[:, :3, 3], axis=1).mean() == pytest.approx(4.0, rel=1e-6)


def test_train_loader_reads_poses_output_and_the_colmap_model_alike(solved):
    cameras, images, out = solved
    meta = json.loads((out / "transforms.json").read_text())
    data = load_dataset(out, holdout_every=0)
    assert data.format == "instant-ngp" and len(data) == len(meta["frames"])
    np.testing.assert_allclose(data.cameras.c2w, [f["transform_matrix"] for f in meta["frames"]], atol=1e-12)
    np.testing.assert_allclose(data.cameras.fx, meta["fl_x"])
    np.testing.assert_allclose(data.cameras.distortion[0], [meta[k] for k in ("k1", "k2", "p1", "p2")])
    np.testing.assert_allclose(data.normalisation.center, 0.0, atol=1e-9)  # already centred
    np.testing.assert_allclose(data.up, [0.0, 0.0, 1.0], atol=1e-9)
    # the COLMAP model poses wrote, as a scene directory sparse/0 + images/, loads as the same cameras
    (out / "colmap" / "images").symlink_to(images.resolve())
    model = load_dataset(out / "colmap", holdout_every=0)
    assert model.format == "colmap" and model.cameras.names == data.cameras.names
    np.testing.assert_allclose(model.cameras.c2w, data.cameras.c2w, atol=1e-9)
    np.testing.assert_allclose(model.images, data.images)


def write_colmap_model(root, c2w: np.ndarray, params: list[float], *more_cameras) -> None:
    """A COLMAP scene ``root/sparse/0`` + ``root/images`` for OpenGL cameras ``c2w`` (N, 4, 4) and one
    OPENCV camera ``params`` (fx fy cx cy k1 k2 p1 p2), converted here from first principles.
    ``more_cameras``: (COLMAP model name, params) of further cameras; image k uses camera k % count."""
    rec = pycolmap.Reconstruction()
    for camera_id, (model, values) in enumerate([("OPENCV", params), *more_cameras], start=1):
        camera = pycolmap.Camera.create_from_model_name(camera_id, model, FOCAL, WIDTH, HEIGHT)
        camera.params = values
        rec.add_camera_with_trivial_rig(camera)
    (root / "images").mkdir(parents=True)
    for k, m in enumerate(c2w):
        opencv = m.copy()
        opencv[:3, 1:3] *= -1  # camera y up -> down, looking down -z -> +z
        camera_id = k % (1 + len(more_cameras)) + 1
        image = pycolmap.Image(name=f"view_{k:02d}.png", camera_id=camera_id, image_id=k + 1)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(np.linalg.inv(opencv)[:3]))
        Image.new("RGB", (WIDTH, HEIGHT), (k, 2 * k, 3 * k)).save(root / "images" / image.name)
    (root / "sparse" / "0").mkdir(parents=True)
    rec.write_binary(str(root / "sparse" / "0"))


def test_a_colmap_model_directory_loads_with_its_cameras(tmp_path):
    cameras = ring_cameras(12)
    params = [150.0, 152.0, 81.5, 58.5, 0.05, -0.08, -0.001, 0.0002]
    write_colmap_model(tmp_path, cameras, params)
    for path in (tmp_path, tmp_path / "sparse", tmp_path / "sparse" / "0"):
        data = load_dataset(path, holdout_every=0)
        assert data.format == "colmap" and data.cameras.names == [f"view_{k:02d}" for k in range(12)]
        np.testing.assert_allclose(data.cameras.fx, 150.0)
        np.testing.assert_allclose(data.cameras.fy, 152.0)
        np.testing.assert_allclose(data.cameras.cx, 81.5)
        np.testing.assert_allclose(data.cameras.cy, 58.5)
        np.testing.assert_allclose(data.cameras.distortion, np.tile(params[4:], (12, 1)))
        # the ring looks at the origin with mean up +z: normalising only scales it to distance 4
        np.testing.assert_allclose(data.cameras.c2w[:, :3, :3], cameras[:, :3, :3], atol=1e-9)
        np.testing.assert_allclose(data.cameras.c2w[:, :3, 3], cameras[:, :3, 3] * 4 / RING_RADIUS, atol=1e-9)
        assert data.images[3, 0, 0] * 255 == pytest.approx([3, 6, 9], abs=1e-4)


def test_a_colmap_model_is_a_camera_file_even_without_its_photos(tmp_path):
    """render --cameras takes a COLMAP model like train --data does; cameras need no photos."""
    from neural.data.datasets import load_camera_file

    write_colmap_model(tmp_path, ring_cameras(6), [150.0, 152.0, 81.5, 58.5, 0.05, -0.08, -0.001, 0.0002])
    trained = load_dataset(tmp_path, holdout_every=0).cameras
    shutil.rmtree(tmp_path / "images")
    for path in (tmp_path, tmp_path / "sparse" / "0"):
        cameras = load_camera_file(path, width=WIDTH // 2)
        assert cameras.names == trained.names
        np.testing.assert_allclose(cameras.c2w, trained.c2w, atol=1e-12)
        np.testing.assert_allclose(cameras.fx, 75.0)  # half the width: fx and cx halve
        np.testing.assert_allclose(cameras.cx, 81.5 / 2)
        np.testing.assert_allclose(cameras.distortion, trained.distortion)


def test_a_colmap_model_with_two_cameras_gives_per_frame_intrinsics(tmp_path):
    write_colmap_model(
        tmp_path, ring_cameras(6), [150.0, 152.0, 81.5, 58.5, 0.05, -0.08, -0.001, 0.0002],
        ("SIMPLE_RADIAL", [130.0, 79.0, 61.0, -0.03]),
    )  # fmt: skip
    data = load_dataset(tmp_path, holdout_every=0)
    np.testing.assert_allclose(data.cameras.fx, [150.0, 130.0] * 3)
    np.testing.assert_allclose(data.cameras.fy, [152.0, 130.0] * 3)
    np.testing.assert_allclose(data.cameras.cx, [81.5, 79.0] * 3)
    np.testing.assert_allclose(data.cameras.distortion[1::2], [[-0.03, 0.0, 0.0, 0.0]] * 3)
    np.testing.assert_allclose(data.cameras.distortion[0], [0.05, -0.08, -0.001, 0.0002])


def test_a_colmap_model_of_an_unsupported_camera_model_is_one_line(tmp_path):
    write_colmap_model(tmp_path, ring_cameras(4), [FOCAL, FOCAL, 80, 60, 0, 0, 0, 0])
    rec = pycolmap.Reconstruction(str(tmp_path / "sparse" / "0"))
    fisheye = pycolmap.Camera.create_from_model_name(1, "OPENCV_FISHEYE", FOCAL, WIDTH, HEIGHT)
    rec.cameras[1].model, rec.cameras[1].params = fisheye.model, fisheye.params
    rec.write_binary(str(tmp_path / "sparse" / "0"))
    with pytest.raises(InputError, match="COLMAP camera model OPENCV_FISHEYE is not supported"):
        load_dataset(tmp_path)


def test_a_colmap_model_without_images_or_unreadable_is_an_input_error(tmp_path):
    write_colmap_model(tmp_path, ring_cameras(4), [FOCAL, FOCAL, 80, 60, 0, 0, 0, 0])
    (tmp_path / "images").rename(tmp_path / "photos")
    with pytest.raises(InputError, match="COLMAP model without its photos"):
        load_dataset(tmp_path)
    (tmp_path / "photos").rename(tmp_path / "images")
    (tmp_path / "sparse" / "0" / "cameras.bin").write_bytes(b"\x07" * 64)
    with pytest.raises(InputError, match="cannot read the COLMAP model"):
        load_dataset(tmp_path)


def test_poses_fails_in_one_line_when_too_few_photos_register(tmp_path, capsys, rng):
    (tmp_path / "noise").mkdir()
    for k in range(4):  # unrelated noise: features, but no verified matches
        Image.fromarray(rng.integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8)).save(
            tmp_path / "noise" / f"n{k}.png"
        )
    err = _error(capsys, ["poses", "--images", tmp_path / "noise", "--out", tmp_path / "out"])
    assert err == (
        f"shellsim: error: --images {tmp_path / 'noise'}: only 0 of 4 photos could be posed (needs 3, "
        "--min-registered 0.5): photos need texture and overlap with each other"
    )
    assert not (tmp_path / "out" / "transforms.json").exists()


def test_poses_lists_what_it_cannot_use(tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    err = _error(capsys, ["poses", "--images", empty, "--out", tmp_path / "out"])
    assert err.startswith(f"shellsim: error: {empty}: no readable images (.jpg")
    (empty / "broken.jpg").write_bytes(b"\xff\xd8\xff not really a jpeg")
    (empty / "notes.txt").write_text("not an image")
    err = _error(capsys, ["poses", "--images", empty, "--out", tmp_path / "out", "--overwrite"])
    assert err.endswith("; 1 unreadable")
    err = _error(capsys, ["poses", "--images", tmp_path / "nowhere", "--out", tmp_path / "out"])
    assert err == f"shellsim: error: --images {tmp_path / 'nowhere'}: no such directory"


def test_poses_refuses_to_replace_its_output(solved, capsys):
    _, images, out = solved
    err = _error(capsys, ["poses", "--images", images, "--out", out])
    target = out / "transforms.json"
    assert err == f"shellsim: error: --out {out}: {target} already exists; give --overwrite to replace it"


def test_poses_without_pycolmap_says_how_to_install_it(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "pycolmap", None)  # import pycolmap -> ImportError
    (tmp_path / "images").mkdir()
    err = _error(capsys, ["poses", "--images", tmp_path / "images", "--out", tmp_path / "out"])
    assert err.endswith('pip install -e ".[sfm]"')
