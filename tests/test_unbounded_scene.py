"""The synthetic unbounded capture of tests/scenes.py (:func:`scenes.write_unbounded_scene`): it loads as an
instant-ngp dataset without alpha, its images agree with an analytic intersection of the loader's own
rays, every pixel sees geometry, and its room shows parallax (no direction-only map reproduces it)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from PIL import Image
from scenes import (
    SURFACE_OBJECT,
    SURFACE_ROOM,
    SURFACE_TABLE,
    UNBOUNDED,
    pinhole_rays,
    sphere_color,
    trace_unbounded,
    unbounded_object_mask,
    write_unbounded_scene,
)

from neural.data import camera_rays, load_dataset, pixel_to_ray
from neural.data.datasets import NGP_CUBE_FRACTION

N_VIEWS, WIDTH, HEIGHT = 24, 40, 30
CENTER = np.array(UNBOUNDED.object_center)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return write_unbounded_scene(tmp_path_factory.mktemp("unbounded"), N_VIEWS, WIDTH, HEIGHT)


@pytest.fixture(scope="module")
def data(scene):
    return load_dataset(scene, downscale=1)


def object_hits(o: np.ndarray, d: np.ndarray, radius: float = UNBOUNDED.object_radius):
    """The test's own intersection of rays (N, 3) with the object sphere: (hit (N,), normal (N, 3))."""
    oc = o - CENTER
    b = (oc * d).sum(1)
    disc = b * b - (oc * oc).sum(1) + radius**2
    t = -b - np.sqrt(np.maximum(disc, 0))
    return (disc > 0) & (t > 0), (oc + t[:, None] * d) / UNBOUNDED.object_radius


def test_loads_as_an_instant_ngp_capture_without_alpha(scene, data):
    assert data.format == "instant-ngp" and data.alphas is None
    assert data.images.shape == (N_VIEWS, HEIGHT, WIDTH, 3) and len(data.cameras) == N_VIEWS
    assert (len(data.train_idx), len(data.test_idx)) == (21, 3)
    cams = data.cameras
    assert np.all(cams.width == WIDTH) and np.all(cams.height == HEIGHT) and not cams.has_distortion
    np.testing.assert_allclose(cams.fx, UNBOUNDED.focal_per_width * WIDTH)
    np.testing.assert_allclose(cams.fy, cams.fx)
    np.testing.assert_allclose(
        np.stack([cams.cx, cams.cy], 1), np.tile([WIDTH / 2, HEIGHT / 2], (N_VIEWS, 1))
    )
    with Image.open(scene / "images" / "frame_00000.png") as im:
        assert im.mode == "RGB"
    # every camera looks at the target: it is the focus point, the normalisation centre
    np.testing.assert_allclose(data.normalisation.center, UNBOUNDED.target, atol=1e-9)
    distance = np.linalg.norm(cams.c2w[:, :3, 3] - np.array(UNBOUNDED.target), axis=1)
    assert np.all(np.abs(distance - UNBOUNDED.camera_distance) < 0.25)
    bound = 1 / data.normalisation.scale
    assert bound == pytest.approx(NGP_CUBE_FRACTION * distance.mean())
    # the object lies inside the field's cube; the room inside the loader's scene radius (aabb_scale)
    unit = data.normalisation.to_unit(CENTER)
    assert np.all(np.abs(unit) + UNBOUNDED.object_radius * data.normalisation.scale < 1)
    assert data.scene_radius == pytest.approx(bound * UNBOUNDED.aabb_scale)
    assert data.scene_radius > UNBOUNDED.room_radius + np.linalg.norm(UNBOUNDED.target)
    np.testing.assert_allclose(data.up, [0, 0, 1], atol=0.05)


