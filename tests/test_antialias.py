"""Anti-aliased frames (:func:`shellsim.film.motion_frames.antialiased`): jittered rays per pixel, averaged.

The scene is an opaque white half-plane on black, one unit in front of a pinhole camera and facing it, with
a slanted edge: its image is the half-plane ``n . (px, py) < c`` in pixel coordinates, so the fraction of a
pixel's square it covers has a closed form (the square clipped by the line, its area by the shoelace
formula), independent of the renderer. Rays come from the real camera model (:func:`camera_rays`), so the
shifted principal point is tested as the renderers see it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from neural.data import Cameras, camera_rays
from shellsim.film.cameras import MOTION_ANTIALIAS
from shellsim.film.motion_frames import antialiased, pixel_offsets
from shellsim.io.png import renderer_identity

W, H = 48, 36
FOCAL = 40.0
NORMAL = np.array([math.cos(0.35), math.sin(0.35)])  # the edge is slanted, not along a pixel row
EDGE = NORMAL @ np.array([W / 2 + 0.3, H / 2 - 0.2])  # the image is n . p < EDGE


def view() -> Cameras:
    """The camera at the origin looking down -z (OpenGL axes), principal point at the centre."""
    return Cameras(np.eye(4)[None], [FOCAL], [FOCAL], [W / 2], [H / 2], [W], [H], np.zeros((1, 4)), ["c"])


def render_half_plane(camera: Cameras) -> tuple[np.ndarray, dict]:
    """(H, W, 3) image of the half-plane through ``camera`` (a possibly shifted copy of :func:`view`): each
    ray meets the plane z = -1 at a point whose pixel coordinates in :func:`view` decide its colour."""
    _, dirs = camera_rays(camera, 0, dtype=torch.float64)
    d = dirs.numpy()
    x, y = d[:, 0] / -d[:, 2], d[:, 1] / -d[:, 2]
    pixel = np.stack([x * FOCAL + W / 2, -y * FOCAL + H / 2], -1)
    hit = (pixel @ NORMAL < EDGE).astype(np.float32).reshape(H, W)
    stats = {"ms": 2.0, "samples_per_pixel": 1.0, "counts": np.ones((H, W), np.int64)}
    return np.repeat(hit[..., None], 3, -1), stats


def clipped_area(square: np.ndarray) -> float:
    """Area of the polygon ``square`` (4, 2) on the side n . p < EDGE (Sutherland-Hodgman, shoelace)."""
    kept = []
    for a, b in zip(square, np.roll(square, -1, 0), strict=True):
        da, db = a @ NORMAL - EDGE, b @ NORMAL - EDGE
        if da < 0:
            kept.append(a)
        if (da < 0) != (db < 0):
            kept.append(a + (b - a) * da / (da - db))
    if len(kept) < 3:
        return 0.0
    p = np.array(kept)
    return 0.5 * abs(float(p[:, 0] @ np.roll(p[:, 1], -1) - p[:, 1] @ np.roll(p[:, 0], -1)))


def coverage() -> np.ndarray:
    """(H, W) exact fraction of each pixel's square (column j, row i: [j, j + 1] x [i, i + 1]) covered."""
    unit = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    return np.array([[clipped_area(unit + (j, i)) for j in range(W)] for i in range(H)])


@pytest.mark.parametrize("samples", [1, 2, 4, 6, 9, 16])
def test_offsets_are_one_per_cell_row_and_column_and_fixed(samples):
    offsets = pixel_offsets(samples)
    assert offsets.shape == (samples, 2)
    assert np.all(offsets >= -0.5) and np.all(offsets < 0.5)
    g = max(d for d in range(1, math.isqrt(samples) + 1) if samples % d == 0)
    cells = np.floor((offsets + 0.5) * (g, samples // g)).astype(int)
    assert len({tuple(c) for c in cells}) == samples  # every cell of the g x h grid holds one offset
    for axis in (0, 1):  # and every one of the samples columns and rows (n-rooks)
        assert len(set(np.floor((offsets[:, axis] + 0.5) * samples).astype(int))) == samples
    np.testing.assert_array_equal(offsets, pixel_offsets(samples))  # deterministic frames
    if samples == 1:
        np.testing.assert_array_equal(offsets, [[0.0, 0.0]])  # the pixel centre


@pytest.mark.parametrize("samples", [0, -1, 2.0])
def test_offsets_refuse_a_count_that_is_not_a_positive_integer(samples):
    with pytest.raises(ValueError, match="samples: expected a positive integer"):
        pixel_offsets(samples)


def test_one_ray_per_pixel_is_the_renderer_itself():
    assert antialiased(render_half_plane, 1) is render_half_plane


def test_edge_pixels_approach_the_area_they_cover():
    """One ray per pixel gives only 0 or 1; jittered rays approach the covered area, better with more; pixels
    wholly on one side stay exactly 0 or 1. Measured: mean |error| over the 49 edge pixels 0.19 (1 ray), 0.076
    (4), 0.031 (16); the largest 0.50, 0.26, 0.094."""
    exact = coverage()
    edge = (exact > 0) & (exact < 1)
    assert edge.sum() > 40  # the edge crosses the image
    errors = {}
    for samples in (1, 4, 16):
        image, stats = antialiased(render_half_plane, samples)(view())
        assert image.shape == (H, W, 3) and image.dtype == np.float32
        assert stats["ms"] == 2.0 * samples and stats["samples_per_pixel"] == samples  # summed over passes
        np.testing.assert_array_equal(stats["counts"], samples)
        value = image[..., 0]
        np.testing.assert_array_equal(value[~edge], exact[~edge])
        if samples == 1:
            assert set(np.unique(value[edge])) <= {0.0, 1.0}
        errors[samples] = float(np.abs(value - exact)[edge].mean())
    assert errors[1] > 0.15 and errors[4] < 0.1 and errors[16] < 0.05
    assert errors[16] < errors[4] < errors[1]


def test_the_rays_per_pixel_are_in_the_frame_record():
    """Changing the rays per pixel renders frames again; one ray keeps the record of frames made before."""

    class Asset:
        background = (1.0, 1.0, 1.0)

        def narrowband_config(self):
            from neural.config import NarrowBandConfig

            return NarrowBandConfig()

    one, four = renderer_identity(Asset(), 1), renderer_identity(Asset(), MOTION_ANTIALIAS)
    assert one == renderer_identity(Asset()) and one != four != renderer_identity(Asset(), 9)
