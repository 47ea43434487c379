"""Anti-aliased frames (:func:`shellsim.film.antialias.antialiased`): jittered rays per pixel, averaged.

The scene is an opaque white half-plane on black, one unit in front of a pinhole camera and facing it, with
a slanted edge: its image is the half-plane ``n . (px, py) < c`` in pixel coordinates, so the fraction of a
pixel's square it covers has a closed form (the square clipped by the line, its area by the shoelace
formula), independent of the renderer. Rays come from the real camera model (:func:`camera_rays`), so the
shifted principal point is tested as the renderers see it.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from neural.data import Cameras, camera_rays
from shellsim.film.antialias import (
    ADAPTIVE_THRESHOLD,
    adaptive,
    antialiased,
    pixel_offsets,
    refine_mask,
    shifted,
)
from shellsim.film.cameras import MOTION_ANTIALIAS
from shellsim.io.png import renderer_identity

W, H = 48, 36
FOCAL = 40.0
NORMAL = np.array([math.cos(0.35), math.sin(0.35)])  # the edge is slanted, not along a pixel row
EDGE = NORMAL @ np.array([W / 2 + 0.3, H / 2 - 0.2])  # the image is n . p < EDGE


def view() -> Cameras:
    """The camera at the origin looking down -z (OpenGL axes), principal point at the centre."""
    return Cameras(np.eye(4)[None], [FOCAL], [FOCAL], [W / 2], [H / 2], [W], [H], np.zeros((1, 4)), ["c"])


def trace_half_plane(camera: Cameras, pixels=None) -> tuple[torch.Tensor, dict]:
    """Colours (P, 3) of the half-plane at the pixels ``pixels`` (row-major; None: all) of ``camera`` (a
    possibly shifted copy of :func:`view`): each ray meets the plane z = -1 at a point whose pixel
    coordinates in :func:`view` decide its colour; ``counts`` 1 where it is white (a "field" was entered)."""
    _, dirs = camera_rays(camera, 0, dtype=torch.float64, pixels=pixels)
    d = dirs.numpy()
    x, y = d[:, 0] / -d[:, 2], d[:, 1] / -d[:, 2]
    pixel = np.stack([x * FOCAL + W / 2, -y * FOCAL + H / 2], -1)
    hit = pixel @ NORMAL < EDGE
    stats = {"ms": 2.0, "counts": hit.astype(np.int64)}
    return torch.as_tensor(np.repeat(hit[:, None], 3, 1), dtype=torch.float32), stats


def render_half_plane(camera: Cameras) -> tuple[np.ndarray, dict]:
    """(H, W, 3) image of :func:`trace_half_plane` through ``camera``, one sample per pixel."""
    colors, stats = trace_half_plane(camera)
    stats = {"ms": 2.0, "samples_per_pixel": 1.0, "counts": np.ones((H, W), np.int64)}
    return colors.numpy().reshape(H, W, 3), stats


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


def test_refine_mask_picks_the_pixels_whose_neighbourhood_varies():
    """A vertical step between columns 9 and 10: columns 9 and 10 see both sides in their 3x3 neighbourhood;
    a step below the threshold, or none, picks nothing; a change of ``entered`` alone picks its two sides."""
    colors = np.zeros((6, 16, 3))
    colors[:, 10:] = 0.5
    picked = refine_mask(colors, np.zeros((6, 16), bool))
    assert set(np.flatnonzero(picked.any(0))) == {9, 10} and picked[:, 9:11].all()
    assert not refine_mask(colors * ADAPTIVE_THRESHOLD, np.zeros((6, 16), bool)).any()
    entered = np.zeros((6, 16), bool)
    entered[2:, :] = True
    picked = refine_mask(np.zeros((6, 16, 3)), entered)
    assert set(np.flatnonzero(picked.any(1))) == {1, 2} and picked[1:3].all()


@pytest.mark.parametrize("samples", [4, 9])
def test_adaptive_rays_equal_full_supersampling_where_they_refine(samples):
    """The refined pixels are those of full supersampling exactly, the others their first ray's colour. On
    the half-plane every pixel the edge crosses is refined (its neighbours' first rays see both sides), so
    the whole image is full supersampling's at a fraction of the rays."""
    full, _ = antialiased(render_half_plane, samples)(view())
    image, stats = adaptive(trace_half_plane, samples)(view())
    first = trace_half_plane(shifted(view(), pixel_offsets(samples)[0]))[0].numpy().reshape(H, W, 3)
    refined = refine_mask(first, first[..., 0] > 0)
    np.testing.assert_array_equal(image[refined], full[refined])
    np.testing.assert_array_equal(image[~refined], first[~refined])
    exact = coverage()
    assert refined[(exact > 0) & (exact < 1)].all()
    np.testing.assert_array_equal(image, full)
    assert 0.04 < stats["refined"] < 0.1  # measured 5.7% (4 rays), 2 pixels by 1.2 rows of 48 x 36
    assert stats["rays_per_pixel"] == 1 + (samples - 1) * stats["refined"]
    assert stats["ms"] == 2.0 * (1 + (samples - 1)) and stats["counts"].shape == (H, W)


def test_adaptive_rays_on_a_lit_scene_are_within_40_db_of_full_supersampling():
    """The scene of ``test_static_world`` (ground, obstacles, meshes, a field and their shadows), 4 rays per
    pixel: the refined pixels are full supersampling's to float32 rounding, the frame within 40 dB of it."""
    from test_static_world import BACKGROUND, LOOK, ball, field_body, static_world
    from test_static_world import view as scene_view

    from neural.metrics import psnr
    from shellsim.film.obstacles import Meshes
    from shellsim.film.renderer import trace_world

    # squares of 0.4 m: at 64 x 48 pixels those of 0.1 m would leave little flat ground
    static, camera = static_world(dataclasses.replace(LOOK, square=0.4)), scene_view()

    def trace(v, pixels=None):
        return trace_world([field_body(1)], v, pixels, BACKGROUND, "cpu", static, Meshes([ball(1)]))

    def render(v):
        colors, stats = trace(v)
        return colors.numpy().reshape(camera.height[0], camera.width[0], 3), stats

    full, _ = antialiased(render, 4)(camera)
    image, stats = adaptive(trace, 4)(camera)
    first = trace(shifted(camera, pixel_offsets(4)[0]))
    refined = refine_mask(
        first[0].numpy().reshape(image.shape), first[1]["counts"].reshape(image.shape[:2]) > 0
    )
    np.testing.assert_allclose(image[refined], full[refined], atol=1e-6)
    assert stats["refined"] == refined.mean()
    assert 0.1 < stats["refined"] < 0.8  # measured 69%: at 64 x 48 pixels edges are most of the frame
    assert psnr(image, full) > 40  # measured 45.6 dB