def test_the_image_centre_sees_the_object(data):
    cams = data.cameras
    rows, cols = np.full(N_VIEWS, HEIGHT // 2), np.full(N_VIEWS, WIDTH // 2)
    o, d = pixel_to_ray(cams, np.arange(N_VIEWS), cols + 0.5, rows + 0.5, dtype=torch.float64)
    hit, normal = object_hits(o.numpy(), d.numpy())
    assert hit.all()
    np.testing.assert_allclose(data.images[np.arange(N_VIEWS), rows, cols], sphere_color(normal), atol=0.03)


@pytest.mark.parametrize("i", [0, 5, 13])
def test_loaded_rays_hit_the_object_where_the_writer_drew_it(data, i):
    cams = data.cameras
    o, d = (v.numpy() for v in camera_rays(cams, i, dtype=torch.float64))
    rows, cols = np.meshgrid(np.arange(HEIGHT) + 0.5, np.arange(WIDTH) + 0.5, indexing="ij")
    o_w, d_w = pinhole_rays(cams.c2w[i], cams.fx[i], cams.fy[i], cams.cx[i], cams.cy[i], cols, rows)
    np.testing.assert_allclose(o_w.reshape(-1, 3), o, atol=1e-12)
    np.testing.assert_allclose(d_w.reshape(-1, 3), d, atol=1e-9)  # same pixel centres, y down, -z forward

    hit, normal = object_hits(o, d)
    assert 100 < hit.sum() < 0.4 * WIDTH * HEIGHT  # the object fills about the centre third to half
    np.testing.assert_array_equal(unbounded_object_mask(cams, i).reshape(-1), hit)
    np.testing.assert_array_equal(trace_unbounded(o, d)[1] == SURFACE_OBJECT, hit)
    # away from the silhouette the anti-aliased pixels are the albedo at the exact hit
    inner, _ = object_hits(o, d, 0.8 * UNBOUNDED.object_radius)
    np.testing.assert_array_equal(
        unbounded_object_mask(cams, i, pad=-0.2 * UNBOUNDED.object_radius), inner.reshape(HEIGHT, WIDTH)
    )
    assert inner.sum() > 50
    np.testing.assert_allclose(data.images[i].reshape(-1, 3)[inner], sphere_color(normal[inner]), atol=0.03)


def test_every_pixel_sees_geometry(data):
    images = data.images.reshape(N_VIEWS, -1, 3)
    for constant in (0.0, 1.0):
        assert np.abs(images - constant).max(axis=2).min() > 0.05  # no background colour anywhere
    seen = np.zeros(4, int)
    for i in range(N_VIEWS):
        o, d = (v.numpy() for v in camera_rays(data.cameras, i, dtype=torch.float64))
        rgb, surface, t = trace_unbounded(o, d)
        assert np.all(np.isfinite(t) & (t > 0) & (t <= UNBOUNDED.room_radius + 3))
        assert np.all(np.isin(surface, [SURFACE_OBJECT, SURFACE_TABLE, SURFACE_ROOM]))
        below = (surface == SURFACE_ROOM) & ((o + t[:, None] * d)[:, 2] < 0)
        seen += [(surface == s).any() for s in (SURFACE_OBJECT, SURFACE_TABLE, SURFACE_ROOM)] + [below.any()]
        # the pixels are the traced colours, up to anti-aliasing at edges and on the far table
        assert np.median(np.abs(images[i] - rgb).max(axis=1)) < 0.03
    assert seen.tolist() == [N_VIEWS] * 4  # object, table, room above and room below the table disc


def test_the_room_shows_parallax(data):
    """From another camera position the same directions see other room colours: the room is at a finite
    distance, so a direction-only environment map cannot reproduce it."""
    cams = data.cameras
    o, d = (v.numpy() for v in camera_rays(cams, 0, dtype=torch.float64))
    rgb, surface, _ = trace_unbounded(o, d)
    for j in (6, 12):
        rgb_j, surface_j, _ = trace_unbounded(np.broadcast_to(cams.c2w[j, :3, 3], d.shape), d)
        both = (surface == SURFACE_ROOM) & (surface_j == SURFACE_ROOM)
        assert both.sum() > 100
        assert np.abs(rgb - rgb_j)[both].mean() > 0.05


def test_writing_is_deterministic(scene, tmp_path):
    again = write_unbounded_scene(tmp_path, N_VIEWS, WIDTH, HEIGHT)
    assert (again / "transforms.json").read_text() == (scene / "transforms.json").read_text()
    for k in (0, 7, N_VIEWS - 1):
        name = f"images/frame_{k:05d}.png"
        assert (again / name).read_bytes() == (scene / name).read_bytes()
